"""Real recordings as they come (issue 46): records made by tests/twin.py, which shares no
code with labrig, imported as their owners would, and run through the loop."""
import json

import numpy as np
import pytest

from labrig.core.errors import FitDiverged
from labrig.io.runs import read_dataset
from labrig.loop.refit import refit_with
from labrig.model.effects import CATALOGUE, get_effect
from labrig.model.model import Model
from conftest import labrig


# -- never a crash: a start whose simulation diverges -------------------------------------

@pytest.fixture(scope="module")
def emps_record(tmp_path_factory):
    """A long force-driven axis in the shape of the EMPS benchmark, imported as its
    users import it (a force drive of 35.15 N/V, position in m)."""
    from twin import emps_like_axis

    tmp = tmp_path_factory.mktemp("emps")
    src = emps_like_axis(tmp / "export")
    labrig("import", src, "-o", tmp / "runs", "--map", "t=t,u=vir,pos=qm", "--axis", "linear",
           "--drive", "force", "--input-gain", "35.15065", "--pos-unit", "m", check=0)
    return tmp / "runs"


def _stiff_model(runs_dir, tmp):
    """The linear model with a stiff mechanical pole (a mass of 0.3 g against 1183 N s/m):
    Coulomb friction's explicit sub-steps overflow from such a start."""
    out = tmp / "m0.json"
    labrig("identify", runs_dir, "--method", "co", "-o", out, check=0)
    doc = json.loads(out.read_text())
    doc["params"] = {"M": 3e-4, "Fv": 1183.0}
    bad = tmp / "stiff.json"
    bad.write_text(json.dumps(doc))
    return bad


@pytest.mark.slow
def test_every_effect_refitted_from_ten_seeds_never_crashes(emps_record, tmp_path):
    """Every catalogue effect re-fitted from seeds 0-9 on the long force-driven record,
    from a start whose simulation overflows: each re-fit ends with a finite fit, or says
    that every start diverged (FitDiverged, exit 1); nothing else. On the old code the
    Coulomb friction re-fit ended 'min() arg is an empty sequence'."""
    runs = read_dataset(emps_record)
    base = Model.from_json(json.loads(_stiff_model(emps_record, tmp_path).read_text()), "stiff")
    outcomes = {}
    for name in CATALOGUE:
        for seed in range(10):
            try:
                fit = refit_with(runs, base, get_effect(name), seed=seed)
            except FitDiverged as exc:
                assert "every start" in str(exc) and "--model" in str(exc)
                outcomes[name, seed] = "diverged"
                continue
            assert np.isfinite(fit.fitness), (name, seed)
            outcomes[name, seed] = "fitted"
    assert "diverged" in outcomes.values()   # the record does exercise a divergence


@pytest.mark.slow
def test_diagnose_from_a_diverging_start_says_so(emps_record, tmp_path):
    """``labrig diagnose --seed 2`` (and 3, 4) from that start: no internal error; the
    candidate whose every start diverged is named as not ranked."""
    bad = _stiff_model(emps_record, tmp_path)
    for seed in (2, 3, 4):
        p = labrig("diagnose", emps_record, "--model", bad, "--seed", seed, "--json")
        assert p.returncode in (0, 1), p.stderr
        assert "internal error" not in p.stderr and "Traceback" not in p.stderr
        assert "RuntimeWarning" not in p.stderr
        if p.returncode == 0:
            doc = json.loads(p.stdout)
            assert doc["diverged"] == ["coulomb_friction"]
            assert "Not ranked: coulomb_friction" in doc["verdict"]
        else:
            assert len(p.stderr.strip().splitlines()) == 1
