"""How to wire each rig's bridge: the wires, the parts, and the schematic drawn from them.

One description per rig, in code: the board's pins come from the firmware's pin maps
(:mod:`labrig.bridge.pins`, each checked against the
firmware's hardware layer and the Arduino core's pin tables by the tests), the MS150's
output stage from :data:`labrig.bridge.circuits.OUTPUT_STAGE`. The drawing, the wiring
table and the bill of materials are all made from these, so they cannot disagree.

Examples
--------
>>> from labrig.io.config import load_rig
>>> w = wiring(load_rig("configs/rig_arduino_hbridge.toml"), board="uno")
>>> w.to_pandas().loc[0, ["signal", "pin", "to"]].tolist()
['PWM / IN1', 'D9', 'AIN1 (TB6612FNG) / IN1 (DRV8833)']
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from labrig.bridge import circuits
from labrig.bridge.pins import BOARD_PARTS, ESTOP_PINS, HBRIDGE_PINS, MS150_PINS, PIN_FUNCTIONS
from labrig.io.board_pins import board_for

@dataclass(frozen=True)
class Wire:
    """One connection from the board: the signal, the board's pin, where it goes."""

    signal: str
    pin: str
    to: str
    note: str = ""


@dataclass(frozen=True)
class Part:
    """A line of the bill of materials. ``number`` is the maker's part number, or for a
    passive part the specification any maker's part meeting it satisfies."""

    qty: int
    part: str
    number: str
    role: str


@dataclass(frozen=True)
class Wiring:
    """The wiring of one rig's bridge to one board.

    Attributes
    ----------
    rig_kind : str
        ``"ms150"`` or ``"hbridge"`` (the rig file's ``[bridge] firmware``).
    board : str
        ``"uno"``, ``"nano"`` or ``"mega"``.
    options : dict
        The rig file's options that change the wiring (H-bridge: drive mode, off phase,
        current sense, index).
    wires : tuple of Wire
    parts : tuple of Part
    """

    rig_kind: str
    board: str
    options: dict
    wires: tuple
    parts: tuple

    def pin(self, signal: str) -> str:
        """The board pin of ``signal`` (a key of the firmware's pin map, or ``estop``)."""
        if signal == "estop":
            return ESTOP_PINS[self.board]
        pins = HBRIDGE_PINS if self.rig_kind == "hbridge" else MS150_PINS
        return pins[self.board][signal]

    def to_pandas(self):
        """The wires as a table: signal, pin, the pin's timer or interrupt, to, note."""
        import pandas as pd

        return pd.DataFrame([{"signal": w.signal, "pin": w.pin,
                              "function": PIN_FUNCTIONS[self.rig_kind][self.board].get(w.pin, ""),
                              "to": w.to, "note": w.note} for w in self.wires])

    def bom(self):
        """The bill of materials as a table: qty, part, number, role."""
        import pandas as pd

        return pd.DataFrame([vars(p) for p in self.parts])

    def drawing(self, canvas="svg"):
        """The schematic as a ``schemdraw.Drawing`` (``canvas``: ``"svg"``,
        ``"matplotlib"`` or a matplotlib Axes)."""
        from labrig.bridge import schematic

        return schematic.draw(self, canvas=canvas)

    def plot(self, ax=None):
        """Draw the schematic on ``ax`` (a new figure when None); returns the Axes."""
        import matplotlib.pyplot as plt

        if ax is None:
            _, ax = plt.subplots(figsize=(11, 6))
        self.drawing(canvas=ax).draw(show=False)
        ax.set_axis_off()
        return ax

    def save(self, folder: Path | str) -> dict[str, Path]:
        """Write ``schematic.svg``, ``schematic.png``, ``wiring.csv`` and ``bom.csv``
        into ``folder`` (created); returns the paths by kind."""
        from labrig.core.fileio import atomic_write

        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        out = {k: folder / n for k, n in (("svg", "schematic.svg"), ("png", "schematic.png"),
                                          ("wiring", "wiring.csv"), ("bom", "bom.csv"))}
        atomic_write(out["svg"], self.drawing("svg").get_imagedata("svg").decode())
        atomic_write(out["wiring"], self.to_pandas().to_csv(index=False))
        atomic_write(out["bom"], self.bom().to_csv(index=False))
        import matplotlib.pyplot as plt

        ax = self.plot()
        fig = ax.figure
        tmp = out["png"].with_name(".schematic.png.tmp")
        fig.savefig(tmp, dpi=110, bbox_inches="tight", format="png")
        plt.close(fig)
        tmp.replace(out["png"])
        return out


def wiring(rig, board: str | None = None) -> Wiring:
    """How to wire ``rig``'s bridge to ``board``: the wires, the parts, the schematic.

    Parameters
    ----------
    rig : labrig.io.config.RigConfig
        The rig file's contents; its ``[bridge]`` says which firmware (MS150 DAC stage or
        H-bridge + encoder) and, for the H-bridge, the drive mode and current sense.
    board : {"uno", "nano", "mega"}, optional
        The Arduino the firmware is built for (default: the rig file's ``bridge.board``,
        else the Uno).

    Returns
    -------
    Wiring
        ``.to_pandas()`` the wiring table, ``.bom()`` the parts, ``.plot(ax)`` and
        ``.drawing()`` the schematic, ``.save(folder)`` all four files.

    Raises
    ------
    UserError
        ``board`` is not one of the three, or not the one the rig file names.
    """
    board = board_for(rig, board)
    b = rig.bridge
    w = _hbridge(rig, board) if b.firmware == "hbridge" else _ms150(board)
    if not b.estop:
        return w
    # the E-stop: a normally-closed switch from D7 to GND (the pin pulled up inside): pressed,
    # or its wire broken, the pin rises and the board stops
    wires = list(w.wires)
    wires.insert(len(wires) - 2, Wire("E-stop", ESTOP_PINS[board], "E-stop switch (NC), other "
                                      "side to GND", "internal pull-up on; open = stop "
                                      "([bridge] estop)"))
    parts = w.parts + (Part(1, "emergency-stop push button", "22 mm, latching, 1 NC contact "
                            "(e.g. Schneider XB5AS8442)", "the E-stop, D7 to GND"),)
    return Wiring(w.rig_kind, board, {**w.options, "estop": True}, tuple(wires), parts)


def _hbridge(rig, board: str) -> Wiring:
    b, p = rig.bridge, HBRIDGE_PINS[board]
    in12 = b.drive_mode == "in1_in2"
    supply = max(abs(v) for v in b.dac_range_v)
    wires = [
        Wire("PWM / IN1", p["pwm_in1"],
             "AIN1 (TB6612FNG) / IN1 (DRV8833)" if in12 else "ENA (L298N, jumper removed)",
             "the PWM on one input, the other input low (or PWM'd for brake)" if in12
             else "the PWM: the bridge conducts while it is high"),
        Wire("DIR / IN2", p["dir_in2"],
             "AIN2 (TB6612FNG) / IN2 (DRV8833)" if in12 else "IN1 (L298N), and IN2 through a 74HC04 inverter",
             "" if in12 else "the direction: IN1 = DIR, IN2 = not DIR"),
        Wire("encoder A", p["enc_a"], "encoder channel A", "internal pull-up on"),
        Wire("encoder B", p["enc_b"], "encoder channel B", "internal pull-up on"),
    ]
    if b.index_counts:
        wires.append(Wire("encoder index", p["index"], "encoder index (Z, I)",
                          f"internal pull-up on; once every {b.index_counts} counts "
                          "([bridge] index_counts)"))
    if b.current_sense:
        s = rig.sensors
        wires.append(Wire("current sense", p["current"],
                          "VIOUT of the current-sense amplifier in the motor lead, through "
                          "1 k / 100 nF", f"{s.current_zero_v:g} V at 0 A, "
                          f"{s.current_v_per_a:g} V per A ([sensors] current_zero_v, "
                          "current_v_per_a)"))
    wires += [Wire("5 V", "5V", "encoder VCC" + (", TB6612FNG VCC, STBY, PWMA" if in12
                                                 else ", L298N +5 V logic (jumper off)")),
              Wire("ground", "GND", "encoder GND, bridge logic GND, motor supply - (one point)")]
    board_name, board_pn = BOARD_PARTS[board]
    parts = [Part(1, board_name, board_pn, "the bridge's controller")]
    if in12:
        parts += [Part(1, "TB6612FNG motor driver carrier", "Pololu 713 (or SparkFun ROB-14451)",
                       "the H-bridge (a DRV8833 carrier, Pololu 2130, wires the same)")]
    else:
        parts += [Part(1, "L298N dual H-bridge module", "ST L298N on a module with 78M05",
                       "the H-bridge (its ENA jumper removed)"),
                  Part(1, "hex inverter", "SN74HC04N", "IN2 = not DIR")]
    per_turn = rig.sensors.encoder_counts_per_unit * 2 * math.pi   # counts per output turn
    lines = per_turn / (b.decoding * rig.gear_ratio)
    parts += [Part(1, "gear motor with Hall quadrature encoder",
                   f"{lines:.0f} lines per motor turn, 1:{rig.gear_ratio:g} (e.g. JGA25-370)",
                   "the plant (what the rig file's counts and gear ratio say)"),
              Part(1, f"{supply:g} V 2 A DC supply", f"{supply:g} V, 2 A, barrel or terminals",
                   "the motor supply"),
              Part(1, "electrolytic capacitor", "470 uF 25 V, low ESR",
                   "across the motor supply at the bridge")]
    if b.current_sense:
        s = rig.sensors
        parts += [Part(1, "bidirectional current-sense amplifier",
                       f"{s.current_v_per_a:g} V/A, {s.current_zero_v:g} V at 0 A "
                       "(e.g. ACS712ELCTR-05B-T: 0.185 V/A, 2.5 V)",
                       "in series with the motor; its output to A0"),
                  Part(1, "resistor", "1 k 1 % 0.25 W", "sense filter"),
                  Part(1, "capacitor", "100 nF C0G/X7R", "sense filter")]
    return Wiring("hbridge", board, {"drive_mode": b.drive_mode, "off_phase": b.off_phase,
                                     "current_sense": b.current_sense, "supply_v": supply,
                                     "index_counts": b.index_counts},
                  tuple(wires), tuple(parts))


def _ms150(board: str) -> Wiring:
    p = MS150_PINS[board]
    gain = {name: ohms for name, _, _, ohms in circuits.OUTPUT_STAGE}
    r1, r2 = gain["R1a"], gain["R2a"]
    wires = (
        Wire("DAC chip select", p["dac_cs"], "MCP4822 pin 2 (CS)"),
        Wire("SPI clock", p["dac_sck"], "MCP4822 pin 3 (SCK)"),
        Wire("SPI data", p["dac_sdi"], "MCP4822 pin 4 (SDI)"),
        Wire("tacho", p["tacho"], "tacho divider node", "+-10 V -> 0..5 V"),
        Wire("output pot", p["out_pot"], "output-pot divider node", "+-10 V -> 0..5 V"),
        Wire("input pot / reference", p["in_pot"], "input-pot divider node", "+-10 V -> 0..5 V"),
        Wire("5 V", "5V", "MCP4822 pin 1 (VDD), dividers' 10 k"),
        Wire("ground", "GND", "MCP4822 pins 5 (LDAC) and 7 (VSS), SA150D 0 V (one star point)"),
    )
    board_name, board_pn = BOARD_PARTS[board]
    parts = (
        Part(1, board_name, board_pn, "the bridge's controller"),
        Part(1, "dual 12-bit SPI DAC", "MCP4822-E/P", "the output, 2.048 V reference"),
        Part(1, "dual op-amp", "TL072CP (or OPA2277PA)", "the difference amplifier, on +-15 V"),
        Part(2, "resistor", f"{r1 / 1e3:.1f} k 0.1 % 0.25 W", "output stage R1 (2)"),
        Part(2, "resistor", f"{r2 / 1e3:.1f} k 0.1 % 0.25 W", "output stage R2 (2)"),
        Part(1, "resistor", "100 R 1 % 0.25 W", "output series, isolates the cable"),
        Part(3, "resistor", f"{circuits.DIVIDER['R2'] / 1e3:.1f} k 0.1 % 0.25 W",
             "dividers' R2 to 5 V (3)"),
        Part(6, "resistor", f"{circuits.DIVIDER['R1'] / 1e3:.1f} k 0.1 % 0.25 W",
             "dividers' R1 and R3 (6)"),
        Part(3, "capacitor", "100 nF C0G", "divider anti-alias"),
        Part(3, "dual Schottky diode", "BAT54S", "ADC input clamps"),
        Part(3, "capacitor", "100 nF X7R", "decoupling: DAC, op-amp rails"),
        Part(1, "capacitor", "10 uF", "DAC supply"),
        Part(1, "proto shield", "any of the board's format, 4 mm sockets or screw terminals",
             "the build"),
    )
    return Wiring("ms150", board, {}, wires, _merged(parts))


def _merged(parts) -> tuple:
    """One line per part number: equal resistors of different roles are one order."""
    out: dict = {}
    for p in parts:
        key = (p.part, p.number)
        if key in out:
            q = out[key]
            out[key] = Part(q.qty + p.qty, q.part, q.number, f"{q.role}, {p.role}")
        else:
            out[key] = p
    return tuple(out.values())
