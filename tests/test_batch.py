"""labrig batch: one task over many folders, on joblib and on a Dask cluster."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from conftest import labrig, make_rig, sim_dataset, square_plan
from pathlib import Path

from labrig.classroom.batch import Analyse, output_names, run_batch, write_batch

OPTS = {"method": "jfo", "pop": 16, "iters": 20, "seed": 1}


@pytest.fixture(scope="module")
def class_dir(tmp_path_factory):
    """Three students' runs (Coulomb friction of different sizes) and one broken hand-in."""
    root = tmp_path_factory.mktemp("class")
    plan = square_plan(amps=(1.5, 2.5), periods=1)
    for k, tc in enumerate((0.1, 0.2, 0.3), start=1):
        sim_dataset(root, make_rig({"coulomb_friction": {"tc_v": tc}}), plan,
                    name=f"student{k}", seed=k)
    (root / "broken").mkdir()
    (root / "broken" / "run.csv").write_text("t,u\n0,1\n")
    return root


def _folders(root):
    return sorted(p for p in root.iterdir() if p.is_dir())


def test_joblib_two_processes_give_the_serial_table(class_dir):
    rows = []
    serial = run_batch("identify", _folders(class_dir), options=OPTS, jobs=1)
    par = run_batch("identify", _folders(class_dir), options=OPTS, jobs=2,
                    progress=rows.append)
    assert len(rows) == 4  # the progress saw every folder, the broken one included
    assert [r["status"] for r in par.rows] == ["failed", "ok", "ok", "ok"]
    assert par.failed == 1 and "broken" in par.rows[0]["error"]
    assert "labrig-batch-" not in par.rows[0]["error"]  # the user's path, not the worker's
    for a, b in zip(serial.rows[1:], par.rows[1:]):  # same seed, same numbers, any worker
        assert a["figures"] == b["figures"]
    km = [r["figures"]["km"] for r in par.rows[1:]]
    assert all(80 < k < 100 for k in km)  # the default rig's Km (about 90 rad/s per V)


def test_dask_local_cluster_of_two_workers(class_dir):
    distributed = pytest.importorskip("dask.distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        res = run_batch("identify", _folders(class_dir), options=OPTS,
                        scheduler=cluster.scheduler_address)
        assert res.engine.startswith("dask tcp://")
        workers = len(cluster.scheduler_info["workers"])
    assert workers == 2
    ref = run_batch("identify", _folders(class_dir), options=OPTS, jobs=1)
    assert [r["status"] for r in res.rows] == [r["status"] for r in ref.rows]
    for a, b in zip(ref.rows[1:], res.rows[1:]):
        assert a["figures"] == b["figures"]


def test_cli_writes_the_table_and_each_model(class_dir, tmp_path):
    out = tmp_path / "out"
    # stdout is a pipe: the batch's idle workers must not hold it open after labrig exits
    # (loky keeps them 5 minutes unless the batch shuts its executor down)
    p = labrig("batch", "identify", *_folders(class_dir), "-o", out, "--jobs", "2",
               "--pop", "16", "--iters", "20", "--json", check=1, timeout=240)
    doc = json.loads(p.stdout)
    assert doc["folders"] == 4 and doc["failed"] == 1
    with open(out / "results.csv") as f:
        table = list(csv.DictReader(f))
    assert [r["status"] for r in table] == ["failed", "ok", "ok", "ok"]
    assert table[0]["error"] and not table[1]["error"]
    # exit 1: one folder failed, and the one line on stderr says where to look
    assert "1 of 4 folders failed" in p.stderr and "Traceback" not in p.stderr
    assert abs(float(table[1]["km"]) - doc["rows"][1]["figures"]["km"]) < 1e-9
    for name in ("student1", "student2", "student3"):
        model = json.loads((out / name / "model.json").read_text())
        assert model["params"]["R"] > 0
    assert not (out / "broken").exists()
    # nothing overwritten without --force, and the refusal is one line, exit 2
    again = labrig("batch", "identify", *_folders(class_dir), "-o", out, check=2)
    assert "--force" in again.stderr and "Traceback" not in again.stderr


def test_cli_bad_scheduler_is_one_line(class_dir, tmp_path):
    p = labrig("batch", "analyse", *_folders(class_dir), "-o", tmp_path / "o",
               "--scheduler", "not-an-address", check=2)
    assert "tcp://" in p.stderr and "Traceback" not in p.stderr
    p = labrig("batch", "analyse", *_folders(class_dir), "-o", tmp_path / "o2",
               "--scheduler", "tcp://127.0.0.1:9", check=2)
    assert "cannot reach" in p.stderr and "Traceback" not in p.stderr
    for bad in ("tcp://127.0.0.1", "tcp://127.0.0.1:99999", "tcp://127.0.0.1:0",
                "tcp://127.0.0.1:port"):
        p = labrig("batch", "analyse", *_folders(class_dir), "-o", tmp_path / "o4",
                   "--scheduler", bad, check=2)
        assert len(p.stderr.strip().splitlines()) == 1 and "port" in p.stderr, p.stderr
        assert not (tmp_path / "o4").exists()
    # an unknown effect is the user's mistake once, before any folder runs
    p = labrig("batch", "identify", *_folders(class_dir), "-o", tmp_path / "o3",
               "--effects", "nonsense", check=2)
    assert "unknown effect 'nonsense'" in p.stderr and not (tmp_path / "o3").exists()


def test_analyse_diagnose_and_check_tasks(class_dir, tmp_path):
    folders = _folders(class_dir)[1:2]
    res = run_batch("analyse", folders)
    assert res.rows[0]["status"] == "ok"
    assert 0.05 < res.rows[0]["figures"]["deadband_v"] < 0.3  # 0.1 V of friction
    # a hand-in: the mystery and the student's model beside the runs
    hand = tmp_path / "hand"
    hand.mkdir()
    labrig("mystery", "new", "--seed", "6", "-o", hand / "m.mystery", check=0)
    labrig("sweep", "--sim", "--rig", hand / "m.mystery", "-o", hand, check=0)
    labrig("identify", hand, "--method", "co", "-o", hand / "model.json", check=0)
    res = run_batch("check", [hand])
    row = res.rows[0]
    assert row["status"] == "ok", row["error"]
    assert row["figures"]["score"] >= 0 and row["figures"]["pass"] in (True, False)
    assert row["files"]["check.json"]["file"] == "m.mystery"  # no worker paths


def test_output_names_stay_inside_and_unique(tmp_path):
    names = output_names([tmp_path / "a b", tmp_path / "x" / "a b", tmp_path / "..", "/"])
    assert names[0] == "a_b" and names[1] == "a_b_2"
    assert all("/" not in n and n not in ("", ".", "..") for n in names)
    # a folder named like a generated name, or like the batch's own table, or in
    # another case (a file system may not tell A from a)
    names = output_names([tmp_path / "x" / "a", tmp_path / "y" / "a", tmp_path / "a_2",
                          tmp_path / "A", tmp_path / "results.csv", tmp_path / "results.json"])
    assert len({n.lower() for n in names}) == 6, names
    assert not {"results.csv", "results.json"} & {n.lower() for n in names}


def test_colliding_folders_keep_their_own_results(class_dir, tmp_path):
    """x/a, y/a, a_2 and a folder called results.csv: four rows, four output folders,
    the table intact; a second batch into the same -o is refused without --force."""
    root = tmp_path / "in"
    src = _folders(class_dir)[1]
    folders = [root / "x" / "a", root / "y" / "a", root / "a_2", root / "results.csv"]
    for f in folders:
        f.mkdir(parents=True)
        for g in src.iterdir():
            (f / g.name).write_bytes(g.read_bytes())
    out = tmp_path / "out"
    p = labrig("batch", "analyse", *folders, "-o", out, "--json", check=0, timeout=240)
    doc = json.loads(p.stdout)
    assert [r["status"] for r in doc["rows"]] == ["ok"] * 4
    names = [r["name"] for r in doc["rows"]]
    assert len(set(names)) == 4
    for n in names:
        assert (out / n / "analysis.json").is_file()
    with open(out / "results.csv") as f:
        assert len(list(csv.DictReader(f))) == 4
    # a new batch whose folders' results would land on these is refused before any work
    (out / "results.csv").unlink()
    (out / "results.json").unlink()
    again = labrig("batch", "analyse", folders[0], "-o", out, check=2)
    assert "a" in again.stderr and "--force" in again.stderr
    assert len(again.stderr.strip().splitlines()) == 1
    assert not (out / "results.csv").exists()


class _Fatal(Analyse):
    """The analyse task, but a folder named ``poison`` kills its own worker (SIGKILL, as
    the out-of-memory killer would), every time or, for ``flaky``, once."""

    name = "fatal"

    def run(self, folder, options):
        import os
        import signal

        if folder.name == "poison":
            os.kill(os.getpid(), signal.SIGKILL)
        marker = Path(options["tmp"]) / "flaky-died-once"
        if folder.name == "flaky" and not marker.exists():
            marker.write_text("x")
            os.kill(os.getpid(), signal.SIGKILL)
        return super().run(folder, options)


def test_a_killed_worker_costs_only_its_folder(class_dir, tmp_path, monkeypatch):
    """A worker killed under one folder: that folder is a failed row saying so, a folder
    whose worker died once is run again and kept, every other row is there, and the
    table is written; the killed workers' copies of the folders are not left behind."""
    import tempfile

    scratch = tmp_path / "scratch"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))   # this process's
    monkeypatch.setenv("TMPDIR", str(scratch))               # the workers'
    src = _folders(class_dir)[1]
    names = ["s1", "flaky", "s2", "poison", "s3", "s4"]
    folders = []
    for n in names:
        f = tmp_path / "in" / n
        f.mkdir(parents=True)
        for g in src.iterdir():
            (f / g.name).write_bytes(g.read_bytes())
        folders.append(f)
    seen = []
    res = run_batch(_Fatal(), folders, options={"tmp": str(tmp_path)}, jobs=2,
                    progress=seen.append)
    assert len(seen) == len(names) == len(res.rows)
    status = {Path(r["folder"]).name: r for r in res.rows}
    assert status["poison"]["status"] == "failed"
    assert "worker died while running this folder" in status["poison"]["error"]
    assert all(status[n]["status"] == "ok" for n in names if n != "poison"), \
        [(n, status[n]["error"]) for n in names]
    assert (tmp_path / "flaky-died-once").exists()  # it did die once, and was run again
    km = {status[n]["figures"]["km"] for n in names if n != "poison"}
    assert len(km) == 1  # the same folder gives the same numbers on any worker
    written = write_batch(res, tmp_path / "out")
    with open(tmp_path / "out" / "results.csv") as f:
        table = list(csv.DictReader(f))
    assert [r["status"] for r in table] == ["ok", "ok", "ok", "failed", "ok", "ok"]
    assert tmp_path / "out" / "results.json" in written
    assert not list(scratch.iterdir())


@pytest.mark.slow
def test_diagnose_task_finds_the_hidden_friction(class_dir):
    res = run_batch("diagnose", _folders(class_dir)[3:4], options={"max_rounds": 1})
    row = res.rows[0]
    assert row["status"] == "ok", row["error"]
    assert "coulomb_friction" in row["figures"]["effects"] or "deadband" in row["figures"]["effects"]
    assert np.isfinite(row["figures"]["rmse_over_noise"])


def test_a_link_out_of_a_hand_in_is_not_followed(class_dir, tmp_path):
    """A hand-in is read with the grader's rights: a run file that links outside its
    folder (to another student's work, to a system file) is a failed row, never read."""
    secret = tmp_path / "secret.csv"
    secret.write_text("t,u,tacho\nroot:x:0:0,1,2\n")
    hand = tmp_path / "hand"
    hand.mkdir()
    src = _folders(class_dir)[1]
    for g in src.iterdir():
        (hand / g.name).write_bytes(g.read_bytes())
    victim = sorted(hand.glob("*.csv"))[0]
    victim.unlink()
    victim.symlink_to(secret)
    res = run_batch("analyse", [hand])
    row = res.rows[0]
    assert row["status"] == "failed" and "outside the folder" in row["error"]
    assert "root:x" not in row["error"]  # nothing of the linked file
