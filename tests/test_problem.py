"""A fitting problem (labrig.identification.problem.Problem): the one place a model's
values become the optimisers' search vector."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def _moving_runs(tmp_path):
    """Exercise 5's logs: four of the five runs start in motion (their starts are fitted)."""
    import labrig as lr

    for v in ("3.00", "4.50", "6.00"):
        subprocess.run([sys.executable, "-m", "labrig", "import",
                        str(ROOT / "data" / "arduino_hbridge" / f"step_{v}V.csv"), "--map",
                        "t=ms,u=u_V,pos=count", "--time-unit", "ms", "--pos-unit",
                        "counts:1320", "--gear-ratio", "30", "-o", str(tmp_path / "runs")],
                       check=True, capture_output=True)
    return lr.read_runs(tmp_path / "runs")


def test_a_problems_space_holds_the_runs_starts_whatever_is_asked_first(tmp_path):
    """The objective adds each moving run's fitted start to the search space; a model's
    search vector asked for before anything else has them too (a simplex polish once asked
    first and got a vector five entries short)."""
    from labrig.identification.problem import Problem

    runs = _moving_runs(tmp_path)
    first = Problem(runs, ["asymmetric_deadband"])
    x = first.point(first.initial_point())          # the space asked for first
    lo, hi = first.bounds_of_search()
    assert len(x) == len(lo) == len(hi)
    assert any(n.startswith("start[") for n in first.space.names)
    other = Problem(runs, ["asymmetric_deadband"])
    other.objective                                  # the objective built first
    assert len(other.point(other.initial_point())) == len(x)
    f = first.fitness_of_vectors(x[None, :])
    assert f.shape == (1,) and np.isfinite(f[0])
    assert np.allclose(f, other.fitness_of_vectors(x[None, :]))
