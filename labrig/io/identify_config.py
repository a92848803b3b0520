"""The identify config TOML: bounds, fixed values and effects an identification reads
besides the runs (``labrig identify --config``).

Model files are :class:`labrig.model.model.Model` (``Model.load`` / ``Model.save``).
"""
from __future__ import annotations

from labrig.core.errors import ConfigError
from labrig.core.schemas import IdentifyConfig, validate
from labrig.io.config import read_toml
from labrig.model.effectset import EffectSet


def load_identify_config(path) -> dict:
    """An optional identify config TOML (schema :class:`labrig.core.schemas.IdentifyConfig`):
    ``[bounds]`` name = [lo, hi], ``[fixed]`` name = value, ``effects = [...]``.

    Its effects are checked here, as names from a data file: catalogue names, or a user
    effect only from a file trusted with ``--trust-code``.
    """
    if not path:
        return {}
    cfg = validate(IdentifyConfig, read_toml(path, "identify config"), path, ConfigError)
    EffectSet.parse(cfg.effects, origin=f"{path}: key 'effects'")
    return {"bounds": {k: tuple(v) for k, v in cfg.bounds.items()},
            "fixed": dict(cfg.fixed), "effects": list(cfg.effects)}
