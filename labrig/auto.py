"""``labrig diagnose --auto``: the missing-physics loop run to the end.

Round after round, :func:`labrig.diagnose.diagnose` re-fits every effect the model
lacks and the recommended one is added, until nothing more earns its parameters (or
``max_rounds`` effects were added). The result holds the final model, the error ladder
and the *confusable pairs*: candidates that explain the data about equally well, with
the regime where their predictions differ most (where an experiment should look).
"""
from __future__ import annotations

from dataclasses import dataclass, field

from .diagnosis import Candidate, Diagnosis
from .ladder import Ladder, add_effects
from .model.model import Model
from .residuals import REGIME_TEXT
from .tables import Table, fmt

#: two candidates are confusable when their errors differ by less than this (relative)
CONFUSABLE = 0.10


@dataclass
class ConfusablePair:
    """Two effects that explain the data about equally well."""

    first: str
    second: str
    rmse_over_noise: tuple
    differ_in: dict | None  # {"channel", "regime", "first", "second"}: where they differ most
    round: int

    def to_json(self) -> dict:
        return {"pair": [self.first, self.second], "rmse_over_noise": list(self.rmse_over_noise),
                "differ_in": self.differ_in, "round": self.round}


@dataclass
class AutoDiagnosis:
    """Every round's diagnosis, the final model, its ladder and the confusable pairs."""

    rounds: list[Diagnosis]
    model: Model
    ladder: Ladder
    confusable: list[ConfusablePair] = field(default_factory=list)

    @property
    def added(self) -> list[str]:
        return [d.recommendation for d in self.rounds if d.recommendation]

    def to_json(self) -> dict:
        return {"effects": self.model.names, "added": self.added,
                "final_model": self.model.to_json(), "ladder": self.ladder.to_json()["steps"],
                "confusable": [p.to_json() for p in self.confusable],
                "rounds": [d.to_json() for d in self.rounds],
                "verdict": self.rounds[-1].verdict if self.rounds else ""}

    def table_rows(self) -> list[Table]:
        pairs = Table("confusable pairs (about equally good: an experiment should decide)",
                      ["round", "pair", "rmse/noise", "they differ most in"])
        for p in self.confusable:
            d = p.differ_in
            where = (f"{REGIME_TEXT[d['regime']]} of the {d['channel']} "
                     f"({d['first']:.2f} vs {d['second']:.2f})") if d else "-"
            pairs.rows.append([str(p.round), f"{p.first} / {p.second}",
                               f"{fmt(p.rmse_over_noise[0], '.2f')} / "
                               f"{fmt(p.rmse_over_noise[1], '.2f')}", where])
        if not self.confusable:
            pairs.notes.append("none: every supported effect was clearly better than the next")
        return [self.ladder.table_rows(), pairs]

    def to_text(self) -> str:
        out = [t.to_text() + "\n" for t in self.table_rows()]
        out.append(f"final model: {self.model.describe()}")
        if self.rounds:
            out.append(self.rounds[-1].verdict)
        return "\n".join(out)

    def plot(self, ax=None):
        return self.ladder.plot(ax=ax)


def confusable_pairs(diag: Diagnosis, round_no: int, margin: float = CONFUSABLE) -> list:
    """Candidates of one round that clearly improve the model (by the diagnosis' minimum
    gain) and lie within ``margin`` of the best one, each paired with the best, and the
    regime where their errors differ most."""
    useful = [c for c in diag.ranking if c.improvement >= diag.criteria["min_improvement"]]
    if len(useful) < 2:
        return []
    best = min(useful, key=lambda c: c.rmse_over_noise)
    out = []
    for c in useful:
        if c is best or c.rmse_over_noise > (1 + margin) * best.rmse_over_noise:
            continue
        out.append(ConfusablePair(best.effect, c.effect, (best.rmse_over_noise, c.rmse_over_noise),
                                  _where_they_differ(best, c), round_no))
    return out


def _where_they_differ(a: Candidate, b: Candidate) -> dict | None:
    best = None
    for ch, regs in (a.regimes or {}).get("by_regime", {}).items():
        for reg, va in regs.items():
            vb = (b.regimes or {}).get("by_regime", {}).get(ch, {}).get(reg)
            if vb is None or va["share_of_time"] < 0.005:
                continue
            gap = abs(va["rmse_over_noise"] - vb["rmse_over_noise"])
            if best is None or gap > best[0]:
                best = (gap, {"channel": ch, "regime": reg, "first": va["rmse_over_noise"],
                              "second": vb["rmse_over_noise"]})
    return best[1] if best else None


def auto_diagnose(runs, model: Model | None = None, *, max_rounds: int = 3, seed: int = 0,
                  fixed: dict | None = None, log=None) -> AutoDiagnosis:
    """Diagnose, add the recommendation, repeat (:func:`labrig.ladder.add_effects`), and
    name the confusable pairs of every round.

    Parameters
    ----------
    runs : list of Run
    model : Model, optional
        Where to start (default: the linear model, identified by the first round).
    max_rounds : int
        At most this many effects are added.
    seed : int
    fixed : dict, optional
        Parameters known from other measurements.
    log : callable(str), optional
    """
    rounds, ladder, model = add_effects(runs, model, max_rounds=max_rounds, seed=seed,
                                        fixed=fixed, log=log)
    pairs = [p for k, diag in enumerate(rounds, 1) for p in confusable_pairs(diag, k)]
    return AutoDiagnosis(rounds=rounds, model=model, ladder=ladder, confusable=pairs)
