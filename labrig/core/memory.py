"""Keep freed memory in the process instead of handing it back to the kernel at once.

A fit allocates and frees the same few arrays thousands of times a second (a Jacobian's
trajectories, residual rows: a few MB each). glibc's malloc returns the top of its heap to
the kernel as soon as more than its trim threshold is free, and serves large requests with
fresh ``mmap`` pages, so each of those arrays is faulted in page by page again, zeroed by
the kernel, on every call, and the threads of two fits queue on the process's memory map
while it happens. On the README's ``diagnose --auto`` case that was a quarter of the wall
time, in the kernel (benchmarks/README.md, 'Where the time goes', has the measurement).

:func:`keep_freed_memory` asks glibc (``mallopt(M_TOP_PAD)``) for that padding. The
command line calls it once at start, and so does ``import labrig`` (a notebook's diagnose
round is the command line's fits, and was as much slower without it); the heap then keeps
up to 64 MB free at its top. Elsewhere (macOS, musl) it does nothing.
"""
from __future__ import annotations

import ctypes
import sys

#: glibc's ``mallopt`` parameter (malloc.h)
M_TOP_PAD = -2
#: how much free memory the heap keeps at its top (and grows by)
TOP_PAD_BYTES = 64 << 20

_done = False


def keep_freed_memory() -> bool:
    """Once per process: let the heap keep ``TOP_PAD_BYTES`` free instead of trimming it.
    Returns True when glibc took the setting."""
    global _done
    if _done or not sys.platform.startswith("linux"):
        return False
    _done = True

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return mallopt(M_TOP_PAD, TOP_PAD_BYTES) == 1
