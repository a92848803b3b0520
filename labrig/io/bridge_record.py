"""What a run's sidecar says the bridge did to it, checked when the run is read: samples
lost on the link (gaps), an encoder that lost counts, a run the board ended on its own
(a trip). Each gives a run that is not, or not all, a measurement."""
from __future__ import annotations

from labrig.core.errors import RunFileError


#: a run of which more than this share was lost on the link is not data
MAX_GAP_SHARE = 0.5


def check_gaps(run):
    """Lost samples are interpolated to keep the time base; a run that is mostly
    interpolation has too little measurement left to stand for the experiment."""
    lost, n = run.n_gaps, len(run)
    if lost > MAX_GAP_SHARE * n:
        raise RunFileError(f"{run.path}: {lost} of {n} samples "
                           f"({100 * lost / n:.0f} %) were lost on the link (gap = 1); "
                           f"more than {MAX_GAP_SHARE:.0%} is not a measurement: record the "
                           "run again (check the cable, or lower the sample rate)")


def encoder_problems(meta: dict) -> list | None:
    """The sentences a run's ``bridge.encoder`` record gives against its counts (None: no
    record, or no problem); ``ValueError`` when the record is not what a sweep writes."""
    enc = (meta.get("bridge") or {}).get("encoder") or {}
    problems = enc.get("problems") if isinstance(enc, dict) else None
    if not isinstance(enc, dict) or not (problems is None or isinstance(problems, list)
                                         and all(isinstance(p, str) for p in problems)):
        raise ValueError("not an object whose 'problems' is a list of sentences")
    return problems or None


def check_encoder(run):
    """A run whose board said its encoder lost counts (``bridge.encoder.problems``, written
    by the sweep that played it) has positions off by the counts lost after the first: not
    a measurement of the shaft."""
    try:
        problems = encoder_problems(run.meta)
    except ValueError:
        raise RunFileError(f"{run.path.with_suffix('.json')}: key 'bridge.encoder' must be an "
                           "object whose 'problems' is a list of sentences, as a sweep writes "
                           "it; restore the sidecar the sweep wrote, or remove the key") from None
    if problems:
        raise RunFileError(f"{run.path}: its encoder lost counts while it played "
                           f"({problems[0]}; bridge.encoder in its sidecar): its positions are "
                           "not the shaft's; play the run again (check the encoder's wiring, "
                           "lower the speed or the decoding)")


def cut_at_trip(run):
    """A run the board ended on its own (``bridge.trip``: a limit passed, a reset) is the
    samples it took, up to the one that tripped: the rows after it, written as gaps to keep
    the planned length, were never measured and are dropped here."""
    trip = (run.meta.get("bridge") or {}).get("trip")
    if trip is None:
        return run
    k = trip.get("after_sample") if isinstance(trip, dict) else None
    if not isinstance(k, int) or isinstance(k, bool) or not 0 <= k < len(run.data):
        raise RunFileError(f"{run.path.with_suffix('.json')}: key 'bridge.trip' must be an object "
                           f"whose 'after_sample' is a sample of the run (0..{len(run.data) - 1}), "
                           "as a sweep writes it; restore the sidecar the sweep wrote")
    run.data = run.data.iloc[:k + 1].reset_index(drop=True)
    return run
