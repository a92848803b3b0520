"""Shared fixtures: simulated rigs and datasets with known truth."""
from __future__ import annotations

import copy
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from labrig.bridge.base import Experiment
from labrig.bridge.sim import SimRig
from labrig.acquire import sweep
from labrig.config import load_rig

ROOT = Path(__file__).resolve().parent.parent


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
