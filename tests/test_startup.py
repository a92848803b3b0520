"""Start-up: what a command imports, and the first compile."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest


from conftest import sim_dataset, square_plan


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
    pandas yes; scipy.signal (the floors' filter is scipy's, through scipy.linalg and
    scipy.ndimage), scipy.stats, scipy.optimize, python-control, matplotlib, h5py, dask,
    joblib no."""
    folder = sim_dataset(tmp_path, rig, square_plan(amps=(1.5,), periods=1), seed=1)
    code = ("from labrig.io.runs import read_dataset\n"
            "from labrig.identification.objective import Objective, build_space\n"
            "from labrig.model.effectset import EffectSet\n"
            f"runs = read_dataset([r'{folder}'])\n"
            "space = build_space(EffectSet.parse([]), None, None)\n"
            "obj = Objective(runs, EffectSet.parse([]), space)\n"
            "import numpy as np\n"
            "obj.fitness_batch(np.array([space.to_search(dict(zip(space.names, "
            "np.sqrt(space.lower * space.upper))))]))\n")
    mods = _imported(code)
    assert "numba" in mods and "pandas" in mods
    heavy = [m for m in HEAVY if m in mods]
    assert not heavy, heavy


def test_cold_cache_is_announced_once_before_compiling(monkeypatch, capsys):
    """A cold numba cache: one line on stderr saying what happens and about how long,
    then the compile; never again in the same process."""
    from labrig.simulation import warm

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
    """The install step (labrig-warm, run by make) filled numba's cache, so no command in
    this suite compiles."""
    from pathlib import Path

    from labrig.simulation import warm

    out = subprocess.run([str(Path(sys.executable).with_name("labrig-warm"))],
                         capture_output=True, text=True, check=True)
    assert "loaded from the cache" in out.stdout or "compiled" in out.stdout
    assert warm.cache_is_warm()


def test_the_install_step_refuses_what_it_does_not_take():
    """labrig-warm takes no arguments: one usage line and exit 2, no traceback."""
    from pathlib import Path

    proc = subprocess.run([str(Path(sys.executable).with_name("labrig-warm")), "--bogus"],
                          capture_output=True, text=True)
    assert proc.returncode == 2 and "unrecognized arguments: --bogus" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_the_floors_filter_is_scipys_to_the_last_bit():
    """labrig.analysis.savgol is scipy.signal's Savitzky-Golay filter ('interp' mode) and
    coefficients, and ndimage's convolution, without importing either: equal with ==, on
    smooth, quantised and noisy signals, every window the analyser and the floors use,
    value and derivative."""
    import numpy as np
    import scipy.signal as ss
    from scipy.ndimage import convolve1d

    from labrig.analysis import savgol

    rng = np.random.default_rng(7)
    for n, w in [(7, 7), (64, 7), (300, 5), (1001, 21), (4500, 11), (8500, 31)]:
        for y in (rng.normal(size=n).cumsum(), np.round(rng.normal(size=n) * 40) / 7,
                  3 * np.sin(0.01 * np.arange(n)) + 1e-3 * rng.normal(size=n)):
            assert np.array_equal(savgol.savgol_filter(y, w, 2),
                                  ss.savgol_filter(y, w, 2, mode="interp"))
            assert np.array_equal(savgol.savgol_filter(y, w, 2, deriv=1, delta=1e-3),
                                  ss.savgol_filter(y, w, 2, deriv=1, delta=1e-3, mode="interp"))
        assert np.array_equal(savgol.savgol_coeffs(w, 2), ss.savgol_coeffs(w, 2))
        # the convolution as ndimage sums it, for a filter with no symmetry too
        f = rng.normal(size=w)
        assert np.array_equal(savgol.convolve(y, f), convolve1d(y, f, mode="constant"))


def test_the_starts_hypercube_is_scipys_to_the_last_bit():
    """labrig.identification.lhs draws scipy.stats.qmc's Latin hypercube (spawned from the
    caller's generator, scaled to the box) without importing scipy.stats: equal with ==,
    and the caller's generator left as scipy leaves it (a second draw equal too)."""
    import numpy as np
    from scipy.stats import qmc

    from labrig.identification.lhs import latin_hypercube

    for seed, n, d in [(0, 4, 5), (1, 8, 7), (12345, 1, 3), (7, 50, 12)]:
        lo, hi = -np.arange(1.0, d + 1), np.linspace(0.5, 40.0, d)
        ours, theirs = np.random.default_rng(seed), np.random.default_rng(seed)
        for _ in range(2):
            want = qmc.scale(qmc.LatinHypercube(d=d, rng=theirs).random(n), lo, hi)
            assert np.array_equal(latin_hypercube(n, lo, hi, ours), want)
        assert np.array_equal(ours.random(3), theirs.random(3))


def test_the_command_line_keeps_freed_memory_in_the_heap():
    """glibc takes the heap padding once per process (labrig/core/memory.py), when labrig
    is imported (a notebook's fits as the command line's); a second call does nothing;
    elsewhere the call is a no-op."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", "import labrig.core.memory as m; "
                          "print(m._done, m.keep_freed_memory())"], capture_output=True,
                         text=True, check=True)
    linux = sys.platform.startswith("linux")
    assert out.stdout.split() == [str(linux), "False"]


@pytest.mark.parametrize("first, user, want", [
    ("import numpy\nimport labrig", None, 1),     # a notebook that imported numpy first
    ("import labrig\nimport numpy", None, 1),     # labrig first: the environment does it
    ("import numpy\nimport labrig", "2", 2),      # the user's own setting is kept
])
def test_import_labrig_holds_numpys_blas_to_one_thread(first, user, want):
    """``import labrig`` makes the command line's BLAS setting whatever was imported
    first (a notebook's fits then sum in the command line's order, at its speed), unless
    the user set the thread count."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items()
           if k not in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS")}
    if user:
        env["OPENBLAS_NUM_THREADS"] = user
    code = (f"{first}\nfrom threadpoolctl import threadpool_info\n"
            "print(max(i['num_threads'] for i in threadpool_info() "
            "if i['user_api'] == 'blas'))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, check=True)
    # OpenBLAS counts the CPUs this process may run on (taskset, a container's cpuset)
    assert int(out.stdout) == min(want, len(os.sched_getaffinity(0)))


def test_numpy_loads_after_the_command_line_holds_blas_to_one_thread():
    """What ``labrig.cli.run`` imports before ``main`` sets OPENBLAS_NUM_THREADS=1 (the
    step-metrics helper's module among it) loads no numpy: a BLAS that starts threaded
    sums in another order, and the last digits of a fit moved with it."""
    mods = _imported("import labrig.cli\nimport labrig.step_helper as h\nh.allow()")
    assert "numpy" not in mods
