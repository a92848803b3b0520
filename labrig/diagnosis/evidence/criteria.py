"""The diagnosis's criteria: every threshold and rule of "supported", "undecided",
"refined" and "near the floor", in one place, with why (docs/physics.md, 'Diagnosis').

The diagnosis (:mod:`labrig.diagnosis.loop.diagnose`), the search (:mod:`labrig.diagnosis.loop.search`) and
the ranking's words (:mod:`labrig.diagnosis.results.diagnosis`) read them from here; nothing else holds
a copy.
"""
from __future__ import annotations

import math

from labrig.model.effects import CATALOGUE, get_effect

#: a candidate must lower the cross-validated (and the in-sample) error by this much
MIN_GAIN = 0.05
#: and be strongly supported by BIC (Kass & Raftery: |dBIC| > 10 is "very strong")
MIN_DBIC = -10.0
#: below this rmse/noise the model is called at the noise floor (in words only: the
#: decision is the cross-validation's)
FLOOR = 1.15
#: candidates cross-validated per round (the best by in-sample error)
CV_CANDIDATES = 4
#: relative penalty per extra parameter when held-out errors are compared
PARSIMONY = 0.02
#: a candidate whose in-sample error (with the parsimony penalty) is more than this share
#: above what the best supported candidate predicts held out is not cross-validated
#: (:func:`out_of_reach`): a fit's held-out error is not below its in-sample error by
#: that much (docs/physics.md, 'Diagnosis', has the measurement)
CV_REACH = 0.25
#: two supported explanations whose scores are this close are reported as undecided
UNDECIDED = 0.02
#: a base this much worse than a candidate with its effect switched off is refined ...
REFINE = 0.01
#: ... at most this many times
MAX_REFINE = 2
#: a replacement by an effect with as many parameters must gain this much (held out)
SWAP_GAIN = 0.02
#: a simpler replacement (fewer parameters) may be this much worse on held-out data
SIMPLER_MARGIN = 0.02
#: the screen (:func:`screen`): a candidate's re-fit is looked at after this many
#: iterations ...
SCREEN_AFTER = 3
#: ... and ended there when the effect has gained less than this much so far ...
SCREEN_GAIN = MIN_GAIN / 2
#: ... and its last iteration gained less than this (of the base's error): it has stalled
SCREEN_STALL = 0.005
#: the search tries pairs when no single candidate comes this near the floor ...
NEAR_FLOOR = 1.5
#: ... among this many leading candidates (one per family)
PAIR_POOL = 3


def bic(sse, n, n_eff, k):
    """BIC with the sample count corrected for the residuals' colour (``n_eff``)."""
    return n_eff * math.log(max(sse, 1e-300) / n) + k * math.log(n_eff)


def screen(f0: float, n_eff: float):
    """The rule that screens a candidate out of a round (``stop`` of its re-fit,
    :func:`labrig.diagnosis.loop.refit.refit_with`), for a base of fitness ``f0`` on data of
    ``n_eff`` effective samples.

    After :data:`SCREEN_AFTER` iterations a re-fit is ended there when all three hold: it
    has gained less than :data:`SCREEN_GAIN`; it has stalled (its last iteration gained
    under :data:`SCREEN_STALL` of ``f0``); and BIC does not already call it strong
    evidence (its dBIC so far, counting one parameter, is not below :data:`MIN_DBIC`).
    A move that gains under :data:`MIN_GAIN` is never cross-validated, hence never
    supported; one that has stopped moving at half of that will not get there; and the
    third condition keeps a small but real effect near the noise floor (a 4 ms delay the
    electrical pole nearly absorbs gains 1 % after three iterations and climbs slowly on)
    in the ranking with its fitted size. Most of a round's candidates are effects the
    data do not show, and most of a re-fit's iterations go to polishing them at zero
    gain; a re-fit that is not ended runs to the end exactly as without the screen.
    Whether the screen ever changes a recommendation is tested on every test case
    (``diagnose(screen=False)`` is the full round)."""
    def stop(history: list) -> bool:
        if len(history) != SCREEN_AFTER + 1:
            return False
        f, prev = history[-1], history[-2]
        dbic = n_eff * math.log(max(f, 1e-300) ** 2 / f0 ** 2) + math.log(n_eff)
        return 1.0 - f / f0 < SCREEN_GAIN and (prev - f) / f0 < SCREEN_STALL \
            and dbic >= MIN_DBIC
    return stop


def supported(c) -> bool:
    """The decision on a :class:`~labrig.diagnosis.results.diagnosis.Candidate`, in the terms the ranking
    table states (:meth:`Diagnosis._ranking_rules`)."""
    cv = c.cross_validated
    if cv is None or c.unresolved:
        return False
    majority = cv["folds_improved"] > cv["folds"] / 2
    if c.move == "remove":   # the mirror of adding: it stays only when it earns MIN_GAIN
        return cv["with_effect"] < cv["baseline"] / (1 - MIN_GAIN)
    if c.move == "replace" and c.extra_params < 0:   # simpler and about as good
        return cv["with_effect"] <= (1 + SIMPLER_MARGIN) * cv["baseline"]
    gain = SWAP_GAIN if c.move == "replace" and c.extra_params == 0 else MIN_GAIN
    return bool(c.delta_bic < MIN_DBIC and c.improvement >= gain and cv["improvement"] >= gain
                and majority)


def score(c) -> float:
    """Cross-validated error with a mild penalty per parameter the move adds beyond one
    (a bonus per parameter it takes away), so a simpler model that predicts held-out
    data about as well ranks first (a symmetric dead zone over an asymmetric one that
    fits no better, Coulomb friction over stiction, a model without a useless effect)."""
    return c.cross_validated["with_effect"] * _parsimony(c)


def _parsimony(c) -> float:
    """The factor :func:`score` puts on an error for the parameters the move adds."""
    return 1 + PARSIMONY * (c.extra_params - 1)


def out_of_reach(c, best: float) -> bool:
    """Whether candidate ``c`` cannot come near a supported candidate whose score is
    ``best``: its in-sample error, scored as held-out errors are, is above ``best`` by
    more than :data:`UNDECIDED` and :data:`CV_REACH` together. Its held-out error would be
    higher still, so cross-validating it could change neither the recommendation nor
    what is undecided."""
    return c.evaluation.fitness * _parsimony(c) > (1 + UNDECIDED) * (1 + CV_REACH) * best


def undecided(a, b) -> bool:
    """Whether the runner-up ``b``, a different explanation (another family), predicts
    held-out data within :data:`UNDECIDED` of the first ``a``: their order is not
    evidence."""
    if a.effect == b.effect or \
            get_effect(a.effect).family_name == get_effect(b.effect).family_name:
        return False
    return score(b) <= (1 + UNDECIDED) * score(a)



def simpler_first(names) -> tuple:
    """The deterministic order between explanations the data do not tell apart: fewer
    parameters first, then the catalogue's order (:data:`labrig.model.effects.CATALOGUE`).
    It reads only the effects' names, so no seed and no last digit of a fit can change
    it."""
    order = list(CATALOGUE)
    names = list(names)
    return (sum(len(get_effect(n).params) for n in names),
            sorted(order.index(n) if n in order else len(order) for n in names))


def candidate_order(c) -> tuple:
    """:func:`simpler_first` for a round's move: the parameters it adds (fewer when it
    takes some away), then the catalogue's order of its effect."""
    return (c.extra_params,) + simpler_first([c.effect])[1:]


def decide_ties(items: list, error, simpler) -> list:
    """``items`` best first by ``error(item)``, except that those within :data:`UNDECIDED`
    of the best come first in the order of ``simpler(item)`` (:func:`simpler_first`):
    where the data cannot tell explanations apart, the answer is the simpler one by a
    stated rule, not whichever one the seed or the BLAS kernel's rounding left a hair
    ahead."""
    items = sorted(items, key=error)
    if not items:
        return items
    e0 = error(items[0])
    near = [x for x in items if error(x) <= (1 + UNDECIDED) * e0]
    return sorted(near, key=simpler) + items[len(near):]
