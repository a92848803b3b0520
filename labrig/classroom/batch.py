"""One task over many run folders: a class's hand-ins, a parameter study.

``run_batch(task, folders, ...)`` is the thin public function: it reads each folder's
files (so the workers need no shared file system), runs the task on every folder through
joblib on this machine (``jobs``) or a Dask distributed cluster (``scheduler``), and
returns a :class:`BatchResult`, one row per folder. A folder's failure is a row with its
message; it never stops the others.

Tasks (:data:`TASKS`) are small classes: ``figures`` names the key figures of the table,
``run(folder, options)`` returns them and the files to keep for that folder.
"""
from __future__ import annotations

import json
import os
import re
import tempfile
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated

from pydantic import Field, PlainSerializer, computed_field

import labrig.verbs as lr
from labrig.core.defaults import METHOD
from labrig.core.errors import LabrigError, UserError
from labrig.core.fileio import atomic_write, dumps
from labrig.core.record import Record

#: a hand-in larger than this is refused (a run folder is a few MB)
MAX_FOLDER_BYTES = 200 * 2 ** 20
#: the files a task may read from a folder
_KEPT = re.compile(r"^[\w.\- ]+\.(csv|json|mystery|toml|mat)$", re.IGNORECASE)
#: what the batch itself writes into -o: no folder's results may take these names
RESERVED = ("results.csv", "results.json")
#: a Dask scheduler's address: protocol, host and a port (inproc needs none)
_ADDRESS = re.compile(r"^(?:(?:tcp|tls|ucx)://(?:\[[0-9A-Fa-f:.]+\]|[\w.\-]+):(\d{1,5})"
                      r"|inproc://\S+)$")
#: the row of a folder whose worker process died under it, twice
WORKER_DIED = ("worker died while running this folder (killed, or out of memory); "
               "it was tried again alone and died again")


class Task(ABC):
    """One kind of work on one folder. Subclasses set ``name``, ``figures`` and ``run``."""

    name = ""
    help = ""
    #: the key figures, in the order of the table's columns
    figures: tuple = ()

    @abstractmethod
    def run(self, folder: Path, options: dict) -> tuple[dict, dict]:
        """Returns (key figures, {file name: JSON-able object to write for this folder})."""


class Analyse(Task):
    name, help = "analyse", "deadband, Km and tau_m of the open-loop runs (labrig analyse)"
    figures = ("runs", "deadband_v", "km", "tau_s", "gain_trend")

    def run(self, folder, options):
        res = lr.analyse([folder]).to_json()
        figs = {k: res.get(k) for k in self.figures if k != "runs"}
        figs["runs"] = len(res.get("runs") or [])
        return figs, {"analysis.json": res}


class Identify(Task):
    name, help = "identify", "fit the plant and effects (labrig identify)"
    figures = ("method", "effects", "fitness", "km", "tau_m_s", "rmse_speed", "rmse_position",
               "at_bound")

    def run(self, folder, options):
        # the runs as read, as the batch always fitted them
        res = lr.identify([folder], options.get("method", METHOD), options.get("effects") or [],
                          seed=options.get("seed", 1), through=None,
                          pop=options.get("pop", 50), iters=options.get("iters", 200))
        d = res.to_json()
        ident, rmse = d.get("identifiable") or {}, d.get("rmse_over_noise") or {}
        figs = {"method": d["method"], "effects": ",".join(d["effects"]) or "-",
                "fitness": d["fitness"], "km": (ident.get("km") or {}).get("value"),
                "tau_m_s": (ident.get("tau_m_s") or {}).get("value"),
                "rmse_speed": rmse.get("speed"), "rmse_position": rmse.get("position"),
                "at_bound": sum("bound" in w for w in d.get("warnings") or [])}
        return figs, {"model.json": res.model().to_json(), "identify.json": d}


class Diagnose(Task):
    name, help = "diagnose", "find the missing effects, round by round (labrig diagnose --auto)"
    figures = ("effects", "rmse_over_noise", "confusable")

    def run(self, folder, options):
        res = lr.auto([folder], max_rounds=options.get("max_rounds", 3),
                      seed=options.get("seed", 0), through=None)
        steps = res.ladder.to_json()["steps"]
        final = (steps[-1].get("rmse_over_noise") or {}) if steps else {}
        figs = {"effects": ",".join(res.model.names) or "-",
                "rmse_over_noise": final.get("overall"),
                "confusable": ";".join(f"{p.first}/{p.second}" for p in res.confusable) or "-"}
        return figs, {"model.json": res.model.to_json(), "diagnosis.json": res.to_json()}


class Check(Task):
    name, help = "check", "score a hand-in's model against its mystery rig (labrig mystery check)"
    figures = ("pass", "score", "found", "missed", "extra", "rmse_over_noise")

    def run(self, folder, options):
        mystery = _one(folder, "*.mystery", "mystery file", options.get("mystery"))
        model = folder / options.get("model", "model.json")
        if not model.exists():
            raise UserError(f"{folder.name}: no {model.name}; hand in the model saved by "
                            "`labrig identify -o` or `labrig diagnose -o`, or name it "
                            "with `model`")
        res = lr.check_mystery(mystery, model, tolerance=options.get("tolerance", 20.0) / 100.0)
        res["file"], res["model"] = mystery.name, model.name  # no worker paths in the output
        figs = {"pass": res["pass"], "score": res["score"],
                "found": ",".join(res["found"]) or "-", "missed": ",".join(res["missed"]) or "-",
                "extra": ",".join(res["extra"]) or "-", "rmse_over_noise": res["rmse_over_noise"]}
        return figs, {"check.json": res}


TASKS: dict[str, Task] = {t.name: t for t in (Analyse(), Identify(), Diagnose(), Check())}


def _one(folder: Path, pattern: str, what: str, given: str | None) -> Path:
    if given:
        return Path(given)
    found = sorted(folder.glob(pattern))
    if len(found) != 1:
        raise UserError(f"{folder.name}: {len(found)} {what}s ({pattern}); put exactly one "
                        "in the folder or give it with `mystery`")
    return found[0]


# -- the folders, their names in the output, and their files ------------------------------
def output_names(folders) -> list[str]:
    """A safe, unique name per folder for its results (its own name, made safe).

    Names are unique whatever the folders are called (``x/a``, ``y/a`` and ``a_2`` give
    ``a``, ``a_2`` and ``a_2_2``; a file system may not tell case apart), and never the
    name of the batch's own table (a folder called ``results.csv``)."""
    names, taken = [], set(RESERVED)
    for f in folders:
        base = re.sub(r"[^\w.\-]", "_", Path(f).resolve().name).strip("._") or "folder"
        base, name, n = base[:200], base[:200], 1
        while name.lower() in taken:
            n += 1
            name = f"{base}_{n}"
        taken.add(name.lower())
        names.append(name)
    return names


def read_folder(folder: Path) -> dict[str, bytes]:
    """The folder's data files as bytes (what a worker needs, whatever machine it is on)."""
    if not folder.is_dir():
        raise UserError(f"{folder}: not a folder of runs")
    files, total = {}, 0
    inside = folder.resolve()
    for p in sorted(folder.iterdir()):
        if p.is_symlink() and _KEPT.match(p.name) and inside not in p.resolve().parents:
            # a hand-in is read by the grader's account: a link must not reach its files
            raise UserError(f"{folder}: {p.name} is a link to a file outside the folder; "
                            "copy the file into the folder instead")
        if p.is_file() and _KEPT.match(p.name):
            total += p.stat().st_size
            if total > MAX_FOLDER_BYTES:
                raise UserError(f"{folder}: more than {MAX_FOLDER_BYTES >> 20} MB of data; "
                                "is it a run folder?")
            files[p.name] = p.read_bytes()
    if not files:
        raise UserError(f"{folder}: no run files (.csv with .json), model or mystery file")
    return files


def run_one(task: "str | Task", name: str, files: dict, options: dict, threads: int = 0,
            shown: str = "", tmp_root: str | None = None) -> dict:
    """One folder on a worker: its files in a private temporary folder (inside
    ``tmp_root`` when given: the batch's own, which it removes even if a worker was
    killed), the task (a name in :data:`TASKS` or a :class:`Task`), and a row (never an
    exception: a failure is a row with its message, which names the folder as the user
    gave it, ``shown``)."""
    t0 = time.perf_counter()
    folder = None
    if threads:
        import numba  # ~0.2 s to import; only when threads are set

        numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))
    try:
        with tempfile.TemporaryDirectory(prefix="labrig-batch-", dir=tmp_root) as tmp:
            folder = Path(tmp) / name
            folder.mkdir()
            for fname, data in files.items():
                (folder / Path(fname).name).write_bytes(data)
            figs, keep = _task(task).run(folder, options)
        return {"status": "ok", "figures": figs, "files": keep, "error": "",
                "seconds": round(time.perf_counter() - t0, 2)}
    except Exception as exc:  # a bug met on one folder must not stop the class either
        msg = str(exc) if isinstance(exc, LabrigError) else f"{type(exc).__name__}: {exc}"
        msg = (msg.splitlines() or [""])[0]
        if folder is not None:  # the user's folder, not the worker's private copy
            msg = msg.replace(str(folder), shown or name)
        return {"status": "failed", "figures": {}, "files": {}, "error": msg,
                "seconds": round(time.perf_counter() - t0, 2)}


# -- the result ---------------------------------------------------------------------------
def _rows_json(rows: list[dict]) -> list[dict]:
    # (a row's files stay in its folder: the JSON says what was done)
    return [{k: r[k] for k in ROW_KEYS} for r in rows]


#: what the JSON keeps of a row
ROW_KEYS = ("folder", "name", "status", "figures", "seconds", "error")


@dataclass
class BatchResult(Record):
    """One row per folder: folder, output name, status, the task's key figures, error."""

    task: str
    rows: Annotated[list[dict], PlainSerializer(_rows_json)] = field(default_factory=list)
    engine: str = ""
    #: the task's key figures (the table's columns); a built-in task's when empty
    figures: Annotated[tuple, Field(exclude=True)] = ()

    @computed_field
    @property
    def failed(self) -> int:
        """The folders whose task failed."""
        return sum(r["status"] != "ok" for r in self.rows)

    @computed_field
    @property
    def folders(self) -> int:
        """The folders it ran on."""
        return len(self.rows)

    def to_pandas(self):
        import pandas as pd  # ~0.2 s to import, for a notebook's table only

        cols = ["folder", "name", "status", *(self.figures or TASKS[self.task].figures),
                "seconds", "error"]
        return pd.DataFrame([{**{k: r.get(k) for k in ("folder", "name", "status", "seconds",
                                                        "error")}, **r["figures"]}
                             for r in self.rows], columns=cols)

    def to_text(self) -> str:
        df = self.to_pandas().drop(columns=["name"])
        with_pd = df.to_string(index=False, na_rep="-", float_format=lambda x: f"{x:.4g}")
        return (f"{self.task} on {len(self.rows)} folders ({self.engine}): "
                f"{len(self.rows) - self.failed} ok, {self.failed} failed\n\n{with_pd}")


def run_batch(task: str, folders, *, options: dict | None = None, jobs: int = 1,
              scheduler: str | None = None, progress=None,
              threads: int | None = None) -> BatchResult:
    """Run ``task`` on every folder.

    Parameters
    ----------
    task : {"analyse", "identify", "diagnose", "check"} or Task
        A name in :data:`TASKS`, or a :class:`Task` of your own (its class must be
        importable by the workers).
    folders : list of path
    options : dict
        The task's options (method, effects, seed, pop, iters; max_rounds; mystery,
        model, tolerance).
    jobs : int
        Processes on this machine (joblib); -1 for one per core.
    scheduler : str, optional
        ``tcp://HOST:PORT`` of a running Dask distributed scheduler: the folders go to
        its workers instead (``jobs`` is then ignored).
    progress : callable, optional
        Called with each finished row, in the order they finish.
    threads : int, optional
        numba's threads in each process (default: the machine's cores shared among the
        ``jobs``); a class server's grading gives 1, its share of the class's cores.
    """
    if not isinstance(task, Task) and task not in TASKS:
        raise UserError(f"batch: unknown task '{task}'; choose {', '.join(TASKS)}")
    if scheduler:
        check_scheduler(scheduler)
    folders = [Path(f) for f in folders]
    if not folders:
        raise UserError("batch: give at least one folder")
    options = dict(options or {})
    if options.get("effects"):  # a bad name is the user's mistake, once, not every folder's
        lr.parse_effects(options["effects"])
    names = output_names(folders)
    rows: list[dict | None] = [None] * len(folders)
    work = []
    for k, (folder, name) in enumerate(zip(folders, names)):
        try:
            work.append((k, name, read_folder(folder), str(folder)))
        except LabrigError as exc:  # an unreadable hand-in is a row, like any failure
            rows[k] = {"status": "failed", "figures": {}, "files": {}, "seconds": 0.0,
                       "error": str(exc).splitlines()[0]}
    for k, row in enumerate(rows):
        if row is not None:
            _finish(rows, k, folders, names, row, progress)
    if scheduler:
        engine = f"dask {scheduler}"
        for k, row in _dask(scheduler, task, work, options):
            _finish(rows, k, folders, names, row, progress)
    else:
        n = os.cpu_count() or 1
        jobs = n if jobs in (-1, 0) else max(1, min(int(jobs), len(work) or 1))
        engine = f"joblib, {jobs} process{'es' if jobs > 1 else ''}"
        per = threads if threads else max(1, n // jobs)
        for k, row in _joblib(jobs, task, work, options, threads=per):
            _finish(rows, k, folders, names, row, progress)
    spec = _task(task)
    return BatchResult(task=spec.name, rows=rows, engine=engine, figures=tuple(spec.figures))


def _finish(rows, k, folders, names, row, progress):
    row = {"folder": str(folders[k]), "name": names[k], **row}
    rows[k] = row
    if progress:
        progress(row)


def _joblib(jobs, task, work, options, threads):
    """Rows as they finish, from ``jobs`` loky processes (joblib's own pool).

    A worker that dies (SIGKILL, the out-of-memory killer) breaks the pool and fails every
    folder then in it, without saying whose worker it was. Those folders are run again on
    a fresh pool; any that fails so a second time is run alone, where a death is its own:
    that folder is a failed row (:data:`WORKER_DIED`), every other row is kept.
    """
    if jobs == 1:  # in this process: no pool to start for one at a time
        for k, name, files, shown in work:
            yield k, run_one(task, name, files, options, 0, shown)
        return
    # loky: ~0.17 s to import, only for a pool (jobs > 1)
    from joblib.externals.loky import get_reusable_executor

    # the workers' folders inside one of the batch's: a killed worker's goes with it
    with tempfile.TemporaryDirectory(prefix="labrig-batch-") as root:
        run = (task, options, threads, root)
        try:
            lost = yield from _pool_round(jobs, run, work)
            if lost:
                lost = yield from _pool_round(min(jobs, len(lost)), run, lost)
            for item in lost:
                again = yield from _pool_round(1, run, [item])
                if again:
                    yield item[0], {"status": "failed", "figures": {}, "files": {},
                                    "seconds": 0.0, "error": WORKER_DIED}
        finally:
            # idle workers outlive the batch by loky's idle timeout (5 min) and hold the
            # caller's stdout open meanwhile: `labrig batch ... | cat` would not return
            get_reusable_executor().shutdown(wait=True)


def _pool_round(jobs, run, work):
    """Yield the rows of ``work`` run on a pool of ``jobs`` (``run``: the task, its options,
    the threads per worker, the workers' temporary root); return the items whose worker
    died (the pool breaks for all of them at once)."""
    task, options, threads, root = run
    # only for a pool: concurrent.futures.process ~0.015 s, loky ~0.17 s to import
    from concurrent.futures import as_completed
    from concurrent.futures.process import BrokenProcessPool

    from joblib.externals.loky import get_reusable_executor

    executor = get_reusable_executor(max_workers=jobs)
    futures = {executor.submit(_tagged, item[0], task, *item[1:3], options, threads, item[3],
                               root): item for item in work}
    lost = []
    for fut in as_completed(futures):
        try:
            yield fut.result()
        except BrokenProcessPool:  # loky's TerminatedWorkerError is one
            lost.append(futures[fut])
    return sorted(lost, key=lambda item: item[0])


def _tagged(k, *args):
    return k, run_one(*args)


def check_scheduler(scheduler: str) -> None:
    """A Dask scheduler address with a host and a port (1-65535), or one line."""
    m = _ADDRESS.match(scheduler)
    if m is None or (m.group(1) is not None and not 0 < int(m.group(1)) < 65536):
        raise UserError(f"`scheduler`: '{scheduler}' is not an address like "
                        "tcp://HOST:8786 (a protocol, a host and a port from 1 to 65535)")


def _task(task) -> Task:
    return task if isinstance(task, Task) else TASKS[task]


def _dask(scheduler, task, work, options):
    try:
        from dask.distributed import Client, as_completed  # only for --scheduler; may be missing
    except ImportError:  # pragma: no cover - a dependency, but say what to install
        raise UserError("`scheduler` needs dask.distributed: pip install 'dask[distributed]'")
    try:
        client = Client(scheduler, timeout="10s")
    except (OSError, TimeoutError) as exc:
        raise UserError(f"`scheduler`: cannot reach {scheduler} ({exc}); start one with "
                        "`dask scheduler` and workers with `dask worker ADDRESS`") from None
    with client:
        futures = {client.submit(run_one, task, name, files, options, 1, shown, pure=False,
                                 key=f"labrig-{task}-{k}-{name}"): k
                   for k, name, files, shown in work}
        for fut in as_completed(futures):
            k = futures[fut]
            try:
                row = fut.result()
            except Exception as exc:  # the worker itself died: that folder failed
                row = {"status": "failed", "figures": {}, "files": {}, "seconds": 0.0,
                       "error": f"worker lost: {type(exc).__name__}: {exc}".splitlines()[0]}
            yield k, row


def write_batch(result: BatchResult, out: Path) -> list[Path]:
    """results.csv, results.json and each folder's files under ``out/<name>/``."""
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for r in result.rows:
        for fname, obj in (r.get("files") or {}).items():
            p = out / r["name"] / Path(fname).name
            p.parent.mkdir(exist_ok=True)
            atomic_write(p, dumps(obj))
            written.append(p)
    atomic_write(out / "results.csv", result.to_pandas().to_csv(index=False))
    atomic_write(out / "results.json", json.dumps(json.loads(dumps(result.to_json())),
                                                  indent=2) + "\n")
    return written + [out / "results.csv", out / "results.json"]
