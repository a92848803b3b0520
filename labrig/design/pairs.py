"""Which two explanations a proposal tells apart: the pair asked for (``between``), the
model's effect and its usual look-alike, or the first confusable pair a search wrote; the
size that tells them apart and where the model's threshold sits on the input."""
from __future__ import annotations

from pathlib import Path

from labrig.core.errors import UserError
from labrig.core.schemas import read_json
from labrig.model.effects import catalogue_name, get_effect
from labrig.model.model import Model


def default_pair(model: Model, between: str | None) -> tuple:
    """``between="a,b"``; else the model's effect and its usual rival."""
    if between:
        names = [catalogue_name(n.strip()) for n in between.split(",") if n.strip()]
        if len(names) != 2:
            raise UserError(f"`between`: give two effects, e.g. deadband,coulomb_friction; got "
                            f"{between!r}")
        for n in names:
            get_effect(n)   # an unknown name fails here, with the catalogue listed
        if names[0] == names[1]:
            raise UserError("`between`: the two effects must differ")
        return tuple(names)
    for e in model.effects:
        if e.rival:
            return e.name, e.rival
    raise UserError("the model has no effect with a usual look-alike (dead zone, friction, "
                    "stiction, delay, backlash); name the pair with `between=a,b`")


def pair_from_diagnosis(model_path) -> str | None:
    """The first confusable pair of the ``diagnosis.json`` that ``diagnose --auto -o DIR``
    wrote beside the model, as ``"a,b"``; None when there is none. The file is data: its
    names are checked against the catalogue like ``--between``."""
    path = Path(model_path).parent / "diagnosis.json"
    if not path.is_file():
        return None
    doc = read_json(path, "diagnosis", UserError)
    pairs = doc.get("confusable") if isinstance(doc, dict) else None
    if not isinstance(pairs, list) or not pairs:
        return None
    pair = pairs[0].get("pair") if isinstance(pairs[0], dict) else None
    if not (isinstance(pair, list) and len(pair) == 2 and all(isinstance(n, str) for n in pair)):
        raise UserError(f"{path}: key 'confusable.0.pair' is not two effect names; give the "
                        "pair with `between=a,b`")
    return ",".join(proposed_as(n) for n in pair)


def proposed_as(name: str) -> str:
    """The effect a proposal tests in place of ``name`` (the symmetric form of an
    asymmetric one; :attr:`~labrig.model.effect_base.Effect.proposed_as`)."""
    return get_effect(name).proposed_as or name


def threshold_of(model: Model) -> float:
    """The input level where the model's threshold effect acts (V), 0 when it has none."""
    out = []
    for e, ps in model.effect_params.items():
        if "d_v" in ps:
            out.append(ps["d_v"])
        elif "dpos_v" in ps:
            out.append(0.5 * (ps["dpos_v"] + ps["dneg_v"]))
        elif "tc_v" in ps:
            out.append(ps["tc_v"] * (1.0 + ps.get("excess", 0.0)))
    return float(max(out)) if out else 0.0


def varied_key(effect: str, rival: str) -> str:
    """The size that tells ``effect`` from ``rival``: its threshold, or, when the rival is
    the simpler law it contains (Coulomb friction within stiction), the parameter the rival
    lacks (stiction's breakaway excess: at zero the two are the same model)."""
    eff = get_effect(effect)
    if eff.simpler == rival:
        extra = [p.name for p in eff.params
                 if p.name not in {q.name for q in get_effect(rival).params}]
        if len(extra) == 1:
            return extra[0]
    return eff.threshold or ""
