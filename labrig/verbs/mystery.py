"""Mystery rigs for a class: draw one with hidden physics, write it so a student cannot
read it, reveal it to the instructor, and grade a student's model against it
(:mod:`labrig.io.mystery`)."""
from __future__ import annotations


def new_mystery(seed: int, base_rig=None) -> dict:
    """A rig with its plant perturbed and one or two hidden effects, drawn from ``seed``
    (the same seed, the same rig)."""
    from labrig.io.mystery import new_mystery as _new

    return _new(seed, base_rig)


def write_mystery(doc: dict, path, seed: int | None = None, overwrite: bool = False):
    """Store a mystery rig (``new_mystery``) as a ``.mystery`` file: a rig file ``labrig
    sweep --sim --rig`` plays, that a student cannot read by opening it."""
    from labrig.io.mystery import write_mystery as _write

    return _write(doc, path, seed=seed, overwrite=overwrite)


def reveal(path) -> dict:
    """The truth of a mystery file, for the instructor (``format_reveal`` says it)."""
    from labrig.io.mystery import reveal as _reveal

    return _reveal(path)


def check_mystery(path, model_path, tolerance: float | None = None) -> dict:
    """Grade a student's model file against the mystery rig at ``path``: effects found,
    missed and extra, the plant's Km and tau_m within ``tolerance``."""
    from labrig.io.mystery import PASS_TOLERANCE, check

    return check(path, model_path, PASS_TOLERANCE if tolerance is None else tolerance)


def blind(result: dict) -> dict:
    """A grade (``check_mystery``) with the truth taken out, for the student."""
    from labrig.io.mystery import blind as _blind

    return _blind(result)


def format_reveal(result: dict) -> str:
    from labrig.io.mystery import format_reveal as _fmt

    return _fmt(result)


def format_check(result: dict, blind_mode: bool = False) -> str:
    from labrig.io.mystery import format_check as _fmt

    return _fmt(result, blind_mode)
