"""model.json: a saved model (structure, effects, parameters, fit, data set)."""
from __future__ import annotations

import json
from pathlib import Path

from ..errors import UserError
from ..model.effects import get_effect
from ..model.servo import PLANT_NAMES

FORMAT = "labrig-model/1"


def save_model(model: dict, path: Path | str, overwrite: bool = True) -> Path:
    from ..runs import _atomic_write, _json_default

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    _atomic_write(path, json.dumps(model, indent=2, default=_json_default) + "\n")
    return path


def load_model(path: Path | str) -> dict:
    """Read and check a model file; returns the dict with ``effect_objects`` added."""
    path = Path(path)
    if not path.exists():
        raise UserError(f"{path}: model file not found (make one with `labrig identify DIR -o {path.name}`)")
    try:
        model = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise UserError(f"{path}: not a valid model file ({exc})") from None
    if not isinstance(model, dict) or model.get("format") != FORMAT:
        raise UserError(f"{path}: key 'format' must be \"{FORMAT}\"; is this a labrig model?")
    params = model.get("params")
    if not isinstance(params, dict) or any(
            not isinstance(params.get(k), (int, float)) or not params[k] > 0 for k in PLANT_NAMES):
        raise UserError(f"{path}: key 'params' must give positive R, L, J, B and K")
    model["effect_objects"] = [get_effect(s) for s in model.get("effects", [])]
    for e in model["effect_objects"]:
        ep = model.get("effect_params", {}).get(e.name, {})
        for p in e.params:
            if not isinstance(ep.get(p.name), (int, float)):
                raise UserError(f"{path}: key 'effect_params.{e.name}.{p.name}' missing or not a number")
    return model


def model_start(model: dict) -> dict:
    """Flatten a model's parameters into the ``start`` dict of ``identify``."""
    out = dict(model["params"])
    for e, ps in model.get("effect_params", {}).items():
        for k, v in ps.items():
            out[f"{e}.{k}"] = v
    return out
