"""Subcommands, one module each; importing them registers them with the CLI."""
from . import acquisition  # noqa: F401
from . import analysis  # noqa: F401
from . import identification  # noqa: F401
from . import hardware  # noqa: F401
from . import loop  # noqa: F401
from . import demo  # noqa: F401
from . import mystery  # noqa: F401
from . import report  # noqa: F401
from . import propose  # noqa: F401
from . import batch  # noqa: F401
