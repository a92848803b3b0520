"""The serial link under damage: the real firmware under simavr behind a proxy that drops,
corrupts and injects frames (tests/linkproxy.py). Per-run counters, lost tails, lost
ACK/DONE, malformed bodies, the wording of link failures, and the acceptance test:
a whole sweep through the CLI with random faults in both directions."""
from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np
import pytest

from labrig.bridge.sweep import sweep
from labrig.bridge import protocol as P
from labrig.io.experiment import Experiment
from labrig.bridge.emulate import APT_PACKAGES, missing_tools
from labrig.bridge.serial import SerialBridge, bridge_settings, volts_to_dac_word
from labrig.io.config import load_rig
from labrig.core.errors import RigError
from labrig.io.runs import read_dataset
from conftest import ROOT
from linkproxy import B2H, H2B, LinkProxy

_missing = missing_tools()
pytestmark = [
    pytest.mark.firmware,
    pytest.mark.skipif(bool(_missing), reason=f"firmware toolchain missing ({', '.join(_missing)}): "
                                              f"apt-get install {APT_PACKAGES}"),
]

SPEED = 2.0   # the emulated board runs at twice real time: shorter tests, same firmware
# ... so its watchdog (simulated ms) is doubled to keep the bench's 500 ms of wall time:
# a host stalled by a busy test machine must not trip it
WATCHDOG_MS = 1000


@pytest.fixture
def rig():
    r = load_rig()
    r.bridge.watchdog_ms = WATCHDOG_MS
    # these tests lose samples on purpose and look at the runs; the rig's loss tolerance
    # (a sweep exits 1 above it) has a test of its own
    r.bridge.max_lost_fraction = 1.0
    return r


def _exp(name, seconds=0.5, amp=1.5, **kw):
    return Experiment(name=name, amplitude_v=amp, frequency_hz=2.0, lead_in_s=0.1,
                      periods=(seconds - 0.1) * 2.0, **kw)


def _words(run, s):
    """The DAC and ADC words behind a run's volts (no calibration in the default rig)."""
    lo, hi = s.dac_range_v
    dac = np.rint((run.u - lo) * 2 ** s.dac_bits / (hi - lo)).astype(int)
    alo, ahi = s.adc_range_v
    adc = [np.rint((run.data[c].to_numpy(float) - alo) * 2 ** s.adc_bits / (ahi - alo)).astype(int)
           for c in ("tacho", "pos", "ref")]
    return np.column_stack([dac, *adc])


def _sweep(proxy, plan, rig, out):
    sweep(SerialBridge(proxy.path, rig), plan, rig, out)
    return {r.name: r for r in read_dataset(out)}


def _gap(run):
    return run.data["gap"].to_numpy() if "gap" in run.data else np.zeros(len(run), dtype=np.int8)


def test_counters_are_each_runs_own(tmp_path, emulators, rig):
    """Point 4: run 2 must not report run 1's losses (it used to: cumulative counters)."""
    plan = [_exp("a"), _exp("b"), _exp("c")]

    def policy(d, f, run, nth):
        if d != B2H or f.type != P.SAMPLES:
            return None
        first = P.parse_samples(f.body)[0]
        if run == 1 and first in (100, 110):
            return "drop"
        if run == 1 and first == 200:
            return "corrupt"
        if run == 2 and first == 300:
            return "drop"
        return None

    emu = emulators("uno", rig, speed=SPEED)
    with LinkProxy(emu.pty, policy=policy) as proxy:
        runs = _sweep(proxy, plan, rig, tmp_path / "ds")
    got = {k: {c: r.meta["bridge"][c] for c in ("samples", "dropped_samples", "crc_errors",
                                                  "framing_errors", "stale_frames", "bad_frames")}
           for k, r in runs.items()}
    assert got == {"a": dict(samples=470, dropped_samples=30, crc_errors=1, framing_errors=0,
                             stale_frames=0, bad_frames=0),
                   "b": dict(samples=490, dropped_samples=10, crc_errors=0, framing_errors=0,
                             stale_frames=0, bad_frames=0),
                   "c": dict(samples=500, dropped_samples=0, crc_errors=0, framing_errors=0,
                             stale_frames=0, bad_frames=0)}
    for r in runs.values():
        assert len(r) == 500 and _gap(r).sum() == r.meta["bridge"]["dropped_samples"]
        # the board's own counters are per run too: it sent every sample once, heard us
        assert r.meta["bridge"]["board_samples_sent"] == 500
        assert r.meta["bridge"]["board_rx_crc_errors"] == 0


def test_lost_tail_and_done_become_gap_rows(tmp_path, emulators, rig):
    """Point 5: the last frames and DONE lost -> the run keeps its planned length, the
    tail holds the last value and is flagged; it is counted as dropped."""
    plan = [_exp("a"), _exp("b")]

    def policy(d, f, run, nth):
        if run == 1 and d == B2H and f.type == P.DONE:
            return "drop"
        if run == 1 and d == B2H and f.type == P.SAMPLES and P.parse_samples(f.body)[0] in (250, 480, 490):
            return "drop"
        return None

    emu = emulators("uno", rig, speed=SPEED)
    with LinkProxy(emu.pty, policy=policy) as proxy:
        runs = _sweep(proxy, plan, rig, tmp_path / "ds")
    a = runs["a"]
    gap = _gap(a)
    assert len(a) == 500 and a.meta["bridge"]["dropped_samples"] == 30 == gap.sum()
    assert np.flatnonzero(gap).tolist() == list(range(250, 260)) + list(range(480, 500))
    assert np.all(a.u[480:] == a.u[479]) and np.all(a.data["tacho"].to_numpy()[480:] == a.data["tacho"].iloc[479])
    assert np.allclose(a.t, np.arange(500) / 1000.0)
    assert runs["b"].meta["bridge"]["dropped_samples"] == 0 and "gap" not in runs["b"].data


def test_lost_acks_and_done_are_retried_without_restarting(tmp_path, emulators, rig):
    """Point 6: a lost CONFIGURE, two lost ACKs, a START whose ACK and first samples are
    lost (so the host retransmits it while the board runs), a lost DONE and a lost STOP
    ACK: the sweep completes, the retransmitted START does not restart the experiment."""
    plan = [_exp("a", seconds=2.0), _exp("b")]

    def policy(d, f, run, nth):
        if run != 1:
            return None
        if d == H2B and f.type == P.CONFIGURE and nth == 0:
            return "drop"                                  # CONFIGURE lost on the way
        if d == B2H and f.type == P.ACK:
            acked = P.parse_ack(f.body)["type"]
            if acked == P.CONFIGURE and nth == 0:
                return "drop"                              # its ACK lost once
            if acked == P.START and nth == 2:
                return "drop"                              # START's first ACK lost
            if acked == P.STOP and nth >= 4 and not getattr(policy, "stop_dropped", False):
                policy.stop_dropped = True
                return "drop"                              # STOP's ACK lost once
        if d == B2H and f.type == P.SAMPLES and P.parse_samples(f.body)[0] < 1000:
            return "drop"                                  # 0.5 s of samples: > one try
        if d == B2H and f.type == P.DONE:
            return "drop"
        return None

    emu = emulators("uno", rig, speed=SPEED)
    with LinkProxy(emu.pty, policy=policy) as proxy:
        runs = _sweep(proxy, plan, rig, tmp_path / "ds")
    cmds = [t for t, _ in proxy.frames[H2B, 1] if t != P.HEARTBEAT]
    starts = {seq for t, seq in proxy.frames[H2B, 1] if t == P.START}
    assert cmds.count(P.CONFIGURE) == 3 and cmds.count(P.START) == 2 and len(starts) == 1
    assert cmds.count(P.STOP) >= 2
    a = runs["a"].meta["bridge"]
    # 2 CONFIGURE + 1 START + 1 STOP retransmissions; the board ran the experiment once
    assert a["retries"] == 4 and a["board_samples_sent"] == 2000
    assert a["dropped_samples"] == 1000 == _gap(runs["a"]).sum() and len(runs["a"]) == 2000
    assert runs["b"].meta["bridge"]["retries"] == 0
    assert runs["b"].meta["bridge"]["dropped_samples"] == 0


def test_lost_heartbeats_do_not_trip_the_watchdog(tmp_path, emulators, rig):
    """A link losing 11 of every 12 heartbeats: with one every 50 ms the board still hears
    the host every ~0.66 s, inside a 1 s watchdog (2 s simulated at speed 2); at the old
    100 ms it heard it every 1.2 s: a trip and an aborted sweep."""
    rig.bridge.watchdog_ms = 2 * WATCHDOG_MS
    plan = [_exp("a", seconds=3.0)]

    def policy(d, f, run, nth):
        return "drop" if d == H2B and f.type == P.HEARTBEAT and nth % 12 else None

    emu = emulators("uno", rig, speed=SPEED)
    with LinkProxy(emu.pty, policy=policy) as proxy:
        runs = _sweep(proxy, plan, rig, tmp_path / "ds")
    b = runs["a"].meta["bridge"]
    assert sum(t == P.HEARTBEAT for t, _ in proxy.frames[H2B, 1]) >= 24
    assert b["board_watchdog_trips"] == 0 and b["dropped_samples"] == 0 and len(runs["a"]) == 3000


def test_malformed_bodies_are_counted_not_fatal(tmp_path, emulators, rig):
    """Point 7: CRC-valid frames with short or inconsistent bodies (which used to raise
    IndexError or end the run) are counted as bad frames; the run completes intact."""
    bad = [P.encode_frame(P.ERROR, 1, b""), P.encode_frame(P.ACK, 2, b"\x03"),
           P.encode_frame(P.DONE, 3, b"\x01\x02\x03"), P.encode_frame(P.STATUS, 4, b"\x00" * 7),
           P.encode_frame(P.SAMPLES, 5, P.samples_body(100, [[1, 2, 3, 4]])[:-2])]
    plan = [_exp("a")]

    asked, injected = [], []

    def policy(d, f, run, nth):
        if d == H2B and f.type == P.HELLO_REQ:
            asked.append(f.seq)
        # once, before the first greeting after the host has asked (a greeting before that may
        # reach a port the host has not opened yet; under load the host may ask twice first)
        if d == B2H and f.type == P.HELLO and asked and not injected:
            injected.append(f.seq)
            return ("before", P.encode_frame(P.HELLO, 9, b"\x01\x01"))
        if run == 1 and d == B2H and f.type == P.SAMPLES and P.parse_samples(f.body)[0] == 100:
            return ("before", b"".join(bad))
        return None

    emu = emulators("uno", rig, speed=SPEED)
    with LinkProxy(emu.pty, policy=policy) as proxy:
        bridge = SerialBridge(proxy.path, rig)
        sweep(bridge, plan, rig, tmp_path / "ds")
    (a,) = read_dataset(tmp_path / "ds")
    assert a.meta["bridge"]["bad_frames"] == 5 and a.meta["bridge"]["dropped_samples"] == 0
    assert bridge.bad_frames == 6 and len(a) == 500 and "gap" not in a.data


def test_no_answer_says_whether_the_link_is_silent_or_garbled(emulators, rig):
    """Point 6: a silent link asks whether the board is plugged in; a link that answers
    with damaged frames says how many and suggests a better cable or lower baud rate."""
    emu = emulators("uno", rig, speed=SPEED)
    # a silent port fails after 4 tries (1.2 s); a garbling link gets twice the patience
    for action, tries, want, unwanted in (
            ("drop", 4, "is the board plugged in?", "garble"),
            ("corrupt", 8, "garbles (8 damaged frame(s), 0 intact)", "plugged in")):
        def policy(d, f, run, nth):
            return action if run == 1 and d == B2H else None

        with LinkProxy(emu.pty, policy=policy) as proxy:
            bridge = SerialBridge(proxy.path, rig)
            bridge.open()
            t0 = time.monotonic()
            with pytest.raises(RigError) as err:
                bridge.configure(_exp("a"))
            took = time.monotonic() - t0
            bridge.zero()
            bridge.close()
        msg = str(err.value)
        assert f"CONFIGURE after {tries} tries" in msg and want in msg and unwanted not in msg, msg
        assert ("cable" in msg and "baud" in msg) == (action == "corrupt")
        assert 0.3 * tries - 0.1 < took < 0.3 * tries + 1.5


# ---- acceptance: the whole CLI through random faults in both directions ------------

ACCEPT_PLAN = """\
[defaults]
sample_rate_hz = 1000.0
lead_in_s = 0.2

[[experiment]]
loop = "open"
waveform = "square"
amplitudes_v = [1.2, 2.0, 2.5]
frequency_hz = 1.0
periods = 1.3

[[experiment]]
loop = "open"
waveform = "step"
amplitudes_v = [-1.5]
duration_s = 1.3
"""
P_FAULT = 1e-3   # per byte, each direction: half bit flips, half drops
# seed whose host->board fault stream hits within the first few hundred bytes, so both
# directions are damaged in every sweep (the byte positions of faults are seeded)
SEED = 5


@pytest.mark.slow
def test_sweep_through_faults_in_both_directions(tmp_path, emulators, rig):
    """`labrig sweep --port` through a link with 1e-3 per-byte faults both ways: exit 0,
    not one wrong sample, and per-run counts that match what the proxy did to that run."""
    from labrig.io.config import load_plan

    plan_file = tmp_path / "plan.toml"
    plan_file.write_text(ACCEPT_PLAN)
    plan = load_plan(plan_file, rig)
    rig_file = tmp_path / "rig.toml"   # the default rig, watchdog scaled to the emulator's speed
    text = (ROOT / "configs" / "rig_default.toml").read_text()
    assert "watchdog_ms = 500" in text
    rig_file.write_text(text.replace("watchdog_ms = 500", f"watchdog_ms = {WATCHDOG_MS}\n"
                                     "max_lost_fraction = 1.0"))   # losses are the point here
    emu = emulators("uno", rig, speed=SPEED)
    faults = (P_FAULT / 2, P_FAULT / 2)
    with LinkProxy(emu.pty, b2h=faults, h2b=faults, seed=SEED) as proxy:
        t0 = time.monotonic()
        proc = subprocess.run([sys.executable, "-m", "labrig", "sweep", "--port", proxy.path,
                               "--rig", rig_file, "--plan", plan_file, "-o", tmp_path / "ds"],
                              capture_output=True, text=True, timeout=120)
        took = time.monotonic() - t0
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    runs = {r.name: r for r in read_dataset(tmp_path / "ds")}
    assert list(runs) == sorted(e.name for e in plan)
    s = bridge_settings(rig)
    assert proxy.upstream_bad == 0, proxy.upstream_bad_frames
    assert proxy.total(proxy.faults, B2H) > 50 and proxy.total(proxy.faults, H2B) >= 1
    report = []
    for k, exp in enumerate(plan, start=1):
        r, b = runs[exp.name], runs[exp.name].meta["bridge"]
        n, gap = exp.n_samples, _gap(runs[exp.name])
        ok = np.flatnonzero(gap == 0)
        assert len(r) == n
        # 0 wrong samples: every non-gap row is what the firmware sent, word for word,
        # and its DAC word is the plan's
        sent = proxy.sent[k]
        want = np.array([sent[i] for i in ok])
        assert np.array_equal(_words(r, s)[ok], want)
        plan_words = [volts_to_dac_word(v, s) for v in exp.waveform_at(ok / exp.sample_rate_hz)]
        assert np.array_equal(want[:, 0], plan_words)
        # every lost sample is a gap row, and exactly those the proxy kept from the host
        delivered = {i for i in proxy.delivered[k] if i < n}
        assert b["dropped_samples"] == gap.sum() == n - len(delivered)
        assert b["samples"] == len(delivered) == len(ok)
        # the run's damaged frames as the host's decoder counted them, and as the proxy's
        # copy of that decoder saw the same bytes; +-2 for the frames around the run's
        # edges (a late answer, the final STOP/STATUS of the sweep)
        errs, want_errs = b["crc_errors"] + b["framing_errors"], proxy.errors[B2H, k]
        assert abs(errs - want_errs) <= 2, (exp.name, errs, want_errs)
        if proxy.faults[B2H, k] >= 3:
            assert errs > 0
        # the board's count of damaged host frames in this run, within the same tolerance
        if "board_rx_crc_errors" in b:
            board_errs = b["board_rx_crc_errors"] + b["board_rx_overruns"]
            assert abs(board_errs - proxy.errors[H2B, k]) <= 2, (exp.name, board_errs)
        report.append((exp.name, proxy.faults[B2H, k], proxy.faults[H2B, k], errs,
                       b["dropped_samples"], b["retries"]))
    print(f"\n{took:.1f} s; per run (name, faults b2h, faults h2b, errors, dropped, retries): {report}")


# ---- one user per port ---------------------------------------------------------------

def test_a_second_user_of_a_held_port_is_refused_and_the_first_loses_nothing(tmp_path, emulators):
    """A sweep holds its port: a second sweep on it is refused at once in one line naming
    the holder's PID and command (exit 1, nothing written), and the first completes with
    every sample. A lab station (``open_bridge``) holds its board between runs too, until
    it closes."""
    import labrig.verbs as lr

    # two square waves: the second one, 6 s long, plays while the second sweep is refused
    # (the default plan's four runs, 34 s of real time, proved no more)
    plan = tmp_path / "open.toml"
    plan.write_text('[defaults]\nsample_rate_hz = 1000.0\nlead_in_s = 0.2\n\n'
                    '[[experiment]]\nloop = "open"\nwaveform = "square"\namplitudes_v = [1.2]\n'
                    'frequency_hz = 2.0\nperiods = 3\n\n'
                    '[[experiment]]\nloop = "open"\nwaveform = "square"\namplitudes_v = [2.0]\n'
                    'frequency_hz = 0.5\nperiods = 3\n')
    emu = emulators("uno", load_rig())
    first = subprocess.Popen([sys.executable, "-m", "labrig", "sweep", "--port", emu.pty,
                              "--plan", plan, "-o", tmp_path / "a"], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while not list((tmp_path / "a").glob("*.csv")) and time.monotonic() < deadline:
            time.sleep(0.2)   # the first run is written: the sweep is well under way
        second = subprocess.run([sys.executable, "-m", "labrig", "sweep", "--port", emu.pty,
                                 "--plan", plan, "-o", tmp_path / "b"], capture_output=True, text=True,
                                timeout=60)
        out, err = first.communicate(timeout=120)
    finally:
        if first.poll() is None:
            first.kill()
    assert second.returncode == 1, second.stderr
    msg = second.stderr.strip()
    assert len(msg.splitlines()) == 1 and "Traceback" not in msg
    assert f"PID {first.pid} (" in msg and "labrig sweep --port" in msg, msg
    assert not (tmp_path / "b").exists()
    assert first.returncode == 0, err
    runs = read_dataset(tmp_path / "a")
    assert len(runs) == 2
    assert all(r.meta["bridge"]["dropped_samples"] == 0 and "gap" not in r.data for r in runs)

    make, _, close = lr.open_bridge(load_rig(), port=emu.pty)
    try:
        held = subprocess.run([sys.executable, "-m", "labrig", "sweep", "--port", emu.pty,
                               "--plan", plan, "-o", tmp_path / "c"], capture_output=True,
                              text=True, timeout=60)
        assert held.returncode == 1 and f"PID {os.getpid()} (" in held.stderr, held.stderr
    finally:
        close()


def test_a_run_that_lost_more_than_the_rig_allows_is_kept_and_the_sweep_exits_1(tmp_path, emulators):
    """A link losing 1 sample frame in 20: every run is written with the lost samples
    flagged as gaps, and `labrig sweep` exits 1 naming the runs and their losses, above
    [bridge] max_lost_fraction (0.001)."""
    rig_file = tmp_path / "rig.toml"
    rig_file.write_text((ROOT / "configs" / "rig_default.toml").read_text())
    plan = tmp_path / "plan.toml"
    plan.write_text('[defaults]\nsample_rate_hz = 1000.0\nlead_in_s = 0.1\n\n[[experiment]]\n'
                    'loop = "open"\nwaveform = "square"\namplitudes_v = [1.2, 2.0]\n'
                    'frequency_hz = 2.0\nperiods = 2\n')

    def policy(d, f, run, nth):
        return "drop" if d == B2H and f.type == P.SAMPLES and nth % 20 == 7 else None

    emu = emulators("uno", load_rig())
    with LinkProxy(emu.pty, policy=policy) as proxy:
        r = subprocess.run([sys.executable, "-m", "labrig", "sweep", "--port", proxy.path,
                            "--rig", rig_file, "--plan", plan, "-o", tmp_path / "ds"],
                           capture_output=True, text=True, timeout=120)
    assert r.returncode == 1, r.stderr
    msg = r.stderr.strip().splitlines()[-1]
    assert "2 run(s)" in msg and "max_lost_fraction = 0.001" in msg and "gaps" in msg, msg
    runs = read_dataset(tmp_path / "ds")
    assert len(runs) == 2
    for run in runs:
        lost = int(run.data["gap"].sum())
        assert lost == run.meta["bridge"]["dropped_samples"] > 0.001 * len(run)
        assert f"{run.name} {lost} of {len(run)}" in msg
