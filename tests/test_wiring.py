"""The wiring of both rigs: one description drawn, tabled and listed, and the same pins the
firmware drives."""
from __future__ import annotations

import dataclasses
import math
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from labrig.bridge import circuits, hbridge
from labrig.bridge.pins import ESTOP_PINS, MS150_PINS
from labrig.bridge.wiring import wiring
from labrig.io.config import load_rig

from test_hbridge_rig import _arduino_pins

ROOT = Path(__file__).resolve().parents[1]
HBRIDGE = ROOT / "configs" / "rig_arduino_hbridge.toml"
MS150 = ROOT / "configs" / "rig_default.toml"
VARIANTS = Path("/usr/share/arduino/hardware/arduino/avr/variants")


def _rig(path, **bridge):
    """The rig file's rig with other ``[bridge]`` keys; its board left open (the shipped
    H-bridge file names the Uno; these draw every board)."""
    rig = load_rig(path)
    rig.bridge = dataclasses.replace(rig.bridge, **{"board": "", "pins": {}, **bridge})
    return rig


CASES = [(MS150, board, opts) for board in ("uno", "nano", "mega")
         for opts in ({}, {"estop": True})] + [
    (HBRIDGE, board, opts) for board in ("uno", "nano", "mega")
    for opts in ({}, {"drive_mode": "pwm_dir", "off_phase": "coast"}, {"current_sense": True},
                 {"index_counts": 44}, {"index_counts": 44, "estop": True})]


def _texts(svg: bytes) -> list[str]:
    return ["".join(t.itertext()).strip() for t in ET.fromstring(svg).iter()
            if t.tag.endswith("}text")]


@pytest.mark.parametrize("path, board, opts", CASES)
def test_the_drawing_wires_the_pins_of_the_table(path, board, opts):
    """Each signal pin of the table is on the board's symbol, labelled with its timer or
    interrupt, and a drawn wire leaves exactly that pin; the pins are the firmware's map."""
    w = wiring(_rig(path, **opts), board)
    table = w.to_pandas()
    pins = dict(zip(table.signal, table.pin))
    fw = hbridge.PINS[board] if w.rig_kind == "hbridge" else MS150_PINS[board]
    signal_pins = {p for p in pins.values() if p not in ("5V", "GND")}
    optional = {"current": opts.get("current_sense"), "index": opts.get("index_counts")}
    assert signal_pins == {p for k, p in fw.items() if optional.get(k, True)} | (
        {ESTOP_PINS[board]} if opts.get("estop") else set())

    d = w.drawing("svg")
    texts = _texts(d.get_imagedata("svg"))
    for p, fn in zip(table.pin, table.function):
        assert p in texts, (p, texts)
        if fn:
            assert fn in texts, (fn, p)
    board_ic = next(e for e in d.elements if type(e).__name__ == "Ic"
                    and any(f"p_{p}" in e.absanchors for p in signal_pins))
    ends = [e.absanchors[k] for e in d.elements if type(e).__name__ != "Ic"
            for k in ("start", "end") if k in e.absanchors]
    for p in signal_pins:
        at = board_ic.absanchors[f"p_{p}"]
        assert min(math.dist(at, e) for e in ends) < 1e-9, f"no wire leaves {p}"


def test_the_ms150_drawing_carries_the_netlist_values_and_gain():
    """The output stage's resistors are drawn with OUTPUT_STAGE's values, its gain printed
    is R2/R1, and the divider at the pins maps +-10 V onto the ADC's 0..5 V."""
    texts = " ".join(_texts(wiring(_rig(MS150), "uno").drawing("svg").get_imagedata("svg")))
    for name, _, _, ohms in circuits.OUTPUT_STAGE:
        assert f"{name[:2]} {ohms / 1e3:.3g} k" in texts
    gain = circuits.OUTPUT_STAGE[1][3] / circuits.OUTPUT_STAGE[0][3]
    assert f"u = {gain:.3g} (VA - VB)" in texts
    for s in (-10.0, 0.0, 10.0, 3.3):
        assert circuits.divider_node(s) == pytest.approx((s + 10.0) / 4, abs=1e-12)
    # the host's count -> volts, `s = -10 + count x 20/1024` (docs/hardware.md), is the
    # divider inverted at the 10-bit ADC's 5 V reference
    for count in (0, 512, 1023):
        s = -10 + count * 20 / 1024
        assert circuits.divider_node(s) / circuits.ADC_REF_V * 1024 == pytest.approx(count)


def test_the_bill_of_materials_follows_the_rig_file():
    """The parts change with the rig file: the motor's encoder lines and gear ratio from
    its counts, the supply from its range, an inverter only for PWM + DIR on an L298N, the
    sense filter only with current sense; the MS150's resistors are the netlist's."""
    rig = _rig(HBRIDGE)
    bom = wiring(rig, "uno").bom()
    motor = bom[bom.part.str.contains("gear motor")].number.item()
    lines = rig.sensors.encoder_counts_per_unit * 2 * math.pi / (4 * rig.gear_ratio)
    assert motor.startswith(f"{lines:.0f} lines per motor turn, 1:30") and round(lines) == 11
    assert bom.part.str.contains("12 V 2 A").any()
    assert not bom.number.str.contains("74HC04").any()
    l298 = wiring(_rig(HBRIDGE, drive_mode="pwm_dir", current_sense=True), "mega").bom()
    assert l298.number.str.contains("SN74HC04N").any() and l298.number.str.contains("1 k").any()
    assert l298.number.str.contains("A000067").any()
    ms = wiring(_rig(MS150), "uno").bom()
    qty = dict(zip(ms.number, ms.qty))
    r1, r2 = circuits.OUTPUT_STAGE[0][3], circuits.OUTPUT_STAGE[1][3]   # 10 k, 24.3 k
    assert qty[f"{r1 / 1e3:.1f} k 0.1 % 0.25 W"] == 2 + 3   # and the dividers' R2
    assert qty[f"{r2 / 1e3:.1f} k 0.1 % 0.25 W"] == 2 and qty["20.0 k 0.1 % 0.25 W"] == 6
    assert qty["MCP4822-E/P"] == 1


@pytest.mark.parametrize("path", [MS150, HBRIDGE])
def test_docs_bill_of_materials_is_the_generated_one(path):
    """docs/hardware.md lists each rig's parts as `labrig wiring` does (Uno)."""
    doc = (ROOT / "docs" / "hardware.md").read_text()
    w = wiring(_rig(path), "uno")
    for part in w.parts:
        row = f"| {part.qty} | {part.part} | {part.number} | {part.role} |"
        assert row in doc, row


def test_docs_wiring_table_of_the_ms150_is_the_firmware_s():
    """The MS150 wiring table in docs/hardware.md has the pins of MS150_PINS."""
    doc = (ROOT / "docs" / "hardware.md").read_text().split("## Output stage")[0]
    for key, label in (("dac_cs", "DAC chip select"), ("dac_sck", "SPI clock"),
                       ("dac_sdi", "SPI data"), ("tacho", "tacho"), ("out_pot", "output pot")):
        row = next(r for r in doc.splitlines() if r.startswith(f"| {label} |"))
        cells = [c.strip() for c in row.split("|")]
        assert cells[2].split()[0] == MS150_PINS["uno"][key], row
        assert cells[3].split()[0] == MS150_PINS["mega"][key], row


@pytest.mark.skipif(not VARIANTS.exists(), reason="arduino-core-avr not installed")
@pytest.mark.parametrize("board, variant", [("uno", "standard"), ("mega", "mega")])
def test_the_ms150_pins_are_the_ones_its_firmware_drives(board, variant):
    """MS150_PINS against hal_ms150.inc's SPI port bits, through the Arduino core's table."""
    hal = (ROOT / "firmware" / "labrig_bridge" / "src" / "hal_ms150.inc").read_text()
    mega, other = re.search(r"#if defined\(__AVR_ATmega2560__\)\n(.*?)#endif", hal, re.S
                            ).group(1).split("#else")
    defs = dict(re.findall(r"#define (\w+_BIT) P([A-Z]\d)", mega if board == "mega" else other))
    pins = _arduino_pins(variant)
    for key, define in (("dac_cs", "CS_BIT"), ("dac_sck", "SCK_BIT"), ("dac_sdi", "MOSI_BIT")):
        assert pins[MS150_PINS[board][key]] == (defs[define][0], int(defs[define][1])), key


@pytest.mark.skipif(not VARIANTS.exists(), reason="arduino-core-avr not installed")
@pytest.mark.parametrize("board, variant", [("uno", "standard"), ("nano", "standard"),
                                            ("mega", "mega")])
def test_the_estop_pin_is_the_one_the_firmware_reads(board, variant):
    """ESTOP_PINS against the sketch's ESTOP_PIN port and bit, through the Arduino core's
    table; and the wiring table names the switch only when the rig file has one."""
    ino = (ROOT / "firmware" / "labrig_bridge" / "labrig_bridge.ino").read_text()
    mega, other = re.search(r"#if defined\(__AVR_ATmega2560__\)\n(.*?)#endif",
                            ino[ino.index("ESTOP") - 200:], re.S).group(1).split("#else")
    text = mega if board == "mega" else other
    port = re.search(r"#define ESTOP_PIN PIN([A-Z])", text).group(1)
    bit = int(re.search(r"#define ESTOP_BIT (\d)", text).group(1))
    assert _arduino_pins(variant)[ESTOP_PINS[board]] == (port, bit)
    for path in (MS150, HBRIDGE):
        assert "E-stop" not in wiring(_rig(path), board).to_pandas().signal.tolist()
        w = wiring(_rig(path, estop=True), board)
        assert w.pin("estop") == "D7" and "E-stop" in w.to_pandas().signal.tolist()
        assert any("emergency-stop" in p for p in w.bom().part)


def test_wiring_cli_writes_the_four_files_and_refuses_to_overwrite(tmp_path):
    """`labrig wiring -o DIR` writes the schematic (SVG, PNG), the table and the parts
    for the rig file's own board (the shipped H-bridge file names an Uno); a second time
    refuses in one line (exit 2) unless --force; another board than the file's, too."""
    out = tmp_path / "wiring"
    other = subprocess.run([sys.executable, "-m", "labrig", "wiring", "--rig", str(HBRIDGE),
                            "--board", "nano"], capture_output=True, text=True, timeout=120)
    assert other.returncode == 2 and "bridge.board" in other.stderr
    assert len(other.stderr.strip().splitlines()) == 1 and "Traceback" not in other.stderr
    cmd = [sys.executable, "-m", "labrig", "wiring", "--rig", str(HBRIDGE), "-o", str(out)]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "D9" in r.stdout and "OC1A" in r.stdout and "Pololu 713" in r.stdout
    files = {p.name: p for p in out.iterdir()}
    assert set(files) == {"schematic.svg", "schematic.png", "wiring.csv", "bom.csv"}
    assert files["schematic.png"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert files["schematic.png"].stat().st_size > 20_000
    assert "encoder A,D2,INT0" in files["wiring.csv"].read_text()
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert again.returncode == 2 and "--force" in again.stderr
    assert len(again.stderr.strip().splitlines()) == 1 and "Traceback" not in again.stderr
    forced = subprocess.run(cmd + ["--force"], capture_output=True, text=True, timeout=120)
    assert forced.returncode == 0, forced.stderr
    # a copy for a person to look at
    art = ROOT / "tests" / "artefacts"
    art.mkdir(exist_ok=True)
    (art / "wiring_hbridge_uno.png").write_bytes(files["schematic.png"].read_bytes())


@pytest.mark.parametrize("path, name", [(MS150, "wiring_ms150_uno.svg"),
                                        (HBRIDGE, "wiring_hbridge_uno.svg")])
def test_docs_schematics_are_what_the_command_draws(path, name):
    """The schematics shown in docs/hardware.md are `labrig wiring --rig FILE -o DIR`'s
    schematic.svg for the Uno, byte for byte: redraw them with that command when the
    wiring changes."""
    shown = (ROOT / "docs" / "figures" / name).read_text()
    drawn = wiring(_rig(path), "uno").drawing("svg").get_imagedata("svg").decode()
    assert shown == drawn
