"""The library speaks Python; the command line translates (issue 62, item 4).

A library error names a parameter as a Python caller passes it, in backticks ("`method`",
"`loop=closed`"); the command line shows the option instead ("--method", "--loop
closed"; labrig.commands.options), so every command-line message reads as before.
"""
from __future__ import annotations

import argparse
import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

import labrig
from labrig.commands.options import PARAM_OPTIONS, translate

ROOT = Path(__file__).resolve().parent.parent
PKG = ROOT / "labrig"
OPTION = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]*")
NAMED = re.compile(r"`([A-Za-z_][A-Za-z0-9_]*)(?:=[^`]+)?`")

#: commands to type, quoted whole in a library message: a command line, not a parameter
#: ("{}" stands for an interpolated value). Keep this list short.
CLI_INSTRUCTIONS = (
    "labrig identify DATA -o m0.json, then --model m0.json",   # diagnosis/loop: a diverged fit
    "labrig flash --board BOARD",                   # bridge/serial.py, bridge/settings.py
    "labrig wiring --rig FILE --board {}",          # bridge/hbridge.py
    "labrig mystery new --seed N -o FILE.mystery",  # io/mysteryfile.py
    "apt-get install -y --no-install-recommends",   # bridge/emulate.py: a shell command
)


def _library_files():
    for f in sorted(PKG.rglob("*.py")):
        rel = f.relative_to(ROOT).as_posix()
        if not (rel.startswith("labrig/commands/") or rel == "labrig/cli.py"):
            yield rel, ast.parse(f.read_text())


def _text(node) -> str:
    """A string or f-string as its template: each interpolated value is "{}"."""
    if isinstance(node, ast.Constant):
        return node.value
    return "".join(v.value if isinstance(v, ast.Constant) else "{}" for v in node.values)


def _strings(expr):
    """The string templates inside an expression (an f-string whole, not its parts)."""
    inner = {id(v) for n in ast.walk(expr) if isinstance(n, ast.JoinedStr)
             for v in ast.walk(n) if v is not n}
    for n in ast.walk(expr):
        if id(n) in inner:
            continue
        if isinstance(n, ast.JoinedStr) or (isinstance(n, ast.Constant)
                                            and isinstance(n.value, str)):
            yield _text(n)


def _is_error_class(cls: ast.ClassDef) -> bool:
    return any(isinstance(b, ast.Name) and (b.id.endswith("Error") or b.id in
                                            ("Interrupted", "Exception")) for b in cls.bases)


def _messages():
    """(file, line, text) of every string an exception is built from: in a ``raise``,
    in a call of an ``...Error`` class (an error built to be raised later), and in an
    exception class's ``super().__init__(...)``."""
    out = []
    for rel, tree in _library_files():
        for node in ast.walk(tree):
            exprs = []
            if isinstance(node, ast.Raise) and node.exc is not None:
                exprs.append(node.exc)
            elif isinstance(node, ast.Call):
                f = node.func
                name = f.id if isinstance(f, ast.Name) else f.attr \
                    if isinstance(f, ast.Attribute) else ""
                if name.endswith("Error"):
                    exprs.append(node)
            elif isinstance(node, ast.ClassDef) and _is_error_class(node):
                for call in ast.walk(node):
                    if (isinstance(call, ast.Call) and isinstance(call.func, ast.Attribute)
                            and call.func.attr == "__init__"
                            and isinstance(call.func.value, ast.Call)
                            and getattr(call.func.value.func, "id", "") == "super"):
                        exprs.append(call)
            for e in exprs:
                out.extend((rel, node.lineno, s) for s in _strings(e))
    return out


def _labels():
    """Whole-string labels a library helper puts in front of its message
    (``check_run_name(name, "`name`")``, ``where="`effects`"``)."""
    return [(rel, n.lineno, n.value) for rel, tree in _library_files() for n in ast.walk(tree)
            if isinstance(n, ast.Constant) and isinstance(n.value, str)
            and NAMED.fullmatch(n.value)]


def test_library_errors_name_no_command_line_option():
    found = []
    for rel, line, text in _messages():
        for cmd in CLI_INSTRUCTIONS:
            text = text.replace(cmd, "")
        found += [(rel, line, opt) for opt in OPTION.findall(text)]
    assert not found, "\n".join(f"{r}:{n}: {o} (name the Python parameter: `name`)"
                                for r, n, o in sorted(set(found)))


def test_every_backticked_name_is_translated():
    unknown = sorted({(rel, line, name) for rel, line, text in _messages() + _labels()
                      for name in NAMED.findall(text) if name not in PARAM_OPTIONS})
    assert not unknown, unknown


def _parser_options() -> set[str]:
    from labrig.cli import build_parser

    opts = set()

    def walk(parser):
        for action in parser._actions:
            opts.update(action.option_strings)
            if isinstance(action, argparse._SubParsersAction):
                for sub in action.choices.values():
                    walk(sub)

    walk(build_parser())
    return opts


def test_every_option_exists_on_the_command_line():
    missing = {k: v for k, v in PARAM_OPTIONS.items() if v not in _parser_options()}
    assert not missing, missing


def test_translate():
    assert translate("`method`: unknown method 'x'") == "--method: unknown method 'x'"
    assert translate("only with `loop=closed`") == "only with --loop closed"
    assert translate("e.g. `controller=pd:kp=2,kd=0.1`") == "e.g. --controller pd:kp=2,kd=0.1"
    assert translate("`fixed`: every parameter is fixed") == "--fix: every parameter is fixed"
    # not a parameter: left as it is
    assert translate("run `labrig sweep` or `dask worker ADDRESS`; `nope`") == \
        "run `labrig sweep` or `dask worker ADDRESS`; `nope`"


# -- the same mistake, from Python and from the command line ---------------------------

def _cli(*args, cwd=ROOT):
    return subprocess.run([sys.executable, "-m", "labrig", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True)


def test_method_in_python_and_on_the_command_line():
    runs = labrig.read_runs(ROOT / "data" / "sweep_default")
    with pytest.raises(labrig.UserError) as err:
        labrig.identify(runs, method="nope")
    text = str(err.value)
    assert "`method`" in text and "--method" not in text, text
    # the command line would say it as it always did ...
    assert translate(text) == "--method: unknown method 'nope'; choose jfo, pso, co or all"
    # ... but its parser refuses the name first, naming the option
    proc = _cli("identify", "data/sweep_default", "--method", "nope")
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.splitlines()[-1].startswith("labrig: error: argument --method: invalid "
                                                   "choice: 'nope'"), proc.stderr


def test_fixed_in_python_and_fix_on_the_command_line():
    runs = labrig.read_runs(ROOT / "data" / "sweep_default")
    with pytest.raises(labrig.UserError, match=r"^`fixed`: unknown parameter 'Q'"):
        labrig.identify(runs, method="co", fixed={"Q": 1.0})
    proc = _cli("identify", "data/sweep_default", "--fix", "Q=1")
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr == ("labrig: error: --fix: unknown parameter 'Q'; the model has "
                           "R, L, J, B, K\n")


SCOPE = "Time,CH1,CH2\n" + "".join(f"{i * 0.001:.3f},{1 + (i > 9)},{i % 3}\n"
                                   for i in range(20))


@pytest.mark.parametrize("python, options, line", [
    (dict(mapping="t=Time,u=CH1,speed=CH2", time_unit="h"),
     ["--map", "t=Time,u=CH1,speed=CH2", "--time-unit", "h"],
     "--time-unit: unknown unit 'h'; expected one of s, ms, us"),
    (dict(mapping="t=Time,u=CH1,sped=CH2"), ["--map", "t=Time,u=CH1,sped=CH2"],
     "--map: unknown target 'sped'; expected one of t, u, speed, pos, tacho, ref, current"),
    (dict(mapping="t=Time,u=CH1,speed=CH2", controller="pd:kp=2"),
     ["--map", "t=Time,u=CH1,speed=CH2", "--controller", "pd:kp=2"],
     "--controller/--position-gain/--velocity-gain: only with --loop closed"),
])
def test_import_in_python_and_on_the_command_line(tmp_path, python, options, line):
    import labrig.verbs as lr

    src = tmp_path / "scope.csv"
    src.write_text(SCOPE)
    with pytest.raises(labrig.UserError) as err:
        lr.import_run(src, tmp_path / "py", **python)
    text = str(err.value)
    assert "`" in text and "--" not in text, text
    assert translate(text) == line
    proc = _cli("import", src, "-o", tmp_path / "cli", *options)
    assert proc.returncode == 2 and proc.stderr == f"labrig: error: {line}\n", proc.stderr


def test_batch_rows_say_the_option(tmp_path):
    """A folder's error is a row: the library's names the parameter, the command's table
    and results.csv the option."""
    from labrig.classroom.batch import run_batch
    from labrig.io.mystery import new_mystery, write_mystery

    folder = tmp_path / "alice"
    write_mystery(new_mystery(3), folder / "m.mystery", seed=3)
    res = run_batch("check", [folder])
    assert res.rows[0]["error"].endswith("or name it with `model`"), res.rows
    proc = _cli("batch", "check", folder, "-o", tmp_path / "out")
    assert proc.returncode == 1, proc.stderr
    assert "or name it with --model" in proc.stdout
    assert "or name it with --model" in (tmp_path / "out" / "results.csv").read_text()
