"""Subcommands, one module each; importing them registers them with the CLI."""
from labrig.commands import acquisition  # noqa: F401
from labrig.commands import analysis  # noqa: F401
from labrig.commands import identification  # noqa: F401
from labrig.commands import hardware  # noqa: F401
from labrig.commands import loop  # noqa: F401
from labrig.commands import demo  # noqa: F401
from labrig.commands import mystery  # noqa: F401
from labrig.commands import report  # noqa: F401
from labrig.commands import propose  # noqa: F401
from labrig.commands import batch  # noqa: F401
from labrig.commands import lab  # noqa: F401
from labrig.commands import classroom  # noqa: F401
