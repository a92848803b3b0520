"""Subcommands, one module each; importing them registers them with the CLI."""
from . import acquisition  # noqa: F401
