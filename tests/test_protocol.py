"""The Python frame codec against firmware/test_vectors.json (also checked by the C tests),
plus property/fuzz tests of the stream decoder."""
import json
import random
from pathlib import Path

import pytest
from hypothesis import given, settings, strategies as st

from labrig.bridge import protocol as P

VECTORS = json.loads((Path(__file__).resolve().parents[1] / "firmware" / "test_vectors.json").read_text())


def test_crc_vectors():
    assert P.crc16(b"123456789") == 0x29B1
    for v in VECTORS["crc16_ccitt_false"]:
        data = v["ascii"].encode() if "ascii" in v else bytes.fromhex(v["hex"])
        assert P.crc16(data) == int(v["crc"], 16)


@pytest.mark.parametrize("case", VECTORS["cobs"], ids=lambda c: c["decoded"][:12] or "empty")
def test_cobs_vectors(case):
    dec, enc = bytes.fromhex(case["decoded"]), bytes.fromhex(case["encoded"])
    assert P.cobs_encode(dec) == enc
    assert P.cobs_decode(enc) == dec


@pytest.mark.parametrize("bad", VECTORS["cobs_invalid"])
def test_cobs_invalid(bad):
    with pytest.raises(P.FrameError):
        P.cobs_decode(bytes.fromhex(bad))


PARSERS = {P.CONFIGURE: P.parse_configure, P.HELLO: P.parse_hello, P.STATUS: P.parse_status,
           P.DONE: P.parse_done, P.ERROR: P.parse_error, P.ACK: P.parse_ack}


@pytest.mark.parametrize("case", VECTORS["frames"], ids=lambda c: c["name"])
def test_frame_vectors(case):
    body, wire = bytes.fromhex(case["body"]), bytes.fromhex(case["wire"])
    assert P.encode_frame(case["type"], case["seq"], body) == wire
    f = P.decode_frame(wire)
    assert (f.type, f.seq, f.body) == (case["type"], case["seq"], body)
    if f.type == P.SAMPLES:
        first, words = P.parse_samples(f.body)
        assert first == case["fields"]["first_index"]
        assert words.tolist() == case["fields"]["rows"]
    elif f.type in PARSERS:
        assert PARSERS[f.type](f.body) == case["fields"]
    if f.type == P.CONFIGURE:   # the builder reproduces the vector from its fields
        fields = dict(case["fields"])
        assert P.configure_body(**fields) == body


@pytest.mark.parametrize("case", VECTORS["reject"], ids=lambda c: c["name"])
def test_reject_vectors(case):
    d = P.StreamDecoder()
    assert d.feed(bytes.fromhex(case["wire"])) == []
    if case["error"] == "crc":
        assert (d.crc_errors, d.framing_errors) == (1, 0)
    elif case["error"] == "framing":
        assert (d.crc_errors, d.framing_errors) == (0, 1)
    else:
        assert d.crc_errors + d.framing_errors == 1


def test_stream_vector_resyncs_after_garbage():
    s = VECTORS["stream"]
    d = P.StreamDecoder()
    wire = bytes.fromhex(s["wire"])
    got = []
    for i in range(0, len(wire), 7):   # arbitrary chunking must not matter
        got += d.feed(wire[i:i + 7])
    assert [(f.type, f.seq, f.body.hex()) for f in got] == [(x["type"], x["seq"], x["body"]) for x in s["frames"]]
    assert (d.crc_errors, d.framing_errors) == (s["crc_errors"], s["framing_errors"])


def test_every_single_bit_flip_and_byte_drop_is_rejected():
    """Exhaustive over one full SAMPLES frame: no single fault is accepted."""
    rows = [[2048 + 7 * i, 511 - i, 300 + 3 * i, 1000 - i] for i in range(P.BATCH)]
    wire = P.encode_frame(P.SAMPLES, 42, P.samples_body(1000, rows))
    for i in range(len(wire) - 1):
        for bit in range(8):
            bad = bytearray(wire)
            bad[i] ^= 1 << bit
            assert P.StreamDecoder().feed(bytes(bad)) == [], (i, bit)
        dropped = wire[:i] + wire[i + 1:]
        assert P.StreamDecoder().feed(dropped) == [], i


frames_st = st.lists(st.tuples(st.integers(0, 255), st.integers(0, 255), st.binary(max_size=P.MAX_BODY)),
                     min_size=1, max_size=6)


@settings(max_examples=200, deadline=None)
@given(frames_st, st.integers(1, 64))
def test_roundtrip_any_chunking(frames, chunk):
    wire = b"".join(P.encode_frame(t, s, b) for t, s, b in frames)
    d = P.StreamDecoder()
    got = []
    for i in range(0, len(wire), chunk):
        got += d.feed(wire[i:i + chunk])
    assert [(f.type, f.seq, f.body) for f in got] == frames
    assert d.crc_errors == d.framing_errors == 0


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=2000))
def test_garbage_never_crashes(data):
    d = P.StreamDecoder()
    for f in d.feed(data):
        # anything accepted from pure noise carries a valid CRC by construction
        assert P.crc16(bytes([f.type, f.seq]) + f.body) is not None
        assert len(f.body) <= P.MAX_BODY


# derandomized: a CRC-16 lets about 1 in 65536 multi-bit corruptions through, so the
# examples are fixed to keep the test reproducible rather than rarely flaky
@settings(max_examples=300, deadline=None, derandomize=True)
@given(frames_st, st.integers(0, 2 ** 32 - 1), st.integers(1, 8))
def test_corrupted_stream_never_yields_a_wrong_frame(frames, seed, n_faults):
    wire = bytearray(b"".join(P.encode_frame(t, s, b) for t, s, b in frames))
    rng = random.Random(seed)
    for _ in range(n_faults):
        i = rng.randrange(len(wire))
        kind = rng.randrange(3)
        if kind == 0:
            wire[i] ^= 1 << rng.randrange(8)
        elif kind == 1:
            del wire[i]
        else:
            wire.insert(i, rng.randrange(256))
        if not wire:
            break
    d = P.StreamDecoder()
    originals = {(t, s, b) for t, s, b in frames}
    for f in d.feed(bytes(wire)):
        assert (f.type, f.seq, f.body) in originals
