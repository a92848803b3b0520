"""The boards' pins each rig's firmware uses, what ties them there, and the rule a rig
file's ``[bridge] board`` and ``[bridge.pins]`` must meet.

The pins are not a choice of the rig file: each is the output of the timer that makes the
PWM, an external interrupt that counts the encoder, or the SPI that talks to the DAC, and
the firmware's hardware layers (``firmware/labrig_bridge/src/hal_*.inc``) use them through
their ports (the tests check the two agree through the Arduino core's own pin tables). A
rig file may name its board and state the pins its bench is wired to: they are checked
here, so a bench wired another way is told before anything plays. The wiring table, the
bill of materials and the schematic (``labrig wiring``, :mod:`labrig.bridge.wiring`) are
drawn from these maps.
"""
from __future__ import annotations

from labrig.core.errors import ConfigError, UserError

BOARDS = ("uno", "nano", "mega")

#: the H-bridge build's pins, per board (``hal_hbridge.inc``: Timer1's two outputs, the
#: two external interrupts, the index's interrupt -- a pin change on the Uno and Nano,
#: whose two external interrupts the encoder takes, INT2 on the Mega -- and the current
#: sense's analog input)
HBRIDGE_PINS = {
    "uno": {"pwm_in1": "D9", "dir_in2": "D10", "enc_a": "D2", "enc_b": "D3", "index": "D4",
            "current": "A0"},
    "nano": {"pwm_in1": "D9", "dir_in2": "D10", "enc_a": "D2", "enc_b": "D3", "index": "D4",
             "current": "A0"},
    "mega": {"pwm_in1": "D11", "dir_in2": "D12", "enc_a": "D2", "enc_b": "D3", "index": "D19",
             "current": "A0"},
}

#: the MS150 build's pins, per board (``hal_ms150.inc``: SPI to the DAC, the three analog
#: inputs)
MS150_PINS = {
    "uno": {"dac_cs": "D10", "dac_sck": "D13", "dac_sdi": "D11",
            "tacho": "A0", "out_pot": "A1", "in_pot": "A2"},
    "nano": {"dac_cs": "D10", "dac_sck": "D13", "dac_sdi": "D11",
             "tacho": "A0", "out_pot": "A1", "in_pot": "A2"},
    "mega": {"dac_cs": "D53", "dac_sck": "D52", "dac_sdi": "D51",
             "tacho": "A0", "out_pot": "A1", "in_pot": "A2"},
}

#: the E-stop input of every build (``labrig_bridge.ino``: Uno/Nano PD7, Mega PH4 -- D7 on
#: each), pulled up; a normally-closed switch to GND (``[bridge] estop = true``)
ESTOP_PINS = {"uno": "D7", "nano": "D7", "mega": "D7"}

#: each rig's pin map, by the firmware's name
PINS = {"hbridge": HBRIDGE_PINS, "ms150": MS150_PINS}

#: the alternate function that ties a pin to each rig's firmware (what a builder must not
#: move): a timer's output, an external interrupt, the SPI
PIN_FUNCTIONS = {
    "hbridge": {"uno": {"D9": "OC1A", "D10": "OC1B", "D2": "INT0", "D3": "INT1", "D4": "PCINT20"},
                "mega": {"D11": "OC1A", "D12": "OC1B", "D2": "INT4", "D3": "INT5", "D19": "INT2"}},
    "ms150": {"uno": {"D10": "SS", "D13": "SCK", "D11": "MOSI"},
              "mega": {"D53": "SS", "D52": "SCK", "D51": "MOSI"}},
}
for _kind in PIN_FUNCTIONS.values():
    _kind["nano"] = _kind["uno"]

BOARD_NAMES = {"uno": "an Uno", "nano": "a Nano", "mega": "a Mega 2560"}


def pin_name(value) -> str:
    """A pin as a rig file may write it (``9``, ``"d9"``, ``"D9"``, ``"a0"``) -> ``"D9"``."""
    if isinstance(value, bool):
        raise ValueError(value)
    if isinstance(value, int):
        return f"D{value}"
    text = str(value).strip().upper()
    return text if text[:1] in "DA" and text[1:].isdigit() else f"D{text}" if text.isdigit() \
        else text


def check_pins(firmware: str, board: str, pins: dict, path) -> dict:
    """The ``[bridge.pins]`` of a rig file against the ``firmware``'s map on ``board``.

    Parameters
    ----------
    firmware : {"ms150", "hbridge"}
        The rig file's ``bridge.firmware``.
    board : {"uno", "nano", "mega"} or ""
        The rig file's ``bridge.board`` ("" when it names none).
    pins : dict
        The table as written: signal -> pin (``"D9"``, ``9``, ``"A0"``).
    path : str or Path
        The file, for the messages.

    Returns
    -------
    dict
        The pins by signal, as the firmware names them (``"D9"``).

    Raises
    ------
    ConfigError
        A table without a board, an unknown signal, or a pin the firmware does not use for
        it: naming the key, the pin the build uses, what ties it there and the fix.
    """
    if not pins:
        return {}
    if not board:
        raise ConfigError(f"{path}: key 'bridge.pins' needs 'bridge.board' (uno, nano or mega): "
                          "the firmware's pins differ between boards")
    want = PINS[firmware][board]
    out = {}
    for signal, value in pins.items():
        if signal not in want:
            raise ConfigError(f"{path}: key 'bridge.pins.{signal}': the {firmware} firmware has "
                              f"no such signal; it uses {', '.join(want)}")
        try:
            pin = pin_name(value)
        except ValueError:
            pin = str(value)
        if pin != want[signal]:
            why = PIN_FUNCTIONS[firmware][board].get(want[signal])
            tied = (f" (its {why}: the pin cannot move without rebuilding the firmware's "
                    "timers)") if why else ""
            raise ConfigError(f"{path}: key 'bridge.pins.{signal}' = {value!r}: the {firmware} "
                              f"firmware on {BOARD_NAMES[board]} uses {want[signal]}{tied}; "
                              f"wire {signal} to {want[signal]} and set it so, or remove the key")
        out[signal] = pin
    return out


def board_for(rig, board: str | None) -> str:
    """The board to build, emulate or wire for: ``board`` as given, else the rig file's
    ``bridge.board``, else the Uno.

    Raises
    ------
    UserError
        ``board`` is not one of the three, or differs from the board the rig file names.
    """
    named = getattr(rig.bridge, "board", "") if rig is not None else ""
    if board is None:
        return named or "uno"
    if board not in BOARDS:
        raise UserError(f"board: unknown board {board!r}; choose uno, nano or mega")
    if named and board != named:
        raise UserError(f"board: {board!r}, but the rig file ({rig.source or 'given'}) is built "
                        f"on {BOARD_NAMES[named]} (bridge.board = \"{named}\"); give that "
                        "board, or change the rig file")
    return board
