"""The same answers before and after a reshaping: every command's JSON from two source
trees of labrig, compared with the timings left out.

    python benchmarks/same_answers.py OLD_TREE [NEW_TREE]
    python benchmarks/same_answers.py --sheets OLD_TREE [NEW_TREE]

``OLD_TREE`` is a checkout of the commit to compare with (``git worktree add /tmp/old
COMMIT``); ``NEW_TREE`` defaults to this checkout. Each command runs in a fresh process
with ``PYTHONPATH`` set to the tree, on the repository's own data (``data/``) and a
simulated sweep made here, in a temporary folder per tree; its ``--json`` output (or the
JSON files it writes) is compared key by key. A difference is printed with its path and
both values, and the exit status is the number of commands that differ.

With ``--sheets``: every command of the five exercise sheets (in order, in a fresh
folder with copies of ``data/`` and ``configs/``, as ``tests/test_exercises.py`` runs
them) and every command the README's and the sheets' checked figures name, in both
trees: each command's exit status and ``--json`` output, and every JSON file the
commands left in the folder, compared the same way (about five minutes a tree).

This is how a change that should keep behaviour is checked (issue 47: the front ends
through the verbs): run it before committing, on a quiet machine (the fits are
deterministic, the timings are not and are dropped).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "data" / "sweep_default"

#: (name, argv after ``labrig``, the JSON files it writes in its folder)
COMMANDS = [
    ("analyse", ["analyse", str(DATA), "--json"], []),
    ("identify", ["identify", str(DATA), "--method", "co", "--json", "-o", "m0.json"],
     ["m0.json"]),
    ("identify --model", ["identify", str(DATA), "--model", "m0.json", "--effects", "deadband",
                          "--json", "-o", "m1.json"], ["m1.json"]),
    ("compare", ["compare", str(DATA), "--model", "m1.json", "--json", "-o", "cmp"], []),
    ("ladder", ["ladder", str(DATA), "--models", "m0.json,m1.json", "--json", "-o", "lad"], []),
    ("diagnose", ["diagnose", str(DATA), "--model", "m0.json", "--json", "-o", "d1.json"],
     ["d1.json"]),
    ("propose", ["propose", str(DATA), "--model", "m1.json", "--between",
                 "deadband,coulomb_friction", "--json", "-o", "plan.toml"], []),
    ("sweep", ["sweep", "--sim", "--plan", str(ROOT / "configs" / "plan_five.toml"),
               "--rig", str(ROOT / "configs" / "rig_deadzone_rail.toml"), "-o", "runs5"], []),
    ("diagnose --auto", ["diagnose", "runs5", "--auto", "--json", "-o", "auto"],
     ["auto/model.json", "auto/ladder.json"]),
    ("batch", ["batch", "identify", str(DATA), "runs5", "-o", "batch", "--jobs", "1",
               "--method", "co"],
     ["batch/results.json"]),
    ("mystery", ["mystery", "new", "--seed", "7", "-o", "lab.mystery"], []),
    ("mystery reveal", ["mystery", "reveal", "lab.mystery", "--json"], []),
]

#: keys whose values are wall-clock times, paths of the temporary folder, or drawn fresh
#: each time (an emulated board's id is random when it is first given one)
DROP = {"seconds", "elapsed_s", "time_s", "wall_s", "figure", "figures", "paths", "path",
        "folder", "plan", "created", "board_id"}


def _clean(x):
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items() if k not in DROP}
    if isinstance(x, list):
        return [_clean(v) for v in x]
    if isinstance(x, str) and ("/tmp" in x or tempfile.gettempdir() in x):
        return "<tmp>"
    return x


def _diff(a, b, path="") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b)):
            if k not in a or k not in b:
                out.append(f"{path}/{k}: only in {'new' if k in b else 'old'}")
            else:
                out += _diff(a[k], b[k], f"{path}/{k}")
        return out
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{path}: {len(a)} items -> {len(b)}"]
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in _diff(x, y, f"{path}[{i}]")]
    return [] if a == b else [f"{path}: {a!r} -> {b!r}"]


def _run(tree: Path, work: Path) -> dict:
    env = {**os.environ, "PYTHONPATH": str(tree), "CI": "true"}
    out = {}
    for name, argv, files in COMMANDS:
        p = subprocess.run([sys.executable, "-m", "labrig", *argv], cwd=work, env=env,
                           capture_output=True, text=True, timeout=1800)
        doc = {"exit": p.returncode}
        try:
            doc["stdout"] = json.loads(p.stdout) if "--json" in argv else None
        except json.JSONDecodeError:
            doc["stdout"] = p.stdout
        for f in files:
            fp = work / f
            doc[f] = json.loads(fp.read_text()) if fp.is_file() else None
        out[name] = _clean(doc)
        print(f"  {tree.name}: {name} (exit {p.returncode})", file=sys.stderr)
    return out


def _one(work: Path, line: str, env: dict) -> dict:
    """One line of a sheet or a checked figure, run in ``work`` (on the tree ``env`` names)."""
    import shlex

    argv = shlex.split(line, comments=True)
    cmd = ([sys.executable, "-m", "labrig"] if argv[0] == "labrig" else [sys.executable]) \
        + argv[1:]
    p = subprocess.run(cmd, cwd=work, env=env, capture_output=True, text=True, timeout=1800)
    doc = {"exit": p.returncode}
    if "--json" in argv:
        try:
            doc["stdout"] = json.loads(p.stdout)
        except json.JSONDecodeError:
            doc["stdout"] = p.stdout
    return doc


def _run_sheets(tree: Path, work: Path) -> dict:
    """Every sheet's and the README's commands on ``tree``: ``{where: result}``."""
    sys.path.insert(0, str(ROOT / "tests"))
    import quoted
    import test_exercises as ex

    env = {**os.environ, "PYTHONPATH": str(tree), "CI": "true", "MPLBACKEND": "Agg",
           "PYTHONHASHSEED": "0"}
    out = {}
    for sheet in [*ex.SHEETS, None]:
        wd = work / (sheet.stem if sheet else "readme")
        ex.setup_workdir(wd)
        done = set()
        for step in (ex.parse_sheet(sheet) if sheet else []):
            if step[0] == "file":
                (wd / step[1]).parent.mkdir(parents=True, exist_ok=True)
                (wd / step[1]).write_text(step[2], encoding="utf-8")
                continue
            line = step[4]
            out[f"{sheet.name}: {line}"] = _clean(_one(wd, line, env))
            done.add(line)
        for doc in (ex._docs_of(sheet) if sheet else [ROOT / "README.md"]):
            for c in quoted.parse(doc):
                for line in c.after + [c.command]:
                    if line not in done:
                        out[f"{doc.name}: {line}"] = _clean(_one(wd, line, env))
                        done.add(line)
        for f in sorted(wd.rglob("*.json")):
            rel = f.relative_to(wd)
            if rel.parts[0] not in ("data", "configs"):
                try:
                    out[f"{wd.name}/{rel}"] = _clean(json.loads(f.read_text()))
                except json.JSONDecodeError:
                    out[f"{wd.name}/{rel}"] = "not JSON"
        print(f"  {tree.name}: {wd.name} done", file=sys.stderr)
    return out


def main(argv) -> int:
    sheets = "--sheets" in argv
    argv = [a for a in argv if a != "--sheets"]
    if not argv:
        print(__doc__)
        return 2
    old, new = Path(argv[0]).resolve(), Path(argv[1] if len(argv) > 1 else ROOT).resolve()
    run = _run_sheets if sheets else _run
    with tempfile.TemporaryDirectory() as a, tempfile.TemporaryDirectory() as b:
        before, after = run(old, Path(a)), run(new, Path(b))
    differ = 0
    names = list(dict.fromkeys([*before, *after])) if sheets else [n for n, _, _ in COMMANDS]
    for name in names:
        if name not in before or name not in after:
            print(f"{name}: only in {'new' if name in after else 'old'}")
            differ += 1
            continue
        d = _diff(before[name], after[name])
        print(f"{name}: {'same' if not d else f'{len(d)} difference(s)'}")
        for line in d[:20]:
            print(f"    {line}")
        differ += bool(d)
    return differ


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
