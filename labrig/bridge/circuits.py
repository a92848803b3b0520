"""The MS150 bridge's output stage as a netlist, and what an ideal op-amp makes of it.

The one description of the stage's wiring: docs/hardware.md draws it, and the tests solve
this netlist for the output at every DAC word and compare its sign and gain with what the
emulator (``firmware/emulator/harness.c``) and the host's calibration assume.
"""
from __future__ import annotations

import numpy as np

#: the four-resistor difference amplifier: (name, node, node, ohms). VOUTB goes to the
#: inverting input and VOUTA to the non-inverting one, so u = (R2/R1) (VA - VB): the
#: output rises with channel A's word.
OUTPUT_STAGE = (
    ("R1a", "VOUTB", "inv", 10.0e3),
    ("R2a", "out", "inv", 24.3e3),
    ("R1b", "VOUTA", "noninv", 10.0e3),
    ("R2b", "noninv", "GND", 24.3e3),
)
#: the MCP4822 at gain 2x: 2.048 V reference, 12 bits
DAC_VREF, DAC_GAIN, DAC_BITS = 2.048, 2.0, 12


def stage_output(va: float, vb: float, netlist=OUTPUT_STAGE) -> float:
    """The op-amp's output (V) for DAC outputs ``va`` and ``vb``: nodal analysis with an
    ideal op-amp (no input current, its inputs at one voltage, any output current)."""
    fixed = {"VOUTA": va, "VOUTB": vb, "GND": 0.0}
    unknown = sorted({n for _, a, b, _ in netlist for n in (a, b)} - set(fixed))
    idx = {n: i for i, n in enumerate(unknown)}
    rows, rhs = [], []
    for node in ("inv", "noninv"):   # KCL where no current leaves (the op-amp's inputs)
        row, c = np.zeros(len(unknown)), 0.0
        for _, a, b, r in netlist:
            if node not in (a, b):
                continue
            other = b if a == node else a
            row[idx[node]] -= 1 / r
            if other in fixed:
                c -= fixed[other] / r
            else:
                row[idx[other]] += 1 / r
        rows.append(row)
        rhs.append(c)
    row = np.zeros(len(unknown))
    row[idx["inv"]], row[idx["noninv"]] = 1.0, -1.0   # the virtual short
    rows.append(row)
    rhs.append(0.0)
    v = np.linalg.solve(np.array(rows), np.array(rhs))
    return float(v[idx["out"]])


def output_for_word(word: int, zero_word: int = 2048, netlist=OUTPUT_STAGE) -> float:
    """The stage's output for channel A at ``word`` and channel B at ``zero_word``."""
    scale = DAC_GAIN * DAC_VREF / 2 ** DAC_BITS
    return stage_output(word * scale, zero_word * scale, netlist)


#: each analog input's divider (+-10 V sensor -> 0..5 V at the ADC): R1 from the sensor,
#: R2 to the 5 V reference, R3 to ground, all meeting at the ADC node
DIVIDER = {"R1": 20.0e3, "R2": 10.0e3, "R3": 20.0e3}
ADC_REF_V = 5.0


def divider_node(sensor_v: float, divider=DIVIDER) -> float:
    """The ADC node's voltage for a sensor at ``sensor_v``: the three resistors' currents
    into the node sum to zero."""
    g1, g2, g3 = (1 / divider[k] for k in ("R1", "R2", "R3"))
    return (sensor_v * g1 + ADC_REF_V * g2) / (g1 + g2 + g3)
