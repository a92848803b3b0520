"""One background process for the page's fits, so the page stays responsive while the
numba kernels run (they hold the interpreter lock), and Cancel can end a fit at once.

Built on the standard library's ``multiprocessing.Pool`` (spawn: no state inherited from
the server); Cancel terminates the pool and starts a fresh one. A job may report progress
lines through ``log``: they arrive on :meth:`Worker.logs`. A job that must have the rig
play something (the rig belongs to the page's process) asks through ``ask_rig``: the
request arrives on :meth:`Worker.logs` as an event of kind ``rig``, and the job waits for
the page's :meth:`Worker.reply`.
"""
from __future__ import annotations

import inspect
import multiprocessing
import os
import time

from labrig.core.memory import keep_freed_memory

_LOG = None     # the worker's end of the log queue (set by _init in the worker)
_REPLIES = None  # the page's answers to a job's requests of the rig


def _init(queue, replies, threads: int = 0) -> None:
    global _LOG, _REPLIES
    _LOG, _REPLIES = queue, replies
    if threads:   # a class's share of the server's cores: the fits' threads and numba's
        import numba

        os.environ["LABRIG_THREADS"] = str(threads)
        numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))
    # a spawned process has the parent's environment (one BLAS thread) but not its
    # allocator setting: without it every fit's arrays are faulted in afresh, and the
    # page's fits ran up to twice as long as the command line's
    keep_freed_memory()
    import matplotlib

    matplotlib.use("Agg")   # the worker draws figures to PNG, never to a window
    import warnings

    warnings.simplefilter("ignore", RuntimeWarning)  # wild candidates overflow on purpose


def _ask_rig(request: dict):
    """From a job: have the page play ``request`` on the rig, and wait for its answer."""
    _LOG.put({"kind": "rig", **request})
    return _REPLIES.get()


def _call(fn, args, kw):
    params = inspect.signature(fn).parameters
    if "log" in params:
        kw = {**kw, "log": _LOG.put}
    if "ask_rig" in params:
        kw = {**kw, "ask_rig": _ask_rig}
    return fn(*args, **kw)


def _warm() -> bool:
    """While the page opens: the loop's modules, numba's cache, and python-control (the
    step metrics of every fit; its import is the slowest), so a first click waits for
    none of them. The kernels load with the first fit (a first diagnosis after it took
    1.35 s, a warm one 1.37 s: the fit loads what it needs); loaded here they took a
    core from a sweep started as the page opened (its live view 0.74 s behind, not 0.5)."""
    import control  # noqa: F401

    import labrig.verbs as lr

    lr.warm_up(load=False)
    return True


class Worker:
    """Runs one job at a time in a separate process; ``threads``: the cores its fits use
    (0: every core of the machine; numba's threads and labrig's parallel fits alike)."""

    def __init__(self, threads: int = 0):
        self.threads = threads
        self._ctx = multiprocessing.get_context("spawn")
        self._queue = self._ctx.Queue()
        self._replies = self._ctx.Queue()
        self._pool = None
        self._job = None
        self.name = ""
        self.started = 0.0
        self._start()

    def _start(self) -> None:
        self._pool = self._ctx.Pool(1, initializer=_init,
                                    initargs=(self._queue, self._replies, self.threads))
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

    def reply(self, answer) -> None:
        """The page's answer to the running job's request of the rig."""
        self._replies.put(answer)

    def cancel(self) -> None:
        """End the running job at once (the process is terminated) and start afresh."""
        self._pool.terminate()
        self._pool.join()
        self._job = None
        while not self._replies.empty():   # an answer the ended job never read
            try:
                self._replies.get_nowait()
            except Exception:
                break
        self._start()

    def close(self) -> None:
        self._pool.terminate()
        self._pool.join()
        for q in (self._queue, self._replies):
            q.close()
            q.join_thread()
