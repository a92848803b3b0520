"""labrig: a hardware-in-the-loop acquisition and identification station for DC-servo labs."""

__version__ = "0.1.0"
