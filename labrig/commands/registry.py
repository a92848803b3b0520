"""The command registry and the one JSON writer every command uses.

Commands register themselves with :func:`command`; ``labrig.cli`` builds the parser
from :data:`COMMANDS`. Nothing imports ``labrig.cli``.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from labrig.core.fileio import dumps
from labrig.core.errors import UserError

#: name -> (function(args), one-line help); each function has a ``configure(parser)``
COMMANDS: dict = {}


def command(name, help, fits=False):
    """Register ``func(args)`` as a subcommand; ``func.configure(parser)`` adds options.
    ``fits``: the command fits models and reports their step metrics (the command line
    starts its step-metrics helper for it, ``labrig.step_helper``)."""
    def deco(func):
        func.fits = fits
        COMMANDS[name] = (func, help)
        return func
    return deco


def emit_json(obj) -> None:
    """Exactly one JSON object on stdout (progress and logs go to stderr).

    Non-finite numbers (an unbounded interval, the rmse of a diverged candidate)
    become null: strict JSON has no inf/nan, and they are results, not bugs.
    """

    sys.stdout.write(dumps(obj))


def float_opt(text: str) -> float:
    """argparse type: a number (a bad one is a usage error, exit 2)."""
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got '{text}'") from None


#: the longest file name (bytes) the usual file systems (ext4, APFS, NTFS) allow
NAME_MAX = 255


def too_long(path: Path | str) -> None:
    """Refuse an output path whose name the file system cannot hold, in one line (the
    OS says "File name too long" only when the file is written, after the work)."""

    path = Path(path)
    shown = str(path) if len(str(path)) <= 60 else str(path)[:40] + "..." + str(path)[-12:]
    for part in path.parts:
        n = len(part.encode("utf-8", "surrogateescape"))
        if n > NAME_MAX:
            raise UserError(f"{shown}: a name in it is {n} bytes long, more than the "
                            f"{NAME_MAX} a file system allows; give a shorter -o")
    if len(str(path).encode("utf-8", "surrogateescape")) > 4000:
        raise UserError(f"{shown}: the path is longer than a file system allows; give a "
                        "shorter -o")


def output_folder(path: Path | str) -> None:
    """An output folder (-o) must be a folder or not exist yet, with a name the file
    system can hold; checked before any work."""
    refuse_existing([path], force=True, what="folder")


def refuse_existing(paths, force: bool, what: str = "file") -> None:
    """Refuse to replace existing output files unless ``--force``.

    Commands call this before any fitting, so a user is not refused after a 30 s wait.
    ``what="folder"``: ``paths[0]`` is the output folder (it may exist; it must not be
    a file) and the rest are the files the command would write into it.
    """

    paths = [Path(p) for p in paths]
    for p in paths:
        too_long(p)
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


def add_loop_option(p) -> None:
    """``--loop``: which inputs a proposal may be (propose, diagnose --ask-rig)."""
    p.add_argument("--loop", choices=("open", "closed", "any"), default="open",
                   help="the proposed inputs: to the amplifier (open, the default), "
                        "references of the rig's analog position loop (closed: its gains "
                        "from a closed-loop run of the data, else --rig's standard loop), "
                        "or whichever separates better (any)")
