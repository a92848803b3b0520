"""Independent fits on both cores.

A round of the loop fits several structures, or one structure on several folds, or from
two starts; each fit is a chain of small simulations (a Jacobian is a handful of
candidates, too few for the kernels' own threads). Those fits run side by side in
threads: the serial kernels release the GIL, so two fits keep both cores busy without a
second interpreter to start or data to copy. The results come back in the order given,
and each fit is the same computation it is alone: the answer does not depend on the
number of threads.

Threads are used only where numba's threading layer is threadsafe (OpenMP or TBB, both
present in the usual wheels); with its fallback layer the fits run one after another.
``LABRIG_THREADS=1`` does the same on purpose.
"""
from __future__ import annotations

import functools
import os
import sys
import threading

from labrig.core.errors import UserError

_local = threading.local()


@functools.cache
def _threadsafe() -> bool:
    # probes, inside: either pool may be missing (ImportError), and numba (numpy) must not
    # load with this module, which the command line imports before one_blas_thread()
    try:
        from numba.np.ufunc import omppool  # noqa: F401
        return True
    except ImportError:
        pass
    try:
        from numba.np.ufunc import tbbpool  # noqa: F401
        return True
    except ImportError:
        return False


#: the variables the BLAS libraries numpy ships with read when they load
BLAS_VARS = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def one_blas_thread() -> None:
    """Hold numpy's BLAS to one thread, unless the user has set it. labrig's matrices are
    small (a fit's few-by-few SVDs and Gram matrices, norms of one run), so BLAS threads
    never pay; OpenBLAS's idle threads spin for a while after every call, on the core a
    second fit needs (a diagnose round markedly slower on 2 cores), and a
    threaded norm sums in an order that depends on the machine's core count (the last
    digits of a fit percentage moved with it). Before numpy loads its BLAS the
    environment does it (the command line calls this first); once it has loaded (a
    notebook that imported numpy before labrig), threadpoolctl sets the loaded BLAS."""
    told = any(var in os.environ for var in BLAS_VARS)
    for var in BLAS_VARS:
        os.environ.setdefault(var, "1")
    if not told and "numpy" in sys.modules:
        from threadpoolctl import threadpool_limits  # (loads nothing numpy has not)

        threadpool_limits(1, user_api="blas")


def jobs() -> int:
    """How many fits run at once: the cores, unless ``LABRIG_THREADS`` says otherwise
    (at most twice the cores)."""
    want = os.environ.get("LABRIG_THREADS", "").strip()
    if want and not (want.isdigit() and int(want) > 0):
        raise UserError(f"LABRIG_THREADS={want!r}: give a whole number of threads >= 1 "
                        "(1 runs the fits one after another), or unset it")
    n = int(want) if want else (os.cpu_count() or 1)
    return min(n, 2 * (os.cpu_count() or 1)) if _threadsafe() else 1


def each(fn, items) -> list:
    """``[fn(x) for x in items]``, on both cores; nested calls run in the caller's thread."""
    items = list(items)
    n = min(jobs(), len(items))
    if n <= 1 or getattr(_local, "inside", False):
        return [fn(x) for x in items]
    from joblib import Parallel, delayed  # ~0.1 s to import; only when fits run at once

    def run(x):
        _local.inside = True
        try:
            return fn(x)
        finally:
            _local.inside = False

    return Parallel(n_jobs=n, backend="threading")(delayed(run)(x) for x in items)
