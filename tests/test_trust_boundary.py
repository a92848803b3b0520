"""The file boundary: names stay inside -o, data files never run code, files are
written with the user's umask, big inputs are bounded."""
from __future__ import annotations

import json
import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from labrig.cli import main
from labrig.core.errors import RunFileError, UserError
from labrig.io.runs import Run, make_meta, read_run, write_run

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "data" / "sweep_default"

# A user effect whose import leaves a mark: if the mark appears, code ran.
EVIL = '''
from pathlib import Path
Path(__file__).with_name("RAN").write_text("the data file ran this code")
from labrig.model.effects import Effect, Param
import numpy as np

class Evil(Effect):
    """A harmless Coulomb friction, but importing this file leaves a mark."""
    name = "evil"
    stage = "friction"
    params = (Param("tc_v", "V", 1e-3, 2.0, "friction as a voltage"),)

    def friction(self, plant, tc_v):
        t = tc_v * plant.Ka * plant.K / plant.R
        return t, t

    def initial_guess(self, runs, plant):
        return {"tc_v": 0.1}
'''


@pytest.fixture
def evil(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "evil.py").write_text(EVIL)
    return tmp_path


def _model(path: Path, effects, effect_params) -> Path:
    doc = {"format": "labrig-model/1", "effects": effects,
           "params": {"R": 8.0, "L": 0.0085, "J": 5.2245e-5, "B": 1e-5, "K": 0.05},
           "effect_params": effect_params,
           "constants": {"Ka": 5.0, "N": 30.0, "Kt": 0.026, "Kpot": 0.5, "kp": 2.0, "kv": 0.15}}
    path.write_text(json.dumps(doc))
    return path


def _one_run(tmp_path) -> Path:
    d = tmp_path / "runs"
    d.mkdir()
    for ext in ("csv", "json"):
        shutil.copy(DATA / f"sq_2.00V.{ext}", d / f"sq_2.00V.{ext}")
    return d


def _err(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


# -- data files never run code ---------------------------------------------------------

def test_model_naming_user_effect_is_refused_without_trust(evil, capsys):
    d = _one_run(evil)
    m = _model(evil / "student.json", ["evil.py:Evil"], {"evil": {"tc_v": 0.2}})
    assert main(["compare", str(d), "--model", str(m)]) == 2
    err = _err(capsys)
    assert "Python code" in err and "--trust-code evil.py" in err and "student.json" in err
    assert not (evil / "RAN").exists()


def test_model_naming_user_effect_runs_with_explicit_trust(evil, capsys):
    d = _one_run(evil)
    m = _model(evil / "student.json", ["evil.py:Evil"], {"evil": {"tc_v": 0.2}})
    code = main(["compare", str(d), "--model", str(m), "--trust-code", "evil.py", "--json"])
    assert code == 0, capsys.readouterr().err
    assert (evil / "RAN").exists()


def test_rig_file_naming_user_effect_is_refused(evil, capsys):
    rig = evil / "rig.toml"
    rig.write_text('[effects."evil.py:Evil"]\ntc_v = 0.2\n')
    assert main(["sweep", "--sim", "--rig", str(rig), "-o", str(evil / "out")]) == 2
    assert "Python code" in _err(capsys)
    assert not (evil / "RAN").exists() and not (evil / "out").exists()


def test_identify_config_naming_user_effect_is_refused(evil, capsys):
    d = _one_run(evil)
    cfg = evil / "id.toml"
    cfg.write_text('effects = ["evil.py:Evil"]\n')
    assert main(["identify", str(d), "--config", str(cfg)]) == 2
    assert "Python code" in _err(capsys)
    assert not (evil / "RAN").exists()


def test_mystery_check_never_runs_the_students_code(evil, capsys):
    from labrig.io.mystery import new_mystery, write_mystery

    path = write_mystery(new_mystery(10), evil / "c.mystery", seed=10)
    m = _model(evil / "student.json", ["evil.py:Evil"], {"evil": {"tc_v": 0.2}})
    assert main(["mystery", "check", str(path), str(m), "--json"]) == 0
    capsys.readouterr()
    assert not (evil / "RAN").exists()


def test_trust_is_per_command_line(evil, capsys):
    """Trusting a file once (in-process) does not trust it for the next command."""
    d = _one_run(evil)
    m = _model(evil / "student.json", ["evil.py:Evil"], {"evil": {"tc_v": 0.2}})
    assert main(["compare", str(d), "--model", str(m), "--trust-code", "evil.py", "--json"]) == 0
    (evil / "RAN").unlink()
    capsys.readouterr()
    assert main(["compare", str(d), "--model", str(m)]) == 2
    assert "Python code" in _err(capsys)


def test_help_says_user_effects_are_code(capsys):
    with pytest.raises(SystemExit):
        main(["compare", "--help"])
    out = capsys.readouterr().out
    assert "--trust-code" in out and "Python code" in " ".join(out.split())


# -- names stay inside the output folder -------------------------------------------------

@pytest.mark.parametrize("name", ["../x", "../../x", "/tmp/labrig_abs_x", ".hidden", "",
                                  "a/b", "a\\b", "x" * 101, "with space"])
def test_write_run_refuses_unsafe_names(tmp_path, name):
    run = read_run(DATA / "sq_1.20V.csv")
    run.name = name
    with pytest.raises(UserError, match="valid run name"):
        write_run(run, tmp_path / "out")
    assert not any(p.name.startswith("x") for p in tmp_path.rglob("*"))
    assert not Path("/tmp/labrig_abs_x.csv").exists()


def test_plan_name_cannot_escape(tmp_path, capsys):
    plan = tmp_path / "plan.toml"
    plan.write_text('[[experiment]]\nname = "../../escaped"\n')
    out = tmp_path / "a" / "b" / "out"
    assert main(["sweep", "--sim", "--plan", str(plan), "-o", str(out)]) == 2
    assert "valid run name" in _err(capsys)
    assert not list(tmp_path.rglob("escaped*"))


def test_import_name_cannot_escape_and_odd_stems_are_made_safe(tmp_path, capsys):
    src = tmp_path / "scope export (1).csv"
    src.write_text("Time,CH1,CH2\n" + "".join(f"{i * 0.001:.3f},1,2\n" for i in range(20)))
    out = tmp_path / "deep" / "out"
    assert main(["import", str(src), "-o", str(out), "--map", "t=Time,u=CH1,speed=CH2",
                 "--name", "../escaped"]) == 2
    assert "--name" in _err(capsys)
    assert not list(tmp_path.rglob("escaped*"))
    assert main(["import", str(src), "-o", str(out), "--map", "t=Time,u=CH1,speed=CH2"]) == 0
    capsys.readouterr()
    assert sorted(p.name for p in out.iterdir()) == ["scope_export__1_.csv",
                                                      "scope_export__1_.json"]


# -- files follow the umask ----------------------------------------------------------------

def test_run_files_follow_the_umask(tmp_path):
    run = read_run(DATA / "sq_1.20V.csv")
    old = os.umask(0o022)
    try:
        path = write_run(run, tmp_path / "out")
        os.umask(0o077)
        run.name = "private"
        private = write_run(run, tmp_path / "out")
    finally:
        os.umask(old)
    for p in (path, path.with_suffix(".json")):
        assert stat.S_IMODE(p.stat().st_mode) == 0o644, oct(p.stat().st_mode)
    assert stat.S_IMODE(private.stat().st_mode) == 0o600


def test_model_file_follows_the_umask(tmp_path):
    from labrig.model.model import Model

    old = os.umask(0o022)
    try:
        p = Model({"R": 8.0, "L": 0.0085, "J": 5e-5, "B": 1e-5, "K": 0.05}).save(tmp_path / "m.json")
    finally:
        os.umask(old)
    assert stat.S_IMODE(p.stat().st_mode) == 0o644


# -- big inputs are bounded --------------------------------------------------------------

@pytest.mark.slow
def test_ten_million_row_run_reads_in_bounded_memory(tmp_path):
    """A 10-million-row run is read with well under 8 GB: in a child process whose
    address space is capped at 3 GB (the text reader of the first round needed ~8 GB)."""
    n = 10_000_000
    d = tmp_path / "big"
    d.mkdir()
    rng = np.random.default_rng(1)
    t = np.arange(n) / 1000.0
    with open(d / "big.csv", "w") as fh:
        fh.write("t,u,tacho,pos\n")
        step = 1_000_000
        for i in range(0, n, step):
            blk = np.column_stack([t[i:i + step], np.ones(step), rng.normal(0, 0.01, step),
                                   np.zeros(step)])
            np.savetxt(fh, blk, fmt=["%.3f", "%.1f", "%.4f", "%.1f"], delimiter=",")
    meta = make_meta(sample_rate_hz=1000.0, experiment={"loop": "open"},
                     sensors={"tacho_v_per_rad_s": 0.026, "pos_v_per_rad": 0.5},
                     rig={"gear_ratio": 30.0}, source="test")
    (d / "big.json").write_text(json.dumps(meta))
    code = ("import resource, sys\n"
            "resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))\n"
            "from labrig.io.runs import read_run\n"
            f"r = read_run({str(d / 'big.csv')!r})\n"
            "print(len(r), resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=300)
    assert p.returncode == 0, p.stderr[-2000:]
    rows, maxrss_kb = map(int, p.stdout.split())
    assert rows == n
    assert maxrss_kb < 2.5e6, f"peak {maxrss_kb / 1e6:.2f} GB"


# -- special files (issue 29): refused in one line, before anything opens them -------------

def _special_runs(tmp_path, kind):
    """A copy of a shipped run whose CSV is a FIFO, a symlink to /dev/zero or a folder."""
    import os
    import shutil

    from conftest import ROOT

    d = tmp_path / kind
    d.mkdir()
    shutil.copy(ROOT / "data" / "sweep_default" / "sq_1.20V.json", d / "sq_1.20V.json")
    csv = d / "sq_1.20V.csv"
    if kind == "fifo":
        os.mkfifo(csv)
    elif kind == "device":
        os.symlink("/dev/zero", csv)
    else:
        csv.mkdir()
    return d, csv


@pytest.mark.parametrize("kind, what", [("fifo", "a FIFO"), ("device", "a character device"),
                                        ("folder", "a folder")])
def test_a_run_that_is_a_fifo_a_device_or_a_folder_is_refused_at_once(tmp_path, kind, what):
    from conftest import labrig

    d, csv = _special_runs(tmp_path, kind)
    proc = labrig("analyse", d, timeout=60)           # a FIFO used to block forever
    assert proc.returncode == 2, proc.stderr
    assert f"sq_1.20V.csv: is {what}" in proc.stderr and "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1
    # the same file given to import
    proc = labrig("import", csv, "--map", "t=t,u=u,pos=pos", "-o", tmp_path / "out", timeout=60)
    assert proc.returncode == 2 and f"is {what}" in proc.stderr, proc.stderr


@pytest.mark.parametrize("args", [
    ["sweep", "--sim", "-o", "{file}"],
    ["import", "{csv}", "--map", "t=ms,u=u_V,pos=count", "--time-unit", "ms",
     "--pos-unit", "counts:1320", "-o", "{file}"],
    ["sweep", "--sim", "-o", "{long}"],
    ["analyse", "{data}", "-o", "{long}"],
    ["identify", "{data}", "-o", "{long}.json"],
])
def test_an_output_that_is_a_file_or_too_long_is_refused_before_the_work(tmp_path, args):
    from conftest import ROOT, labrig

    (tmp_path / "afile").write_text("mine")
    subs = {"{file}": str(tmp_path / "afile"), "{long}": str(tmp_path / ("x" * 300)),
            "{data}": str(ROOT / "data" / "sweep_default"),
            "{csv}": str(ROOT / "data" / "arduino_hbridge" / "step_3.00V.csv")}
    argv = [subs.get(a, a.replace("{long}", subs["{long}"])) for a in args]
    proc = labrig(*argv, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert "internal error" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert ("exists and is not a folder" in proc.stderr
            or "more than the 255 a file system allows" in proc.stderr), proc.stderr
    assert (tmp_path / "afile").read_text() == "mine"
