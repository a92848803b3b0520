"""One lab station: a rig, a data folder, the runs coming in and the loop's rungs.

The state behind the lab page, with no page in it: a sweep plays in a thread (every
block handed to the live view, every run written by the same code as ``labrig sweep``),
and the loop's fits run in a worker process (:mod:`labrig.lab.jobs`). One browser
session owns the rig at a time; the others watch.
"""
from __future__ import annotations

import threading
import time
from types import SimpleNamespace
from pathlib import Path

import numpy as np

import labrig.verbs as lr
from labrig.core.errors import Interrupted, LabrigError, UserError
from labrig.lab import jobs
from labrig.lab.live import Live
from labrig.lab.worker import Worker

class Station:
    """The rig, the folder and the loop of one lab bench.

    Parameters
    ----------
    folder : Path
        The data folder: runs are read from it and new sweeps written to it.
    rig : RigConfig
    make_bridge : callable() -> Bridge
        A fresh bridge for each sweep (simulated, serial or the emulated board).
    realtime : bool
        Pace a simulated rig to real time, so a run comes in as it would on the bench.
    rig_name : str
        The rig in words, for the page.
    remote : object, optional
        A bench on another PC (:class:`labrig.classroom.remote.RemoteBench`): it plays
        the sweeps instead of ``make_bridge``.
    """

    def __init__(self, folder, rig, make_bridge, *, realtime: bool = True, rig_name: str = "",
                 remote=None, threads: int = 0):
        self.folder = Path(folder)
        #: a bench on another PC that plays the sweeps (``play(plan, outdir, ...)``), or None
        self.remote = remote
        self.rig = rig
        self.rig_name = rig_name
        self.make_bridge = make_bridge
        self.realtime = realtime
        self.owner = None
        self.live = Live()
        self.sweeping = False
        self.sweep_note = ""
        self.written: list[str] = []
        self._stop = threading.Event()
        self._thread = None
        self.worker = Worker(threads)   # (0: every core; a class's station: 1)
        self.rungs: list[dict] = []        # fit() results, the ladder's rungs
        self.diagnosis: dict | None = None
        self.ladder: dict | None = None
        self.proposal: dict | None = None
        self.prediction: dict | None = None
        self.decision: dict | None = None
        #: asking until sure: the finished job's result, and the step the rig plays now
        self.asking: dict | None = None
        self._rig_request: tuple | None = None   # (folder the step's runs go to)
        self.error = ""
        self.log: list[str] = []
        #: the running job's events (a candidate re-fitted or cross-validated, a rung)
        self.stream: list[dict] = []
        #: the last finished job's name and whole stream (the next job starts its own)
        self.streamed: tuple = ("", [])
        self._bridge = None
        self._from_auto = False
        self._queued = None                # a click that came while overlays were drawn
        self.wanted: str | None = None     # the run the page shows: drawn first
        self.on_close: list = []
        s = rig.sensors_sidecar()
        self._kt = s.get("tacho_v_per_rad_s")
        self._kpot, self._pos0 = s["pos_v_per_rad"], s.get("pos_offset_v", 0.0)

    # -- ownership -------------------------------------------------------------------
    def claim(self, session: str) -> bool:
        """The first session owns the rig; the others watch (read-only)."""
        if self.owner is None:
            self.owner = session
        return self.owner == session

    def release(self, session: str) -> None:
        """A closed page or a lost connection: stop the rig safely, free the station."""
        if self.owner == session:
            self.stop()
            self._answer_rig()   # an asking's step was playing: its job ends now, not later
            self.owner = None

    # -- acquisition -----------------------------------------------------------------
    def runs_on_disk(self) -> list[str]:
        return sorted(p.stem for p in self.folder.glob("*.csv")
                      if p.with_suffix(".json").exists())

    _origins: tuple = (None, None)

    def origins(self) -> list:
        """The folder's runs' origins (:func:`labrig.verbs.run_origins`), read again only
        when its runs change (the page asks at every refresh)."""
        names = tuple(self.runs_on_disk())
        if names != self._origins[0]:
            self._origins = (names, lr.run_origins(self.folder))
        return self._origins[1]

    def holds(self) -> str:
        """What the station's folder holds, in a line."""
        return self.origins().describe()

    def foreign(self) -> str:
        """Why this station's rig may not play into its folder ("" when it may): the folder
        holds runs it did not play (imported recordings, another rig's sweeps), and a fit
        of the folder would be of two systems at once."""
        other = self.origins().not_played_by(self.rig.name)
        if not other:
            return ""
        return (f"{self.folder} holds runs this rig did not play ({other.describe()}); "
                f"play '{self.rig.name}' into another folder (labrig lab NEW_FOLDER)")

    def start_sweep(self, plan, into: Path | None = None) -> None:
        """Play ``plan`` (a list of Experiments) in a thread, writing to ``into`` (default
        the station's folder) exactly as ``labrig sweep`` does; refused while the folder
        holds runs another rig played or that were imported (:meth:`foreign`)."""
        if self.sweeping:
            raise LabrigError("a sweep is running; Stop it first")
        why = self.foreign()
        if why:
            raise UserError(why)
        lr.check_plan(plan, self.rig)    # a bad plan is refused before the rig moves
        self._stop.clear()
        self.sweeping, self.sweep_note, self.written = True, "", []
        self._thread = threading.Thread(target=self._sweep, args=(plan, into or self.folder),
                                        daemon=True)
        self._thread.start()

    def _sweep(self, plan, outdir) -> None:
        current = {}

        def on_start(exp):
            current["exp"] = exp
            self.live = Live(name=exp.name, n_planned=exp.n_samples)

        def on_done(exp, run):
            self.written.append(exp.name)

        try:   # an unplugged board fails here: one line on the page, like any rig error
            if self.remote is not None:
                self._play_remote(plan, outdir)
            else:
                self._bridge = lr.live(self.make_bridge(), self._on_block,
                                       realtime=self.realtime, stop=self._stop)
                lr.play(self._bridge, plan, self.rig, outdir, on_start=on_start,
                        on_done=on_done)
            self.sweep_note = f"{len(self.written)} run(s) written to {outdir}"
        except Interrupted as exc:
            self.sweep_note = f"{exc} ({len(self.written)} run(s) written to {outdir})"
        except LabrigError as exc:
            self.sweep_note = f"error: {exc}"
        except Exception as exc:  # a fault of the rig's link: one line, the rig at 0 V
            self.sweep_note = f"error: {type(exc).__name__}: {exc}"
        finally:
            self.sweeping = False

    def _play_remote(self, plan, outdir) -> None:
        """The sweep played by a bench on another PC (:attr:`remote`): its samples and
        finished runs come back as it plays; Stop reaches it as an event."""
        counters: dict = {}
        self._bridge = SimpleNamespace(counters=lambda: counters)

        def on_start(name, n):
            self.live = Live(name=name, n_planned=n)

        def on_block(msg):
            counters.clear()
            counters.update(msg["counters"])
            arr = lambda k: None if msg[k] is None else np.asarray(msg[k], float)  # noqa: E731
            self._on_block(SimpleNamespace(index=np.asarray(msg["index"]), u=arr("u"),
                                           tacho=arr("tacho"), pos=arr("pos")))

        self.remote.play(plan, outdir, on_start=on_start, on_block=on_block,
                         on_done=self.written.append, stop=self._stop)

    def _on_block(self, blk) -> None:
        live = self.live
        fs = self.rig.bridge.sample_rate_hz
        step = max(1, int(fs // 500))          # at most 500 points per second on screen
        idx = blk.index[::step]
        with live.lock:
            live.t.extend(idx / fs)
            live.u.extend(blk.u[::step])
            if blk.tacho is not None and self._kt:
                live.speed.extend(blk.tacho[::step] / self._kt)
            if blk.pos is not None:
                live.pos.extend((blk.pos[::step] - self._pos0) / self._kpot)
            live.points += len(idx)
        live.samples = int(blk.index[-1]) + 1
        live.counters = dict(self._bridge.counters())

    def stop(self) -> None:
        """Stop as Ctrl-C does: STOP and ZERO sent, finished runs kept."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)

    # -- the loop --------------------------------------------------------------------
    def folders(self) -> list[Path]:
        """The station's folder, and the runs asked of the rig (``asked/``, and one
        folder per step of an asking until sure, ``asked/step<k>/``)."""
        asked = self.folder / "asked"
        if not asked.is_dir():
            return [self.folder]
        steps = sorted((d for d in asked.glob("step*") if d.name[4:].isdigit()),
                       key=lambda d: int(d.name[4:]))
        return [self.folder] + [d for d in [asked, *steps]
                                if d.is_dir() and any(d.glob("*.csv"))]

    def busy(self) -> bool:
        """A click must wait: a job runs, other than the background drawing of overlays
        (a click overtakes that after its current figure), or a click is already queued."""
        return (self._queued is not None or self._waiting is not None
                or (self.worker.busy and not self.drawing()))

    def drawing(self) -> bool:
        """The worker draws the model on the runs the fit left, one run per job."""
        return self.worker.busy and self.worker.name == "overlays"

    def idle(self) -> bool:
        """Nothing running, no result waiting for :meth:`poll`, nothing queued."""
        return not self.worker.pending and self._queued is None and self._waiting is None

    def submit(self, name, fn, *args, **kw) -> None:
        self.error = ""
        self.log = []
        self.stream = []
        if self.drawing():   # after this figure (about half a second), not after them all
            self._queued = (name, fn, args, kw)
            return
        self._waiting = (name, fn, args, kw)
        if self.cores is None:
            self.start_waiting()
        else:   # a class's stations take turns for the server's cores
            self.cores.ask(self)

    _waiting = None
    #: the class's turns for the cores (:class:`~labrig.lab.turns.Turns`), or None: the job starts at once
    cores = None

    def start_waiting(self) -> bool:
        """Start the job waiting for its turn, if any (the turns call this)."""
        if self._waiting is None:
            return False
        (name, fn, args, kw), self._waiting = self._waiting, None
        self.worker.submit(name, fn, *args, **kw)
        self.warm()
        return True

    def waiting_note(self) -> str:
        """What the page says while the job waits for its turn ("" when it does not)."""
        if self._waiting is None or self.cores is None:
            return ""
        return (f"waiting for a free core: {self._waiting[0]} ({self.cores.ahead(self)} "
                "ahead of it)")

    def warm(self) -> None:
        """Load the simulator's kernels into this process, once, in the background: the
        hand view simulates here (a cold first comparison is many times a warm one).
        Called by the first job sent (the page waits for it) or by :meth:`poll` once the
        station has been idle a while: loaded when its rung arrived, they ran beside the
        worker's diagnosis; at the server's start they slowed the page's first load; at
        the page's load they delayed a sweep started at once (its live view fell behind).
        The worker warms its own."""
        if self._warming is None:
            self._warming = threading.Thread(target=lr.warm_up, name="labrig-warm",
                                             daemon=True)
            self._warming.start()

    _warming = None

    def fit_linear(self) -> None:
        self.rungs, self.diagnosis, self.ladder = [], None, None
        self.submit("fit", jobs.fit, [self.folder])

    def fit_from(self, model_doc: dict) -> None:
        """Fit the model the page set by hand, from its values (*Fit from here*)."""
        self.submit("fit", jobs.fit, [self.folder], model_doc, from_here=True)

    def take_refined(self) -> None:
        """The last diagnosis's better-placed model as the next rung, as it stands (nothing
        to add, its own parameters re-fitted to better values: ``diagnose -o``'s model)."""
        doc = (self.diagnosis or {}).get("refined")
        if doc is None:
            raise LabrigError("the last diagnosis found no better values to take")
        self.submit("fit", jobs.take, [self.folder], doc)   # a rung, as a fit's

    def add(self, effect: str) -> None:
        self.submit("fit", jobs.fit, [self.folder], self.model(), add=[effect])

    def remove(self, effect: str) -> None:
        self.submit("fit", jobs.fit, [self.folder], self.model(), remove=[effect])

    def replace(self, old: str, new: str) -> None:
        self.submit("fit", jobs.fit, [self.folder], self.model(), add=[new], remove=[old])

    def auto(self) -> None:
        self.rungs, self.diagnosis, self.ladder = [], None, None
        self.submit("auto", jobs.auto, [self.folder])

    def propose(self, between: str, loop: str = "open") -> None:
        """``loop``: the inputs proposed (open, closed: through the rig's position loop,
        any)."""
        self.proposal, self.prediction, self.decision = None, None, None
        self.submit("propose", jobs.propose, [self.folder], self.model(), between,
                    loop=loop, rig=self._loop_rig(loop))

    def _loop_rig(self, loop: str):
        # a closed-loop input needs the loop's gains: the station's rig file has them when
        # the data hold no closed-loop run (an open-loop proposal keeps the data's limits)
        return None if loop == "open" else self.rig

    def predict(self, which: str, why: str) -> None:
        self.prediction = {"which": which, "why": why.strip(), "at": time.time()}

    def play_proposal(self) -> None:
        """Play the proposed plan into ``asked/`` (only after a prediction is recorded)."""
        if self.proposal is None or self.prediction is None:
            raise LabrigError("record your prediction first: which explanation, and why")
        if self.proposal.get("plan") is None:   # nothing within the budget separates them
            raise LabrigError("no input within the budget separates the pair, so there is "
                              "nothing to play; see the proposal's text for what would")
        asked = self.folder / "asked"
        asked.mkdir(exist_ok=True)
        name = f"proposed_{len(list(asked.glob('*.csv'))) + 1}"
        plan_file = asked / f"{name}.toml"
        plan_file.write_text(self.proposal["plan"].replace('name = "proposed"', f'name = "{name}"'))
        self.start_sweep(lr.load_plan(plan_file, self.rig), into=asked)

    def decide(self) -> None:
        self.submit("decide", jobs.decide, self.folders(), self.model())

    def ask_until_sure(self, between: str, step_s: float = 5.0, loop: str = "open") -> None:
        """Short experiments played one at a time, judged after each (the worker's job
        asks the rig for each step: :meth:`_play_step`), until one explanation wins."""
        if self.sweeping:
            raise LabrigError("a sweep is running; Stop it first")
        self.asking = None
        self.submit("ask", jobs.ask_until_sure, self.folders(), self.model(), between,
                    step_s=step_s, loop=loop, rig=self._loop_rig(loop))

    def _play_step(self, request: dict) -> None:
        """The worker's job asks the rig to play a step: into ``asked/step<n>/`` (the
        next free number), streamed like any sweep; :meth:`poll` answers once it ends."""
        asked = self.folder / "asked"
        n = 1
        while (asked / f"step{n}").exists():
            n += 1
        folder = asked / f"step{n}"
        folder.mkdir(parents=True)
        plan_file = folder / "plan.toml"
        # the run is named after its folder: names stay unique across askings
        plan_file.write_text(request["plan"].replace(f'name = "asked{request["k"]}"',
                                                     f'name = "step{n}"'))
        self._rig_request = (folder,)
        try:
            self.start_sweep(lr.load_plan(plan_file, self.rig), into=folder)
        except LabrigError:
            self._rig_request = None
            self.worker.reply({"stopped": True})
            raise

    def _answer_rig(self) -> None:
        """A step the rig played has ended: its runs (or that it was stopped) go back to
        the worker's job."""
        if self._rig_request is None or self.sweeping:
            return
        (folder,), self._rig_request = self._rig_request, None
        done = any(folder.glob("*.csv"))
        self.worker.reply({"folder": str(folder)} if done else {"stopped": True})

    def cancel(self) -> None:
        self._queued = None
        self._waiting = None
        if self.cores is not None:
            self.cores.forget(self)
        if self._rig_request is not None:   # the step being played stops too (at 0 V)
            self.stop()
            self._rig_request = None
        self.worker.cancel()
        self.error = "cancelled"

    def model(self) -> dict | None:
        return self.rungs[-1]["model"] if self.rungs else None

    #: the station idle this long after the page's first look (no sweep, no job): the
    #: kernels are loaded then (:meth:`warm`)
    WARM_WHEN_IDLE_S = 1.5
    _first_poll = None

    def poll(self) -> bool:
        """Take in a finished job's result; True when something changed."""
        now = time.monotonic()
        self._first_poll = self._first_poll or now
        if self._warming is None and now - self._first_poll > self.WARM_WHEN_IDLE_S \
                and not self.sweeping and not self.worker.pending:
            self.warm()
        for item in self.worker.logs():   # lines to read, events to show as they come
            if isinstance(item, dict) and item.get("kind") == "rig":
                try:
                    self._play_step(item)
                except LabrigError as exc:
                    self.error = str(exc).splitlines()[0]
                continue
            (self.stream if isinstance(item, dict) else self.log).append(item)
        self._answer_rig()
        done = self.worker.poll()
        if done is None:
            return False
        if self.cores is not None:   # this station's turn is over: the next one's
            self.cores.tick()
        name, value, error = done
        self.streamed = (name, list(self.stream))   # the finished job's, whole
        if error is not None:
            message = str(error).splitlines()[0] if str(error) else type(error).__name__
            self._submit_queued()   # a figure failed; the click that waited on it still runs
            self.error = message
            return True
        if self._queued is not None:   # a click came while a figure was drawn: its turn
            if name == "overlays" and self.rungs:   # (a new linear fit has cleared them)
                self.rungs[-1]["overlays"].update(value)
            self._submit_queued()
            return True
        if name == "fit":
            self.rungs.append(value)
            self.submit("diagnose", jobs.diagnose, [self.folder], self.model())
        elif name == "diagnose":
            self.diagnosis = value
            if self._from_auto:   # the search's own ladder stays
                self._from_auto = False
                self.draw_overlays()
            else:
                self.submit("ladder", jobs.ladder, [self.folder], [r["model"] for r in self.rungs])
        elif name == "ladder":
            self.ladder = value
            self.draw_overlays()
        elif name == "overlays":
            self.rungs[-1]["overlays"].update(value)
            self.draw_overlays()
        elif name == "auto":
            self.ladder = {"json": {"steps": value["json"]["ladder"]}, "tables": value["tables"]}
            self._from_auto = True
            self.submit("fit", jobs.fit, [self.folder], value["model"])
        elif name == "propose":
            self.proposal = value
        elif name == "decide":
            self.decision = value
        elif name == "ask":
            self.asking = value
        return True

    def _submit_queued(self) -> None:
        if self._queued is not None:
            (name, fn, args, kw), self._queued = self._queued, None
            self.submit(name, fn, *args, **kw)

    def draw_overlays(self) -> None:
        """Last in a fit's chain, in the background (and again after a Cancel, when a run
        is picked): the model on the runs the fit did not draw."""
        r = self.rungs[-1] if self.rungs else None
        rest = [n for n in r["runs"] if n not in r["overlays"]] if r else []
        rest.sort(key=lambda n: n != self.wanted)   # the run on screen first
        if rest:   # one run per job: a click waits for one figure at most
            self.submit("overlays", jobs.overlays, [self.folder], r["model"], rest[:1])

    def close(self) -> None:
        self.stop()
        self.worker.close()
        for f in self.on_close:
            f()
