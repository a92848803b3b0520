"""The package version, in one place (the CLI, the report and the bridge handshake quote it)."""

__version__ = "0.1.0"
