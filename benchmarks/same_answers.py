"""The same answers before and after a reshaping: every command's JSON from two source
trees of labrig, compared with the timings left out.

    python benchmarks/same_answers.py OLD_TREE [NEW_TREE]

``OLD_TREE`` is a checkout of the commit to compare with (``git worktree add /tmp/old
COMMIT``); ``NEW_TREE`` defaults to this checkout. Each command runs in a fresh process
with ``PYTHONPATH`` set to the tree, on the repository's own data (``data/``) and a
simulated sweep made here, in a temporary folder per tree; its ``--json`` output (or the
JSON files it writes) is compared key by key. A difference is printed with its path and
both values, and the exit status is the number of commands that differ.

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

#: keys whose values are wall-clock times or paths of the temporary folder
DROP = {"seconds", "elapsed_s", "time_s", "wall_s", "figure", "figures", "paths", "path",
        "folder", "plan", "created"}


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


def main(argv) -> int:
    if not argv:
        print(__doc__)
        return 2
    old, new = Path(argv[0]).resolve(), Path(argv[1] if len(argv) > 1 else ROOT).resolve()
    with tempfile.TemporaryDirectory() as a, tempfile.TemporaryDirectory() as b:
        before, after = _run(old, Path(a)), _run(new, Path(b))
    differ = 0
    for name, _, _ in COMMANDS:
        d = _diff(before[name], after[name])
        print(f"{name}: {'same' if not d else f'{len(d)} difference(s)'}")
        for line in d[:20]:
            print(f"    {line}")
        differ += bool(d)
    return differ


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
