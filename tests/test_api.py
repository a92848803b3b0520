"""The public API: `import labrig as lr` gives the verbs and types a user needs, each
takes a folder, files or runs, and every result shows itself readably."""
from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

import labrig as lr

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "data" / "sweep_default"


def test_every_public_name_is_documented_and_resolves():
    doc = (ROOT / "docs" / "api.md").read_text()
    for name in lr.__all__:
        if name == "__version__":
            continue
        assert re.search(rf"`(lr\.)?{name}\b", doc), f"{name} is not in docs/api.md"
        assert getattr(lr, name) is not None
    assert "docs/api.md" in (ROOT / "README.md").read_text()


def test_the_sites_api_reference_lists_exactly_the_public_names():
    """docs/reference/api.md generates a page for every name of ``labrig.__all__`` and for
    nothing else: the reference and the exports stay in step."""
    text = (ROOT / "docs" / "reference" / "api.md").read_text()
    listed = re.findall(r"^   ([A-Za-z_]\w*)$", text, re.M)
    assert sorted(listed) == sorted(n for n in lr.__all__ if n != "__version__")


def test_import_is_light_and_picks_no_backend():
    code = ("import sys, labrig as lr; "
            "print(sorted(m for m in ('numba', 'matplotlib', 'scipy') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "[]"
    # the whole library imported, still no backend chosen: a notebook keeps its own
    code = ("import matplotlib; import labrig.report.html, labrig.diagnosis.loop.auto, "
            "labrig.analysis.plots; print(matplotlib.rcParams._get_backend_or_none())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, env={"PATH": "/usr/bin:/bin", "MPLBACKEND": ""}).stdout
    assert out.strip() == "None"


def test_verbs_take_a_folder_files_or_runs_alike():
    runs = lr.read_runs(DATA)
    files = sorted(str(p) for p in DATA.glob("*.csv"))
    assert [r.name for r in lr.read_runs(files)] == [r.name for r in runs]
    assert [r.name for r in lr.read_runs([runs[0], files[1]])] == sorted(
        [runs[0].name, Path(files[1]).stem])
    a = lr.identify(str(DATA), seed=3, starts=2)
    b = lr.identify(runs, seed=3, starts=2)
    assert a.method == "co"                       # the command line's default
    assert a.metrics["fitness"] == pytest.approx(b.metrics["fitness"], rel=1e-12)
    with pytest.raises(lr.UserError, match="source"):
        lr.read_runs(42)
    with pytest.raises(lr.UserError, match="source: empty"):
        lr.read_runs([])


def test_results_show_one_screen_and_html(tmp_path):
    runs = lr.read_runs(DATA)
    fit = lr.identify(runs, seed=1, starts=2)
    ev = lr.compare(runs, fit)
    lad = lr.ladder(runs, [fit])
    model_file = fit.model().save(tmp_path / "m.json")
    assert lr.load_model(model_file).params == pytest.approx(fit.model().params)
    diag = lr.diagnose(runs, fit, candidates=["deadband", "coulomb_friction"])
    for obj in (fit, ev, lad, lr.analyse(runs), lr.effects(), diag):
        text = repr(obj)   # one screen: 30 lines of 100 columns, 2,000 characters
        assert text.startswith("<") and len(text.splitlines()) <= 30, type(obj).__name__
        assert len(text) <= 2000, (type(obj).__name__, len(text))
        html = obj._repr_html_()
        assert "<table>" in html
    for obj in (fit, ev, lad):   # the results of the loop show their figure
        assert "data:image/png;base64" in obj._repr_html_()
    assert repr(runs[0]).startswith("Run('cl_sq_0.50V': 900 samples at 200 Hz")
    assert repr(fit.model()).startswith("Model(voltage: linear (R = ")
    # the fit overlays the model on every run it was fitted to (CO too)
    fig = fit.plot()
    assert len(fig.axes) == 4 and fig.axes[0].get_lines()
    assert fit.plot(kind="convergence").axes
    assert json.dumps(fit.to_json())


def test_catalogue_lists_every_effect_with_its_physics():
    cat = lr.effects()
    df = cat.to_pandas()
    assert {"deadband", "coulomb_friction", "stiction", "backlash", "delay"} <= set(df.effect)
    assert all(df.summary.str.len() > 20) and all(df.signature.str.len() > 10)
    assert cat["deadband"].name == "deadband"


def test_the_same_files_give_the_same_fit_and_a_fresh_seed_is_said():
    """No random default: the same files and command give the same answer; a fresh seed
    is drawn only when asked, and printed so the fit can be repeated."""
    a = lr.identify(DATA, method="jfo", pop=12, iters=8)
    b = lr.identify(DATA, method="jfo", pop=12, iters=8)
    assert a.result.seed == b.result.seed == 0 and a.params == b.params
    p = subprocess.run([sys.executable, "-m", "labrig", "identify", str(DATA), "--method",
                        "jfo", "--pop", "12", "--iters", "8", "--seed", "new", "--json"],
                       capture_output=True, text=True)
    said = int(re.search(r"seed (\d+) \(a fresh one; --seed \1 repeats", p.stderr).group(1))
    assert json.loads(p.stdout)["seed"] == said


def test_one_progress_hook_for_every_verb(tmp_path):
    """The events a verb reports while it works (what the command line's bars and the
    lab's streaming both draw from): an identifier's iterations with the best fitness so
    far, a diagnosis' candidates as their re-fits start, a sweep's experiments, samples
    and runs."""
    events = []
    fit = lr.identify(DATA, "jfo", seed=1, pop=10, iters=5, progress=events.append)
    its = [e for e in events if e.kind == "iteration"]
    assert [e.done for e in its][-1] == 5 and all(e.total == 5 for e in its)
    assert its[-1].data == pytest.approx(fit.fitness, rel=1e-9)
    events.clear()
    diag = lr.diagnose(DATA, fit, candidates=["deadband"], progress=events.append)
    # the ranking as it forms: the re-fit started, done, then its held-out error known (a
    # base of 5 JFO iterations is not converged: the candidate's re-fit finds it better
    # values of its own, and the round starts again from them, re-fitting the candidate)
    kinds = [(e.verb, e.kind) for e in events]
    pairs = (len(kinds) - 1) // 2
    assert pairs >= 1 and kinds == [("diagnose", "candidate"), ("diagnose", "fitted")] * pairs \
        + [("diagnose", "validated")], kinds
    assert events[0].data == "deadband" and events[-2].data.effect == "deadband"
    assert events[-1].done == pytest.approx(diag.ranking[0].cross_validated["with_effect"],
                                            rel=1e-9)
    events.clear()
    lr.sweep(tmp_path / "runs", plan=ROOT / "configs" / "plan_two_steps.toml",
             progress=events.append)
    kinds = [e.kind for e in events]
    assert kinds.count("experiment") == kinds.count("run") == 2
    assert sum(e.done for e in events if e.kind == "samples") == sum(
        len(r.t) for r in lr.read_runs(tmp_path / "runs"))


def test_the_interactive_view_draws_what_compare_computes():
    """``Evaluation.view()`` (the lab page's figures) holds the evaluation's own numbers;
    a model set by hand (an effect tried, then one parameter moved) is compared as any."""
    import numpy as np
    from bokeh.events import RangesUpdate

    import labrig.verbs as verbs
    from labrig.core.errors import UserError
    from labrig.diagnosis.results.interactive import MAX_POINTS

    runs = lr.read_runs(DATA)
    m = lr.identify(runs, seed=0).model()
    ev = lr.compare(runs, m)
    view = ev.view()
    rr = ev.worst_run()
    assert view.channels == tuple(rr["channels"])
    drawn = view.drawn   # the whole run in view, at most MAX_POINTS of it drawn
    n = len(rr["t"])
    assert drawn.start == 0 and drawn.stop == n and len(range(n)[drawn]) <= MAX_POINTS
    for ch, c in rr["channels"].items():
        src = view.sources[ch].data
        assert np.array_equal(src["residual"], c["residual"][drawn])
        assert np.array_equal(src["model"], c["simulated"][drawn])
    # a slider's quick evaluation: the same numbers, without regimes and correlations
    quick = lr.compare(runs, m, detail=False)
    for key in ("rmse_over_noise", "fit_percent"):
        assert quick.metrics[key] == ev.metrics[key]
    assert [r["channels"]["speed"]["rmse_over_noise"] for r in quick.per_run] == \
        [r["channels"]["speed"]["rmse_over_noise"] for r in ev.per_run]
    assert not quick.regimes and "stretches" not in quick.per_run[0]["channels"]["speed"]
    # zoomed into a second of the run: every sample of it drawn
    view._zoomed(RangesUpdate(view.figures[0], x0=1.0, x1=2.0))
    t = view.sources["speed"].data["t"]
    assert t[0] <= 1.0 and t[-1] >= 2.0 and np.allclose(np.diff(t), rr["t"][1] - rr["t"][0])
    tried = verbs.try_effect(runs, m, "coulomb_friction")
    assert tried.names == ["coulomb_friction"] and tried.params == m.params
    hand = tried.with_value("coulomb_friction.tc_v", 0.129)
    assert hand.effect_params["coulomb_friction"]["tc_v"] == 0.129
    assert verbs.set_by_hand(runs, m, {"coulomb_friction.tc_v": 0.129}).effect_params == \
        hand.effect_params
    with pytest.raises(UserError, match="outside its range"):
        verbs.set_by_hand(runs, m, {"coulomb_friction.tc_v": 50.0})
    moved = lr.compare(runs, hand).metrics["rmse_over_noise"]["overall"]
    # friction without the plant re-fitted: the linear fit's gain already absorbed it
    assert moved > ev.metrics["rmse_over_noise"]["overall"]
    with pytest.raises(KeyError):
        hand.with_value("deadband.d_v", 0.1)


def test_the_ladder_and_the_ranking_as_interactive_figures():
    """``Ladder.view()`` and ``Diagnosis.view()``: the numbers of the results they show."""
    runs = lr.read_runs(DATA)
    m0 = lr.identify(runs, seed=0).model()
    diag = lr.diagnose(runs, m0, candidates=["deadband", "coulomb_friction"])
    fig = diag.view()
    data = fig.renderers[0].data_source.data
    assert list(data["label"])[::-1] == [c.label for c in diag.ranking]
    assert list(data["rmse"])[::-1] == [c.rmse_over_noise for c in diag.ranking]
    lad = lr.ladder(runs, [m0, diag.recommended_model()])
    src = lad.view().renderers[0].data_source.data
    assert list(src["overall"]) == [s.rmse_over_noise["overall"] for s in lad.steps]


#: the public verbs (the functions `import labrig as lr` gives)
#: the verbs `import labrig as lr` gives (the rest of labrig.verbs is the front ends' door)
VERBS = ("sweep", "read_runs", "analyse", "identify", "add_effect", "remove_effect",
         "diagnose", "auto", "propose", "decide", "compare", "ladder", "effects",
         "load_model", "try_effect", "set_by_hand", "ask_until_sure")


def test_the_reference_lists_exactly_the_public_set():
    """docs/api.md names as `lr.X` exactly what `import labrig as lr` gives (the verbs and
    the result classes): nothing it documents is missing from the package, and every
    public verb is documented."""
    import labrig

    doc = (ROOT / "docs" / "api.md").read_text()
    named = set(re.findall(r"\blr\.([A-Za-z_]+)\b", doc))
    assert named <= set(labrig.__all__), sorted(named - set(labrig.__all__))
    assert set(VERBS) == {n for n in labrig.__all__ if n[0].islower() and n != "__version__"}
    assert set(VERBS) <= named, sorted(set(VERBS) - named)


@pytest.mark.parametrize("name", VERBS)
def test_every_verb_is_documented_as_an_api(name):
    """Each public verb's docstring has numpydoc Parameters (when it takes any), Returns
    and Examples sections, each naming every parameter it takes."""
    import inspect

    fn = getattr(lr, name)
    doc = inspect.getdoc(fn)
    sections = {s for s in ("Parameters", "Returns", "Raises", "Examples")
                if re.search(rf"^{s}\n-+$", doc, re.M)}
    takes = [p for p in inspect.signature(fn).parameters.values()
             if p.kind is not p.VAR_KEYWORD]
    assert {"Returns", "Examples"} <= sections, (name, sections)
    if takes:
        assert "Parameters" in sections, name
        params = doc.split("Parameters\n")[1].split("\nReturns\n")[0]
        for p in takes:
            assert re.search(rf"\b{p.name}\b", params), f"{name}: {p.name} is not described"


def test_the_verbs_examples_run_as_written(monkeypatch):
    """The verbs' examples that are cheap to run (reading runs, the analyser, the
    catalogue) give what they show, from the repository's folder; the others (fits of
    several seconds) are marked as not run."""
    import doctest

    import importlib

    monkeypatch.chdir(ROOT)
    ran = 0
    for name in ("labrig.verbs.acquire", "labrig.verbs.data", "labrig.verbs.fit",
                 "labrig.verbs.loop", "labrig.io.runs", "labrig.model.catalogue",
                 "labrig.identification.engine", "labrig.identification.fit",
                 "labrig.diagnosis.results.diagnosis",
                 "labrig.diagnosis.loop.auto", "labrig.diagnosis.results.ladder",
                 "labrig.design.proposal", "labrig.model.model", "labrig.analysis.result",
                 "labrig.diagnosis.evidence.evaluation", "labrig.identification.problem"):
        mod = importlib.import_module(name)
        res = doctest.testmod(mod, optionflags=doctest.ELLIPSIS)
        assert res.failed == 0, mod.__name__
        ran += res.attempted
    assert ran >= 10


#: the public results (the classes `import labrig as lr` gives that the verbs return)
RESULTS = ("Model", "Run", "AnalysisResult", "Identification", "Diagnosis", "AutoDiagnosis",
           "Evaluation", "Ladder", "Proposal", "Catalogue")


@pytest.mark.parametrize("name", RESULTS)
def test_every_result_is_documented_as_an_api(name):
    """Each public result's docstring lists its attributes and shows it in use (numpydoc
    Attributes and Examples)."""
    import inspect

    doc = inspect.getdoc(getattr(lr, name))
    assert re.search(r"^Attributes\n-+$", doc, re.M), name
    assert re.search(r"^Examples\n-+$", doc, re.M), name


#: the verbs that read files or fit: their docstrings say what they raise
RAISING = ("sweep", "read_runs", "analyse", "identify", "add_effect", "remove_effect",
           "diagnose", "auto", "propose", "decide", "compare", "ladder", "load_model")


@pytest.mark.parametrize("name", RAISING)
def test_every_verb_that_reads_or_fits_says_what_it_raises(name):
    import inspect

    assert re.search(r"^Raises\n-+$", inspect.getdoc(getattr(lr, name)), re.M), name


def test_removing_an_effect_the_model_lacks_names_the_argument():
    """``remove_effect`` validates at entry, naming its parameter and the model's effects
    (it used to hand back the model unchanged)."""
    from labrig.model.effectset import EffectSet

    m = lr.Model(params={"R": 8.0, "L": 0.01, "K": 0.05, "J": 1e-4, "B": 1e-5},
                 effects=EffectSet.parse(["deadband"]), effect_params={"deadband": {"d_v": 0.3}})
    assert lr.remove_effect(m, "deadband").names == []
    with pytest.raises(lr.UserError, match=r"^name: 'stiction' is not an effect of the "
                                           r"model; its effects: deadband$"):
        lr.remove_effect(m, "stiction")


#: methods whose docstrings belong to the JSON form, not to this check
JSON_METHODS = ("to_json", "from_json", "json_schema", "to_dict")


def _public_methods(cls) -> dict:
    """``{name: function}`` of ``cls``'s public methods defined in a labrig class (the
    class itself or a base such as Displayable); classmethods and staticmethods unwrapped."""
    import inspect

    owners = {k.__qualname__ for k in cls.__mro__ if k.__module__.startswith("labrig")}
    out = {}
    for name, member in inspect.getmembers(cls, inspect.isroutine):
        if name.startswith("_") or name in JSON_METHODS:
            continue
        fn = inspect.unwrap(getattr(member, "__func__", member))
        if inspect.isfunction(fn) and fn.__qualname__.split(".")[0] in owners:
            out[name] = fn
    return out


def _returns_a_value(fn) -> bool:
    """The function has ``return <value>`` in its own body (not in a nested function),
    or a return annotation other than None."""
    import ast
    import inspect
    import textwrap

    ann = inspect.signature(fn).return_annotation
    if ann not in (inspect.Signature.empty, None, "None"):
        return True
    tree = ast.parse(textwrap.dedent(inspect.getsource(fn))).body[0]
    todo = list(tree.body)
    while todo:
        node = todo.pop()
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef)):
            continue
        if isinstance(node, ast.Return) and node.value is not None and not (
                isinstance(node.value, ast.Constant) and node.value.value is None):
            return True
        todo.extend(ast.iter_child_nodes(node))
    return False


@pytest.mark.parametrize("name", RESULTS)
def test_every_results_public_method_is_documented(name):
    """Each public method of a public result has a numpydoc docstring: a ``Parameters``
    section naming every parameter (``*args``/``**kwargs`` aside) and a ``Returns`` section
    when it returns a value."""
    import inspect

    cls = getattr(lr, name)
    methods = _public_methods(cls)
    if name != "Run":   # a run's channels are properties; every other result has methods
        assert methods, name
    for meth, fn in methods.items():
        where = f"{name}.{meth}"
        doc = inspect.getdoc(fn)
        assert doc and doc.strip(), f"{where}: no docstring"
        params = [p.name for p in inspect.signature(fn).parameters.values()
                  if p.name not in ("self", "cls")
                  and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]
        if params:
            m = re.search(r"^Parameters\n-{10}\n(.*?)(?=^\w[\w ]*\n-+\n|\Z)", doc, re.M | re.S)
            assert m, f"{where}: no Parameters section"
            for p in params:
                assert re.search(rf"^{re.escape(p)}\b.*?(:|$)", m.group(1), re.M), \
                    f"{where}: parameter {p!r} not in its Parameters section"
        if _returns_a_value(fn):
            assert re.search(r"^Returns\n-{7}$", doc, re.M), f"{where}: no Returns section"


#: the order a student meets the public names in (each example may use the files the ones
#: before it wrote: ``runs`` from sweep's, ``plan.toml`` from propose's)
TOUR = ("sweep", "read_runs", "analyse", "identify", "add_effect", "remove_effect",
        "diagnose", "auto", "compare", "ladder", "effects", "load_model", "try_effect",
        "set_by_hand", "propose", "decide", "ask_until_sure", "Model", "Run", "Effect",
        "Param", "AnalysisResult", "Identification", "Diagnosis", "AutoDiagnosis",
        "Evaluation", "Ladder", "Proposal", "Catalogue", "LabrigError", "UserError")


@pytest.mark.slow
def test_every_public_names_example_runs(tmp_path, monkeypatch):
    """Every example of every name ``import labrig as lr`` gives runs as a doctest, those
    marked ``+SKIP`` for the quick run too (they fit for seconds), in a folder holding
    what they name: the shipped sweep (``data/sweep_default``), a sweep of the simulated
    rig (``runs``, made by sweep's own example), the linear model and one with Coulomb
    friction (``m0.json``, ``m1.json``), and the runs a proposal's plan played
    (``runs/new``)."""
    import doctest
    import inspect
    import shutil

    assert sorted(TOUR) == sorted(n for n in lr.__all__ if n != "__version__")
    shutil.copytree(ROOT / "data" / "sweep_default", tmp_path / "data" / "sweep_default")
    monkeypatch.chdir(tmp_path)
    parser = doctest.DocTestParser()
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    failed, ran = [], 0
    for name in TOUR:
        if name == "identify":   # the models the later examples name
            lr.identify("runs").model().save("m0.json")
            lr.identify("runs", effects=["coulomb_friction"]).model().save("m1.json")
        if name == "decide":     # the proposal's plan, played as `labrig sweep --plan` does
            lr.sweep("runs/new", plan="plan.toml")
        doc = inspect.getdoc(getattr(lr, name))
        examples = doc[doc.index("Examples\n--------"):].replace("# doctest: +SKIP", "")
        test = parser.get_doctest(examples, {}, f"lr.{name}", None, 0)
        assert test.examples, f"lr.{name} has no example"
        res = runner.run(test, out=lambda s: failed.append(s))
        ran += res.attempted
    assert not failed, "".join(failed)
    assert ran >= 60


@pytest.mark.parametrize("name", [n for n in lr.__all__ if n[:1].isupper()])
def test_every_public_class_says_what_it_holds_and_shows_it(name):
    """Each public class's docstring has numpydoc Attributes or Parameters (what it holds,
    or what it is made from) and Examples."""
    import inspect

    doc = inspect.getdoc(getattr(lr, name))
    sections = set(re.findall(r"^(\w+)\n-{3,}$", doc, re.M))
    assert "Examples" in sections and sections & {"Attributes", "Parameters"}, (name, sections)
