#!/usr/bin/env python3
"""Regenerate firmware/test_vectors.json.

The CRC check value and the COBS cases are independent of this code (the CRC catalogue's
check value, the classic COBS examples); the frames are produced by the Python codec and
checked byte for byte by the C tests, so the two implementations cannot drift apart.
Run from the repository root: ``python3 firmware/tools/gen_vectors.py``.
"""
import json
import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2]))
from labrig.bridge import protocol as p  # noqa: E402

H = bytes.hex
out = {"_comment": "labrig bridge protocol test vectors; see firmware/PROTOCOL.md. "
                   "Hex strings; 'wire' includes the trailing 0x00 delimiter."}

out["crc16_ccitt_false"] = [
    {"ascii": "123456789", "crc": "29b1"},   # catalogue check value
    {"ascii": "", "crc": "ffff"},
    {"ascii": "A", "crc": "b915"},
    {"hex": "00", "crc": f"{p.crc16(bytes(1)):04x}"},
    {"hex": H(bytes(range(256))), "crc": f"{p.crc16(bytes(range(256))):04x}"},
]
assert p.crc16(b"123456789") == 0x29B1 and p.crc16(b"A") == 0xB915

r254 = bytes(range(1, 255))
cobs = [
    ("", "01"), ("00", "0101"), ("0000", "010101"), ("001100", "01021101"),
    ("11220033", "0311220233"), ("11223344", "0511223344"), ("11000000", "0211010101"),
    (H(r254), "ff" + H(r254)),
    (H(bytes(range(0, 255))), "01ff" + H(r254)),
    (H(bytes(range(1, 256))), "ff" + H(r254) + "02ff"),
    (H(bytes(range(2, 256)) + b"\x00"), "ff" + H(bytes(range(2, 256))) + "0101"),
    (H(bytes(range(3, 256)) + b"\x00\x01"), "fe" + H(bytes(range(3, 256))) + "0201"),
]
for dec, enc in cobs:
    assert p.cobs_encode(bytes.fromhex(dec)).hex() == enc, dec
out["cobs"] = [{"decoded": d, "encoded": e} for d, e in cobs]
out["cobs_invalid"] = ["00", "05112233", "0311", "0300ff"]

cfg = dict(loop="open", waveform="square", sample_rate_hz=1000, n_samples=4500,
           lead_in_samples=500, segment_samples=2000, dac_zero=2048, dac_min=1024,
           dac_max=3072, watchdog_ms=500, levels=[2663, 1433])
cfg_st = dict(loop="closed", waveform="staircase", sample_rate_hz=500, n_samples=2000,
              lead_in_samples=250, segment_samples=250, dac_zero=2048, dac_min=1024,
              dac_max=3072, watchdog_ms=300, levels=[2048, 2458, 2867, 1638],
              position_gain=10.0, velocity_gain=1.0)
cfg_pwl = dict(loop="open", waveform="pwl", sample_rate_hz=1000, n_samples=1200,
               lead_in_samples=100, segment_samples=0, dac_zero=2048, dac_min=1024,
               dac_max=3072, watchdog_ms=500, levels=[2048, 2663, 1433, 2048],
               pieces=[300, 400, 250])
hello = (bytes([1, 1]) + (15).to_bytes(2, "little") + (4000).to_bytes(2, "little")
         + bytes([10, 12, 10, 3, 32]) + b"".join(v.to_bytes(2, "little") for v in (2048, 922, 3174, 500))
         + b"labrig-fw 1.0.0 uno")
# protocol 2: the same 19 bytes, then the build's rig (an H-bridge board: 10 kHz clock,
# IN1/IN2 + brake + index, x4, 8-bit PWM, 50 Hz least), then the id
hello2 = (bytes([2, 3]) + (31).to_bytes(2, "little") + (2000).to_bytes(2, "little")
          + bytes([10, 9, 10, 0, 32]) + b"".join(v.to_bytes(2, "little") for v in (256, 0, 512, 500))
          + bytes([2]) + (10000).to_bytes(4, "little") + bytes([11, 4, 8]) + (50).to_bytes(2, "little")
          + b"labrig-fw 2.1.0 nano hbridge")
rows = [[2048 + i, 512 + i, 300 - i, 1023 - i] for i in range(10)]
# an H-bridge board's samples: word, count (low, high half), current; count -70000
count_rows = [[256 + i, (-70000 + i) & 0xFFFF, ((-70000 + i) >> 16) & 0xFFFF, 0] for i in range(3)]
frames = [
    ("HELLO_REQ", p.HELLO_REQ, 0, b"", {}),
    ("CONFIGURE square", p.CONFIGURE, 1, p.configure_body(**cfg), p.parse_configure(p.configure_body(**cfg))),
    ("CONFIGURE staircase closed", p.CONFIGURE, 2, p.configure_body(**cfg_st),
     p.parse_configure(p.configure_body(**cfg_st))),
    ("CONFIGURE pwl", p.CONFIGURE, 5, p.configure_body(**cfg_pwl),
     p.parse_configure(p.configure_body(**cfg_pwl))),
    ("START", p.START, 3, b"", {}),
    ("STOP", p.STOP, 4, b"", {}),
    ("HEARTBEAT", p.HEARTBEAT, 255, b"", {}),
    ("STATUS_REQ", p.STATUS_REQ, 6, b"", {}),
    ("ZERO", p.ZERO, 7, b"", {}),
    ("ACK", p.ACK, 0, bytes([p.START, 3]), {"type": p.START, "seq": 3}),
    ("HELLO", p.HELLO, 1, hello, p.parse_hello(hello)),
    ("HELLO protocol 2 hbridge", p.HELLO, 2, hello2, p.parse_hello(hello2)),
    ("SAMPLES hbridge counts", p.SAMPLES, 3, p.samples_body(0, count_rows),
     {"first_index": 0, "rows": count_rows, "counts": [-70000, -69999, -69998]}),
    ("SAMPLES", p.SAMPLES, 2, p.samples_body(123456, rows), {"first_index": 123456, "rows": rows}),
    ("SAMPLES zeros", p.SAMPLES, 0, p.samples_body(0, [[0, 0, 0, 0]]), {"first_index": 0, "rows": [[0, 0, 0, 0]]}),
    ("STATUS", p.STATUS, 3, bytes.fromhex("a0860100" "05000000" "02000000" "01000000" "01000000"
                                         "00000000" "02" "0008" "0000"), None),
    ("INDEX", p.INDEX, 6, p.index_body(1234, -70000, 3),
     {"sample": 1234, "count": -70000, "pulse": 3}),
    ("DONE", p.DONE, 4, bytes.fromhex("94110000" "00000000"), {"n_samples": 4500, "samples_lost": 0}),
    ("ERROR", p.ERROR, 5, bytes([6]) + b"host silent: output set to 0 V",
     {"code": 6, "name": "WATCHDOG", "text": "host silent: output set to 0 V"}),
]
fr = []
for name, t, seq, body, fields in frames:
    if fields is None:
        fields = p.parse_status(body)
    fr.append({"name": name, "type": t, "seq": seq, "body": H(body),
               "wire": H(p.encode_frame(t, seq, body)), "fields": fields})
out["frames"] = fr

good = p.encode_frame(p.SAMPLES, 2, p.samples_body(123456, rows))
flip = bytearray(good); flip[20] ^= 0x04
crcswap = bytearray(p.cobs_decode(good[:-1])); crcswap[-2:] = crcswap[-1:-3:-1]
long_raw = bytes([p.ERROR, 0]) + bytes([0x41]) * (p.MAX_BODY + 1)
long_raw += p.crc16(long_raw).to_bytes(2, "big")
short_raw = bytes([p.HEARTBEAT, 0])
reject = [
    ("bit flip in a sample", H(bytes(flip)), "crc"),
    ("CRC bytes swapped", H(p.cobs_encode(bytes(crcswap)) + b"\x00"), "crc"),
    ("truncated (delimiter inside a COBS block)", H(good[:30] + b"\x00"), "framing"),
    ("last byte dropped", H(good[:-2] + b"\x00"), "any"),
    ("two bytes only", H(p.cobs_encode(short_raw) + b"\x00"), "framing"),
    ("body longer than MAX_BODY with a valid CRC", H(p.cobs_encode(long_raw) + b"\x00"), "framing"),
    ("COBS code past the end", "0511223300", "framing"),
    ("garbage", H(b"\x13\x37garbage!\xff\xfe" + b"\x00"), "any"),
]
for name, wire, kind in reject:
    d = p.StreamDecoder()
    assert d.feed(bytes.fromhex(wire)) == [], name
    if kind == "crc":
        assert d.crc_errors == 1 and d.framing_errors == 0, name
    elif kind == "framing":
        assert d.framing_errors == 1 and d.crc_errors == 0, name
out["reject"] = [{"name": n, "wire": w, "error": k} for n, w, k in reject]

# a stream: garbage, a frame, a corrupted frame, empty frames, a frame split by noise
f1 = p.encode_frame(p.HELLO, 1, hello)
f2 = p.encode_frame(p.ACK, 2, bytes([3, 3]))
stream = b"\xaa\x55\x01" + b"\x00" + f1 + bytes(flip) + b"\x00\x00" + f2 + b"\x07\x08"
d = p.StreamDecoder()
got = d.feed(stream)
out["stream"] = {"wire": H(stream), "frames": [{"type": f.type, "seq": f.seq, "body": H(f.body)} for f in got],
                 "crc_errors": d.crc_errors, "framing_errors": d.framing_errors}
assert len(got) == 2

# a pwl played by the board: the words after the lead-in, by the rule of PROTOCOL.md
out["pwl"] = {"configure_body": H(p.configure_body(**cfg_pwl)),
              "lead_in": cfg_pwl["lead_in_samples"], "n_samples": cfg_pwl["n_samples"],
              "dac_zero": cfg_pwl["dac_zero"],
              # u16 little-endian, as hex (one word per sample)
              "words": H(b"".join(w.to_bytes(2, "little") for w in p.pwl_words(
                  cfg_pwl["levels"], cfg_pwl["pieces"],
                  cfg_pwl["n_samples"] - cfg_pwl["lead_in_samples"])))}

# the MS150 board's own loop (loop 2), sample by sample: the pot and tacho words it reads
# and the DAC word the model's law gives for them (labrig.simulation.sampled_kernel's
# pd_counts, the law labrig fits with), clamps and negative floors included
from labrig.simulation.sampled_kernel import pd_counts  # noqa: E402

cfg_board = dict(loop="board", waveform="square", sample_rate_hz=1000, n_samples=60,
                 lead_in_samples=5, segment_samples=20, dac_zero=2048, dac_min=1024,
                 dac_max=3072, watchdog_ms=500, levels=[333, 282], gain_words=(4096, 307),
                 board_loop=(307, 512))
steps = [(k * 37) % 61 - 30 for k in range(cfg_board["n_samples"])]   # a fixed scramble
pot = [300 + 2 * d for d in steps]
tacho = [512 + d // 2 for d in steps]
board_words = []
for k in range(cfg_board["n_samples"]):
    lead = cfg_board["lead_in_samples"]
    ref = 307 if k < lead else cfg_board["levels"][((k - lead) // cfg_board["segment_samples"]) % 2]
    o = pd_counts(4096.0, 307.0, float(ref - pot[k]), float(tacho[k] - 512), 1024.0 - 2048.0,
                  3072.0 - 2048.0)
    board_words.append(int(2048 + o))
out["board_loop"] = {"configure_body": H(p.configure_body(**cfg_board)),
                     "n_samples": cfg_board["n_samples"],
                     "pot": pot, "tacho": tacho, "words": board_words}

path = pathlib.Path(__file__).resolve().parents[1] / "test_vectors.json"
path.write_text(json.dumps(out, indent=1) + "\n")
print(f"wrote {path}")
