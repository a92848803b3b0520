"""One background process for the page's fits, so the page stays responsive while the
numba kernels run (they hold the interpreter lock), and Cancel can end a fit at once.

Built on the standard library's ``multiprocessing.Pool`` (spawn: no state inherited from
the server); Cancel terminates the pool and starts a fresh one. A job may report progress
lines through ``log``: they arrive on :meth:`Worker.logs`.
"""
from __future__ import annotations

import inspect
import multiprocessing
import time

from labrig.core.memory import keep_freed_memory

_LOG = None     # the worker's end of the log queue (set by _init in the worker)


def _init(queue) -> None:
    global _LOG
    _LOG = queue
    # a spawned process has the parent's environment (one BLAS thread) but not its
    # allocator setting: without it every fit's arrays are faulted in afresh, and the
    # page's fits ran up to twice as long as the command line's
    keep_freed_memory()
    import matplotlib

    matplotlib.use("Agg")   # the worker draws figures to PNG, never to a window
    import warnings

    warnings.simplefilter("ignore", RuntimeWarning)  # wild candidates overflow on purpose


def _call(fn, args, kw):
    if "log" in inspect.signature(fn).parameters:
        kw = {**kw, "log": _LOG.put}
    return fn(*args, **kw)


def _warm() -> bool:
    """While the page opens: the loop's modules, numba's cache, and python-control (the
    step metrics of every fit; its import is the slowest), so a first click waits for
    none of them."""
    import control  # noqa: F401

    import labrig.verbs as lr

    lr.warm_up()
    return True


class Worker:
    """Runs one job at a time in a separate process."""

    def __init__(self):
        self._ctx = multiprocessing.get_context("spawn")
        self._queue = self._ctx.Queue()
        self._pool = None
        self._job = None
        self.name = ""
        self.started = 0.0
        self._start()

    def _start(self) -> None:
        self._pool = self._ctx.Pool(1, initializer=_init, initargs=(self._queue,))
        self._pool.apply_async(_warm)

    @property
    def busy(self) -> bool:
        return self._job is not None and not self._job.ready()

    @property
    def pending(self) -> bool:
        """A job running, or finished and not yet taken by :meth:`poll`."""
        return self._job is not None

    def submit(self, name: str, fn, *args, **kw) -> None:
        if self.busy:
            raise RuntimeError(f"busy with {self.name}")
        self.name, self.started = name, time.monotonic()
        self._job = self._pool.apply_async(_call, (fn, args, kw))

    def poll(self):
        """``None`` while running (or idle); ``(name, value, error)`` once, when done."""
        if self._job is None or not self._job.ready():
            return None
        job, self._job = self._job, None
        try:
            return self.name, job.get(), None
        except Exception as exc:   # the job's own error, shown on the page as one line
            return self.name, None, exc

    def logs(self) -> list:
        """What the job reported since: lines (str) and events (dicts, what the page
        streams: a candidate done, a rung of the ladder)."""
        out = []
        while not self._queue.empty():
            try:
                item = self._queue.get_nowait()
            except Exception:
                break
            out.append(item if isinstance(item, dict) else str(item))
        return out

    def cancel(self) -> None:
        """End the running job at once (the process is terminated) and start afresh."""
        self._pool.terminate()
        self._pool.join()
        self._job = None
        self._start()

    def close(self) -> None:
        self._pool.terminate()
        self._pool.join()
        self._queue.close()
        self._queue.join_thread()
