"""The exception hierarchy; the CLI maps it to exit codes in one place (cli.py)."""


class LabrigError(Exception):
    """Base of every error labrig raises on purpose."""

    exit_code = 1


class UserError(LabrigError):
    """Bad input, bad option, missing file: the user can fix it (exit 2)."""

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


class Interrupted(LabrigError):
    """The user pressed Ctrl-C (exit 130)."""

    exit_code = 130
