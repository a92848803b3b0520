"""Where a folder's runs come from, read from their sidecars alone: which rig played
each (or which file it was imported from), its drive and its sensors. A station says
this of its folder, and plays into it only runs of the same rig: a sweep never mixes its
runs with another rig's or with imported recordings (a fit of the folder would then be
of two systems at once)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from labrig.io.runs import read_sidecar


@dataclass(frozen=True)
class RunOrigin:
    """One run's origin, as its sidecar states it."""

    name: str
    #: how it was recorded: "sim", "serial", "emulated", "import", ... ("" unsaid)
    source: str
    #: the rig it was recorded on (its file's name), or "imported from FILE"
    rig: str
    #: the file it was imported from, or None
    imported_from: str | None
    drive: str
    axis: str
    #: the position sensor, in words ("encoder, 1320 counts per turn"), or None
    position: str | None

    @property
    def imported(self) -> bool:
        return self.source == "import" or self.imported_from is not None


def _position(sensors: dict, rig: dict) -> str | None:
    k = sensors.get("pos_v_per_rad")
    if not k:
        return None
    linear = rig.get("axis") == "linear"
    if sensors.get("pos_kind") == "encoder":
        per = float(k) if linear else math.tau * float(k)
        return f"encoder, {per:.6g} counts per {'metre' if linear else 'turn'}"
    if sensors.get("pos_kind") is None and float(k) == 1.0:   # imported in physical units
        return f"position in {'m' if linear else 'rad'}"
    return f"pot, {float(k):.4g} V per {'m' if linear else 'rad'}"


class Origins(list):
    """A folder's :class:`RunOrigin` list, which says itself in a line."""

    def describe(self) -> str:
        """"3 runs swept on 'MS150 default (simulated)'; 2 runs imported from a.csv, b.csv
        (voltage drive, rotary; encoder, 1320 counts per turn)"."""
        if not self:
            return "no runs yet"
        parts = []
        swept: dict[str, int] = {}
        for o in self:
            if not o.imported:
                swept[o.rig] = swept.get(o.rig, 0) + 1
        for rig, n in swept.items():
            parts.append(f"{n} run{'s' * (n != 1)} swept on '{rig or 'an unnamed rig'}'")
        imported = [o for o in self if o.imported]
        if imported:
            files = ", ".join(sorted({o.imported_from or o.name for o in imported}))
            kinds = sorted({(o.drive, o.axis, o.position or "no position sensor")
                            for o in imported})
            said = "; ".join(f"{d} drive, {a}; {p}" for d, a, p in kinds)
            n = len(imported)
            parts.append(f"{n} run{'s' * (n != 1)} imported from {files} ({said})")
        return "; ".join(parts)

    def not_played_by(self, rig_name: str) -> "Origins":
        """The runs a rig named ``rig_name`` did not play: imported ones, and those swept
        on another rig."""
        return Origins(o for o in self if o.imported or o.rig != rig_name)


def run_origins(folder: Path | str) -> Origins:
    """Each run's origin in ``folder`` (its ``*.csv`` with a sidecar), by name; a sidecar
    that does not validate is refused as a run file is (exit 2, naming the file)."""
    folder = Path(folder)
    out = Origins()
    for csv in sorted(folder.glob("*.csv")):
        side = csv.with_suffix(".json")
        if not side.exists():
            continue
        meta = read_sidecar(side, csv)
        rig = meta.get("rig", {})
        out.append(RunOrigin(name=csv.stem, source=str(meta.get("source") or ""),
                             rig=str(rig.get("name") or ""),
                             imported_from=meta.get("imported_from"),
                             drive=str(rig.get("drive") or "voltage"),
                             axis=str(rig.get("axis") or "rotary"),
                             position=_position(meta.get("sensors", {}), rig)))
    return out
