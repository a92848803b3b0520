"""The schematic of a :class:`labrig.bridge.wiring.Wiring`, drawn with schemdraw.

Every pin label on the board's symbol is a pin of the wiring's table, and every resistor
of the MS150 output stage carries the value of ``labrig.bridge.circuits.OUTPUT_STAGE``:
the drawing is made from the same description as the table and the firmware's pin map.
"""
from __future__ import annotations

import schemdraw
import schemdraw.elements as elm
import schemdraw.logic as logic

from labrig.bridge import circuits
from labrig.bridge.pins import BOARD_PARTS, PIN_FUNCTIONS

#: vertical pitch of the pins (schemdraw units) and the gap between the blocks
ROW, GAP = 1.0, 5.0


def _pins(names, side, rows, anchors=None, outside=None):
    """IcPins at fixed rows (0 at the top) of a block ``rows`` high: blocks of the same
    height placed at one height have their rows level, so their wires run straight."""
    anchors = anchors or names
    outside = outside or [None] * len(names)
    return [elm.IcPin(name=n, pin=o, side=side, slot=f"{rows - r}/{rows}", anchorname=a)
            for n, r, a, o in zip(names, range(len(names)), anchors, outside) if n is not None]


def _board(w, right, left=(), rows=None):
    """The Arduino: its pins, labelled with the pin and its timer or interrupt."""
    rows = rows or max(len(right), len(left), 4)
    fn = lambda pin: PIN_FUNCTIONS[w.rig_kind][w.board].get(pin)
    pins = _pins(right, "R", rows, [f"p_{p}" if p else None for p in right],
                 [fn(p) for p in right])
    pins += _pins(left, "L", rows, [f"p_{p}" if p else None for p in left], [fn(p) for p in left])
    pins += [elm.IcPin(name="5V", side="T", anchorname="p_5V"),
             elm.IcPin(name="GND", side="B", anchorname="p_GND")]
    name = BOARD_PARTS[w.board][0].replace("Arduino ", "Arduino\n").replace(" Rev3", "")
    return elm.Ic(pins=pins, size=(3.6, (rows + 1) * ROW), pinspacing=ROW, lblsize=11,
                  pinlblsize=10).label(name, "center")


def _estop(w, board) -> None:
    """The E-stop, when the rig has one: a normally-closed push button from its pin (the
    board's left side, bottom row) to GND."""
    if not w.options.get("estop"):
        return
    elm.Line().left(1.2).at(board.absanchors[f"p_{w.pin('estop')}"])
    elm.Button(nc=True).down(1.5).label("E-stop\n(NC)", "top", fontsize=9, ofst=0.2)
    elm.Ground()


def _power(at, up=True, name="+5V"):
    if up:
        elm.Line().up(0.5).at(at)
        elm.Vdd().label(name)
    else:
        elm.Line().down(0.5).at(at)
        elm.Ground()


def draw(w, canvas="svg") -> schemdraw.Drawing:
    """The schematic of wiring ``w`` on ``canvas`` (``"svg"``, ``"matplotlib"`` or an Axes)."""
    d = schemdraw.Drawing(canvas=canvas, show=False)
    d.config(fontsize=11, unit=2.5)
    with d:
        if w.rig_kind == "hbridge":
            _hbridge(w)
        else:
            _ms150(w)
    return d


#: every block is this many pin rows high; the middle row holds the block's name
ROWS = 5


def _hbridge(w) -> None:
    in12 = w.options["drive_mode"] == "in1_in2"
    sense = w.options["current_sense"]
    p = {k: w.pin(k) for k in ("pwm_in1", "dir_in2", "enc_a", "enc_b")}
    a0 = w.pin("current") if sense else None
    index = w.options.get("index_counts", 0) > 0
    # (the middle row is the blocks' names: the index goes below it)
    enc_pins = [p["enc_a"], p["enc_b"]] + ([None, w.pin("index")] if index else [None, None])
    enc_pins += [w.pin("estop")] if w.options.get("estop") else []
    board = _board(w, [p["pwm_in1"], p["dir_in2"], None, None, a0],
                   left=enc_pins, rows=ROWS).right().anchor("center").at((0, 0))
    _power(board.p_5V)
    _power(board.p_GND, up=False)
    _estop(w, board)

    # the encoder, to the board's left: A and B on the interrupt pins, its index on a third
    names = ["A", "B"] + ([None, "I"] if index else [])
    enc = elm.Ic(pins=_pins(names, "R", ROWS, [n.lower() if n else None for n in names])
                 + [elm.IcPin(name="VCC", side="T", anchorname="vcc"),
                    elm.IcPin(name="GND", side="B", anchorname="gnd")],
                 size=(3.0, (ROWS + 1) * ROW), pinspacing=ROW, lblsize=11, pinlblsize=10
                 ).right().anchor("center").at((-3.3 - GAP, 0)).label("quadrature\nencoder",
                                                                     "center")
    elm.Wire("-").at(board.absanchors[f"p_{p['enc_a']}"]).to(enc.a)
    elm.Wire("-").at(board.absanchors[f"p_{p['enc_b']}"]).to(enc.b)
    if index:
        elm.Wire("-").at(board.absanchors[f"p_{w.pin('index')}"]).to(enc.i)
    _power(enc.vcc)
    _power(enc.gnd, up=False)

    # the bridge, to the board's right
    if in12:
        left, name = ["AIN1", "AIN2", None, None, None], "TB6612FNG"
        note = "PWMA, STBY to +5V"
    else:
        left, name = ["ENA", "IN1", None, "IN2", None], "L298N"
        note = "ENA jumper removed"
    pins = _pins(left, "L", ROWS, ["i1", "i2", None, "i3", None])
    pins += _pins(["OUT1", None, None, None, "OUT2"], "R", ROWS, ["o1", None, None, None, "o2"])
    pins += [elm.IcPin(name="VCC", side="T", anchorname="vcc", slot="1/2"),
             elm.IcPin(name="VM", side="T", anchorname="vm", slot="2/2"),
             elm.IcPin(name="GND", side="B", anchorname="gnd")]
    x = 1.8 + GAP + 2.5 + (1.5 if not in12 else 0)
    drv = elm.Ic(pins=pins, size=(5.0, (ROWS + 1) * ROW), pinspacing=ROW, lblsize=11,
                 pinlblsize=10).right().anchor("center").at((x, 0)).label(name, "center")
    drv.side("T", spacing=3.0)
    elm.Label().at((x, -0.4)).label(note, fontsize=9)
    pwm, dirp = board.absanchors[f"p_{p['pwm_in1']}"], board.absanchors[f"p_{p['dir_in2']}"]
    elm.Wire("-").at(pwm).to(drv.i1)
    elm.Wire("-").at(dirp).to(drv.i2)
    if not in12:   # IN1 = DIR, IN2 = not DIR
        tap = elm.Dot().at((dirp[0] + 1.5, dirp[1]))
        elm.Line().down(2 * ROW).at(tap.center)
        logic.Not().right().label("74HC04", "bottom", fontsize=9)
        elm.Wire("-").to(drv.i3)
    if sense:   # the sense amplifier's output, filtered, to A0 (a net named VIOUT)
        elm.Resistor().at(board.absanchors[f"p_{a0}"]).right(2.5).label("1 k", fontsize=9)
        node = elm.Dot()
        elm.Line().right(0.8)
        elm.Label().label("VIOUT", loc="right", fontsize=10)
        elm.Capacitor().down(1.2).at(node.center).label("100 nF", "bottom", fontsize=9)
        elm.Ground()
    _power(drv.vcc)
    _power(drv.gnd, up=False)
    elm.Line().up(0.5).at(drv.vm)
    elm.Vdd().label(f"+{w.options['supply_v']:g} V")
    # the motor across the outputs (through the current-sense amplifier, when there is one)
    elm.Line().right(1.2).at(drv.o1)
    top = elm.Dot()
    if sense:
        elm.Motor().down(2.0)
        elm.MeterA().down(2.4).label("current-sense\namplifier,\nout: VIOUT", "bottom",
                                     fontsize=9, ofst=0.3)
        elm.Line().left().tox(drv.o2[0] + 0.6)
        elm.Line().up().toy(drv.o2)
        elm.Line().left().tox(drv.o2)
    else:
        elm.Motor().down().toy(drv.o2).label("M", "right")
        elm.Line().left().tox(drv.o2)
    elm.Label().at((top.center[0] + 0.7, top.center[1] - (1.0 if sense else 2.0))).label(
        "gear motor,\nencoder on\nits shaft", fontsize=9, loc="right")


def _ms150(w) -> None:
    p = {k: w.pin(k) for k in ("dac_cs", "dac_sck", "dac_sdi", "tacho", "out_pot", "in_pot")}
    board = _board(w, [p["dac_cs"], p["dac_sck"], None, p["dac_sdi"]],
                   left=[p["tacho"], p["out_pot"], None, p["in_pot"]]
                   + ([w.pin("estop")] if w.options.get("estop") else []), rows=ROWS
                   ).right().anchor("center").at((0, 0))
    _power(board.p_5V)
    _power(board.p_GND, up=False)
    _estop(w, board)

    # the MCP4822: function inside, package pin outside
    dac = elm.Ic(pins=_pins(["CS", "SCK", None, "SDI", "LDAC"], "L", ROWS,
                            ["cs", "sck", None, "sdi", "ldac"], ["2", "3", None, "4", "5"])
                 + _pins(["VOUTB", "VOUTA"], "R", ROWS, ["vb", "va"], ["6", "8"])
                 + [elm.IcPin(name="VDD", pin="1", side="T", anchorname="vdd"),
                    elm.IcPin(name="VSS", pin="7", side="B", anchorname="vss")],
                 size=(4.4, (ROWS + 1) * ROW), pinspacing=ROW, lblsize=11, pinlblsize=10
                 ).right().anchor("center").at((1.8 + GAP + 2.2, 0)).label("MCP4822", "center")
    for ours, theirs in (("dac_cs", "cs"), ("dac_sck", "sck"), ("dac_sdi", "sdi")):
        elm.Wire("-").at(board.absanchors[f"p_{p[ours]}"]).to(getattr(dac, theirs))
    elm.Line().left(0.6).at(dac.ldac)
    elm.Ground()
    _power(dac.vdd)
    _power(dac.vss, up=False)

    # the difference amplifier, its resistors' values from the netlist
    r = {name: ohms for name, _, _, ohms in circuits.OUTPUT_STAGE}
    kohm = lambda name: f"{r[name] / 1e3:.3g} k"
    op = elm.Opamp(leads=True).right().anchor("in1").at((dac.vb[0] + 4.5, dac.vb[1]))
    elm.Resistor().right(2.5).at(dac.vb).label(f"R1 {kohm('R1a')}", fontsize=9)  # VOUTB -> -
    minus = elm.Dot()
    elm.Wire("-").to(op.in1)
    elm.Resistor().right(2.5).at(dac.va).label(f"R1 {kohm('R1b')}", "bottom", fontsize=9)
    plus = elm.Dot()                                                           # VOUTA -> +
    elm.Wire("-|").to(op.in2)
    elm.Resistor().down(2.0).at(plus.center).label(f"R2 {kohm('R2b')}", "bottom", fontsize=9)
    elm.Ground()
    elm.Line().up(1.2).at(minus.center)             # R2 from the output to the - input
    elm.Resistor().right().tox(op.out).label(f"R2 {kohm('R2a')}", fontsize=9)
    elm.Line().down().toy(op.out)
    elm.Dot()
    elm.Resistor().right(2.5).at(op.out).label("100 R", fontsize=9)
    elm.Line().right(0.6)
    gain = r["R2a"] / r["R1a"]
    elm.Label().label(f"SA150D input\nu = {gain:.3g} (VA - VB)", loc="right", fontsize=10)

    # the three sensors through their dividers, to the board's left
    for key, name in (("tacho", "tacho"), ("out_pot", "output pot"), ("in_pot", "input pot")):
        pin = board.absanchors[f"p_{p[key]}"]
        elm.Resistor().left(2.5).at(pin).label(f"R1 {circuits.DIVIDER['R1'] / 1e3:.3g} k",
                                                fontsize=9)
        elm.Line().left(0.6)
        elm.Label().label(f"{name} (+-10 V)", loc="left", fontsize=10)
    elm.Label().at((-1.8 - 4.6 - (2.6 if w.options.get("estop") else 0), -2.6)).label(
        f"each input also: R2 {circuits.DIVIDER['R2'] / 1e3:.3g} k to 5 V,\n"
        f"R3 {circuits.DIVIDER['R3'] / 1e3:.3g} k and 100 nF to GND:\n"
        "(s + 10 V) / 4 at the pin, 0..5 V", fontsize=9)
