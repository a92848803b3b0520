"""Benches on other PCs: a bench PC serves its board to the class server through Dask
distributed, over TLS with a certificate per bench.

The class server runs a Dask scheduler that accepts only TLS connections whose
certificate the class's own authority signed (:mod:`labrig.classroom.certs`): an open
Dask scheduler runs any code sent to it. A bench PC runs a Dask worker
(:func:`serve_bench`, ``labrig class bench``) with one resource, its bench's name, in
the process that holds the bench's port (leased for as long as it runs, bound to the
board's id when given). A sweep asked of the bench is one task on that worker
(:func:`play_on_bench`): it plays the plan with the bench's own sweep code, sends the
samples (every 0.1 s) and each finished run's files back through a Dask queue, and
stops at 0 V when the class server sets the sweep's stop event. A bench whose worker
leaves mid-run is seen by the server as gone (:class:`RemoteBench`); the runs it sent
are kept.
"""
from __future__ import annotations

import asyncio
import logging
import tempfile
import threading
import time
import uuid
from pathlib import Path

import numpy as np

import labrig.verbs as lr
from labrig.core.errors import Interrupted, LabrigError, RigError, UserError
from labrig.core.fileio import atomic_write
from labrig.core.schemas import RUN_NAME_RE

#: what this process holds when it serves a bench: {name: (rig, make_bridge, realtime)}
_HELD: dict = {}
#: how long a bench PC tries to reach (or waits to hear again from) the class scheduler
CONNECT_S = 30.0
#: how often the bench sends the samples it has (the page refreshes as often)
SEND_S = 0.1


def resource(bench: str) -> str:
    """The Dask resource a bench's worker offers (one task at a time: one sweep)."""
    return f"bench-{bench}"


# -- the bench PC ----------------------------------------------------------------------

def serve_bench(address: str, bench: str, rig, make_bridge, close, security, *,
                realtime: bool = False, log=print) -> None:
    """Serve ``bench`` to the class scheduler at ``address`` (``tls://HOST:PORT``) until
    Ctrl-C: a Dask worker with the bench's resource, in this process, which holds the
    bench's port (``make_bridge``, ``close``: from :func:`labrig.verbs.open_bridge`);
    ``realtime``: pace a simulated rig to real time, as a board plays."""
    from distributed import Worker

    logging.getLogger("distributed").setLevel(logging.WARNING)   # its news: not the lab's
    _HELD[bench] = (rig, make_bridge, realtime)

    async def run():
        # death_timeout: a scheduler not reached (or lost) for this long ends the bench's
        # process, with a line saying so, instead of retrying forever
        async with Worker(address, security=security, nthreads=1, name=resource(bench),
                          resources={resource(bench): 1}, dashboard=False,
                          memory_limit=0, death_timeout=CONNECT_S) as w:
            log(f"serving {bench} to {address} (worker {w.address}); Ctrl-C stops it")
            await w.finished()
        log(f"stopped serving {bench}: the class server closed, or was not heard from "
            f"for {CONNECT_S:.0f} s")

    try:
        asyncio.run(run())
    except KeyboardInterrupt:
        pass
    except (OSError, TimeoutError, asyncio.TimeoutError) as exc:
        raise RigError(f"{address}: the class server's scheduler did not answer within "
                       f"{CONNECT_S:.0f} s ({type(exc).__name__}); is `labrig class serve` "
                       "running there, the address and port right, the port open to this "
                       "PC?") from None
    finally:
        _HELD.pop(bench, None)
        close()


def play_on_bench(bench: str, plan, key: str) -> str:
    """The task a bench's worker runs: play ``plan`` here, stream it back on queue
    ``key``, stop at 0 V when event ``key``-stop is set. Returns the sweep's note."""
    from distributed import Event, Queue

    rig, make, realtime = _HELD[bench]
    queue, stop_event = Queue(key), Event(f"{key}-stop")
    stop = threading.Event()
    pending: list = []
    lock = threading.Lock()
    done = threading.Event()
    held: dict = {}   # the bridge, once it is open (its counters go with the samples)

    def on_block(blk):
        with lock:
            pending.append(blk)

    def send():
        with lock:
            blocks, pending[:] = list(pending), []
        if blocks:
            cat = lambda k: (None if getattr(blocks[0], k) is None   # noqa: E731
                             else np.concatenate([getattr(b, k) for b in blocks]).tolist())
            queue.put({"kind": "samples", "index": cat("index"), "u": cat("u"),
                       "tacho": cat("tacho"), "pos": cat("pos"),
                       "counters": dict(held["bridge"].counters()) if held else {}})

    def pump():   # the samples out every SEND_S; the server's Stop in
        while not done.is_set():
            if stop_event.is_set():
                stop.set()
            send()
            done.wait(SEND_S)

    with tempfile.TemporaryDirectory(prefix="labrig-bench-") as tmp:
        outdir = Path(tmp)

        def on_start(exp):
            send()
            queue.put({"kind": "start", "name": exp.name, "n": exp.n_samples})

        def on_done(exp, run):
            send()
            files = {p.name: p.read_text(encoding="utf-8")
                     for p in sorted(outdir.glob(f"{exp.name}.*"))}
            queue.put({"kind": "run", "name": exp.name, "files": files})

        pumper = threading.Thread(target=pump, name="labrig-bench-pump", daemon=True)
        pumper.start()
        try:
            bridge = held["bridge"] = lr.live(make(), on_block, realtime=realtime, stop=stop)
            lr.play(bridge, plan, rig, outdir, on_start=on_start, on_done=on_done)
            note = "done"
        except Interrupted as exc:
            note = f"stopped: {exc}"
        except LabrigError as exc:
            note = f"error: {exc}"
        finally:
            done.set()
            pumper.join(5)
            send()
        queue.put({"kind": "end", "note": note})
        return note


# -- the class server ------------------------------------------------------------------

class Scheduler:
    """The class's Dask scheduler (TLS only), in a thread of the class server, and the
    server's client of it.

    Parameters
    ----------
    host, port : str, int
        Where bench PCs reach it.
    security, client_security : distributed.Security
        The scheduler's and the class server's own (:mod:`labrig.classroom.certs`).
    """

    def __init__(self, host: str, port: int, security, client_security):
        from distributed import Client

        logging.getLogger("distributed").setLevel(logging.WARNING)   # its news: not the lab's
        self._ready, self._stop = threading.Event(), None
        self._failed = None
        self.address = None
        self._thread = threading.Thread(target=self._run, args=(host, port, security),
                                        name="labrig-scheduler", daemon=True)
        self._thread.start()
        if not self._ready.wait(60) or self._failed:
            raise RigError(f"the class scheduler did not start on {host}:{port}: "
                           f"{self._failed or 'timed out'}")
        self.client = Client(self.address, security=client_security, timeout=30)

    def _run(self, host, port, security):
        from distributed import Scheduler as DaskScheduler

        async def main():
            self._stop = asyncio.Event()
            self._loop = asyncio.get_running_loop()
            async with DaskScheduler(host=host, port=port, security=security,
                                     dashboard=False, protocol="tls") as s:
                self.address = s.address
                self._ready.set()
                await self._stop.wait()
        try:
            asyncio.run(main())
        except Exception as exc:   # (a port taken: said by __init__)
            self._failed = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            self._ready.set()

    def benches_online(self) -> set[str]:
        """The benches whose worker is connected now."""
        workers = self.client.scheduler_info(n_workers=-1)["workers"].values()
        return {str(w.get("name", ""))[len("bench-"):] for w in workers
                if str(w.get("name", "")).startswith("bench-")}

    def close(self) -> None:
        try:
            self.client.close(timeout=10)
        finally:
            if self._stop is not None:
                self._loop.call_soon_threadsafe(self._stop.set)
            self._thread.join(15)


class RemoteBench:
    """A bench on another PC, as the class server's station plays on it.

    Parameters
    ----------
    scheduler : Scheduler
    bench : str
        Its name (the resource its worker offers).
    """

    #: how long the bench may be silent before the server asks whether it is still there
    SILENT_S = 2.0

    def __init__(self, scheduler: Scheduler, bench: str):
        self.scheduler, self.bench = scheduler, bench

    def _file(self, name) -> str:
        """A run's file name as the bench sent it, if it is one (nothing that could
        leave the student's folder)."""
        p = Path(str(name))
        if p.name != name or p.suffix not in (".csv", ".json") \
                or not RUN_NAME_RE.fullmatch(p.stem):
            raise RigError(f"{self.bench} sent a file named {str(name)[:40]!r}; refused "
                           "(a run's files are NAME.csv and NAME.json)")
        return name

    def online(self) -> bool:
        return self.bench in self.scheduler.benches_online()

    def play(self, plan, outdir: Path, *, on_start, on_block, on_done, stop) -> str:
        """Play ``plan`` on the bench: its samples (and the link's counters) to
        ``on_block(message)``, each
        finished run written (atomically) to ``outdir`` and told to ``on_done(name)``;
        ``stop`` (a threading.Event) stops it at 0 V. Returns the bench's note.

        Raises
        ------
        RigError
            The bench is not connected, or went away mid-run.
        Interrupted
            Stopped.
        """
        from distributed import Event, Queue

        for exp in plan:   # as a sweep on this PC refuses: nothing overwritten
            if (outdir / f"{exp.name}.json").exists() or (outdir / f"{exp.name}.csv").exists():
                raise UserError(f"{outdir / exp.name}.json exists; give the runs other "
                                "amplitudes or names, or use another folder")
        if not self.online():
            raise RigError(f"{self.bench} is not connected: start `labrig class bench` on "
                           "its PC")
        client = self.scheduler.client
        key = f"labrig-{self.bench}-{uuid.uuid4().hex[:12]}"
        queue, stop_event = Queue(key, client=client), Event(f"{key}-stop", client=client)
        future = client.submit(play_on_bench, self.bench, plan, key, pure=False, retries=0,
                               resources={resource(self.bench): 1}, key=key)
        stopped, heard = False, time.monotonic()
        try:
            while True:
                if stop.is_set() and not stopped:
                    stop_event.set()
                    stopped = True
                batch = queue.get(batch=True)     # what has come, without waiting
                if not batch:
                    if time.monotonic() - heard > self.SILENT_S:
                        if future.done() and future.status != "finished":
                            raise RigError(f"{self.bench} failed: {future.exception()}")
                        if not self.online():
                            raise RigError(f"{self.bench} went away mid-run (its PC or its "
                                           "link); the runs it finished are kept")
                        heard = time.monotonic()
                    time.sleep(SEND_S / 2)
                    continue
                heard = time.monotonic()
                for msg in batch:
                    note = self._take(msg, outdir, on_start, on_block, on_done)
                    if note is not None:
                        return note
        finally:
            if not future.done():
                future.cancel()

    def _take(self, msg, outdir, on_start, on_block, on_done) -> str | None:
        """One message of the bench: the note when it is the sweep's end."""
        kind = msg["kind"]
        if kind == "samples":
            on_block(msg)
        elif kind == "start":
            on_start(msg["name"], msg["n"])
        elif kind == "run":
            files = {self._file(n): t for n, t in msg["files"].items()}
            # the sidecar last: a run is listed once both are there
            for name in sorted(files, key=lambda n: n.endswith(".json")):
                atomic_write(outdir / name, files[name])
            on_done(msg["name"])
        elif kind == "end":
            note = msg["note"]
            if note.startswith("stopped"):
                raise Interrupted(note[len("stopped: "):])
            if note.startswith("error"):
                raise RigError(note[len("error: "):])
            return note
        return None
