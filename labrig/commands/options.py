"""The library speaks Python, the command line translates: a library message names a
parameter in backticks ("`method`", or with its value "`loop=closed`"; see
:class:`labrig.core.errors.UserError`), and the command line shows it as the option the
user typed ("--method", "--loop closed").
"""
from __future__ import annotations

import re

#: Python parameter named in a library message -> the command-line option that fills it
PARAM_OPTIONS: dict[str, str] = {
    # fitting (identify, diagnose, propose ...)
    "method": "--method",
    "fixed": "--fix",
    "bounds": "--bounds",
    "effects": "--effects",
    "through": "--through",
    "start_state": "--start",
    "model": "--model",
    "seed": "--seed",
    "trust_code": "--trust-code",
    # experiment design (propose)
    "between": "--between",
    "budget_s": "--budget-s",
    "loop": "--loop",
    "rig": "--rig",
    # import (labrig.io.importer.ImportOptions, import_run)
    "mapping": "--map",
    "name": "--name",
    "controller": "--controller",
    "drive": "--drive",
    "axis": "--axis",
    "speed_unit": "--speed-unit",
    "pos_unit": "--pos-unit",
    "time_unit": "--time-unit",
    "tacho_gain": "--tacho-gain",
    "pos_gain": "--pos-gain",
    "pos_offset": "--pos-offset",
    "gear_ratio": "--gear-ratio",
    "amplifier_gain": "--amplifier-gain",
    "input_gain": "--input-gain",
    "current_gain": "--current-gain",
    "speed_window": "--speed-window",
    "input_step": "--input-step",
    "input_measured": "--input-measured",
    "start": "--start",
    "position_gain": "--position-gain",
    "velocity_gain": "--velocity-gain",
    "skip_rows": "--skip-rows",
    "rate_hz": "--rate",
    # the rig and its board (sweep, flash, doctor)
    "port": "--port",
    "board": "--board",
    "board_id": "--board-id",
    "resume": "--resume",
    # mystery, batch, report
    "overwrite": "--force",   # write_mystery's and import_run's
    "mystery": "--mystery",
    "scheduler": "--scheduler",
    "work": "--work",
    # class
    "force": "--force",
    "host": "--host",
}

#: "`name`" or "`name=value`" (a value without a backtick)
_NAMED = re.compile(r"`([A-Za-z_][A-Za-z0-9_]*)(?:=([^`]+))?`")


def translate(message: str) -> str:
    """``message`` as the command line says it: "`name=value`" becomes "--option value"
    and "`name`" becomes "--option" for every name in :data:`PARAM_OPTIONS`; any other
    backticked text is left as it is."""
    def option(m: re.Match) -> str:
        opt = PARAM_OPTIONS.get(m.group(1))
        if opt is None:
            return m.group(0)
        return opt if m.group(2) is None else f"{opt} {m.group(2)}"

    return _NAMED.sub(option, str(message))
