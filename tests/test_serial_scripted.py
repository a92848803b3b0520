"""SerialBridge against a scripted board (ScriptedTransport): the driver's handshake, runs,
retries and error paths, frame by frame, without hardware or simavr. The real firmware is
tested through the same driver in test_firmware.py and test_link.py."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from labrig.bridge import protocol as P
from labrig.io.experiment import Experiment
from labrig.bridge.serial import SerialBridge
from labrig.bridge.settings import bridge_settings, dac_word_to_volts, volts_to_dac_word
from labrig.bridge.transport import ScriptedTransport, SerialTransport, ack
from labrig.io.config import RigConfig
from labrig.core.errors import RigError, UserError

VECTORS = json.loads((Path(__file__).resolve().parents[1] / "firmware" / "test_vectors.json").read_text())
RIG = RigConfig()
S = bridge_settings(RIG)
#: what the Uno firmware says in HELLO (firmware/test_vectors.json)
HELLO = next(v["fields"] for v in VECTORS["frames"] if v["name"] == "HELLO")
#: short timeouts: a scripted board answers at once, and silence should cost little
FAST = {"ack_timeout": 0.05, "hello_timeout": 0.3, "tail_s": 0.05}
#: 30 samples at 1 kHz of a constant 1 V
EXP = Experiment(name="hold", waveform="constant", amplitude_v=1.0, lead_in_s=0.0, duration_s=0.03)
WORD = volts_to_dac_word(1.0, S)


def status(**fields) -> tuple[int, bytes]:
    """A STATUS reply: an idle board at 0 V with zero counters, except ``fields``."""
    f = {"samples_sent": 0, "rx_frames_ok": 0, "rx_crc_errors": 0, "rx_overruns": 0,
         "watchdog_trips": 0, "sample_overruns": 0, "state": "idle", "dac_word": 2048, **fields}
    return P.STATUS, P.status_body(**f)


def samples(first: int, n: int) -> tuple[int, bytes]:
    """SAMPLES ``first``..``first + n - 1`` at WORD; tacho counts 512 + index (0 V + index LSBs)."""
    k = np.arange(first, first + n)
    return P.SAMPLES, P.samples_body(first, np.column_stack(
        [np.full(n, WORD), 512 + k, np.full(n, 300), np.full(n, 1023)]))


def damaged_ack(frame: P.Frame) -> bytes:
    """The ACK of ``frame`` with one body bit flipped after its CRC was computed."""
    raw = bytes([P.ACK, 9, frame.type, frame.seq])
    crc = P.crc16(raw).to_bytes(2, "big")
    return P.cobs_encode(raw[:-1] + bytes([raw[-1] ^ 0x01]) + crc) + b"\x00"


#: HELLO_REQ -> HELLO, then the ZERO and STATUS_REQ of SerialBridge.open()
HANDSHAKE = [(P.HELLO_REQ, [(P.HELLO, P.hello_body(**HELLO))]), (P.ZERO, [ack]),
             (P.STATUS_REQ, [status()])]


def sent(t: ScriptedTransport) -> list[str]:
    """The host's frames in order, heartbeats left out (their number depends on timing)."""
    return [f.name for f in t.received if f.type != P.HEARTBEAT]


@pytest.mark.parametrize("case", [v for v in VECTORS["frames"]
                                  if v["type"] in (P.ACK, P.HELLO, P.STATUS, P.DONE, P.ERROR)],
                         ids=lambda v: v["name"])
def test_body_builders_reproduce_the_firmware_vectors(case):
    f = case["fields"]
    body = {P.ACK: lambda: P.ack_body(f["type"], f["seq"]), P.HELLO: lambda: P.hello_body(**f),
            P.STATUS: lambda: P.status_body(**f),
            P.DONE: lambda: P.done_body(f["n_samples"], f["samples_lost"]),
            P.ERROR: lambda: P.error_body(f["name"], f["text"])}[case["type"]]()
    assert body == bytes.fromhex(case["body"])


def test_handshake_run_with_a_gap_done_and_stop():
    script = HANDSHAKE + [
        (P.CONFIGURE, [ack]),
        (P.START, [ack, samples(0, 10), samples(20, 10), (P.DONE, P.done_body(30))]),
        (P.STOP, [ack]),
        (P.STATUS_REQ, [status(samples_sent=30, rx_crc_errors=1)]),
    ]
    t = ScriptedTransport(script)
    with SerialBridge(t, RIG, **FAST) as bridge:
        assert bridge.hello == HELLO
        bridge.configure(EXP)
        bridge.start()
        blocks = list(iter(bridge.read, None))
        bridge.stop()
        c = bridge.counters()
    assert t.remaining == 0
    # leaving the context zeroes the output: the one frame after the script
    assert sent(t) == ["HELLO_REQ", "ZERO", "STATUS_REQ", "CONFIGURE", "START", "STOP",
                       "STATUS_REQ", "ZERO"]
    assert [f.name for f in t.unscripted] == ["ZERO"] and not t.is_open
    # the board was sent the experiment in DAC words: 1 V, 30 samples, +-2.5 V limits
    cfg = P.parse_configure(next(f for f in t.received if f.type == P.CONFIGURE).body)
    assert (cfg["waveform"], cfg["n_samples"], cfg["levels"]) == ("constant", 30, [WORD])
    assert (cfg["dac_zero"], cfg["dac_min"], cfg["dac_max"]) == (2048, 1024, 3072)
    # the gap 10..19 is missing from the index and counted, never filled in
    idx = np.concatenate([b.index for b in blocks])
    assert idx.tolist() == list(range(10)) + list(range(20, 30))
    assert np.allclose(np.concatenate([b.u for b in blocks]), dac_word_to_volts(WORD, S))
    assert np.allclose(np.concatenate([b.tacho for b in blocks]), idx * 20.0 / 1024)
    assert (c["samples"], c["dropped_samples"], c["retries"], c["crc_errors"], c["bad_frames"]) \
        == (20, 10, 0, 0, 0)
    # board counters are this run's: the STATUS at stop less the STATUS at open
    assert (c["board_samples_sent"], c["board_rx_crc_errors"]) == (30, 1)
    assert (c["firmware"], c["port"]) == ("labrig-fw 1.0.0 uno", "scripted")


def test_lost_ack_is_retried_with_the_same_seq():
    t = ScriptedTransport(HANDSHAKE + [(P.CONFIGURE, []), (P.CONFIGURE, [ack])])
    with SerialBridge(t, RIG, **FAST) as bridge:
        bridge.configure(EXP)
        c = bridge.counters()
    tries = [f for f in t.received if f.type == P.CONFIGURE]
    assert len(tries) == 2 and tries[0] == tries[1]   # identical frame: same seq and body
    assert c["retries"] == 1 and t.remaining == 0


def test_start_whose_ack_is_lost_has_started_when_samples_arrive():
    run = [samples(0, 10), samples(10, 10), samples(20, 10), (P.DONE, P.done_body(30))]
    t = ScriptedTransport(HANDSHAKE + [(P.CONFIGURE, [ack]), (P.START, run)])
    with SerialBridge(t, RIG, **FAST) as bridge:
        bridge.configure(EXP)
        bridge.start()
        n = sum(len(b.index) for b in iter(bridge.read, None))
        c = bridge.counters()
    assert sent(t).count("START") == 1   # not sent again: that would restart the run
    assert n == 30 and c["dropped_samples"] == 0 and c["retries"] == 0


def test_error_limit_reply_becomes_a_user_error():
    refuse = (P.ERROR, P.error_body("LIMIT", "level beyond dac_max"))
    t = ScriptedTransport(HANDSHAKE + [(P.CONFIGURE, [refuse])])
    with SerialBridge(t, RIG, **FAST) as bridge:
        with pytest.raises(UserError, match="refused the experiment: level beyond dac_max"):
            bridge.configure(EXP)
    assert sent(t).count("CONFIGURE") == 1   # a refusal is final: no retry


def test_other_board_error_is_a_rig_error_kept_in_the_counters():
    err = (P.ERROR, P.error_body("NOT_CONFIGURED", "start before configure"))
    t = ScriptedTransport(HANDSHAKE + [(P.CONFIGURE, [ack]), (P.START, [err])])
    with SerialBridge(t, RIG, **FAST) as bridge:
        bridge.configure(EXP)
        with pytest.raises(RigError, match="reported NOT_CONFIGURED: start before configure"):
            bridge.start()
        assert bridge.counters()["board_errors"] == [
            "board on scripted reported NOT_CONFIGURED: start before configure"]


def test_garbled_replies_are_counted_and_the_command_retried():
    short_ack = P.encode_frame(P.ACK, 8, b"\x02")   # CRC-valid, body one byte short
    t = ScriptedTransport(HANDSHAKE + [(P.CONFIGURE, [short_ack, damaged_ack]),
                                       (P.CONFIGURE, [ack])])
    with SerialBridge(t, RIG, **FAST) as bridge:
        bridge.configure(EXP)
        c = bridge.counters()
    assert (c["bad_frames"], c["crc_errors"], c["framing_errors"], c["retries"]) == (1, 1, 0, 1)


def test_a_link_that_only_garbles_says_so():
    def board(frame):   # a board behind a bad cable: the handshake gets through, then not
        replies = {P.HELLO_REQ: [(P.HELLO, P.hello_body(**HELLO))], P.ZERO: [ack],
                   P.STATUS_REQ: [status()]}
        return replies.get(frame.type, [damaged_ack])

    with SerialBridge(ScriptedTransport(board), RIG, **FAST) as bridge:
        # a damaged frame shows a board is there: twice the tries before giving up
        with pytest.raises(RigError, match=r"CONFIGURE after 8 tries .*: the link answers but "
                                           r"garbles \(8 damaged frame\(s\), 0 intact\)"):
            bridge.configure(EXP)


def test_a_board_that_stops_answering_asks_whether_it_is_plugged_in():
    t = ScriptedTransport(HANDSHAKE)
    with SerialBridge(t, RIG, **FAST) as bridge:
        with pytest.raises(RigError, match=r"no answer from scripted to CONFIGURE after 4 tries "
                                           r"\(0\.2 s\): is the board plugged in\?$"):
            bridge.configure(EXP)
    assert [f.name for f in t.unscripted] == ["CONFIGURE"] * 4 + ["ZERO"]


def test_a_board_that_never_greets_is_not_running_the_firmware():
    t = ScriptedTransport(lambda frame: [])
    bridge = SerialBridge(t, RIG, **FAST)
    with pytest.raises(RigError, match=r"no hello from scripted within 0\.3 s: is the labrig "
                                       r"firmware on the board and nothing else using the port\?"):
        bridge.open()
    assert not t.is_open and set(sent(t)) == {"HELLO_REQ"}


def test_a_port_string_opens_a_serial_transport(tmp_path):
    port = str(tmp_path / "ttyACM9")
    bridge = SerialBridge(port, RIG)
    assert isinstance(bridge.link, SerialTransport) and bridge.port == port
    with pytest.raises(RigError, match="is the board plugged in and is this its port"):
        bridge.open()


def test_a_host_frame_off_the_script_fails_loudly():
    t = ScriptedTransport([(P.START, [ack])])
    with pytest.raises(RigError, match="the script's next step expects START, the host sent HELLO_REQ"):
        SerialBridge(t, RIG, **FAST).open()
