"""The example notebook runs top to bottom in a real Jupyter kernel, and every figure its
text quotes is what its cells compute.

A markdown cell declares its figures in a comment, one per line, as a Python expression
evaluated in the notebook's namespace after the last cell, and the figure the text
quotes (default tolerance: one unit in the last digit; ``±TOL`` overrides; a non-number
is compared as written)::

    <!-- check
    fit.metrics["rmse_over_noise"]["overall"]    8.43
    given: 1.0
    -->

Every decimal figure of a markdown cell must be declared there (``given:`` lists the
settings and definitions it quotes), so no figure in the notebook is written by hand.
The executed notebook is kept in ``tests/artefacts/loop.ipynb`` to look at.
"""
from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from quoted import FIGURE, TOL, default_tolerance, number

ROOT = Path(__file__).resolve().parent.parent
NOTEBOOK = ROOT / "docs" / "notebooks" / "loop.ipynb"
ARTEFACTS = Path(__file__).resolve().parent / "artefacts"
CHECK = re.compile(r"<!--\s*check\s*\n(.*?)-->", re.S)


def _checks(nb) -> tuple[list, list]:
    """(expression, quoted, tolerance) per check line; and the undeclared figures."""
    checks, undeclared = [], []
    for cell in nb.cells:
        if cell.cell_type != "markdown":
            continue
        declared = set()
        for block in CHECK.findall(cell.source):
            for line in filter(None, (s.strip() for s in block.splitlines())):
                if line.startswith("given:"):
                    declared |= set(line[6:].split())
                    continue
                tol = TOL.search(line)
                body = line[:tol.start()].rstrip() if tol else line
                expr, quoted = re.match(r"(.*\S)\s{2,}(\S.*)$", body).groups()
                checks.append((expr, quoted, tol))
                declared.add(quoted)
        prose = CHECK.sub("", cell.source)
        undeclared += [f for f in FIGURE.findall(prose) if f.lstrip("+") not in declared]
    return checks, undeclared


@pytest.mark.slow
@pytest.mark.kernels
def test_the_example_notebook_runs_and_its_figures_hold():
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    nb = nbformat.read(NOTEBOOK, as_version=4)
    checks, undeclared = _checks(nb)
    assert checks and undeclared == []
    exprs = [c[0] for c in checks]
    probe = ("import json as _j\n_v = []\nfor _e in " + repr(exprs) + ":\n"
             "    _x = eval(_e)\n"
             "    _v.append(_x if isinstance(_x, (int, float)) else str(_x))\n"
             "print('CHECKS' + _j.dumps(_v))")
    nb.cells.append(nbformat.v4.new_code_cell(probe))
    nbclient.NotebookClient(nb, timeout=600, kernel_name="python3",
                            resources={"metadata": {"path": str(ROOT)}}).execute()
    out = "".join(o.get("text", "") for o in nb.cells.pop().outputs)
    ARTEFACTS.mkdir(exist_ok=True)
    nbformat.write(nb, ARTEFACTS / "loop.ipynb")
    values = json.loads(out.split("CHECKS", 1)[1])
    for (expr, quoted, tol), value in zip(checks, values):
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            q = number(quoted)
            t = (float(tol.group(1)) * (abs(q) / 100 if tol.group(2) else 1.0)) if tol \
                else default_tolerance(quoted)
            assert abs(value - q) <= t + 1e-12, f"{expr}: computed {value}, quoted {quoted}"
        else:
            assert str(value) == quoted, f"{expr}: computed {value}, quoted {quoted}"
    # every result showed itself as HTML (a table, and a figure where it has one)
    html = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])
            if "text/html" in o.get("data", {})]
    assert len(html) >= 8
    assert sum("data:image/png;base64" in o["data"]["text/html"] for o in html) >= 6

