"""The model's walk through the code: during ``diagnose --auto`` on ``data/sweep_default``,
which modules the model reaches, in which form, and how often the effects are parsed.

    python benchmarks/bench_walk.py [--json] [--save LABEL]

Every call into a labrig function is watched (``sys.setprofile``); a call *carries the
model* when one of its arguments is the model in one of its forms:

- ``Model`` (``labrig.model.model.Model``),
- ``EffectSet`` (the effects alone),
- ``flat`` (a dict of the model's parameters by flat name: ``Km``, ``deadband.d_v``),
- ``Space`` (the search space built from those),
- ``vector`` is not counted (an array is anonymous; the Space's calls stand for it).

Counted over the calls that carry it from one module into another (a method's own
``self`` does not count as carrying it), as distinct hand-offs, so that a loop over many
fits counts once:

- *rooms*: the distinct modules the model enters, and their folders;
- *hand-offs*: distinct (caller module, callee module) pairs;
- *back and forth*: module pairs with hand-offs both ways (the walk returns to a room it
  left);
- *climbs*: hand-offs into a module of a higher layer than the caller's (a callback
  handed down and called back up: the layers of ``tests/test_architecture.py``);
- *form changes*: hand-offs whose callee receives the model in a form the caller did not
  hold it in (e.g. a ``Model`` in, an ``EffectSet`` and a ``flat`` out);
- ``EffectSet.parse`` calls, and those that parsed anything (not handed an EffectSet).

The counts describe the code, not the machine: the same code gives the same numbers on
every machine (the fits are deterministic). Issue 62's note quotes them before and after
its reshaping.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
DATA = ROOT / "data" / "sweep_default"
PKG = str(ROOT / "labrig")


def _layers() -> dict[str, int]:
    from test_architecture import LAYERS

    return {name: i for i, names in enumerate(LAYERS) for name in names}


def _module(filename: str) -> str | None:
    if not filename.startswith(PKG):
        return None
    rel = filename[len(PKG) + 1:-3].replace("/", ".")
    return "labrig." + rel.removesuffix(".__init__")


def walk() -> dict:
    import os

    os.environ["LABRIG_THREADS"] = "1"   # fits one after another, all in this thread
    import labrig.verbs.loop as loop
    from labrig.identification.objective import Space
    from labrig.model.effectset import EffectSet
    from labrig.model.model import Model

    level = _layers()
    plant_names = {"R", "L", "J", "B", "K", "Km", "tau_m", "M", "Fv"}

    def forms(frame) -> frozenset:
        code = frame.f_code
        found = set()
        for name in code.co_varnames[:code.co_argcount + code.co_kwonlyargcount]:
            if name in ("self", "cls"):
                continue
            v = frame.f_locals.get(name)
            if isinstance(v, Model):
                found.add("Model")
            elif isinstance(v, EffectSet):
                found.add("EffectSet")
            elif isinstance(v, Space):
                found.add("Space")
            elif isinstance(v, dict) and v and all(isinstance(k, str) for k in v) and (
                    plant_names & v.keys() or any("." in k for k in v)) and all(
                    isinstance(x, (int, float)) for x in v.values()):
                found.add("flat")
        return frozenset(found)

    edges: dict[tuple[str, str], set] = {}
    parse = {"calls": 0, "parsed": 0}
    stack: list[tuple[str | None, frozenset]] = []

    def part(mod: str) -> str:
        bits = mod.split(".")
        return bits[1] if len(bits) > 1 else "labrig"

    def profile(frame, event, arg):
        if event == "call":
            mod = _module(frame.f_code.co_filename)
            if mod is None:
                stack.append((None, frozenset()))
                return
            if frame.f_code.co_name == "parse" and mod == "labrig.model.effectset":
                parse["calls"] += 1
                if not isinstance(frame.f_locals.get("text"), EffectSet):
                    parse["parsed"] += 1
            here = forms(frame)
            caller = next((s for s in reversed(stack) if s[0] is not None), None)
            if here and caller is not None and caller[0] != mod:
                edges.setdefault((caller[0], mod), set()).add((caller[1], here))
            stack.append((mod, here))
        elif event == "return" and stack:
            stack.pop()

    sys.setprofile(profile)
    try:
        loop.auto(str(DATA))
    finally:
        sys.setprofile(None)
    rooms = sorted({b for _, b in edges})
    folders = sorted({part(m) for m in rooms})
    both = {frozenset(e) for e in edges if (e[1], e[0]) in edges}
    climbs = sorted(f"{a} -> {b}" for a, b in edges
                    if level.get(part(b), 0) > level.get(part(a), 0))
    changes = sorted(f"{a} -> {b}: {'+'.join(sorted(h))} -> {'+'.join(sorted(n))}"
                     for (a, b), seen in edges.items() for h, n in seen if h and not n <= h)
    return {"command": "labrig diagnose data/sweep_default --auto (in process, "
                       "labrig.verbs.loop.auto, one thread)",
            "rooms": len(rooms), "folders": len(folders), "folder_names": folders,
            "hand_offs": len(edges), "back_and_forth": len(both), "climbs": len(climbs),
            "form_changes": len(changes), "effectset_parse": parse,
            "climb_list": climbs, "form_change_list": changes, "room_list": rooms}


RESULTS = ROOT / "benchmarks" / "results_walk.json"


if __name__ == "__main__":
    res = walk()
    if "--save" in sys.argv:   # --save LABEL: kept under LABEL in results_walk.json
        label = sys.argv[sys.argv.index("--save") + 1]
        saved = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
        saved[label] = res
        RESULTS.write_text(json.dumps(saved, indent=1) + "\n")
    if "--json" in sys.argv:
        print(json.dumps(res, indent=1))
    else:
        for k, v in res.items():
            if not k.endswith("_list"):
                print(f"{k}: {v}")
