"""Shared fixtures: simulated rigs and datasets with known truth."""
from __future__ import annotations

from labrig.core.parallel import one_blas_thread

one_blas_thread()  # as the command line does, before numpy is imported

import collections  # noqa: E402
import copy  # noqa: E402
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from labrig.io.experiment import Experiment
from labrig.bridge.sim import SimRig
from labrig.bridge.sweep import sweep
from labrig.io.config import load_rig
from labrig.core.memory import keep_freed_memory

# as the command line does: the fits' arrays stay in the heap between calls
keep_freed_memory()

import outputs_record  # noqa: E402  (LABRIG_RECORD_OUTPUTS: the kernels' measurement)

outputs_record.install()

# A suite started in the background of a non-interactive shell (nohup, `&`, some CI
# runners) inherits SIGINT ignored, and so would every command a test starts: the tests
# of Ctrl-C would then test the launcher. Python's own handler here is reset to the default
# in each child at exec, as in a terminal.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


def pytest_sessionfinish(session):
    outputs_record.write()


# -- the OpenBLAS kernel a test met ---------------------------------------------------------
# `make test-kernels` re-runs the kernels-marked tests on two workers, each under another
# OpenBLAS kernel (OPENBLAS_CORETYPE, set per worker): each test's JUnit record names the
# kernel it met, and the end of the run counts them.

@pytest.fixture(autouse=True)
def _openblas_kernel(record_property):
    kernel = os.environ.get("OPENBLAS_CORETYPE")
    if kernel:
        record_property("openblas_coretype", kernel)


def _kernels_met(terminalreporter):
    met = collections.Counter(
        dict(r.user_properties).get("openblas_coretype")
        for key in ("passed", "failed") for r in terminalreporter.stats.get(key, [])
        if getattr(r, "when", "call") == "call")
    met.pop(None, None)
    if met:
        terminalreporter.write_line("OpenBLAS kernels met: " + ", ".join(
            f"{k} {n} tests" for k, n in sorted(met.items())))


ROOT = Path(__file__).resolve().parent.parent

#: a user's own effect file, as a student writes it: dry friction (tests of user effects)
MY_COULOMB_PY = '''
from labrig.model.effects import Effect, Param


class MyCoulomb(Effect):
    """Dry friction: a constant torque against the motion."""
    name = "my_coulomb"
    stage = "friction"
    params = (Param("tc_v", "V", 1e-3, 2.0, "friction as the input voltage that balances it"),)

    def friction(self, plant, tc_v):
        t = tc_v * plant.Ka * plant.K / plant.R   # the stall torque of tc_v volts
        return t, t                               # (kinetic, breakaway)

    def initial_guess(self, runs, plant):
        return {"tc_v": 0.1}
'''


def make_rig(effects=None, noise=True, **plant):
    """The default rig with its hidden effects replaced by ``effects``."""
    rig = copy.deepcopy(load_rig())
    rig.effects = dict(effects or {})
    for k, v in plant.items():
        setattr(rig.plant, k, v)
    if not noise:
        rig.noise.tacho_v = rig.noise.pos_v = 0.0
    return rig


def square_plan(amps=(1.2, 1.5, 2.0, 2.5), rate=1000.0, periods=2, freq=0.25, lead=0.5):
    return [Experiment(name=f"sq_{a:.2f}V", amplitude_v=a, frequency_hz=freq, periods=periods,
                       lead_in_s=lead, sample_rate_hz=rate) for a in amps]


def sim_dataset(tmp_path, rig, plan, name="ds", seed=None):
    out = Path(tmp_path) / name
    sweep(SimRig(rig, seed=seed), plan, rig, out)
    return out


def labrig(*args, check=None, **kw):
    """Run the real CLI in a subprocess; returns CompletedProcess."""
    proc = subprocess.run([sys.executable, "-m", "labrig", *map(str, args)],
                          capture_output=True, text=True, **kw)
    if check is not None:
        assert proc.returncode == check, proc.stderr
    return proc


@pytest.fixture
def rig():
    return make_rig()


@pytest.fixture
def emulators():
    """``emulators(board, rig, **kw)`` starts an emulated board and returns it.

    Every emulator started through it is stopped at teardown through its own process
    (SIGTERM to that PID, then SIGKILL), even when the test fails; nothing is ever
    killed by name.
    """
    from labrig.bridge.emulate import Emulator

    started = []

    def start(board="uno", rig=None, **kw):
        emu = Emulator(board, rig, **kw)
        started.append(emu)
        emu.start()
        return emu

    yield start
    for emu in started:
        emu.stop()


# -- an emulated board on a machine too busy for it ----------------------------------------
# The emulated board runs in real time by design. On a loaded machine simavr falls behind
# the wall clock, and a test that times the host against the board then measures the
# machine, not the firmware: such a failure is reported as a skip saying by how much the
# board fell behind, and a test that passed while behind is listed at the end; neither is
# silent.

#: an emulated board further behind real time than this ran on a machine too busy for it
EMULATOR_LAG_S = 0.05
_LAGGED: list = []


def _emulator_lag(since: int) -> float:
    from labrig.bridge.emulate import Emulator

    return max([*Emulator.lags[since:], *(e.behind_s() for e in list(Emulator.running))],
               default=0.0)


def pytest_runtest_setup(item):
    if item.get_closest_marker("firmware"):
        from labrig.bridge.emulate import Emulator

        item.emulator_lags_from = len(Emulator.lags)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    rep = outcome.get_result()
    if rep.when != "call" or not hasattr(item, "emulator_lags_from"):
        return
    lag = _emulator_lag(item.emulator_lags_from)
    if lag <= EMULATOR_LAG_S:
        return
    _LAGGED.append((item.nodeid, lag, rep.outcome))
    if rep.failed:
        first = str(rep.longrepr).strip().splitlines()[-1][:300] if rep.longrepr else ""
        rep.outcome = "skipped"
        rep.longrepr = (str(item.path), item.location[1] or 0,
                        f"Skipped: the emulated board fell {1e3 * lag:.0f} ms behind real time "
                        f"(the machine was too busy for a real-time board), so its timing was "
                        f"not tested; the failure was: {first}")


def pytest_terminal_summary(terminalreporter):
    _kernels_met(terminalreporter)
    if _LAGGED:
        terminalreporter.write_sep("-", "emulated boards behind real time")
        for nodeid, lag, outcome in _LAGGED:
            terminalreporter.write_line(f"{nodeid}: {1e3 * lag:.0f} ms behind ({outcome})")


@pytest.fixture(scope="module")
def browser():
    """Headless Chromium for the browser tests (tests/lab_page.py)."""
    from lab_page import launch

    yield from launch()
