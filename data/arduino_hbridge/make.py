"""Make exercise 5's example logs: what an Arduino sketch driving a 12 V gear motor
through an H-bridge writes to its serial port, one file per square wave.

    python data/arduino_hbridge/make.py [OUT]      (default: this folder; --force to replace)

The runs come from labrig's simulated rig (``configs/rig_arduino_hbridge.toml``, with
``configs/plan_arduino.toml``) and are written in the sketch's own format: ``ms`` (the
board's ``millis()``), ``u_V`` (the commanded voltage, PWM duty x 12 V, 3 decimals as the
sketch prints it) and ``count`` (the encoder's quadrature count). Nothing else: no
sidecar, no units, as a student's log arrives. ``tests/test_arduino_data.py`` checks that
the files here are what this script makes.
"""
from __future__ import annotations

import csv
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent


class Exists(Exception):
    """A log is already there and --force was not given."""


def make(out: Path, force: bool = False) -> list[Path]:
    """Write the logs into ``out``; refuse before writing any if one exists (no --force)."""
    there = sorted(out.glob("step_*.csv"))
    if there and not force:
        raise Exists(f"{there[0]} exists; pass --force to replace the logs")
    out.mkdir(parents=True, exist_ok=True)
    written = []
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run([sys.executable, "-m", "labrig", "sweep", "--sim",
                        "--rig", str(ROOT / "configs" / "rig_arduino_hbridge.toml"),
                        "--plan", str(ROOT / "configs" / "plan_arduino.toml"),
                        "-o", str(Path(tmp) / "runs")], check=True, capture_output=True)
        for src in sorted((Path(tmp) / "runs").glob("sq_*.csv")):
            dst = out / src.name.replace("sq_", "step_")
            with open(src, newline="") as f:
                rows = list(csv.DictReader(f))
            with open(dst, "w", newline="") as f:
                w = csv.writer(f, lineterminator="\n")
                w.writerow(["ms", "u_V", "count"])
                for r in rows:
                    w.writerow([round(float(r["t"]) * 1000), f"{float(r['u']):.3f}",
                                round(float(r["pos"]))])
            written.append(dst)
    return written


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a != "--force"]
    try:
        made = make(Path(args[0]) if args else HERE, force="--force" in sys.argv)
    except Exists as exc:  # a refusal is the user's to fix: one line, exit 2
        print(f"make.py: error: {exc}", file=sys.stderr)
        sys.exit(2)
    for p in made:
        print(f"wrote {p}")
