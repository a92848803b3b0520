"""The missing-physics loop: where the model fails, which catalogue effect is missing,
and the evidence, in numbers and in words.

``diagnose(runs, model)``:

1. simulates the current model and locates its error by regime and amplitude against
   each channel's honest noise floor (``labrig.analysis.noise``), with the channels weighted so
   that neither drowns the other;
2. re-fits the model with every catalogue effect it lacks, from starts scanned over
   the range the data can see and in two basins of the electrical pole
   (``labrig.diagnosis.loop.refit``), so no threshold starts on a plateau;
3. compares the candidates on equal terms: BIC with the sample count corrected for
   the colour of simulation residuals, and the error on data the fits did not see,
   by cross-validation (``labrig.diagnosis.evidence.crossval``: whole runs held out in turn, or blocks
   of a single long run), so an extra parameter cannot win by overfitting or by luck;
4. explains the winner: what it is in the rig, where its signature shows in these
   runs (the regimes that carry the held-out evidence), and the experiment that would
   confirm it. ``recommendation`` is None when nothing earns its parameters.
"""
from __future__ import annotations

from labrig.analysis.noise import Weights
# the baseline's helpers and the candidates' rule, under the names callers have used
from labrig.diagnosis.loop.baseline import (agreement_of, at_bounds, balanced_weights,  # noqa: F401
                                       linear_model)
from labrig.diagnosis.loop.candidates import candidate_names  # noqa: F401
# every threshold and rule of the decision (also under the names callers have used)
from labrig.diagnosis.evidence.criteria import (CV_CANDIDATES, FLOOR, MAX_REFINE, MIN_DBIC,  # noqa: F401
                                       MIN_GAIN, PARSIMONY, REFINE, SIMPLER_MARGIN, SWAP_GAIN)
from labrig.diagnosis.results.diagnosis import Diagnosis
from labrig.diagnosis.loop.round import Round, switched_off  # noqa: F401
from labrig.model.model import Model
from labrig.simulation.warm import ready


def diagnose(runs, model: Model | None = None, *, candidates=None, seed: int = 0,
             fixed: dict | None = None, progress=None, weights: Weights | None = None,
             folds=None, revise: bool = True, on_candidate=None,
             screen: bool = True, baseline_cv=None) -> Diagnosis:
    """Locate the model's error and rank the missing effects.

    Parameters
    ----------
    runs : list of Run
    model : Model, optional
        The current model; default: the linear model identified here (CO).
    candidates : list of str, optional
        Catalogue names to try (default: every effect the model lacks).
    seed : int
    fixed : dict, optional
        Parameters known from other measurements.
    progress : callable(i, name), optional
    weights : Weights, optional
        Channel weights (default: balanced on the starting model).
    folds : Folds, optional
        Cross-validation folds (default: :func:`labrig.diagnosis.evidence.crossval.make_folds`).
    revise : bool
        With a model that has effects, also test removing each of them and replacing
        each by its look-alikes and simpler family members (default True; the search of
        ``--auto`` revises on its own).
    on_candidate : callable(Candidate, float or None), optional
        Hears each candidate as its re-fit is done (``None``) and as its held-out error
        is (the cross-validated rmse/noise): the ranking as it forms.
    screen : bool
        End a candidate's re-fit early when it stalls without gaining
        (:func:`labrig.diagnosis.evidence.criteria.screen`; default True). False re-fits every
        candidate to the end: the full round, the same recommendation (tested), slower.
    baseline_cv : CrossValidation, optional
        ``model``'s cross-validation on these ``folds``, when known (the search hands on
        the one of the move it took): not computed again.

    Returns
    -------
    Diagnosis
    """
    ready()  # a first compile is announced and kept out of the timing
    rnd = Round.start(runs, model, seed=seed, fixed=fixed, weights=weights, folds=folds,
                      baseline_cv=baseline_cv)
    first = rnd
    for refined in range(MAX_REFINE + 1):
        ranking, diverged = rnd.candidates(candidates, progress, on_candidate, screen)
        # a candidate whose gain comes from re-fitting the rest of the model, not from its
        # effect, shows that the base was not converged: refine it and start again
        best = rnd.stale(ranking)
        if best is None or refined == MAX_REFINE:
            break
        rnd = rnd.refined(best)
    revisions = rnd.revisions() if revise and rnd.base.names and candidates is None else []
    return rnd.result(rnd.rank(ranking, revisions, on_candidate), diverged,
                      refined_from=first if rnd is not first else None)
