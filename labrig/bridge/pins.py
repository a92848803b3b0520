"""The boards' pins each rig's firmware uses, and what ties them there.

The maps are the rig file's rules too, so they live with them (:mod:`labrig.io.board_pins`);
this module adds the parts a builder buys. Both maps are checked against the firmware's
hardware layers (``firmware/labrig_bridge/src``) through the Arduino core's own pin tables by
the tests.
"""
from __future__ import annotations

from labrig.io.board_pins import BOARDS, ESTOP_PINS, HBRIDGE_PINS, MS150_PINS, PIN_FUNCTIONS

BOARD_PARTS = {"uno": ("Arduino Uno R3", "A000066"), "nano": ("Arduino Nano", "A000005"),
               "mega": ("Arduino Mega 2560 Rev3", "A000067")}

__all__ = ["BOARDS", "ESTOP_PINS", "HBRIDGE_PINS", "MS150_PINS", "PIN_FUNCTIONS", "BOARD_PARTS"]
