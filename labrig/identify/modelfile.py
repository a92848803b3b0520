"""model.json: a saved model (structure, effects, parameters, fit, data set)."""
from __future__ import annotations

import json
from pathlib import Path

from ..errors import UserError
from ..model.effects import parse_effects
from ..schemas import ModelFile, read_json, validate

FORMAT = "labrig-model/1"


def save_model(model: dict, path: Path | str, overwrite: bool = True) -> Path:
    from ..runs import _atomic_write, _json_default

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    _atomic_write(path, json.dumps(model, indent=2, default=_json_default) + "\n")
    return path


def read_model_file(path: Path | str) -> dict:
    """A model file parsed and validated (schema :class:`labrig.schemas.ModelFile`), as a
    plain dict; nothing in it is loaded or run."""
    path = Path(path)
    model = read_json(path, "model file", UserError,
                      f" (make one with `labrig identify DIR -o {path.name}`)")
    if not isinstance(model, dict) or model.get("format") != FORMAT:
        raise UserError(f"{path}: key 'format' must be \"{FORMAT}\"; is this a labrig model?")
    return validate(ModelFile, model, path, UserError).model_dump(exclude_unset=True)


def load_model(path: Path | str) -> dict:
    """Read and check a model file; returns the dict with ``effect_objects`` added.

    Effects are catalogue names; a user effect (FILE.py:Class) loads only if the user
    trusted its file on the command line (``--trust-code``).
    """
    path = Path(path)
    model = read_model_file(path)
    model["effect_objects"] = parse_effects(model.get("effects", []),
                                            origin=f"{path}: key 'effects'")
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


def load_identify_config(path) -> dict:
    """An optional identify config TOML (schema :class:`labrig.schemas.IdentifyConfig`):
    ``[bounds]`` name = [lo, hi], ``[fixed]`` name = value, ``effects = [...]``.

    Its effects are checked here, as names from a data file: catalogue names, or a user
    effect only from a file trusted with ``--trust-code``.
    """
    if not path:
        return {}
    from ..config import _read_toml
    from ..errors import ConfigError
    from ..schemas import IdentifyConfig

    cfg = validate(IdentifyConfig, _read_toml(path, "identify config"), path, ConfigError)
    parse_effects(cfg.effects, origin=f"{path}: key 'effects'")
    return {"bounds": {k: tuple(v) for k, v in cfg.bounds.items()},
            "fixed": dict(cfg.fixed), "effects": list(cfg.effects)}
