"""The command registry and the one JSON writer every command uses.

Commands register themselves with :func:`command`; ``labrig.cli`` builds the parser
from :data:`COMMANDS`. Nothing imports ``labrig.cli``.
"""
from __future__ import annotations

import argparse
import sys

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
    from ..fileio import dumps

    sys.stdout.write(dumps(obj))


def float_opt(text: str) -> float:
    """argparse type: a number (a bad one is a usage error, exit 2)."""
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got '{text}'") from None
