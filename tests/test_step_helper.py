"""The step-metrics helper: python-control imported in a second process while the fit
runs (labrig/step_helper.py). Each case runs in a fresh interpreter, as the command
line does: the helper is only forked from a process without threads."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import pytest

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="the helper is forked on Linux only")

SERVO = "ServoParams(R=8.0, L=0.01, J=2e-4, B=1e-4, K=0.05, Ka=2.0, N=30.0)"


def _run(body: str) -> dict:
    code = ("import json, os, sys\n"
            "from labrig import step_helper\n"
            "from labrig.model.servo import ServoParams, step_info\n" + body)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, check=True)
    return json.loads(out.stdout.splitlines()[-1])


def test_helper_gives_the_numbers_the_process_gives():
    """Same function, same libraries: equal to the last digit; the library's
    ``servo.step_info`` asks the helper once the command line started it, the parent
    never imports python-control, and the helper is gone after stop()."""
    got = _run(
        "step_helper.allow(); step_helper.start()\n"
        "pid = step_helper._helper[0].pid\n"
        f"s = {SERVO}\n"
        "a = [step_info(s, kp, kv) for kp, kv in ((2.0, 0.15), (5.0, 0.05))]\n"
        "parent_has_control = 'control' in sys.modules\n"
        "step_helper.stop()\n"
        "alive = os.path.exists(f'/proc/{pid}')\n"
        "b = [s.position_step_info(kp, kv) for kp, kv in ((2.0, 0.15), (5.0, 0.05))]\n"
        "print(json.dumps({'a': a, 'b': b, 'parent_has_control': parent_has_control,\n"
        "                  'alive': alive}))\n")
    assert got["a"] == got["b"]
    assert 0 < got["a"][0]["rise_time_s"] < got["a"][0]["settling_time_s"] < 3
    assert not got["parent_has_control"]
    assert not got["alive"]


def test_a_helper_that_died_falls_back_to_the_process():
    got = _run(
        "import signal\n"
        "step_helper.allow(); step_helper.start()\n"
        "proc = step_helper._helper[0]\n"
        "os.kill(proc.pid, signal.SIGKILL); proc.join(10)\n"
        f"s = {SERVO}\n"
        "a = step_helper.position_step_info(s, 2.0, 0.15)\n"
        "print(json.dumps({'a': a, 'b': s.position_step_info(2.0, 0.15),\n"
        "                  'helper': step_helper._helper is not None}))\n")
    assert got["a"] == got["b"]
    assert not got["helper"]


def test_no_helper_unless_the_entry_point_allows_it():
    """A library user (notebook, lab page, tests) computes in the process."""
    got = _run("step_helper.start()\n"
               "print(json.dumps({'helper': step_helper._helper is not None}))\n")
    assert not got["helper"]


def test_helper_ends_when_its_parent_ends_without_a_word():
    """The parent killed (os._exit, no stop()): the helper sees its pipe close and ends
    by itself once its import is done."""
    got = _run("step_helper.allow(); step_helper.start()\n"
               "print(json.dumps({'pid': step_helper._helper[0].pid}), flush=True)\n"
               "os._exit(0)\n")
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        if not _running(got["pid"]):
            return
        time.sleep(0.1)
    pytest.fail(f"helper {got['pid']} still running 30 s after its parent ended")


def _running(pid: int) -> bool:
    """Alive and not a zombie (an orphan's exit status waits for whoever adopted it)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rpartition(")")[2].split()[0] != "Z"
    except FileNotFoundError:
        return False


def _children(pid: int) -> list[int]:
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as f:
            return [int(c) for c in f.read().split()]
    except FileNotFoundError:
        return []


@pytest.mark.parametrize("sig, code", [("SIGTERM", 143), ("SIGINT", 130)])
def test_the_command_line_ends_its_helper_on_a_signal(tmp_path, rig, sig, code):
    """``labrig identify`` forks its helper at once; a SIGTERM to labrig alone, or a
    Ctrl-C to the terminal's process group, ends both: labrig's one line and exit code,
    no helper left."""
    import signal

    from conftest import sim_dataset, square_plan

    folder = sim_dataset(tmp_path, rig, square_plan(amps=(1.5,), periods=1), seed=1)
    p = subprocess.Popen([sys.executable, "-m", "labrig", "identify", str(folder),
                          "-o", str(tmp_path / "m.json")], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 30
        while not _children(p.pid) and time.monotonic() < deadline and p.poll() is None:
            time.sleep(0.02)
        helpers = _children(p.pid)
        assert helpers, "no helper forked"
        if sig == "SIGTERM":
            os.kill(p.pid, signal.SIGTERM)
        else:
            os.killpg(p.pid, signal.SIGINT)
        _, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    assert p.returncode == code, err
    assert "Traceback" not in err
    assert len(err.strip().splitlines()) == 1, err
    deadline = time.monotonic() + 5
    while any(map(_running, helpers)) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(map(_running, helpers))
    assert not (tmp_path / "m.json").exists()
