"""The exception hierarchy; the CLI maps it to exit codes in one place (cli.py)."""

import signal


class LabrigError(Exception):
    """Base of every error labrig raises on purpose.

    Attributes
    ----------
    exit_code : int
        The command line's exit status for it: 1 (a rig or runtime fault) unless a
        subclass says otherwise (:class:`UserError`: 2).

    Examples
    --------
    >>> import labrig as lr
    >>> try:
    ...     lr.read_runs("no/such/folder")
    ... except lr.LabrigError as exc:
    ...     print(exc.exit_code)
    2
    """

    exit_code = 1


class UserError(LabrigError):
    """Bad input, bad option, missing file: the user can fix it (exit 2).

    The message names a parameter as the Python caller passes it, in backticks:
    "`method`: unknown method 'x'", or with its value, "only with `loop=closed`". The
    command line shows each as its option ("--method", "--loop closed"; see
    ``labrig.commands.options``), so a notebook reads Python and a terminal reads options.

    Attributes
    ----------
    exit_code : int
        2, the command line's status for bad input.

    Examples
    --------
    >>> import labrig as lr
    >>> try:
    ...     lr.identify("data/sweep_default", method="newton")
    ... except lr.UserError as exc:
    ...     print(exc)
    `method`: unknown method 'newton'; choose jfo, pso, co or all
    """

    exit_code = 2


class RunFileError(UserError):
    """A run file (CSV or JSON sidecar) is missing or malformed."""


class ConfigError(UserError):
    """A rig or plan TOML file is missing, malformed or out of range."""


class AnalysisError(UserError):
    """The data cannot support the requested analysis (no edges, too short...)."""


class RigError(LabrigError):
    """The rig or bridge failed: unplugged board, timeout, protocol fault (exit 1)."""

    exit_code = 1


class WriteError(LabrigError, OSError):
    """A file could not be written (the disk full, a quota, no permission): one line naming
    it, exit 1; what was written before it is whole, and no half-written file is left.
    (An OSError too, for code that handles any failed write.)"""

    exit_code = 1


class Interrupted(LabrigError):
    """The user pressed Ctrl-C (exit 130)."""

    exit_code = 130


class Terminated(Interrupted):
    """SIGTERM or SIGHUP stopped a sweep: exit ``128 + signal number`` like a shell reports
    it (143 for SIGTERM, 129 for SIGHUP), so a supervisor can tell it from Ctrl-C (130).

    Parameters
    ----------
    signum : int
        The signal received.
    detail : str
        What the user needs to know, after "terminated by SIGTERM; ".
    """

    def __init__(self, signum: int, detail: str = ""):
        self.signum = int(signum)
        self.exit_code = 128 + self.signum
        text = f"terminated by {signal.Signals(self.signum).name}"
        super().__init__(f"{text}; {detail}" if detail else text)


class FitDiverged(LabrigError):
    """Every start of a fit diverged: its simulation overflowed or went non-finite (exit 1).
    The message says which fit and what to try."""

    exit_code = 1
