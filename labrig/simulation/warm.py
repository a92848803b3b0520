"""Compile the simulator's kernels once, before anybody waits for them.

numba compiles :mod:`labrig.simulation.kernels` on first use and keeps the machine code in its
on-disk cache (``__pycache__`` beside the sources), so only the first command after an
installation pays. ``make`` warms the cache as part of the install
(``python -m labrig.simulation.warm``); anything else that meets a cold cache says so on
stderr before it compiles (:func:`ready`), and the identifiers' timings start after it.
"""
from __future__ import annotations

import os
import sys
import time

import numpy as np

#: the cold compile measured on the 2-core reference machine (the README's performance table,
#: "first run after installation"); the message quotes it so nobody thinks the program hangs
COMPILE_S = 90
_done = False


def _dispatchers():
    from labrig.simulation import candidate_kernel, expm, kernels, residual_rows, sampled_kernel

    return [kernels.population_par, candidate_kernel.each_par, candidate_kernel.each_ser,
            sampled_kernel.each_sampled, expm.zoh_batch, expm.loop_slot_fill,
            residual_rows.residual_rows]


def _modules() -> list:
    """The kernel modules: a driver inlines functions from all of them."""
    from labrig.simulation import (candidate_kernel, expm, kernels, layout, loop_kernel,
                                   residual_rows, sampled_kernel)

    return [candidate_kernel, expm, kernels, layout, loop_kernel, residual_rows,
            sampled_kernel]


def _sources() -> list[str]:
    """The kernels' source files."""
    return [m.__file__ for m in _modules()]


def _indexes(dispatchers=None) -> tuple[list[str], list[str]]:
    """The cache indexes of ``dispatchers`` (the drivers if None): (present and current,
    missing or stale). numba checks only a function's own file; a driver inlines code
    from the other kernel modules too, so an index older than ANY of them is stale here.
    Raises when numba's private layout differs (callers treat that as a cold cache)."""
    newest = max(os.path.getmtime(f) for f in _sources())
    current, stale = [], []
    for d in _dispatchers() if dispatchers is None else dispatchers:
        p = d._cache._cache_file._index_path
        (current if os.path.exists(p) and os.path.getmtime(p) >= newest else stale).append(p)
    return current, stale


def cache_is_warm() -> bool:
    """True when numba's cache holds every driver kernel, compiled from the kernels' source
    as it is now."""
    try:
        return not _indexes()[1]
    except (AttributeError, KeyError, OSError):  # another numba's private layout: cold
        return False


def _cached_kernels() -> list:
    """Every cached compiled function of the kernel modules, the drivers' callees too: a
    callee's cached code holds what it called and inlined when it was built (``_block``
    the loop's lanes), and numba checks only the callee's own file."""
    import numba.core.registry

    out = []
    # every kernel module, from the one list the staleness check reads (a module left
    # out here kept its stale index, and every command then "compiled" it again)
    for module in _modules():
        for obj in vars(module).values():
            if isinstance(obj, numba.core.registry.CPUDispatcher) and \
                    obj.__module__ == module.__name__ \
                    and hasattr(obj._cache, "_cache_file"):
                out.append(obj)
    return out


def _forget_stale() -> None:
    """Remove every kernel's stale index (the drivers' and their callees'), so numba
    compiles them again instead of loading code built from an older inlined function."""
    try:
        for p in _indexes(_cached_kernels())[1]:
            if os.path.exists(p):
                os.remove(p)
    except (AttributeError, KeyError, OSError):
        pass


def _workload() -> None:
    """Every driver and mode on a tiny problem, with the argument types the simulator
    passes: open and closed loop, friction, delay and play, an input map, trajectories and
    fitness, one candidate at a time and the population kernel (threads from 16)."""
    from labrig.simulation.expm import loop_slot_fill, zoh_batch
    from labrig.simulation.kernels import run_kernels
    from labrig.simulation.sampled_kernel import each_sampled
    from labrig.simulation.residual_rows import residual_rows
    from labrig.simulation.layout import (C_A, C_ASYM, C_D, C_TC, C_TS, C_VMAX, MAP_COLUMNS,
                                     N_COLS, N_SLOTS, SLOT_W)

    n = 60
    u = np.where(np.arange(n) % 30 < 15, 1.5, -1.5)
    consts = np.array([1e-3, 4.0, 30.0, 0.0095, 1.0, 1.0, 0.3, 0.0])
    # a Jacobian's residual rows
    residual_rows(np.empty((3, n)), 0, u, np.zeros((3, n)), np.arange(n), 1.0)
    for P in (3, 20, 40):
        A = np.zeros((P, 3, 3))
        A[:, 0, 0], A[:, 1, 1] = -900.0, -0.2
        Ad, _, g, _ = zoh_batch(A, np.zeros((P, 3)), np.zeros((P, 3)), np.zeros(P), 1e-3)
        loop_slot_fill(np.zeros((P, N_SLOTS, SLOT_W)), 1, A, np.ones((P, 3)), np.ones((P, 3)),
                       np.zeros(P), 1e-3, np.ones(P), np.ones(P), 1.0, 1.0, 1.0, 1.0, 1.0,
                       1.0, True, True, np.ones(P, np.bool_))
        # (a closed loop with its map: each build of the loop's lanes, kernels._loop_sample)
        for closed, nonlinear, mapped, extra in (
                (0, False, False, ()), (0, False, True, (C_TC,)), (1, False, False, (C_A,)),
                (1, True, False, (C_D,)), (1, True, False, (C_ASYM,)),
                (1, True, False, (C_D, C_TC)), (1, True, False, (C_A,)),
                (1, True, False, (C_A, C_TC))):
            prm = np.zeros((P, N_COLS))
            prm[:, :5] = [8.0, 0.0085, 5.2e-5, 1.0e-5, 0.05]
            prm[:, C_VMAX] = np.inf
            for col in extra:
                prm[:, col] = 0.01
            prm[:, C_TS] = prm[:, C_TC]
            m = np.zeros(P, np.int64)
            m[0] = 1  # a delayed lane
            imap = np.zeros((P if mapped else 0, len(MAP_COLUMNS)))
            s = np.ascontiguousarray(u[:, None])
            for store in (False, True):
                out = (np.empty((P, n)),) * 3 if store else (np.empty((1, 1)),) * 3
                run_kernels(s, m, np.zeros(P), Ad, g, g, g, prm,
                            np.full(P, nonlinear, dtype=bool), closed, 4, consts, *out, store,
                            u * 0.0, 1.0, u * 0.0, 1.0, u * 0.0, 0.0, np.zeros(P), imap,
                            np.zeros((P if nonlinear else 0, N_SLOTS, SLOT_W)))
        # a board's own loop (labrig.simulation.sampled_kernel), stored and summed
        imap = np.zeros((P, len(MAP_COLUMNS)))
        pd = np.array([2560.0, 256.0, 200.0, 0.05, -255.0, 255.0])
        for store in (False, True):
            out = (np.empty((P, n)),) * 4 if store else (np.empty((1, 1)),) * 4
            each_sampled(np.round(u * 100.0), np.zeros(P, np.int64), np.zeros(P), Ad, g, g, g,
                         prm, 4, consts, pd, *out, store, u * 0.0, 1.0, u * 0.0, 1.0, u * 0.0,
                         0.0, np.zeros(P), imap)


def warm() -> float:
    """Compile (or load) every kernel in this process; returns the seconds it took."""
    global _done
    _done = True  # the workload's own simulators must not ask again
    t0 = time.perf_counter()
    _forget_stale()
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


def main(argv=None) -> int:
    """``labrig-warm``: the install step that fills the cache (takes no arguments)."""
    import argparse

    argparse.ArgumentParser(
        prog="labrig-warm", description="Compile labrig's simulator kernels into numba's "
        "cache (make runs this at install; later commands load them)").parse_args(argv)
    # run as a script this file is ``__main__``; the simulators ask the imported module
    from labrig.simulation import warm as module

    cold = not module.cache_is_warm()
    seconds = module.warm()
    print(f"labrig: simulator kernels {'compiled' if cold else 'loaded from the cache'} "
          f"in {seconds:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
