"""The boards' pins each rig's firmware uses, and what ties them there.

The H-bridge build's map is :data:`labrig.bridge.hbridge.PINS`; the MS150 build's is here.
Both are checked against the firmware's hardware layers (``firmware/labrig_bridge/src``)
through the Arduino core's own pin tables by the tests.
"""
from __future__ import annotations

from labrig.bridge.hbridge import PINS as HBRIDGE_PINS

BOARDS = ("uno", "nano", "mega")

#: the MS150 build's pins, per board (``firmware/labrig_bridge/src/hal_ms150.inc``: SPI to
#: the DAC, the three analog inputs)
MS150_PINS = {
    "uno": {"dac_cs": "D10", "dac_sck": "D13", "dac_sdi": "D11",
            "tacho": "A0", "out_pot": "A1", "in_pot": "A2"},
    "nano": {"dac_cs": "D10", "dac_sck": "D13", "dac_sdi": "D11",
             "tacho": "A0", "out_pot": "A1", "in_pot": "A2"},
    "mega": {"dac_cs": "D53", "dac_sck": "D52", "dac_sdi": "D51",
             "tacho": "A0", "out_pot": "A1", "in_pot": "A2"},
}

#: the alternate function that ties a pin to each rig's firmware (what a builder must not
#: move): a timer's output, an external interrupt, the SPI
PIN_FUNCTIONS = {
    "hbridge": {"uno": {"D9": "OC1A", "D10": "OC1B", "D2": "INT0", "D3": "INT1"},
                "mega": {"D11": "OC1A", "D12": "OC1B", "D2": "INT4", "D3": "INT5"}},
    "ms150": {"uno": {"D10": "SS", "D13": "SCK", "D11": "MOSI"},
              "mega": {"D53": "SS", "D52": "SCK", "D51": "MOSI"}},
}
for _kind in PIN_FUNCTIONS.values():
    _kind["nano"] = _kind["uno"]

BOARD_PARTS = {"uno": ("Arduino Uno R3", "A000066"), "nano": ("Arduino Nano", "A000005"),
               "mega": ("Arduino Mega 2560 Rev3", "A000067")}

__all__ = ["BOARDS", "HBRIDGE_PINS", "MS150_PINS", "PIN_FUNCTIONS", "BOARD_PARTS"]
