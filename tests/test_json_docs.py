"""Each result is declared once: its dataclass (a :class:`labrig.core.record.Record`) is
its JSON form, and pydantic derives from it the JSON, the schema and the reading back;
there is no hand-written writer and no second document to keep in line (issue 62)."""
from __future__ import annotations

import ast
import json
from pathlib import Path

import jsonschema
import pytest

import labrig as lr
from labrig.core.record import Record
from labrig.identification.doc import IdentRecord
from labrig.identification.table import identification_dict

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "data" / "sweep_default"

#: the two classes that write JSON of their own, and why: a model file is a file format
#: read at the boundary (its one declaration is core/schemas.ModelFile, with its limits);
#: a fit is a live object whose record is declared once as IdentRecord and written
#: through it (identification_record)
OWN_WRITERS = {"model/model.py": "Model", "identification/fit.py": "Identification"}


@pytest.fixture(scope="module")
def results():
    runs = lr.read_runs(DATA)
    fit = lr.identify(runs, seed=2, starts=2)
    diag = lr.diagnose(runs, fit, candidates=["coulomb_friction", "deadband"])
    return {"analysis": lr.analyse(runs), "fit": fit, "diagnosis": diag,
            "ladder": lr.ladder(runs, [fit, diag.recommended_model()])}


def test_no_result_writes_its_json_by_hand():
    """No ``to_json`` in the package but the Record's own (and the two named above)."""
    pkg = ROOT / "labrig"
    found = {}
    for f in pkg.rglob("*.py"):
        rel = f.relative_to(pkg).as_posix()
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.ClassDef):
                if any(isinstance(b, ast.FunctionDef) and b.name in ("to_json", "_old_to_json")
                       for b in node.body):
                    found[rel] = node.name
    assert found == {"core/record.py": "Record", **OWN_WRITERS}


@pytest.mark.parametrize("key", ["analysis", "diagnosis", "ladder"])
def test_the_json_fits_the_schema_derived_from_the_declaration(results, key):
    res = results[key]
    doc = json.loads(json.dumps(res.to_json()))
    jsonschema.validate(doc, type(res).json_schema())
    # every key written is a declared one (nothing slips past the declaration); a key
    # written only when it says something ("diverged") may be absent
    schema = type(res).json_schema()
    assert set(schema.get("required", ())) <= set(doc) <= set(schema["properties"])


def test_every_record_has_a_schema():
    """Every Record in the package derives its schema (a type pydantic cannot describe
    would fail here, not in a user's ``json_schema()``)."""
    import importlib
    import pkgutil

    import labrig

    for m in pkgutil.walk_packages(labrig.__path__, "labrig."):
        # (the front ends hold no result; __main__ would run the command line)
        if not m.name.startswith(("labrig.lab", "labrig.cli", "labrig.commands",
                                  "labrig.__main__", "labrig.step_helper")):
            importlib.import_module(m.name)

    def subclasses(c):
        for s in c.__subclasses__():
            yield s
            yield from subclasses(s)

    records = {c for c in subclasses(Record) if c.__module__.startswith("labrig.")}
    assert len(records) >= 25
    for c in records:
        assert c.json_schema()["type"] == "object", c


def test_the_fit_is_written_through_its_record(results):
    """identify --json is the fit's record (IdentRecord), every key declared: an
    undeclared key is an error where it is written."""
    fit = results["fit"]
    doc = identification_dict(fit)
    assert doc == fit.to_json()
    record = IdentRecord.model_validate(json.loads(json.dumps(doc)), extra="forbid")
    assert record.method == fit.method and record.params["K"] == pytest.approx(fit.params["K"])


def test_a_record_read_back_shows_the_same_tables(results):
    # (an analysis record keeps no tacho volts per level: its level table differs there)
    for key in ("diagnosis", "ladder"):
        res = results[key]
        back = type(res).from_json(json.loads(json.dumps(res.to_json())))
        mine = res.table_rows() if isinstance(res.table_rows(), list) else [res.table_rows()]
        theirs = back.table_rows() if isinstance(back.table_rows(), list) else [back.table_rows()]
        assert [t.rows for t in theirs] == [t.rows for t in mine], key


def test_a_summary_is_not_read_back_as_if_it_were_the_result():
    """A result whose JSON summarises live objects (an evaluation's residuals, a
    proposal's candidate inputs) says so rather than failing on a missing key."""
    from labrig.design.proposal import Proposal
    from labrig.diagnosis.evidence.evaluation import Evaluation

    for cls in (Evaluation, Proposal, lr.AutoDiagnosis):
        with pytest.raises(TypeError, match=f"^{cls.__name__}'s JSON is a summary"):
            cls.from_json({})
        assert cls.json_schema()["type"] == "object"


def test_a_move_not_in_the_ranking_is_named_with_the_ones_that_are(results):
    """``Diagnosis.candidate`` is a lookup by label: a missing one is a KeyError that
    lists the ranking's moves (it was a bare StopIteration)."""
    diag = results["diagnosis"]
    with pytest.raises(KeyError, match="'stiction' is not a move of the ranking; its moves: "
                                       + diag.ranking[0].label):
        diag.candidate("stiction")
    assert diag.candidate(diag.ranking[0].label) is diag.ranking[0]
