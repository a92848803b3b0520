"""Sweeps on the simulated rig: valid runs, atomic writes, interruption keeps runs."""
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from labrig.bridge.sweep import LossError, sweep
from labrig.bridge.sim import SimRig
from labrig.io.runs import read_dataset, read_run
from conftest import MY_COULOMB_PY, ROOT, labrig, make_rig, square_plan


def test_cli_sweep_writes_valid_runs(tmp_path):
    labrig("sweep", "--sim", "-o", tmp_path / "ds", check=0)
    runs = read_dataset(tmp_path / "ds")
    assert [r.name for r in runs if r.loop == "open"] == ["sq_1.20V", "sq_1.50V", "sq_2.00V", "sq_2.50V"]
    assert any(r.loop == "closed" and r.ref is not None for r in runs)
    r = runs[-1]
    assert r.meta["source"] == "sim" and r.meta["bridge"]["dropped_samples"] == 0
    assert r.u[0] == 0 and r.amplitude == pytest.approx(2.5, abs=0.01)
    # a second sweep into the same folder refuses; --resume skips finished runs
    p = labrig("sweep", "--sim", "-o", tmp_path / "ds")
    assert p.returncode == 2 and "--resume" in p.stderr
    labrig("sweep", "--sim", "-o", tmp_path / "ds", "--resume", check=0)


def test_same_seed_same_data(tmp_path):
    rig = make_rig()
    plan = square_plan(amps=(1.5,), periods=0.5)
    sweep(SimRig(rig), plan, rig, tmp_path / "a")
    sweep(SimRig(rig), plan, rig, tmp_path / "b")
    assert (tmp_path / "a" / "sq_1.50V.csv").read_bytes() == (tmp_path / "b" / "sq_1.50V.csv").read_bytes()


class Exploding(SimRig):
    """A rig whose third experiment is interrupted mid-stream."""

    def read(self, timeout=2.0):
        if self._count["experiments"] == 3 and self._pos > 1000:
            raise KeyboardInterrupt
        return super().read(timeout)


def test_interrupted_sweep_keeps_finished_runs_and_zeroes(tmp_path):
    rig = make_rig()
    bridge = Exploding(rig)
    with pytest.raises(KeyboardInterrupt):
        sweep(bridge, square_plan(), rig, tmp_path / "ds")
    assert bridge.output_v == 0.0
    names = sorted(p.name for p in (tmp_path / "ds").iterdir())
    assert names == ["sq_1.20V.csv", "sq_1.20V.json", "sq_1.50V.csv", "sq_1.50V.json"]
    for r in read_dataset(tmp_path / "ds"):
        assert len(r) == 8500


class DeadLink(Exploding):
    """Interrupted mid-stream like :class:`Exploding`, on a link that then fails every
    command: its zero breaks the never-raise contract of a bridge."""

    closed = dead = False

    def read(self, timeout=2.0):
        try:
            return super().read(timeout)
        except KeyboardInterrupt:
            self.dead = True
            raise

    def stop(self):
        if self.dead:
            raise OSError("write failed: the link is gone")
        super().stop()

    def zero(self):
        if self.dead:
            raise OSError("write failed: the link is gone")
        super().zero()

    def close(self):
        self.closed = True


def test_a_zero_that_fails_leaves_the_interrupt_the_error_and_the_link_released(tmp_path):
    """A Ctrl-C in a run on a link that then dies: the interrupt is still the error (not
    the zero's failure, which is said beside it), the link is released all the same, and
    the finished runs are kept; with nothing else wrong, a failed zero is the error."""
    from labrig.bridge.sweep import end_at_zero

    rig = make_rig()
    bridge = DeadLink(rig)
    with pytest.raises(KeyboardInterrupt) as info:
        sweep(bridge, square_plan(), rig, tmp_path / "ds")
    assert bridge.closed
    assert any("0 V afterwards failed too: write failed" in n for n in info.value.__notes__)
    assert len(read_dataset(tmp_path / "ds")) == 2
    quiet = DeadLink(rig)
    quiet.dead = True
    with pytest.raises(OSError, match="the link is gone"):
        end_at_zero(quiet)
    assert quiet.closed


def _files_no_larger_than(limit):
    """A child process's files capped at ``limit`` bytes (RLIMIT_FSIZE): a write past it
    fails as on a full disk (EFBIG; Python ignores SIGXFSZ)."""
    import resource

    return lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))


#: a plan whose second run's file is about three times the first's
GROWING_PLAN = ("[defaults]\nlead_in_s = 0.1\n[[experiment]]\namplitudes_v = [1.2]\n"
                "frequency_hz = 1.0\nperiods = 1.5\n[[experiment]]\namplitudes_v = [2.0]\n"
                "frequency_hz = 1.0\nperiods = 5\n")


def test_a_full_disk_mid_sweep_is_one_line_the_runs_before_it_whole(tmp_path):
    """The disk fills while a run is written (here: files capped between the first run's
    size and the second's): one line naming the file and the system's reason, exit 1, no
    "internal error"; the first run whole, nothing half-written left, and the output
    said at 0 V (the simulated rig; the emulated board's test reads its DAC)."""
    plan = tmp_path / "plan.toml"
    plan.write_text(GROWING_PLAN)
    r = subprocess.run([sys.executable, "-m", "labrig", "sweep", "--sim", "--plan", str(plan),
                        "-o", str(tmp_path / "ds")], capture_output=True, text=True,
                       timeout=120, preexec_fn=_files_no_larger_than(150_000))
    assert r.returncode == 1, r.stderr
    lines = [x for x in r.stderr.strip().splitlines() if not x.startswith("wrote ")]
    assert len(lines) == 1 and "internal error" not in r.stderr and "Traceback" not in r.stderr
    assert lines[0].startswith("labrig: error: "), lines[0]
    assert "sq_2.00V.csv: cannot be written (File too large)" in lines[0], lines[0]
    assert "kept in" in lines[0] and "the output is at 0 V" in lines[0], lines[0]
    runs = read_dataset(tmp_path / "ds")
    assert [x.name for x in runs] == ["sq_1.20V"] and len(runs[0]) == 1600
    assert sorted(p.name for p in (tmp_path / "ds").iterdir()) == ["sq_1.20V.csv",
                                                                    "sq_1.20V.json"]


def test_plan_beyond_output_limit_refused(tmp_path):
    rig = make_rig()
    p = labrig("sweep", "--sim", "-o", tmp_path / "o", "--plan", tmp_path / "p.toml")
    (tmp_path / "p.toml").write_text("[[experiment]]\namplitude_v = 4.0\n")
    p = labrig("sweep", "--sim", "-o", tmp_path / "o", "--plan", tmp_path / "p.toml")
    assert p.returncode == 2 and "exceeds the output limit 2.5 V" in p.stderr
    assert not (tmp_path / "o").exists()


def test_ctrl_c_on_the_cli(tmp_path):
    plan = tmp_path / "p.toml"
    plan.write_text("[defaults]\nlead_in_s = 0.1\nduration_s = 0.6\n"
                    "[[experiment]]\namplitudes_v = [1.0, 1.5, 2.0, 2.5]\n")
    proc = subprocess.Popen([sys.executable, "-m", "labrig", "sweep", "--sim", "--realtime",
                             "--plan", plan, "-o", tmp_path / "ds"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 30
    while time.time() < deadline and not (tmp_path / "ds" / "sq_1.50V.json").exists():
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "interrupted" in err
    runs = read_dataset(tmp_path / "ds")
    assert 2 <= len(runs) < 4
    assert all(len(r) == 600 for r in runs)
    assert not [p for p in (tmp_path / "ds").iterdir() if p.suffix == ".tmp"]


def test_sim_counters_are_per_run(tmp_path):
    """Point 4 on the simulated rig: each sidecar counts its own run's samples."""
    rig = make_rig()
    plan = square_plan(amps=(1.0, 1.5, 2.0), periods=0.5)
    sweep(SimRig(rig), plan, rig, tmp_path / "ds")
    runs = read_dataset(tmp_path / "ds")
    assert [r.meta["bridge"]["samples"] for r in runs] == [2500, 2500, 2500]
    assert all(r.meta["bridge"]["dropped_samples"] == 0 for r in runs)


class LosesTail(SimRig):
    """A rig whose link loses samples 300..309 and everything from 2000 on (and so the
    end of the run): what a serial bridge reports when the last frames and DONE are lost."""

    def read(self, timeout=2.0):
        while (blk := super().read(timeout)) is not None:
            keep = ((blk.index < 300) | (blk.index >= 310)) & (blk.index < 2000)
            if keep.any():
                return type(blk)(index=blk.index[keep], u=blk.u[keep], tacho=blk.tacho[keep],
                                 pos=blk.pos[keep], ref=None)
        return None

    def counters(self):
        return {**super().counters(), "dropped_samples": 510}


def test_lost_tail_becomes_gap_rows_holding_the_last_value(tmp_path):
    """Point 5: a run whose tail is lost keeps its planned length; the tail holds the last
    received value and is flagged gap = 1, like the interpolated hole inside."""
    rig = make_rig()
    (exp,) = square_plan(amps=(1.5,), periods=0.5)   # 2500 samples
    with pytest.raises(LossError, match="sq_1.50V 510 of 2500"):   # beyond the rig's 0.1 %
        sweep(LosesTail(rig), [exp], rig, tmp_path / "ds")
    r = read_run(tmp_path / "ds" / "sq_1.50V")   # ... and written all the same
    gap = r.data["gap"].to_numpy()
    assert len(r) == exp.n_samples == 2500
    assert np.allclose(r.t, np.arange(2500) / 1000.0)
    assert gap.sum() == 510 == r.meta["bridge"]["dropped_samples"]
    assert np.flatnonzero(gap).tolist() == list(range(300, 310)) + list(range(2000, 2500))
    tacho = r.data["tacho"].to_numpy()
    assert np.all(tacho[2000:] == tacho[1999]) and np.all(r.u[2000:] == r.u[1999])


def _plan_file(tmp_path, n=4):
    plan = tmp_path / "p.toml"
    amps = ", ".join(str(a) for a in (1.0, 1.5, 2.0, 2.5)[:n])
    plan.write_text("[defaults]\nlead_in_s = 0.1\nduration_s = 0.6\n"
                    f"[[experiment]]\namplitudes_v = [{amps}]\n")
    return plan


@pytest.mark.parametrize("sig, code", [(signal.SIGTERM, 143), (signal.SIGHUP, 129)],
                         ids=["SIGTERM", "SIGHUP"])
def test_sigterm_and_sighup_stop_like_ctrl_c(tmp_path, sig, code):
    """Point 9: SIGTERM/SIGHUP by PID take the Ctrl-C path: finished runs intact, no
    temporary files, exit 128 + signal number, one line on stderr."""
    proc = subprocess.Popen([sys.executable, "-m", "labrig", "sweep", "--sim", "--realtime",
                             "--plan", _plan_file(tmp_path), "-o", tmp_path / "ds"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 30
    while time.time() < deadline and not (tmp_path / "ds" / "sq_1.50V.json").exists():
        time.sleep(0.05)
    os.kill(proc.pid, sig)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == code, err
    name = signal.Signals(sig).name
    notes = [line for line in err.splitlines() if not line.startswith("wrote ")]
    assert notes == [f"labrig: terminated by {name}; finished runs are kept, the output is at 0 V"]
    runs = read_dataset(tmp_path / "ds")
    assert 2 <= len(runs) < 4 and all(len(r) == 600 for r in runs)
    assert not [p for p in (tmp_path / "ds").iterdir() if p.suffix == ".tmp"]


def test_stale_tmp_files_are_removed_when_a_sweep_starts(tmp_path):
    """Point 9: `.NAME.csv.*.tmp` left by a killed atomic write go when a sweep or a
    --resume starts; temporary files of other names stay."""
    out = tmp_path / "ds"
    out.mkdir()
    stale = [out / ".sq_1.00V.csv.k2j3x.tmp", out / ".sq_1.00V.json.x9a1.tmp"]
    other = out / ".notes.txt.abc.tmp"
    for p in stale + [other]:
        p.write_text("t,u\n0,")
    plan = _plan_file(tmp_path, n=2)
    labrig("sweep", "--sim", "--plan", plan, "-o", out, check=0)
    assert not any(p.exists() for p in stale) and other.exists()
    # a sweep killed while writing its second run: CSV and a tmp sidecar, no .json
    (out / "sq_1.50V.json").unlink()
    left = out / ".sq_1.50V.json.q1w2e3.tmp"
    left.write_text("{")
    labrig("sweep", "--sim", "--plan", plan, "-o", out, "--resume", check=0)
    assert not left.exists() and other.exists()
    assert [r.name for r in read_dataset(out)] == ["sq_1.00V", "sq_1.50V"]


def test_a_trusted_user_effect_in_a_rig_file_gets_its_parameters(tmp_path):
    """A rig file may hide a user effect (FILE.py:Class, trusted on the command line):
    the simulated rig applies it with the parameters the file gives, exactly as the
    catalogue effect of the same physics."""
    import pandas as pd

    from labrig.bridge.sweep import sweep
    from labrig.io.experiment import Experiment
    from labrig.bridge.sim import SimRig
    from labrig.io.config import rig_from_dict
    from labrig.model.effects import reset_trust, trust_code

    user = tmp_path / "mine.py"
    user.write_text(MY_COULOMB_PY)

    def tacho(effects, name):
        rig = rig_from_dict({"effects": effects}, "r.toml")
        exp = Experiment(name="sq", amplitude_v=0.6, periods=1, sample_rate_hz=200.0)
        sweep(SimRig(rig, seed=1), [exp], rig, tmp_path / name)
        return pd.read_csv(tmp_path / name / "sq.csv")["tacho"].to_numpy()

    trust_code([user])
    try:
        mine = tacho({f"{user}:MyCoulomb": {"tc_v": 0.3}}, "mine")
    finally:
        reset_trust()
    cat = tacho({"coulomb_friction": {"tc_v": 0.3}}, "cat")
    lin = tacho({}, "lin")
    assert np.max(np.abs(mine - lin)) > 0.2            # 0.3 V of friction shows (tacho V)
    assert np.array_equal(mine, cat)


def _catches(pid, sig):
    """Whether process `pid` has a handler for `sig` (Linux: SigCgt in /proc/PID/status)."""
    try:
        with open(f"/proc/{pid}/status") as fh:
            mask = next(line for line in fh if line.startswith("SigCgt:")).split()[1]
    except (OSError, StopIteration):
        return False
    return bool(int(mask, 16) >> (sig - 1) & 1)


@pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="needs Linux /proc")
@pytest.mark.parametrize("sig, code", [(signal.SIGTERM, 143), (signal.SIGHUP, 129)],
                         ids=["SIGTERM", "SIGHUP"])
def test_a_signal_in_the_first_moments_of_a_sweep(tmp_path, sig, code):
    """SIGTERM/SIGHUP by PID in the first moments of `labrig sweep` (while Python still
    imports the scientific stack, before the sweep's own handler exists) ends it like a
    later one: exit 128 + signal number and one line on stderr (was: killed by the signal,
    exit -15/-1 and no word). The signal is sent as soon as the child catches it at all,
    tens of ms after it starts; wherever it lands, the code is the same. The attempt counts
    as early if the child had not yet loaded pandas (which the sweep imports before it
    installs its own handler); before labrig.cli.main caught these signals, no attempt was."""
    name = signal.Signals(sig).name
    early = []
    for attempt in range(3):
        out = tmp_path / f"ds{attempt}"
        start = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-m", "labrig", "sweep", "--sim",
                                 "--plan", _plan_file(tmp_path), "-o", out],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        while proc.poll() is None and time.perf_counter() - start < 30:
            if _catches(proc.pid, sig):
                try:
                    with open(f"/proc/{proc.pid}/maps") as fh:
                        loaded = "pandas" in fh.read()
                except OSError:
                    loaded = True
                sent = time.perf_counter() - start
                os.kill(proc.pid, sig)
                break
            time.sleep(0.0005)
        else:
            proc.kill()
            pytest.fail(f"the sweep never caught {name} (exit {proc.wait()})")
        _, err = proc.communicate(timeout=30)
        lines = [line for line in err.splitlines() if not line.startswith("wrote ")]
        assert proc.returncode == code, (attempt, sent, err)
        assert len(lines) == 1 and lines[0].startswith(f"labrig: terminated by {name}"), err
        assert "Traceback" not in err
        assert not out.exists() or not [p for p in out.iterdir() if p.suffix == ".tmp"]
        if not loaded:
            early.append(sent)
            break
    assert early, f"{name} was never caught before the sweep's imports were done"
    assert early[0] < 5.0


def test_the_simulated_board_trips_as_the_board_does_and_the_run_stops_there(tmp_path):
    """A speed limit below what the 2 V square reaches: the simulated bridge ends that run
    at the first sample whose tacho reading passes it (the board's own check, on the same
    words), the sweep writes it up to there, plays nothing after it and exits 1 in one
    line; the run reads back as the samples taken, nothing after the trip."""
    rig_file = tmp_path / "rig.toml"
    rig_file.write_text((ROOT / "configs" / "rig_default.toml").read_text()
                        .replace("[bridge]\n", "[bridge]\ntrip_speed = 150.0\n", 1))
    p = labrig("sweep", "--sim", "--rig", rig_file, "-o", tmp_path / "ds")
    assert p.returncode == 1 and "run 'sq_2.00V': the board tripped" in p.stderr, p.stderr
    assert "over-speed" in p.stderr and "Traceback" not in p.stderr
    assert sorted(q.stem for q in (tmp_path / "ds").glob("*.csv")) == [
        "sq_1.20V", "sq_1.50V", "sq_2.00V"]
    run = read_run(tmp_path / "ds" / "sq_2.00V.csv")
    trip = run.meta["bridge"]["trip"]
    assert trip["fault"] == "TRIP" and len(run.data) == trip["after_sample"] + 1
    assert run.meta["bridge"]["dropped_samples"] == 8500 - len(run.data)
    speed = np.abs(run.data["tacho"].to_numpy()) / run.meta["sensors"]["tacho_v_per_rad_s"]
    quantum = 20.0 / 1024 / run.meta["sensors"]["tacho_v_per_rad_s"]   # one ADC word
    assert speed[-1] > 150.0 - quantum and speed[:-1].max() < 150.0 + quantum
    assert "gap" not in run.data or run.data["gap"].sum() == 0   # nothing after the trip
    # the runs before it are whole
    assert len(read_run(tmp_path / "ds" / "sq_1.50V.csv").data) == 8500


# -- who closes a plan's closed loops on a board, and each family's default plan -------------

def test_a_closed_loop_that_names_no_closer_is_the_boards_where_its_firmware_closes_loops():
    """On an MS150 board whose firmware closes loops (HELLO capability bit 5), the default
    plan's closed-loop steps (no closed_by) are closed by the board at the plan's gains; on
    a rig file that declares its patch they stay the patch's; on an older board they stay
    unset and are refused before anything moves, with the fix."""
    from dataclasses import replace

    from labrig.bridge import protocol as P
    from labrig.bridge.sweep import check_plan, the_rigs_way
    from labrig.core.errors import UserError
    from labrig.io.config import load_plan, load_rig

    rig = load_rig(ROOT / "configs" / "rig_default.toml")
    plan = load_plan(None, rig)
    assert [e.closed_by for e in plan if e.loop == "closed"] == [None, None]
    now = the_rigs_way(plan, rig, P.CAP_BOARD_LOOP | P.CAP_PWL)
    assert [e.closed_by for e in now if e.loop == "closed"] == ["board", "board"]
    assert [e.closed_by for e in now if e.loop == "open"] == [None] * 4
    assert [(e.position_gain, e.velocity_gain) for e in now if e.loop == "closed"] == [(2.0, 0.15)] * 2
    check_plan(now, rig, board=True)
    old = the_rigs_way(plan, rig, P.CAP_PWL)
    assert old == plan
    with pytest.raises(UserError, match='write closed_by = "board" in the plan'):
        check_plan(old, rig, board=True)
    patched = replace(rig, bridge=replace(rig.bridge, loop_kp=2.0, loop_kv=0.15))
    assert the_rigs_way(plan, patched, P.CAP_BOARD_LOOP) == plan


def test_each_rig_family_sweeps_its_own_default_plan():
    """Without --plan an MS150 plays configs/plan_default.toml, an H-bridge gear motor
    configs/plan_arduino.toml (its supply's range at the sketch's 200 Hz)."""
    from labrig.io.config import load_plan, load_rig

    hb = load_plan(None, load_rig(ROOT / "configs" / "rig_arduino_hbridge.toml"))
    assert [e.name for e in hb] == [e.name for e in load_plan(ROOT / "configs" / "plan_arduino.toml")]
    assert {e.sample_rate_hz for e in hb} == {200.0} and max(e.amplitude_v for e in hb) == 12.0
    ms = load_plan(None, load_rig(ROOT / "configs" / "rig_default.toml"))
    assert [e.name for e in ms] == [e.name for e in load_plan(ROOT / "configs" / "plan_default.toml")]
