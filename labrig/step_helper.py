"""The position loop's step metrics from a second process that imports python-control
while the fit runs.

An identified model's rise time, settling time and overshoot are python-control's
``step_info`` (:meth:`ServoParams.position_step_info`). Importing python-control brings
scipy.signal, scipy.stats and matplotlib.pyplot with it: 0.9-1.6 s on one core here
(the host's speed drifts), after the fit, in every ``identify`` and ``diagnose`` a
student waits for. The fit needs none of it, and until its first population the process
runs on one core. So the command line forks one helper process at the start of those
commands (:func:`start`); it imports python-control on the other core while the parent
imports and loads its kernels, then answers each ``(servo, kp, kv)`` with the same
function on the same libraries: the same numbers as in the process (a test compares
them). It runs at the parent's priority: made to yield (SCHED_IDLE, nice 19) it ended the
README's JFO case 0.1 s sooner on an idle machine (medians of 8), but behind any other
load it would starve and keep the parent waiting.

Only a fresh command-line process starts a helper (:func:`allow`, from ``labrig.cli.run``):
forking is safe there because no thread has started yet; a notebook, the lab page and the
tests compute in their own process. The helper ignores Ctrl-C (the parent handles it),
ends when the parent's end of its pipe closes, whatever way the parent ends, and every
failure (no fork on this system, the helper gone, an answer slower than ``TIMEOUT_S``)
falls back to computing in the process.
"""
from __future__ import annotations

import threading
from typing import TYPE_CHECKING

if TYPE_CHECKING:   # the command line's entry imports this module: keep it light
    from labrig.verbs.types import ServoParams

#: how long one answer may take before the process computes it itself (the helper's
#: python-control import is included in the first: a first import may build
#: matplotlib's font cache)
TIMEOUT_S = 120.0

_allowed = False
_helper = None          # (process, connection) while the helper runs
_lock = threading.Lock()  # two fit threads may ask at once


def allow() -> None:
    """Let :func:`start` fork a helper: called by the command line's entry point, in a
    process that has no other thread yet."""
    global _allowed
    _allowed = True


def start() -> None:
    """Fork the helper, if allowed, not running and python-control not yet imported."""
    global _helper
    import sys

    if not _allowed or _helper is not None or "control" in sys.modules:
        return
    if not sys.platform.startswith("linux"):   # fork is only safe to rely on there
        return
    if threading.active_count() != 1:
        return
    import multiprocessing
    import signal

    ctx = multiprocessing.get_context("fork")
    ours, theirs = ctx.Pipe()
    proc = ctx.Process(target=_serve, args=(theirs, ours), name="labrig-step-metrics",
                       daemon=True)
    # a Ctrl-C in the moment between the fork and the helper's own SIG_IGN would raise
    # in the helper (a traceback on the terminal): held back around the fork, then
    # delivered to the parent as usual
    held = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        proc.start()
    except OSError:   # no process to spare: compute in the process
        ours.close()
        return
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, held)
        theirs.close()
    _helper = (proc, ours)
    from labrig.core.offload import hand   # (light: numpy's import keeps its place)

    hand("step_info", position_step_info)   # the library's fits ask the helper from now on


def stop() -> None:
    """End the helper now (the command is done, or the process is about to exit)."""
    global _helper
    with _lock:
        if _helper is not None:
            proc, conn = _helper
            _helper = None
            conn.close()
            if proc.is_alive():
                proc.kill()   # ours, by its PID; it holds nothing worth a clean end
                proc.join(1.0)


def kill_now() -> None:
    """End the helper from a signal handler: no lock (the interrupted code may hold it),
    no wait; the process is about to exit."""
    helper = _helper
    if helper is not None:
        import os
        import signal

        try:
            os.kill(helper[0].pid, signal.SIGKILL)
        except OSError:
            pass


def position_step_info(servo: "ServoParams", kp: float, kv: float) -> dict:
    """``servo.position_step_info(kp, kv)``, from the helper when one runs."""
    global _helper
    with _lock:
        if _helper is not None:
            proc, conn = _helper
            try:
                conn.send((servo, kp, kv))
                if conn.poll(TIMEOUT_S):
                    status, value = conn.recv()
                    if status == "ok":
                        return value
                    raise value
                raise TimeoutError
            except (OSError, EOFError, TimeoutError):
                _helper = None   # gone or stuck: from now on, in the process
                conn.close()
                if proc.is_alive():
                    proc.kill()
    return servo.position_step_info(kp, kv)


def _serve(conn, parent_end) -> None:
    """The helper: import python-control, then answer until the parent's end closes."""
    import signal

    from labrig.core.timing import mark

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    parent_end.close()   # the fork's copy; else the pipe would never see the parent end
    mark("helper-start")
    try:
        import control  # noqa: F401  (the point of this process)
    except Exception:
        pass             # the parent's own import will say what is wrong
    mark("helper-ready")
    while True:
        try:
            servo, kp, kv = conn.recv()
        except (EOFError, OSError):
            return
        try:
            answer = ("ok", servo.position_step_info(kp, kv))
        except Exception as exc:   # the parent raises it as its own computation would
            answer = ("error", RuntimeError(f"{type(exc).__name__}: {exc}"))
        try:
            conn.send(answer)
        except (OSError, ValueError):
            return

