"""The command registry and the one JSON writer every command uses.

Commands register themselves with :func:`command`; ``labrig.cli`` builds the parser
from :data:`COMMANDS`. Nothing imports ``labrig.cli``.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

#: name -> (function(args), one-line help); each function has a ``configure(parser)``
COMMANDS: dict = {}


def command(name, help):
    """Register ``func(args)`` as a subcommand; ``func.configure(parser)`` adds options."""
    def deco(func):
        COMMANDS[name] = (func, help)
        return func
    return deco


def emit_json(obj) -> None:
    """Exactly one JSON object on stdout (progress and logs go to stderr).

    Non-finite numbers (an unbounded interval, the rmse of a diverged candidate)
    become null: strict JSON has no inf/nan, and they are results, not bugs.
    """
    from labrig.core.fileio import dumps

    sys.stdout.write(dumps(obj))


def float_opt(text: str) -> float:
    """argparse type: a number (a bad one is a usage error, exit 2)."""
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got '{text}'") from None


def refuse_existing(paths, force: bool, what: str = "file") -> None:
    """Refuse to replace existing output files unless ``--force``.

    Commands call this before any fitting, so a user is not refused after a 30 s wait.
    ``what="folder"``: ``paths[0]`` is the output folder (it may exist; it must not be
    a file) and the rest are the files the command would write into it.
    """
    from labrig.core.errors import UserError

    paths = [Path(p) for p in paths]
    if what == "folder":
        if paths[0].exists() and not paths[0].is_dir():
            raise UserError(f"{paths[0]}: exists and is not a folder; give a folder name for -o")
        paths = paths[1:]
    else:
        for p in paths:
            if p.is_dir():
                raise UserError(f"{p}: is a folder; give a file name for -o")
    existing = [p for p in paths if p.exists()]
    if existing and not force:
        more = f" (and {len(existing) - 1} more output file{'s' * (len(existing) > 2)})" \
            if len(existing) > 1 else ""
        raise UserError(f"{existing[0]}: already exists{more}; add --force to replace it")
