"""The missing-physics loop: diagnose, the search to the end, the experiment that
separates two explanations, and the decision once it is played."""
from __future__ import annotations

from labrig.core.defaults import SEED
from labrig.core.errors import UserError
from labrig.verbs.data import model_of, read_runs


def diagnose(source, model=None, *, candidates=None, seed: int = SEED,
             fixed: dict | None = None, through: str = "auto"):
    """Where the model fails and which catalogue effect is missing (``labrig diagnose``).

    ``model`` (a Model, a model file or an Identification) defaults to the linear model
    fitted here. Returns a :class:`~labrig.diagnosis.ranking.Diagnosis`; its
    ``recommendedmodel_of()`` is the re-fitted model with the recommended effect.
    """
    from labrig.diagnosis.diagnose import diagnose as _diagnose
    from labrig.model.effects import get_effect

    for c in candidates or ():
        get_effect(c)  # an unknown name fails here, with the catalogue listed
    return _diagnose(read_runs(source, through=through), model_of(model), seed=seed,
                     fixed=fixed, candidates=list(candidates) if candidates else None)


def auto(source, model=None, *, max_rounds: int = 3, seed: int = SEED,
         fixed: dict | None = None, through: str = "auto", log=None, on_step=None):
    """The loop run to the end: add, pair, swap and remove effects while the
    cross-validated error falls (``labrig diagnose --auto``). Returns an
    :class:`~labrig.diagnosis.auto.AutoDiagnosis` with the final model and its ladder;
    ``log(line)`` receives the rounds' summaries and ``on_step(k, model)`` every rung as
    the search climbs the ladder."""
    from labrig.diagnosis.auto import auto_diagnose

    if max_rounds < 1:
        raise UserError(f"max_rounds: {max_rounds} adds nothing; give 1 or more")
    return auto_diagnose(read_runs(source, through=through), model_of(model),
                         max_rounds=max_rounds, seed=seed, fixed=fixed, log=log,
                         on_step=on_step)


def propose(source, model, between: str | None = None, *, budget_s: float = 20.0,
            seed: int = SEED, rig=None, through: str = "auto"):
    """The experiment that best tells two explanations apart (``labrig propose``).

    ``between`` is ``"a,b"`` (default: the model's effect and its usual look-alike);
    ``rig`` a rig file or :class:`~labrig.io.config.RigConfig` whose limits bound the
    input. Returns a :class:`~labrig.diagnosis.proposal.Proposal`; ``to_toml()`` is the plan.
    """
    from labrig.io.config import RigConfig, load_rig
    from labrig.diagnosis.propose import propose as _propose

    amax = None
    if rig is not None:
        rig = rig if isinstance(rig, RigConfig) else load_rig(rig)
        amax = min(rig.bridge.output_limit_v, rig.amplifier.output_limit_v / rig.amplifier.gain)
    return _propose(read_runs(source, through=through), model_of(model), between,
                    budget_s=budget_s, amax=amax, seed=seed, rig=rig)


def decide(source, model=None, *, seed: int = SEED, through: str = "auto", log=None):
    """Both explanations of a proposal fitted with and without the proposed runs that were
    played (``labrig diagnose DIR DIR/new``): a :class:`~labrig.diagnosis.decide.Decision`,
    or None when the runs hold no proposed run."""
    from labrig.diagnosis.decide import decide as _decide

    return _decide(read_runs(source, through=through), model_of(model), seed=seed, log=log)


def confusable_pairs(diagnosis, round_no: int = 1) -> list:
    """The candidates of a diagnosis (round ``round_no`` of a search) that fit about as
    well as the best, each paired with it: the pairs a proposal can separate."""
    from labrig.diagnosis.auto import confusable_pairs as _pairs

    return _pairs(diagnosis, round_no)


def warm_up() -> None:
    """Load the loop's modules and compile the simulator's kernels now (numba's cache), so
    a first click or command waits for neither."""
    import labrig.diagnosis.search  # noqa: F401
    from labrig.model.warm import ready

    ready()
