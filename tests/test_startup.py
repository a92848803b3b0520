"""Start-up: what a command imports, and the noise floor's smoother that keeps
scipy.signal out of every identifying command."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from scipy.signal import savgol_coeffs, savgol_filter

from conftest import sim_dataset, square_plan
from labrig.noise import WINDOW, _quadratic_weights, _smooth_quadratic


@pytest.mark.parametrize("window", [5, 7, WINDOW, 31])
def test_quadratic_smoother_is_savitzky_golay(window):
    rng = np.random.default_rng(3)
    y = np.cumsum(rng.normal(size=400)) + rng.normal(size=400)
    assert np.allclose(_quadratic_weights(window), savgol_coeffs(window, 2), rtol=0, atol=1e-14)
    ref = savgol_filter(y, window, 2, mode="interp")
    assert np.max(np.abs(_smooth_quadratic(y, window) - ref)) < 1e-12 * np.max(np.abs(y)) * window


def _imported(code: str) -> set[str]:
    out = subprocess.run([sys.executable, "-c", code + "\nimport sys, json\n"
                          "print(json.dumps(sorted(sys.modules)))"],
                         capture_output=True, text=True, check=True)
    return set(json.loads(out.stdout.splitlines()[-1]))


HEAVY = ("control", "scipy.signal", "scipy.stats", "scipy.optimize", "matplotlib", "h5py",
         "dask", "joblib")


def test_parser_imports_nothing_heavy():
    """Building the whole command line (every subcommand's options) loads no library."""
    mods = _imported("from labrig.cli import build_parser\nbuild_parser()")
    assert not [m for m in HEAVY if m in mods]
    assert "numba" not in mods and "pandas" not in mods


def test_identify_path_imports_only_what_it_uses(tmp_path, rig):
    """Reading a data set, its noise floors and the objective of a JFO fit: numba and
    pandas yes; python-control, scipy.signal/stats/optimize and matplotlib no."""
    folder = sim_dataset(tmp_path, rig, square_plan(amps=(1.5,), periods=1), seed=1)
    code = ("from labrig.runs import read_dataset\n"
            "from labrig.identify.objective import Objective, build_space\n"
            "from labrig.model.effectset import EffectSet\n"
            f"runs = read_dataset([r'{folder}'])\n"
            "space = build_space(EffectSet.parse([]), None, None)\n"
            "obj = Objective(runs, EffectSet.parse([]), space)\n"
            "import numpy as np\n"
            "obj.fitness_batch(np.array([space.to_search(dict(zip(space.names, "
            "np.sqrt(space.lower * space.upper))))]))\n")
    mods = _imported(code)
    assert "numba" in mods
    assert not [m for m in HEAVY if m in mods], [m for m in HEAVY if m in mods]


def test_cold_cache_is_announced_once_before_compiling(monkeypatch, capsys):
    """A cold numba cache: one line on stderr saying what happens and about how long,
    then the compile; never again in the same process."""
    from labrig.model import warm

    calls = []
    monkeypatch.setattr(warm, "_done", False)
    monkeypatch.setattr(warm, "cache_is_warm", lambda: False)
    monkeypatch.setattr(warm, "_workload", lambda: calls.append(1))
    warm.ready()
    warm.ready()
    err = capsys.readouterr().err
    assert err.count("compiling the simulator once") == 1
    assert f"about {warm.COMPILE_S} s" in err
    assert calls == [1]


def test_installed_cache_is_warm():
    """The install step (python -m labrig.model.warm, run by make) filled numba's cache,
    so no command in this suite compiles."""
    from labrig.model import warm

    out = subprocess.run([sys.executable, "-m", "labrig.model.warm"], capture_output=True,
                         text=True, check=True)
    assert "loaded from the cache" in out.stdout or "compiled" in out.stdout
    assert warm.cache_is_warm()
