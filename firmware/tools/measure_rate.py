#!/usr/bin/env python3
"""Measure the highest gap-free sample rate of the firmware under simavr.

Builds a variant that accepts up to 20 kHz into /tmp/labrig-fwmeas, runs it in the
emulator paced to real time, and for each rate given streams 2 s of samples, counting
received samples, index gaps, CRC errors and the board's own lost-sample count.
Usage: python3 firmware/tools/measure_rate.py [--board uno] 1000 2000 2500 3200 4000
"""
import argparse
import pathlib
import subprocess
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
import serial  # noqa: E402
from labrig.bridge import protocol as p  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--board", default="uno")
ap.add_argument("rates", nargs="*", type=int, default=[1000, 2000, 2500, 3200, 4000, 5000])
a = ap.parse_args()
out = "/tmp/labrig-fwmeas"
subprocess.run(["make", "-C", str(ROOT / "firmware"), f"B={out}", "FW_DEFS=-DLR_MAX_RATE_HZ=20000", a.board],
               check=True, capture_output=True)
subprocess.run(["make", "-C", str(ROOT / "firmware"), "emulator"], check=True, capture_output=True)
proc = subprocess.Popen([str(ROOT / "firmware/build/emulator/labrig-emu"), "--fw", f"{out}/{a.board}/labrig_bridge.elf",
                         "--board", a.board], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
try:
    s = serial.Serial(proc.stdout.readline().strip(), 500000, timeout=0.05)
    for rate in a.rates:
        dec = p.StreamDecoder()
        body = p.configure_body(loop="open", waveform="square", sample_rate_hz=rate, n_samples=2 * rate,
                                lead_in_samples=0, segment_samples=max(rate // 10, 1), dac_zero=2048,
                                dac_min=1024, dac_max=3072, watchdog_ms=500, levels=[2662, 1434])
        s.reset_input_buffer()
        s.write(b"\0" + p.encode_frame(p.CONFIGURE, 1, body) + b"\0" + p.encode_frame(p.START, 2))
        t0, n, nxt, gaps, last, done = time.time(), 0, 0, 0, 0.0, None
        while time.time() - t0 < 6 and done is None:
            for f in dec.feed(s.read(8192)):
                if f.type == p.SAMPLES:
                    first, w = p.parse_samples(f.body)
                    gaps += first != nxt
                    nxt, n = first + len(w), n + len(w)
                elif f.type == p.DONE:
                    done = p.parse_done(f.body)
            if time.time() - last > 0.1:
                s.write(b"\0" + p.encode_frame(p.HEARTBEAT, 0))
                last = time.time()
        print(f"{a.board} {rate} Hz: received {n}/{2 * rate}, gaps {gaps}, crc errors {dec.crc_errors}, "
              f"board lost {done['samples_lost'] if done else 'no DONE'}", flush=True)
        s.write(b"\0" + p.encode_frame(p.ZERO, 3))
        time.sleep(0.2)
finally:
    proc.terminate()
    proc.wait()
