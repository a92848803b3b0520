"""Sweeps: run a plan on any bridge, save each run atomically as it finishes.

The same code drives the simulated rig and the serial bridge. On every exit path
(normal end, error, Ctrl-C) the bridge is stopped and zeroed; every run finished
before an interruption stays on disk, complete.
"""
from __future__ import annotations

import glob
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from labrig.bridge.base import Bridge
from labrig.io.experiment import Experiment
from labrig.core.errors import RigError, UserError, WriteError
from labrig.bridge.settings import board_law
from labrig.io.bridge_record import encoder_problems
from labrig.io.runs import Run, make_meta, run_exists, write_run


def acquire(bridge: Bridge, exp: Experiment, rig, progress: Callable[[int], None] | None = None,
            timeout: float = 5.0) -> Run:
    """Configure, start and stream one experiment; return it as a Run (not yet saved).

    The run always has the planned ``exp.n_samples`` rows. Samples lost on the link --
    inside the run or at its end -- are filled (interpolated inside, the last received
    value held at the end, the first one before the first received sample) and flagged
    with ``gap = 1``; the ``gap`` column exists only when something was lost.
    """
    if bridge.source == "serial":
        check_gains_applied(exp, rig)
    bridge.configure(exp)
    bridge.start()
    blocks = []
    got = 0
    n = int(exp.n_samples)
    while True:
        blk = bridge.read(timeout=timeout)
        if blk is None:
            break
        blocks.append(blk)
        if progress:
            progress(int(blk.index[-1]) + 1 - got)
        got = int(blk.index[-1]) + 1
        if got >= n:
            break
    bridge.stop()
    if progress and got < n:
        progress(n - got)   # a lost tail: the run is over all the same
    if not blocks:
        raise RigError(f"experiment '{exp.name}': the bridge returned no samples")
    idx = np.concatenate([b.index for b in blocks]).astype(np.int64)
    keep = idx < n   # a bridge never sends more, but a record never grows past the plan
    idx = idx[keep]
    raw = {"u": np.concatenate([b.u for b in blocks])[keep]}
    for ch in ("tacho", "pos", "ref", "current", "drive"):  # the channels this rig has
        if getattr(blocks[0], ch) is not None:
            raw[ch] = np.concatenate([getattr(b, ch) for b in blocks])[keep]
    full = np.arange(n)
    cols = {"t": full / exp.sample_rate_hz}
    # a dropped sample must not shift time nor shorten the run: fill it (np.interp holds
    # the end values beyond the first and last received sample) and flag it in the 'gap'
    # column, so the run stays uniform and nobody mistakes it for data
    complete = len(idx) == n
    for k, v in raw.items():
        cols[k] = v if complete else np.interp(full, idx, v)
    if not complete:
        gap = np.ones(n, dtype=np.int8)
        gap[idx] = 0
        cols["gap"] = gap
    experiment = exp.to_sidecar()
    controller = rig.controller_sidecar(exp)
    if controller is not None:
        # the board's own loop (played, or simulated as the board plays it): its law on its
        # count, for the model to run the same
        law = board_law(exp, rig, getattr(bridge, "hello", None)) \
            if bridge.source in ("serial", "sim") else None
        if law is not None:
            controller["sampled"] = law
        experiment["controller"] = controller
    meta = make_meta(sample_rate_hz=exp.sample_rate_hz, experiment=experiment,
                     sensors=rig.sensors_sidecar(), rig=rig.rig_sidecar(),
                     source=bridge.source, bridge={**bridge.counters(),
                                                   "dac_step_v": dac_step_v(rig)})
    return Run(name=exp.name, data=pd.DataFrame(cols), meta=meta)


def check_gains_applied(exp: Experiment, rig) -> None:
    """A closed-loop run on the MS150 board is closed by the board itself (``closed_by =
    "board"``: the plan's gains, applied by the board) or by the rig's patch panel: its
    gains must then be the ones the rig file says are patched.

    Raises
    ------
    UserError
        An analog loop whose rig file says nothing of its patch, or that asks for other
        gains than it says are patched.
    """
    from labrig.io.config import patched_gains

    if exp.loop != "closed" or rig.bridge.firmware != "ms150" or exp.closed_by == "board":
        return
    gains = patched_gains(rig)
    if gains is None:
        raise UserError(
            f"plan experiment '{exp.name}': a closed-loop run on the MS150 is closed by the "
            "rig's patch panel unless the board closes it, and the board does not apply a plan's "
            "gains to a loop it does not close: write closed_by = \"board\" in the plan, or the "
            "gains as patched in the rig file ([bridge] loop_kp and loop_kv; see "
            "docs/hardware.md, 'The MS150 loop, patched on the rig')")
    asked = (float(exp.position_gain), float(exp.velocity_gain))
    if max(abs(a - g) for a, g in zip(asked, gains)) > 1e-9:
        raise UserError(
            f"plan experiment '{exp.name}': asks Kp {asked[0]:g}, Kv {asked[1]:g}, but the rig's "
            f"loop is patched at Kp {gains[0]:g}, Kv {gains[1]:g} ([bridge] loop_kp, loop_kv): "
            "the board does not apply a plan's gains; re-patch and say so in the rig file, "
            "or play the experiment at the patched gains")


def the_rigs_way(plan: list[Experiment], rig, capabilities: int) -> list[Experiment]:
    """Who closes each closed loop whose plan leaves it open (``closed_by`` unset) on an
    MS150 board: the rig's patch panel where the rig file declares the patch (``[bridge]
    loop_kp, loop_kv``), else the board itself where its firmware closes loops (HELLO
    ``capabilities`` bit 5, firmware 2.4.0 on), with the plan's gains; otherwise they stay
    unset and :func:`check_plan` refuses them with its fix. A freshly flashed board thus
    plays the default plan's closed-loop steps as written; a sidecar records who closed
    each run.

    Parameters
    ----------
    plan : list of Experiment
    rig : RigConfig
    capabilities : int
        The board's HELLO capability bits.

    Returns
    -------
    list of Experiment
        The plan, each such loop's ``closed_by`` set.
    """
    from dataclasses import replace

    from labrig.bridge import protocol as P
    from labrig.io.config import patched_gains

    if rig.bridge.firmware != "ms150" or patched_gains(rig) is not None \
            or not capabilities & P.CAP_BOARD_LOOP:
        return list(plan)
    return [replace(e, closed_by="board") if e.loop == "closed" and e.closed_by is None else e
            for e in plan]


def dac_step_v(rig) -> float:
    """One step of the bridge's output (V): the smallest change of the input it can make,
    recorded with each run (``diagnose`` calls no threshold smaller than it resolved)."""
    lo, hi = rig.bridge.dac_range_v
    return abs(float(hi) - float(lo)) / 2 ** int(rig.bridge.dac_bits)


def check_plan(plan: list[Experiment], rig, *, board: bool = False) -> None:
    """Refuse a plan beyond the configured output limit, trips the sensors cannot show,
    or (on a ``board``) loop gains nothing would apply, before anything moves."""
    from labrig.bridge import trips

    for exp in plan:
        if board:
            check_gains_applied(exp, rig)
    # patched for the analog loop, or open (the bridge drives the amplifier: open-loop runs
    # and the loops the board closes itself)
    analog = {e.loop == "closed" and e.closed_by != "board" for e in plan}
    if board and rig.bridge.firmware == "ms150" and len(analog) > 1:
        raise UserError(
            "plan: it mixes runs through the rig's analog loop with runs where the bridge drives "
            "the amplifier (open loops, and loops the board closes itself), but on the MS150 "
            "the analog loop is closed by patching: play them as two plans and re-patch between "
            "them (both may write into the same folder), or write closed_by = \"board\"")

    from labrig.bridge.settings import (board_reference_words, bridge_settings, is_board_loop,
                                        sensor_gain_words, waveform_levels)

    s = bridge_settings(rig)
    for exp in plan:   # a loop the board closes: gains and references in its words
        if is_board_loop(exp, s):
            sensor_gain_words(exp, s)
            board_reference_words(exp, s, waveform_levels(exp))
    limit = rig.bridge.output_limit_v
    for exp in plan:
        if exp.peak_v() > limit + 1e-9:
            raise UserError(f"plan experiment '{exp.name}': peak {exp.peak_v():.3g} V exceeds "
                            f"the output limit {limit:g} V (rig bridge.output_limit_v)")
    trips.check(rig, plan)


def remove_stale_tmp(outdir: Path | str, names) -> list[Path]:
    """Remove the temporary files a killed atomic write left for the runs ``names``.

    ``runs.write_run`` writes ``.NAME.csv.*.tmp`` / ``.NAME.json.*.tmp`` next to the run and
    renames them into place; a SIGKILL in between leaves them behind. Only those of the
    plan's run names go: anything else in the folder is not ours to delete.

    Returns
    -------
    list of Path
        The files removed.
    """
    outdir = Path(outdir)
    gone = []
    if not outdir.is_dir():
        return gone
    for name in names:
        for ext in ("csv", "json"):
            for p in outdir.glob(f".{glob.escape(name)}.{ext}.*.tmp"):
                p.unlink(missing_ok=True)
                gone.append(p)
    return gone


def sweep(bridge: Bridge, plan: list[Experiment], rig, outdir: Path | str, *,
          resume: bool = False, on_start=None, on_progress=None, on_done=None) -> list[Path]:
    """Run every experiment of ``plan`` on ``bridge`` and write it to ``outdir``.

    With ``resume`` the runs already complete in ``outdir`` are skipped; without it
    an existing run is an error (nothing is overwritten silently). Temporary files a
    killed write left for the plan's runs are removed first (:func:`remove_stale_tmp`).
    """
    check_plan(plan, rig)
    outdir = Path(outdir)
    todo = []
    for exp in plan:
        if run_exists(outdir, exp.name):
            if resume:
                continue
            raise UserError(f"{outdir / exp.name}.json exists; use `resume` to continue this "
                            "sweep or choose an empty output folder")
        todo.append(exp)
    remove_stale_tmp(outdir, [exp.name for exp in plan])
    written: list[Path] = []
    lossy, slipped = [], []
    pending: BaseException | None = None
    try:
        bridge.open()
        if bridge.source == "serial":   # the board is there: what it cannot apply, refused now
            caps = int(getattr(bridge, "hello", {}).get("capabilities", 0))
            plan, todo = (the_rigs_way(p, rig, caps) for p in (plan, todo))
            check_plan(plan, rig, board=True)
        for exp in todo:
            if on_start:
                on_start(exp)
            run = acquire(bridge, exp, rig, progress=on_progress)
            written.append(write_run(run, outdir, overwrite=resume))
            trip = run.meta.get("bridge", {}).get("trip")
            if trip:   # the board stopped the rig: nothing more is played on it
                if on_done:
                    on_done(exp, run)
                raise TripError(exp.name, trip, outdir)
            lost = int(run.data["gap"].sum()) if "gap" in run.data else 0
            if lost > rig.bridge.max_lost_fraction * len(run):
                lossy.append((exp.name, lost, len(run)))
            problems = encoder_problems(run.meta)
            if problems:
                slipped.append((exp.name, problems))
            if on_done:
                on_done(exp, run)
    except BaseException as exc:   # (Ctrl-C too: it is the error the user must see)
        pending = exc
        raise
    finally:
        # every exit path: Ctrl-C, a rig fault, a full disk -- leave the output at 0 V
        if end_at_zero(bridge, pending) and isinstance(pending, WriteError):
            pending.add_note(f"the runs finished before it are kept in {outdir}; the "
                             "output is at 0 V")
    if lossy:
        raise LossError(lossy, rig.bridge.max_lost_fraction, outdir,
                        also=EncoderError(slipped, outdir) if slipped else None)
    if slipped:
        raise EncoderError(slipped, outdir)
    return written


def end_at_zero(bridge: Bridge, pending: BaseException | None = None) -> bool:
    """Stop ``bridge``, set its output to 0 V and release its link, whatever fails.

    The link is released even when stopping or zeroing raises (a bridge that breaks its
    never-raise contract must not keep the port held). A failure to zero is raised only
    when no other error is ``pending``: a trip or a Ctrl-C stays the error the user sees,
    and the zero's failure is added to it as a note. True when the output was zeroed."""
    zeroed = False
    try:
        try:
            bridge.stop()
        except Exception:   # a stop on a dead link: the zero below is what makes it safe
            pass
        bridge.zero()
        zeroed = True
    except Exception as exc:
        if pending is None:
            raise
        pending.add_note(f"and setting the output to 0 V afterwards failed too: {exc}")
    finally:
        try:
            bridge.close()
        except Exception as exc:
            if pending is None:
                raise
            pending.add_note(f"and releasing the link failed: {exc}")
    return zeroed


class TripError(RigError):
    """The board ended a run on its own (a trip on a limit of the rig file, or a reset):
    the run is written up to that sample (the rest are gaps, never fitted), and the sweep
    stops there with exit 1."""

    def __init__(self, name: str, trip: dict, outdir):
        why = {"TRIP": "the board tripped", "RESET": "the board restarted"}.get(
            trip.get("fault"), "the board stopped")
        text = str(trip.get("text"))
        check = ("someone pressed the E-stop, or its wire broke: close it" if text == "E-stop"
                 else "the motor went where [bridge] trip_speed or trip_position forbids"
                 if trip.get("fault") == "TRIP" else "its supply, its cable, its watchdog")
        super().__init__(
            f"run '{name}': {why} after sample {trip.get('after_sample')} ({text}); the run "
            f"is kept in {outdir} up to there and the sweep stopped. Check the rig before "
            f"going on ({check}), then continue with `resume`")


class LossError(RigError):
    """Runs that lost more of their samples on the link than the rig file allows: written
    (the lost samples flagged as gaps, never fitted as measured), and the command exits 1."""

    def __init__(self, lossy, tolerance: float, outdir, also: RigError | None = None):
        self.lossy = lossy
        worst = ", ".join(f"{name} {lost} of {n} ({100 * lost / n:.2g} %)"
                          for name, lost, n in lossy[:3]) + (" ..." if len(lossy) > 3 else "")
        super().__init__(
            f"{len(lossy)} run(s) in {outdir} lost more samples on the link than [bridge] "
            f"max_lost_fraction = {tolerance:g} allows: {worst}; they are written with the "
            "lost samples flagged as gaps (never fitted as measured): use a shorter or "
            "shielded USB cable, a lower sample rate, or `resume` after removing them"
            + (f"; and {also}" if also else ""))


class EncoderError(RigError):
    """Runs whose encoder counts cannot be trusted (edges the board could not decode, an
    index pulse off a whole turn, or no index where one is wired): written, with what the
    encoder said in their sidecar's ``bridge.encoder`` block, and the command exits 1."""

    def __init__(self, slipped, outdir):
        self.slipped = slipped
        name, problems = slipped[0]
        more = f" (and {len(slipped) - 1} more run(s))" if len(slipped) > 1 else ""
        super().__init__(
            f"run {name} in {outdir}: {problems[0]}{more}; the runs are written with the "
            "encoder's record in their sidecar (bridge.encoder), but a position after lost "
            "counts is not the shaft's (labrig will not read them): check the encoder's "
            "wiring and supply, lower the speed or the decoding (bridge.decoding), then remove them and play them again "
            "(`resume` keeps the others)")
