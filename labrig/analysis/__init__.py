"""First-order analysis of open-loop runs: deadband, Km, tau_m, Kt, gain trend.

The input of every open-loop run is taken to be piecewise constant (square waves,
steps, staircases). Levels and edges are found from ``u`` itself, never from the
sidecar, so imported runs and foreign waveforms work the same way. For each level
the steady speed comes from the flat part after the transient has died out; for
each edge a first-order step response is fitted (the 63 % point is kept as a
cross-check). The steady points then give the paper's Km = w/V per level, the
incremental gain (slope of speed against voltage), the deadband (where that line
meets zero speed) and the trend of w/V with amplitude, which tells a threshold
(deadband, Coulomb friction: w/V rises) from saturation (w/V falls); docs/physics.md,
'Effect catalogue'.

Runs with only a position pot are analysed on the motor angle
``gear_ratio * theta_out``: the edge model is integrated instead of the data being
differentiated, so pot quantisation does not turn into speed noise.

Modules: ``segments`` (levels and edges of u), ``edges`` (the first-order fit of each
edge), ``levels`` (steady levels, the speed-vs-voltage line, Kt), ``verdict`` (gain
trend and the explanation), ``summarise`` (dataset -> headline numbers), ``run``,
``dataset`` and ``table1`` (the entry points), ``result`` (the result objects) and
``text`` (their tables).

Examples
--------
>>> res = analyse("data/sweep_default")              # doctest: +SKIP
>>> res.km, res.tau_s, res.gain_trend                # doctest: +SKIP
>>> res.to_pandas()                                  # doctest: +SKIP
>>> fig = res.plot()                                 # doctest: +SKIP
>>> for name, fig in res.figures().items():          # doctest: +SKIP
...     fig.savefig(name)
"""
from __future__ import annotations

from labrig.analysis.dataset import analyse
from labrig.analysis.edges import fit_edge
from labrig.analysis.stepfit import StepFit
from labrig.analysis.levels import SETTLE_TAUS
from labrig.analysis.result import GAIN_TOLERANCE, AnalysisResult
from labrig.analysis.run_result import EdgeFit, Level, LineFit, RunAnalysis
from labrig.analysis.run import analyse_run
from labrig.analysis.segments import find_segments
from labrig.analysis.summarise import KT_TOLERANCE
from labrig.analysis.table1 import analyse_table

__all__ = ["analyse", "analyse_run", "analyse_table", "find_segments", "fit_edge",
           "AnalysisResult", "RunAnalysis", "EdgeFit", "StepFit", "Level", "LineFit",
           "GAIN_TOLERANCE", "SETTLE_TAUS", "KT_TOLERANCE"]
