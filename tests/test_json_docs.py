"""Each JSON shape is defined once: the document beside its result declares every key the
result's writer puts in it (so the report's reader and the writer cannot drift apart),
and a record read back gives the same tables."""
from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import BaseModel

import labrig as lr
from labrig.analysis.doc import AnalysisDoc
from labrig.identification.doc import IdentRecord
from labrig.identification.table import identification_dict
from labrig.diagnosis.results.docs import DiagnosisDoc, LadderDoc

DATA = Path(__file__).resolve().parent.parent / "data" / "sweep_default"


def undeclared(obj, where="") -> list[str]:
    """Keys a writer wrote that the document does not declare, anywhere inside it."""
    out = []
    if isinstance(obj, BaseModel):
        out += [f"{where}.{k}" for k in (obj.model_extra or {})]
        for name in type(obj).model_fields:
            out += undeclared(getattr(obj, name), f"{where}.{name}")
    elif isinstance(obj, dict):
        for k, v in obj.items():
            out += undeclared(v, f"{where}.{k}")
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            out += undeclared(v, f"{where}.{i}")
    return out


@pytest.fixture(scope="module")
def results():
    runs = lr.read_runs(DATA)
    fit = lr.identify(runs, seed=2, starts=2)
    diag = lr.diagnose(runs, fit, candidates=["coulomb_friction", "deadband"])
    return {"analysis": lr.analyse(runs), "fit": fit, "diagnosis": diag,
            "ladder": lr.ladder(runs, [fit, diag.recommended_model()])}


@pytest.mark.parametrize("key, doc, write", [
    ("analysis", AnalysisDoc, lambda r: r.to_json()),
    ("fit", IdentRecord, identification_dict),
    ("diagnosis", DiagnosisDoc, lambda r: r.to_json()),
    ("ladder", LadderDoc, lambda r: r.to_json()),
])
def test_the_document_declares_every_key_its_writer_writes(results, key, doc, write):
    record = doc.model_validate(write(results[key]))
    assert undeclared(record) == []


def test_a_record_read_back_shows_the_same_tables(results):
    # (an analysis record keeps no tacho volts per level: its level table differs there)
    for key, doc in (("diagnosis", DiagnosisDoc), ("ladder", LadderDoc)):
        res = results[key]
        back = doc.model_validate(res.to_json()).result()
        mine = res.table_rows() if isinstance(res.table_rows(), list) else [res.table_rows()]
        theirs = back.table_rows() if isinstance(back.table_rows(), list) else [back.table_rows()]
        assert [t.rows for t in theirs] == [t.rows for t in mine], key
