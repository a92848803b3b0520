"""The shape of the code: folders are layers that import downwards only, no cycles,
small modules.

Checked statically on every import statement, including those inside functions and
under ``if TYPE_CHECKING:``, so neither a lazy import nor an annotation can hide a
cycle or a call back up the layers.
"""
from __future__ import annotations

import ast
import re
from pathlib import Path

PKG = Path(__file__).resolve().parent.parent / "labrig"
MAX_LINES = 500

#: the folders (and top-level modules) from the bottom up; a part imports only parts at
#: its own level or below (docs/design.md, 'Architecture')
LAYERS = [
    ["core"],        # errors, atomic files, schemas, tables, figure style, version
    ["simulation"],  # the simulator's numerics: numba kernels, exact hold, their layout
    ["model"],       # plants, effects, model files, the simulator of a model's effects
    ["io"],          # run files, imports, rig and plan files
    ["bridge"],      # the rig: simulated, serial, emulated; sweeps
    ["analysis"],    # deadband, Km, tau_m from runs; noise floors
    ["identification"],  # JFO, PSO, CO fits and their results
    ["diagnosis"],   # the missing-physics loop: the round and search, evidence, words, results
    ["design"],      # experiment design: input families, propose, separation, ask, decide
    ["verbs", "api"],  # the public verbs, the front ends' one door (labrig.api is its old name)
    ["classroom"],   # batches and mystery rigs
    ["report"],      # the HTML report
    ["lab"],         # the lab station in the browser (Panel)
    ["commands"],    # one module per subcommand
    ["cli", "__main__", "step_helper"],   # the command line (its step-metrics helper process)
    ["labrig"],      # the package itself: the public names
]


def _modules() -> dict[str, Path]:
    mods = {}
    for f in PKG.rglob("*.py"):
        parts = f.relative_to(PKG.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        mods[name] = f
    return mods


def _graph():
    mods = _modules()
    graph, private = {}, []
    for m, f in mods.items():
        pkg = m if f.name == "__init__.py" else m.rsplit(".", 1)[0]
        deps = set()
        tree = ast.parse(f.read_text())
        for node in ast.walk(tree):
            targets = []
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = pkg.split(".")[: len(pkg.split(".")) - (node.level - 1)]
                    target = ".".join(base + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                targets = [f"{target}.{a.name}" for a in node.names] + [target]
                private += [(m, a.name) for a in node.names
                            if a.name.startswith("_") and not a.name.startswith("__")
                            and target.startswith("labrig")]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            for t in targets:
                while t and t not in mods and "." in t:
                    t = t.rsplit(".", 1)[0]
                if t in mods and t != m and t.startswith("labrig"):
                    deps.add(t)
        graph[m] = deps
    return graph, private


def _cycles(graph) -> list[list[str]]:
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    return out


def test_no_import_cycles():
    graph, _ = _graph()
    assert _cycles(graph) == []


def test_nothing_imports_the_cli():
    graph, _ = _graph()
    assert [m for m, d in graph.items() if "labrig.cli" in d] == ["labrig.__main__"]


def test_core_never_imports_commands():
    graph, _ = _graph()
    offenders = [m for m, d in graph.items() if not m.startswith(("labrig.commands", "labrig.cli"))
                 and any(x.startswith("labrig.commands") for x in d)]
    assert offenders == []


def test_no_private_helper_crosses_modules():
    _, private = _graph()
    assert private == []


def test_modules_are_small():
    big = {str(f.relative_to(PKG.parent)): n for f in PKG.rglob("*.py")
           if (n := len(f.read_text().splitlines())) > MAX_LINES}
    assert big == {}


#: the loop's and experiment design's floors, read most: smaller still
LOOP_MAX_LINES = 400


def test_the_loop_and_design_modules_are_smaller():
    big = {str(f.relative_to(PKG.parent)): n for folder in ("diagnosis", "design")
           for f in (PKG / folder).rglob("*.py")
           if (n := len(f.read_text().splitlines())) > LOOP_MAX_LINES}
    assert big == {}


def _part(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "labrig"


def test_folders_are_layers():
    graph, _ = _graph()
    level = {name: i for i, names in enumerate(LAYERS) for name in names}
    unknown = sorted({_part(m) for m in graph} - set(level))
    assert unknown == [], f"place these in LAYERS: {unknown}"
    upward = sorted((m, d) for m, deps in graph.items() for d in deps
                    if level[_part(d)] > level[_part(m)])
    assert upward == []


def test_what_the_loop_knows_of_an_effect_lives_on_the_effect():
    """No table keyed by effect name in the loop: a user's own effect takes part in the
    search and in proposals through its own attributes, like a built-in one."""
    from labrig.design.inputs import KINDS
    from labrig.model.effects import CATALOGUE

    names = set(CATALOGUE)
    tables = []
    for f in (PKG / "loop").glob("*.py"):
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.Dict) and any(
                    isinstance(k, ast.Constant) and k.value in names for k in node.keys):
                tables.append(f"{f.name}:{node.lineno}")
    assert tables == []
    for name, cls in CATALOGUE.items():
        e = cls()
        for other in (e.rival, e.simpler, e.proposed_as, *e.look_alikes):
            assert not other or other in names, (name, other)
        assert set(e.responses) <= set(KINDS), name


#: the front ends: they reach the library through its one door, the verbs (and core's
#: errors, defaults, tables and figures), and their own folder; the command line may also
#: start the other front ends
DOOR = ("verbs", "core")
FRONT_ENDS = {"lab": ("classroom",), "classroom": (), "report": (),
              "commands": ("lab", "classroom", "report", "cli")}


def test_front_ends_reach_the_library_through_the_verbs():
    graph, _ = _graph()
    past = sorted((m, d) for m, deps in graph.items() if _part(m) in FRONT_ENDS
                  for d in deps
                  if _part(d) not in DOOR + (_part(m),) + FRONT_ENDS[_part(m)])
    assert past == []


def test_no_benchmark_history_in_the_code():
    """Timings go stale where they are written: they live in benchmarks/ and the README's
    records, and the code's docstrings and comments say why, not how fast it was once
    ("2.4 s against 1.7 s", "3.5 times slower")."""
    stale = re.compile(r"\d ?m?s against \d|\d(\.\d+)? times (slower|faster)|\dx (slower|faster)"
                       r"|one run each")
    found = [f"{p.relative_to(PKG.parent)}:{k}: {line.strip()}"
             for p in sorted(PKG.rglob("*.py"))
             for k, line in enumerate(p.read_text().splitlines(), 1) if stale.search(line)]
    assert not found, "\n".join(found)


#: what turns a problem into the optimisers' form: only identification builds or holds it
SEARCH_FORM = {"build_space", "Objective", "Space"}


def _nodes_outside_identification():
    """(module path, AST node) of every module but identification's."""
    for f in PKG.rglob("*.py"):
        rel = f.relative_to(PKG)
        if rel.parts[0] != "identification":
            yield from ((rel, node) for node in ast.walk(ast.parse(f.read_text())))


def test_only_identification_builds_a_search_space():
    """The loop and the front ends hand identification a problem
    (:class:`labrig.identification.problem.Problem`) and get a fit; the search space, the
    objective and a model's search vector are identification's own (issue 62)."""
    offenders = [f"{rel}: {a.name}" for rel, node in _nodes_outside_identification()
                 if isinstance(node, ast.ImportFrom)
                 and (node.module or "").startswith("labrig.identification.objective")
                 for a in node.names if a.name in SEARCH_FORM]
    assert offenders == []


def test_only_identification_flattens_a_model_for_a_search():
    """A model goes to a fit as a Model, or flattened by identification's own
    ``start_of`` (with what is fixed over it): no front end or loop module merges a
    model's flat values with fixed ones by hand (``{**model.flat(), **fixed}``)."""
    offenders = [f"{rel}:{node.lineno}" for rel, node in _nodes_outside_identification()
                 if isinstance(node, ast.Dict) and any(
                     k is None and isinstance(v, ast.Call) and isinstance(v.func, ast.Attribute)
                     and v.func.attr == "flat" for k, v in zip(node.keys, node.values))]
    assert offenders == []


def test_the_readme_and_design_quote_these_limits():
    """The site's and design.md's architecture sections quote the limits checked here."""
    readme = " ".join((PKG.parent / "docs" / "project" / "architecture.md").read_text().split())
    design = " ".join((PKG.parent / "docs" / "design.md").read_text().split())
    assert f"no module over {MAX_LINES} lines ({LOOP_MAX_LINES} in the loop's" in readme
    assert f"no module over {MAX_LINES} lines ({LOOP_MAX_LINES} in `diagnosis/` and `design/`)" in design
