"""What the report shows, as typed pieces: the :class:`Story` that ``gather`` fills and
``sections`` turns into the page.

Every piece is a result object of the stage that made it (``AnalysisResult``,
``Diagnosis``, ``Ladder``, ``Model``) or a record validated at the JSON boundary
(:mod:`labrig.report.artefacts`), so nothing after gathering looks keys up in dicts.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from labrig.core.figures import png_bytes

if TYPE_CHECKING:  # annotations only: gathering imports the heavy modules lazily
    from labrig.verbs.types import (AnalysisResult, Diagnosis, IdentRecord, Ladder, Model,
                                    Regimes)

#: section key -> heading, in page order
#: the loop first (where the linear model fails, what is missing, the error falling with
#: the corrected model on the data), then the details behind it (the analysis' edges,
#: the identifiers side by side)
SECTIONS = (("sweep", "1. The sweep"),
            ("failures", "2. Where the model fails"),
            ("diagnosis", "3. Diagnosis: what is missing"),
            ("ladder", "4. The error ladder"),
            ("analysis", "5. First-order analysis"),
            ("models", "6. Identified models"))


def fig_bytes(fig, dpi: int = 110) -> bytes:
    """``fig`` as PNG bytes, closed after (see :func:`labrig.core.figures.png_bytes`)."""
    return png_bytes(fig, dpi)


@dataclass
class Figure:
    """One embedded figure: PNG bytes with a title and a caption.

    ``wide`` figures take the page width; narrow ones are paired side by side.
    """

    title: str
    png: bytes
    caption: str = ""
    wide: bool = True


@dataclass
class Story:
    """Everything the page shows, gathered from the work folder or computed.

    Attributes
    ----------
    data_dir : Path
        The folder of runs.
    work : Path or None
        The work folder whose artefacts were read (None: everything computed here).
    runs : list of labrig.io.runs.Run
    quick : bool
        The diagnosis and the ladder were not computed (their files still count).
    sources : dict
        Section key -> where its content came from (a path or "computed by ...").
    missing : dict
        Section key -> the command that would fill the empty section.
    notes : list of str
        Page-level notes: artefacts that were ignored, and why.
    figures : dict
        Section key -> list of :class:`Figure`.
    analysis : AnalysisResult or None
    analysis_error : str or None
        Why the analysis could not be computed here.
    idents : list of IdentRecord
        One identification per method, as ``identify --json`` wrote it.
    best : str or None
        The method whose model the later sections judge.
    model0 : Model or None
        The linear model of sections 4-6; ``model0_source`` says where it came from.
    regimes : Regimes or None
        The linear model's error by regime and by amplitude (section 2).
    worst_run : str or None
        The run shown in section 2's comparison figure.
    diagnosis : Diagnosis or None
    ladder : Ladder or None
    """

    data_dir: Path
    work: Path | None
    runs: list
    quick: bool
    sources: dict = field(default_factory=dict)
    missing: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    figures: dict = field(default_factory=dict)
    analysis: AnalysisResult | None = None
    analysis_error: str | None = None
    idents: list[IdentRecord] = field(default_factory=list)
    best: str | None = None
    model0: Model | None = None
    model0_source: str = ""
    regimes: Regimes | None = None
    worst_run: str | None = None
    diagnosis: Diagnosis | None = None
    ladder: Ladder | None = None

    @property
    def best_ident(self) -> IdentRecord | None:
        """The identification of the best method (the first one if none is named)."""
        return next((r for r in self.idents if r.method == self.best),
                    self.idents[0] if self.idents else None)
