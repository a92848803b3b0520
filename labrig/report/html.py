"""``labrig report``: the whole story of a data set in one self-contained HTML page.

The page has six sections -- the sweep, the first-order analysis, the identified
models side by side, where the model fails, the diagnosis and the error ladder --
plus a header with the key numbers and a footer saying where everything came from.
Figures are embedded as base64 PNG, the CSS is inline and there is no script, so
the file can be mailed, opened in any browser and printed (each section starts on
a new page).

Artefacts written by the earlier stages (``analysis.json``, ``identify_all.json``,
``model0.json``, ``diagnosis.json``, ``model1.json``, ``ladder.json``, ``figures/``;
see ``labrig demo``) are read from a work folder when they exist; what is missing is
computed. A section that cannot be filled says which command fills it.

The work is split: :mod:`~labrig.report.gather` collects a
:class:`~labrig.report.story.Story`, :mod:`~labrig.report.sections` turns it into
section data, :mod:`~labrig.report.render` draws the jinja2 template
``templates/report.html.j2``.

>>> build_report("demo_out/runs", "report.html", work="demo_out")   # doctest: +SKIP
"""
from __future__ import annotations

import sys
from pathlib import Path

from labrig.core.errors import UserError
from labrig.report.gather import gather
from labrig.report.render import render, write
from labrig.report.story import Story, fig_bytes

__all__ = ["ARTEFACTS", "Story", "build_report", "fig_bytes", "find_work", "gather", "render"]

#: files that mark a folder as a work folder of the earlier stages
ARTEFACTS = ("analysis.json", "identify_all.json", "model0.json", "diagnosis.json",
             "model1.json", "ladder.json")


def find_work(data_dir) -> Path | None:
    """The default work folder: the parent of the data folder when it holds artefacts."""
    parent = Path(data_dir).resolve().parent
    if any((parent / a).is_file() for a in ARTEFACTS) or (parent / "figures").is_dir():
        return parent
    return None


def build_report(data_dir, output="report.html", work=None, *, quick=False, seed=1,
                 log=None) -> Path:
    """Write the report of ``data_dir`` to ``output``; returns its path.

    Parameters
    ----------
    data_dir : str or Path
        Folder of runs.
    output : str or Path
        The HTML file to write (atomically).
    work : str, Path, None or False
        Folder with the earlier stages' artefacts (analysis.json, ...); None: the
        parent of ``data_dir`` when it holds any; False: none, everything is computed.
    quick : bool
        Skip the diagnosis and the ladder when their JSON files are absent.
    seed : int
        Seed of what is identified or diagnosed here.
    log : callable(str), optional
        Progress messages (default: printed to stderr).

    Returns
    -------
    Path
        The file written.
    """
    if log is None:
        def log(text):
            print(text, file=sys.stderr, flush=True)
    if work is None:
        work = find_work(data_dir)
    elif work is False:
        work = None
    elif not Path(work).is_dir():
        raise UserError(f"`work={work}`: no such folder")
    story = gather(data_dir, work=work, quick=quick, seed=seed, log=log)
    return write(render(story), output)
