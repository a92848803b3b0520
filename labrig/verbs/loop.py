"""The missing-physics loop: diagnose, the search to the end, the experiment that
separates two explanations, and the decision once it is played."""
from __future__ import annotations

from labrig.core.defaults import SEED
from labrig.core.errors import UserError
from labrig.core.progress import Event, both, note
from labrig.verbs.data import model_of, read_runs


def diagnose(source, model=None, *, candidates=None, seed: int = SEED,
             fixed: dict | None = None, weights=None, through: str | None = "auto",
             progress=None, screen: bool = True):
    """Where the model fails and which catalogue effect is missing (``labrig diagnose``).

    Parameters
    ----------
    source : str, Path, Run, or a list of them
        The runs, as :func:`read_runs` reads them.
    model : Model, model file or Identification, optional
        The model to diagnose; default the linear model, fitted here.
    candidates : list of str, optional
        The catalogue effects to try; default every one the model can take.
    seed : int
        Default 0: the same runs give the same ranking. The loop's multi-starts are the
        default seed's design; another seed's random starts are kept only where they fit
        more than 1 % better, so near-equal minima are not the seed's choice.
    fixed : dict, optional
        Parameters held at a value (``{"R": 8.2}``), as ``--fix``.
    weights : Weights, optional
        Of position and speed (:func:`channel_weights`); default balanced on the model.
    through : {"auto", "loop", "input"} or None
        Closed-loop runs, as :func:`read_runs`'s.
    progress : callable(Event), optional
        Hears each candidate's re-fit start (kind ``candidate``), each re-fit done
        (``fitted``) and each held-out error known (``validated``): the ranking as it
        forms.
    screen : bool
        False re-fits every candidate to the end (``--full``); by default a re-fit that
        stalls without gaining is ended early (:func:`labrig.diagnosis.evidence.criteria.screen`).

    Returns
    -------
    Diagnosis
        The candidates ranked with their evidence (in-sample, held out, by regime) and
        the words for each; ``recommended_model()`` is the re-fitted model with the
        recommended effect, ``plot()`` the residuals by regime.

    Raises
    ------
    UserError
        An unknown candidate name or a source that cannot be read.
    FitDiverged
        Every candidate's re-fit diverged: start from a model nearer the data.

    Examples
    --------
    >>> import labrig as lr
    >>> diag = lr.diagnose("data/sweep_default")  # doctest: +SKIP
    >>> diag.recommendation  # doctest: +SKIP
    'coulomb_friction'
    """
    from labrig.diagnosis.loop.diagnose import diagnose as _diagnose
    from labrig.model.effects import get_effect

    for c in candidates or ():
        get_effect(c)  # an unknown name fails here, with the catalogue listed
    return _diagnose(read_runs(source, through=through), model_of(model), seed=seed,
                     fixed=fixed, candidates=list(candidates) if candidates else None,
                     weights=weights, screen=screen, progress=None if progress is None else (
                         lambda i, name: progress(Event("diagnose", "candidate", i, None,
                                                        f"re-fitting {name}", name))),
                     on_candidate=_candidates(progress, "diagnose"))


def _candidates(progress, verb):
    """``on_candidate(c, cv)`` reporting a candidate done as a ``fitted`` (``cv`` None)
    or ``validated`` event (None: nobody listens)."""
    if progress is None:
        return None

    def done(c, cv):
        if cv is None:
            progress(Event(verb, "fitted", None, None,
                           f"{c.label}: rmse/noise {c.rmse_over_noise:.2f}", c))
        else:
            progress(Event(verb, "validated", cv, None,
                           f"{c.label}: cross-validated {cv:.2f}", c))
    return done


def channel_weights(p: float = 1.0, q: float = 1.0):
    """The weights of position (``p``) and speed (``q``) in the loop's objective
    (``--weights p=..,q=..``)."""
    from labrig.analysis.noise import Weights

    return Weights(p=p, q=q)


def auto(source, model=None, *, max_rounds: int = 3, seed: int = SEED,
         fixed: dict | None = None, weights=None, through: str | None = "auto", log=None,
         on_step=None, progress=None, screen: bool = True):
    """The loop run to the end: add, pair, swap and remove effects while the
    cross-validated error falls (``labrig diagnose --auto``).

    Parameters
    ----------
    source : str, Path, Run, or a list of them
        The runs, as :func:`read_runs` reads them.
    model : Model, model file or Identification, optional
        Where the search starts; default the linear model, fitted here.
    max_rounds : int
        At most this many effects added (1 or more).
    seed, fixed, weights, through, screen
        As :func:`diagnose`'s.
    log : callable(str), optional
        Receives the rounds' summaries.
    on_step : callable(int, Model), optional
        Hears every rung as the search climbs the ladder (0: the start).
    progress : callable(Event), optional
        Hears both (kinds ``note`` and ``rung``, the rung's model as its data) and each
        round's candidates as :func:`diagnose`'s does (``fitted``, ``validated``).

    Returns
    -------
    AutoDiagnosis
        The final ``model``, its ``ladder``, the moves, the rounds' diagnoses and the
        confusable pairs (explanations the data leave about equal).

    Raises
    ------
    UserError
        ``max_rounds`` below 1, or a source that cannot be read.

    Examples
    --------
    >>> import labrig as lr
    >>> res = lr.auto("data/sweep_default")  # doctest: +SKIP
    >>> res.model.names  # doctest: +SKIP
    ['coulomb_friction']
    """
    from labrig.diagnosis.loop.auto import auto_diagnose

    if max_rounds < 1:
        raise UserError(f"max_rounds: {max_rounds} adds nothing; give 1 or more")
    return auto_diagnose(read_runs(source, through=through), model_of(model),
                         max_rounds=max_rounds, seed=seed, fixed=fixed, weights=weights,
                         log=both(log, note(progress, "auto")),
                         on_step=both(on_step, _rungs(progress, "auto")), screen=screen,
                         on_candidate=_candidates(progress, "auto"))


def _rungs(progress, verb):
    """``on_step(k, model)`` reporting each rung as a ``rung`` event (None: nobody listens)."""
    if progress is None:
        return None

    def rung(k, model):
        names = " + ".join(["linear"] + list(model.names))
        progress(Event(verb, "rung", k, None, f"rung {k}: {names}", model))
    return rung


def auto_ladder(source, *, max_steps: int = 3, output=None, seed: int = SEED,
                through: str | None = "auto", log=None, progress=None):
    """The search's ladder from the linear model (``labrig ladder`` without ``--models``);
    each rung's model saved as ``output/step<k>.json`` when ``output`` is given. Returns
    a :class:`~labrig.diagnosis.results.ladder.Ladder`."""
    from labrig.diagnosis.loop.search import auto_ladder as _ladder

    return _ladder(read_runs(source, through=through), max_steps=max_steps, outdir=output,
                   seed=seed, log=both(log, note(progress, "ladder")))


def propose(source, model, between: str | None = None, *, budget_s: float = 20.0,
            seed: int = SEED, rig=None, through: str | None = "auto", log=None,
            rig_amplitude: bool = True, loop: str = "open", progress=None):
    """The experiment that best tells two explanations apart (``labrig propose``).

    Parameters
    ----------
    source : str, Path, Run, or a list of them
        The runs so far, as :func:`read_runs` reads them.
    model : Model, model file or Identification
        The model holding one of the two explanations.
    between : str, optional
        ``"a,b"``: the two effects; default the model's effect and its usual
        look-alike.
    budget_s : float
        Rig seconds the experiment may take.
    seed : int
        Default 0: the same runs give the same plan.
    rig : str, Path or RigConfig, optional
        Its sensors bound the travel and, with ``rig_amplitude``, its output limits the
        input (else the data's largest input does).
    through : {"auto", "loop", "input"} or None
        Closed-loop runs, as :func:`read_runs`'s.
    log : callable(str), optional
        Receives what is tried.
    loop : {"open", "closed", "any"}
        Inputs to the amplifier, references of the rig's position loop (its gains from
        a closed-loop run of the data, else the rig file's), or whichever separates
        better.
    progress : callable(Event), optional
        Hears the notes ``log`` receives.

    Returns
    -------
    Proposal
        The plan (``to_toml()``), both explanations' predictions and the margin between
        them against the noise; ``plot()`` draws them.

    Raises
    ------
    UserError
        An unknown effect in ``between``, a ``loop`` not listed, a source that cannot be
        read.

    Examples
    --------
    >>> import labrig as lr
    >>> p = lr.propose("runs", "m1.json", "deadband,coulomb_friction")  # doctest: +SKIP
    >>> _ = open("plan.toml", "w").write(p.to_toml())  # doctest: +SKIP
    """
    from labrig.design.propose import propose as _propose

    rig, amax = _rig_limit(rig, rig_amplitude)
    return _propose(read_runs(source, through=through), model_of(model), between,
                    budget_s=budget_s, amax=amax, seed=seed, rig=rig, loop=loop,
                    log=both(log, note(progress, "propose")))


def ask_until_sure(source, model, between: str, play, *, budget_s: float = 20.0,
                   step_s: float = 5.0, seed: int = SEED, rig=None,
                   through: str | None = "auto", rig_amplitude: bool = True, log=None,
                   loop: str = "open", progress=None, on_step=None):
    """Ask the rig until sure: experiments of at most ``step_s`` seconds, each the best
    for the data so far, played one at a time and judged after each (the decision's fits
    and margin), until one explanation wins, the budget is spent, or two steps in a row
    show no difference (``labrig diagnose --auto --ask-rig --step-s S``).

    Parameters
    ----------
    source : folder, file, list of them, or runs
        The data so far.
    model : Model, model file or fit
        The model both explanations extend.
    between : str
        The two explanations, ``"a,b"`` (catalogue names).
    play : callable
        ``play(plan_toml, k) -> runs``: plays step ``k``'s plan on the rig and returns
        its runs (a folder, files or runs).
    budget_s, step_s : float
        The rig seconds to spend at most, and each step's longest experiment.
    seed : int
        The fits' seed (default 0).
    rig : RigConfig or rig file, optional
        The rig's limits (its output limit bounds the input with ``rig_amplitude``).
    through : str, optional
        How closed-loop runs are fitted, as :func:`read_runs`'s.
    rig_amplitude : bool
        Bound the input by the rig's limit (else by the data's largest input).
    log : callable, optional
        Told each step in words.
    loop : {"open", "closed", "any"}
        As :func:`propose`'s.
    progress : callable, optional
        The verbs' progress hook.
    on_step : callable, optional
        ``on_step(step, runs)`` hears each step as it is judged.

    Returns
    -------
    Asking
        ``.steps``, ``.sure``, ``.leader``, ``.rig_seconds`` and ``.one_shot_s`` (the
        one-shot plan's length).

    Examples
    --------
    >>> import labrig as lr
    >>> def play(plan_toml, k):  # the simulated rig plays each step into its own folder
    ...     open(f"step{k}.toml", "w").write(plan_toml)
    ...     return lr.sweep(f"asked/step{k}", plan=f"step{k}.toml")
    >>> a = lr.ask_until_sure("runs", "m1.json", "deadband,coulomb_friction", play)  # doctest: +SKIP
    >>> a.leader, a.rig_seconds <= 20.0  # doctest: +SKIP
    ('coulomb_friction', True)
    """
    from labrig.design.ask import ask_until_sure as _ask

    rig, amax = _rig_limit(rig, rig_amplitude)
    return _ask(read_runs(source, through=through), model_of(model), between, play,
                budget_s=budget_s, step_s=step_s, seed=seed, amax=amax, rig=rig, loop=loop,
                log=both(log, note(progress, "ask")), on_step=on_step)


def _rig_limit(rig, rig_amplitude: bool):
    """The rig (a file read, or as given) and the input limit it sets (None: the data's
    largest input)."""
    from labrig.io.config import RigConfig, load_rig

    if rig is None:
        return None, None
    rig = rig if isinstance(rig, RigConfig) else load_rig(rig)
    amax = (min(rig.bridge.output_limit_v, rig.amplifier.output_limit_v / rig.amplifier.gain)
            if rig_amplitude else None)
    return rig, amax


def proposed_as(name: str) -> str:
    """The effect a proposal tests in place of ``name`` (the symmetric form of an
    asymmetric one)."""
    from labrig.design.pairs import proposed_as as _as

    return _as(name)


def pair_from_diagnosis(model_path) -> str | None:
    """The first confusable pair of the ``diagnosis.json`` beside a model that ``diagnose
    --auto -o DIR`` wrote, as ``"a,b"``; None when there is none."""
    from labrig.design.pairs import pair_from_diagnosis as _pair

    return _pair(model_path)


def decide(source, model=None, *, seed: int = SEED, through: str | None = "auto", log=None,
           progress=None):
    """Both explanations of a proposal fitted with and without the proposed runs that were
    played (``labrig diagnose DIR DIR/new``).

    Parameters
    ----------
    source : str, Path, Run, or a list of them
        The runs, the played proposal's among them.
    model : Model, model file or Identification, optional
        The model the proposal was made from.
    seed : int
        Default 0.
    through : {"auto", "loop", "input"} or None
        Closed-loop runs, as :func:`read_runs`'s.
    log : callable(str), optional
        Receives what is fitted.
    progress : callable(Event), optional
        Hears the notes ``log`` receives.

    Returns
    -------
    Decision or None
        Which explanation the proposed runs favour, by how much against the noise, with
        and without them; None when the runs hold no proposed run.

    Raises
    ------
    UserError
        A run folder or model file that cannot be read; a proposed run whose pair the
        model's effects cannot be read from.
    FitDiverged
        Every start of a re-fit diverged (the message says what to try).

    Examples
    --------
    >>> import labrig as lr
    >>> lr.decide(["runs", "runs/new"], "m1.json").leader  # doctest: +SKIP
    'coulomb_friction'
    """
    from labrig.design.decide import decide as _decide

    return _decide(read_runs(source, through=through), model_of(model), seed=seed,
                   log=both(log, note(progress, "decide")))


def confusable_pairs(diagnosis, round_no: int = 1) -> list:
    """The candidates of a diagnosis (round ``round_no`` of a search) that fit about as
    well as the best, each paired with it: the pairs a proposal can separate."""
    from labrig.diagnosis.loop.auto import confusable_pairs as _pairs

    return _pairs(diagnosis, round_no)


def warm_up(load: bool = True) -> None:
    """Load the loop's modules and the simulator's kernels into this process now (from
    numba's cache, compiled into it first on a cold cache), so a first click or command
    waits for neither: a process's first simulation otherwise loads them, numba's own
    start included (a cold first comparison is many times a warm one). ``load=False``: the modules, and the cache compiled if it
    is cold, but the kernels left to load on first use (a process whose first job loads
    what the next ones need, and should not take a core from anything at its start)."""
    import labrig.diagnosis.loop.search  # noqa: F401
    from labrig.simulation.warm import ready, warm

    ready()   # a cold cache: said, and compiled
    if load:
        warm()   # every kernel loaded in this process (about 0.3 s from the cache)
