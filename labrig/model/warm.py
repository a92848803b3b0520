"""Compile the simulator's kernels once, before anybody waits for them.

numba compiles :mod:`labrig.model.kernels` on first use and keeps the machine code in its
on-disk cache (``__pycache__`` beside the sources), so only the first command after an
installation pays. ``make`` warms the cache as part of the install
(``python -m labrig.model.warm``); anything else that meets a cold cache says so on
stderr before it compiles (:func:`ready`), and the identifiers' timings start after it.
"""
from __future__ import annotations

import os
import sys
import time

import numpy as np

#: the cold compile measured on the 2-core reference machine (benchmarks/README.md,
#: "First run"); the message quotes it so nobody thinks the program hangs
COMPILE_S = 30
_done = False


def _dispatchers():
    from . import kernels

    return [kernels._population_par, kernels._each_par, kernels._each_ser,
            kernels._expm_par, kernels._expm_ser]


def cache_is_warm() -> bool:
    """True when numba's cache holds every driver kernel, compiled from the kernels' source
    as it is now (an index older than the source is stale: numba would recompile)."""
    from . import kernels

    try:
        source = os.path.getmtime(kernels.__file__)
        indexes = [d._cache._cache_file._index_path for d in _dispatchers()]
        return all(os.path.exists(p) and os.path.getmtime(p) >= source for p in indexes)
    except (AttributeError, OSError):  # another numba's private layout: assume cold
        return False


def _workload() -> None:
    """Every kernel and mode on a tiny problem: open and closed loop, serial and parallel
    drivers, trajectories and fitness, every kind of effect."""
    from .effects import CATALOGUE
    from .simulate import RunData, Simulator

    t = np.arange(200) * 1e-3
    u = np.where((t > 0.02) & (t < 0.12), 1.5, -1.5)
    common = dict(dt=1e-3, Ka=4.0, N=30.0, Kt=0.0095, Kpot=1.0, theta0=0.0, amplitude=1.5)
    runs = [RunData(name="o", u=u, loop="open", kp=0.0, kv=0.0, w=u * 0, theta=u * 0, **common),
            RunData(name="c", u=u * 0.3, loop="closed", kp=1.0, kv=0.3, w=u * 0, theta=u * 0,
                    **common)]
    plant = np.array([8.0, 0.0085, 5.2e-5, 1.0e-5, 0.05])
    values = {"coulomb_friction": {"tc_v": 0.1}, "deadband": {"d_v": 0.2},
              "delay": {"td_s": 0.0015}, "backlash": {"a_rad": 0.01}}
    for names in ([], ["coulomb_friction"], ["deadband"], ["delay", "backlash"],
                  ["coulomb_friction", "deadband", "delay", "backlash"]):
        sim = Simulator(runs, [CATALOGUE[n]() for n in names])
        ep = {n: values[n] for n in names}
        weights = [(r.w, 1.0, r.theta, 1.0, None, 0.0) for r in runs]
        for P in (3, 40):  # one at a time and the population kernel (expm's threads from 32)
            sim.sse(np.tile(plant, (P, 1)), ep, weights)
        sim.simulate(np.tile(plant, (3, 1)), ep)


def warm() -> float:
    """Compile (or load) every kernel in this process; returns the seconds it took."""
    global _done
    _done = True  # the workload's own simulators must not ask again
    t0 = time.perf_counter()
    _workload()
    return time.perf_counter() - t0


def ready() -> None:
    """Once per process: if the kernels are not in numba's cache yet, say so and compile
    them now, so that no optimiser's timing includes the compilation."""
    global _done
    if _done:
        return
    _done = True
    if not cache_is_warm():
        print(f"labrig: compiling the simulator once (about {COMPILE_S} s on a 2-core "
              "machine; later runs load it from the cache)", file=sys.stderr, flush=True)
        warm()


def main() -> int:
    """``python -m labrig.model.warm``: the install step that fills the cache."""
    # run as a script this file is ``__main__``; the simulators ask the imported module
    from labrig.model import warm as module

    cold = not module.cache_is_warm()
    seconds = module.warm()
    print(f"labrig: simulator kernels {'compiled' if cold else 'loaded from the cache'} "
          f"in {seconds:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
