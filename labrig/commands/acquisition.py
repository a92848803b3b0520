"""``labrig sweep`` and ``labrig import``."""
from __future__ import annotations

import signal
from pathlib import Path

import labrig.verbs as lr
from labrig.commands.registry import command, float_opt, output_folder
from labrig.core.errors import Terminated, UserError
from labrig.commands.progress import Progress


@command("sweep", "acquire a sweep on the board (--port), the emulated board (--emulate) or the simulated rig (--sim)")
def cmd_sweep(args):
    """Acquire a sweep: one run per experiment of the plan, each written atomically as it
    finishes. Interrupting (Ctrl-C, SIGTERM, SIGHUP) stops the board at 0 V and keeps every
    finished run; --resume continues. Exit codes: 130 Ctrl-C, 143 SIGTERM, 129 SIGHUP."""

    output_folder(args.output)
    rig = lr.load_rig(args.rig)
    plan = lr.load_plan(args.plan, rig)
    board_id = lr.board_id(args.board_id) if args.board_id else None
    if not (args.sim or args.port or args.emulate):
        args.port = lr.find_board(board_id)   # several or none: it says which
    total = sum(e.n_samples for e in plan)
    with _StopSignals():
        # the emulated board (the real firmware the rig file names, in simavr) lives as
        # long as this sweep; the board at --port or the simulated rig need no closing
        make, _, close = lr.open_bridge(rig, port=args.port, emulate=args.emulate,
                                        seed=args.seed, board_id=board_id, baud=args.baud)
        try:
            bridge = make()
            if args.sim and args.realtime:
                bridge = lr.live(bridge, realtime=True)
            with Progress("sweep", total=total, unit="samples") as bar:
                written = lr.play(bridge, plan, rig, args.output, resume=args.resume,
                                  progress=bar.hook,
                                  on_done=lambda e, r: bar.log(f"wrote {Path(args.output) / e.name}.csv"))
        finally:
            close()
    print(f"{len(written)} run(s) written to {args.output}"
          + (f" ({len(plan) - len(written)} already there)" if args.resume else ""))
    return 0


def _configure_sweep(p):
    src = p.add_mutually_exclusive_group()
    src.add_argument("--port", help="serial device of the bridge, e.g. /dev/ttyACM0 (default: "
                                    "the one labrig board connected, see labrig ports)")
    src.add_argument("--sim", action="store_true", help="use the simulated rig")
    src.add_argument("--emulate", action="store_true",
                     help="play it on the real firmware under simavr (the one --rig's [bridge] "
                          "names), against a plant of the rig file's values")
    p.add_argument("--rig", help="rig file (TOML or mystery rig); default configs/rig_default.toml")
    p.add_argument("--plan", help="sweep plan (TOML); default: the rig family's, "
                   "configs/plan_default.toml (MS150) or configs/plan_arduino.toml (H-bridge)")
    p.add_argument("-o", "--output", required=True, help="output folder for the runs")
    p.add_argument("--resume", action="store_true", help="skip runs already complete in -o")
    p.add_argument("--seed", type=int, help="noise seed of the simulated rig (default: rig file)")
    p.add_argument("--realtime", action="store_true", help="pace the simulated rig to real time")
    p.add_argument("--baud", type=int, default=500000,
                   help="the serial speed the board's firmware was built for (make -C firmware "
                        "BAUD=...; default 500000)")
    p.add_argument("--board-id", metavar="ID",
                   help="this bench's board (its id, as labrig ports shows it): found on "
                        "whatever port it is, and any other board refused")


cmd_sweep.configure = _configure_sweep


class _StopSignals:
    """SIGTERM and SIGHUP end a sweep the way Ctrl-C does.

    The handler raises :class:`~labrig.core.errors.Terminated` wherever the sweep is, so
    ``acquire.sweep``'s ``finally`` sends STOP and ZERO and closes the port. Further
    SIGTERM/SIGHUP/SIGINT are ignored until that path has run (a second signal must not
    cut the board's stop short); a signal that lands while the sweep is already closing
    is raised once the sweep returns.
    """

    SIGNALS = (signal.SIGTERM, signal.SIGHUP)

    def __enter__(self):
        self.got = None
        self._old = {s: signal.getsignal(s) for s in (*self.SIGNALS, signal.SIGINT)}
        for s in self.SIGNALS:
            signal.signal(s, self._handler)
        return self

    def _handler(self, signum, frame):
        self.got = signum
        for s in self._old:
            signal.signal(s, signal.SIG_IGN)
        raise Terminated(signum, _KEPT)

    def __exit__(self, exc_type, exc, tb):
        for s, h in self._old.items():
            signal.signal(s, h)
        if self.got is not None and exc_type is None:
            raise Terminated(self.got, _KEPT)
        return False


_KEPT = "finished runs are kept, the output is at 0 V"


@command("import", "bring a scope/DAQ export, another lab's CSV or a MATLAB .mat file in as a run")
def cmd_import(args):
    """Import a foreign CSV or MATLAB .mat file as a labrig run. Map channels with --map
    TARGET=COLUMN (a .mat file's variables by name, a struct's fields as s.field, a
    matrix's column as m[k]): t, u and speed and/or pos in physical units, or raw volts
    tacho=/pos= with gains; current= and, in closed loop, ref=. Choose the plant with
    --drive and --axis."""

    if args.overwrite:   # the old spelling: still accepted, said once
        _warn_line("--overwrite is the old spelling of --force (every command replaces "
                   "files only with --force); it will go in a later release")
        args.force = True
    output_folder(args.output)
    path = lr.import_run(args.src, args.output, args.map, speed_unit=args.speed_unit,
                      pos_unit=args.pos_unit, time_unit=args.time_unit,
                      tacho_gain=args.tacho_gain, pos_gain=args.pos_gain,
                      pos_offset=args.pos_offset, gear_ratio=args.gear_ratio,
                      amplifier_gain=args.amplifier_gain, name=args.name,
                      waveform=args.waveform, loop=args.loop, overwrite=args.force,
                      rate_hz=args.rate,
                      position_gain=args.position_gain, velocity_gain=args.velocity_gain,
                      drive=args.drive, axis=args.axis, input_gain=args.input_gain,
                      controller=args.controller,
                      current_gain=args.current_gain, skip_rows=args.skip_rows,
                      speed_window=args.speed_window, input_step=args.input_step,
                      start=args.start, input_measured=args.input_measured, warn=_warn_line)
    print(f"wrote {path} and {path.with_suffix('.json').name}")
    return 0


def _warn_line(text: str) -> None:
    """An import's warning: one line on stderr, its parameters named as the options typed;
    the import goes on (exit 0)."""
    import sys

    from labrig.commands.options import translate

    print(f"labrig: warning: {translate(text)}", file=sys.stderr, flush=True)


def _configure_import(p):
    p.add_argument("src", help="the CSV or MATLAB .mat file to import")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--map", required=True,
                   help="TARGET=COLUMN,...: targets t, u, speed, pos, tacho, ref, current "
                        "(in closed loop: ref= the reference, u= the logged controller output)")
    p.add_argument("--drive", default="voltage", choices=["voltage", "torque", "force"],
                   help="what the input drives: voltage (an armature, default), torque "
                        "(a current-mode drive on a rotary axis) or force (on a linear axis)")
    p.add_argument("--axis", choices=["rotary", "linear"],
                   help="rotary (rad, rad/s) or linear (m, m/s); default from --drive or "
                        "the units")
    p.add_argument("--input-gain", type=float_opt, metavar="KD",
                   help="torque/force drive: N m (or N) per input volt")
    p.add_argument("--speed-unit", help="rad/s (default), rpm, deg/s; linear: m/s "
                                        "(default), mm/s")
    p.add_argument("--pos-unit", help="rad (default), deg, rev; linear: m (default), mm; "
                                      "counts:N for an encoder (N counts per revolution, or "
                                      "per metre on a linear axis)")
    p.add_argument("--time-unit", help="s, ms or us (default: the unit row under the "
                                       "header if it names one, else s)")
    p.add_argument("--rate", type=float_opt, metavar="HZ",
                   help="a log with no time column (no t= in --map): it was sampled at HZ "
                        "samples per second, sample k at k/HZ")
    p.add_argument("--tacho-gain", type=float_opt, help="V per rad/s, for tacho= in volts")
    p.add_argument("--pos-gain", type=float_opt, help="V per rad, for pos= in volts")
    p.add_argument("--pos-offset", type=float_opt, default=0.0, help="pot volts at 0 rad")
    p.add_argument("--current-gain", type=float_opt, default=1.0,
                   help="A per unit of the current= column (default 1: already in A)")
    p.add_argument("--speed-window", type=float_opt, metavar="S",
                   help="the speed column is the travel over the last S seconds over S (a "
                        "sketch's moving window of encoder counts): the window is modelled, "
                        "not fitted as physics")
    p.add_argument("--input-step", type=float_opt, metavar="V",
                   help="one step of the input in volts (a PWM's duty step, e.g. 12/255 for "
                        "8 bits at 12 V): an effect smaller than a step is not resolved")
    p.add_argument("--input-measured", action="store_true",
                   help="torque/force drive: the input column is a measured current "
                        "(times --input-gain, its torque or force constant), not a command: "
                        "no dead zone, rail or offset of an amplifier acts on it, and a "
                        "threshold in it is friction")
    p.add_argument("--start", choices=("auto", "rest", "moving"), default="auto",
                   help="how the run starts: rest (simulated from rest), moving (its speed "
                        "and position at the first sample fitted), auto (decided from its "
                        "first samples; default)")
    p.add_argument("--gear-ratio", type=float_opt, help="motor/output (default 1)")
    p.add_argument("--amplifier-gain", type=float_opt, default=1.0,
                   help="voltage drive: armature volts per input volt (default 1)")
    p.add_argument("--name", help="run name (default: the source file's stem, made safe "
                                  "and, over 100 characters, cut with a short hash)")
    p.add_argument("--skip-rows", type=int, metavar="N",
                   help="a CSV's header row comes after N lines (default: the first of the "
                        "first 100 lines that names every --map column)")
    p.add_argument("--waveform", default="custom",
                   choices=["square", "step", "staircase", "custom"],
                   help="what the input was (default custom)")
    p.add_argument("--loop", default="open", choices=["open", "closed"],
                   help="open (u drives the plant) or closed (a position loop: give "
                        "--controller, map ref= and, if logged, u= the controller output)")
    p.add_argument("--controller", metavar="KIND:GAINS",
                   help="closed loop's controller, e.g. pd:kp=2,kd=0.1 or "
                        "pid:kp=2,kd=0.1,ki=1[,limit=10]: drive = kp (ref - x) - kd x' "
                        "+ ki int(ref - x), in input volts per axis unit")
    p.add_argument("--position-gain", type=float_opt, metavar="KP",
                   help="MS150 analog loop: amplifier volts per volt of position error")
    p.add_argument("--velocity-gain", type=float_opt, metavar="KV",
                   help="MS150 analog loop: amplifier volts per volt of tacho feedback")
    p.add_argument("--force", action="store_true", help="replace an existing run")
    p.add_argument("--overwrite", action="store_true",
                   help="the old spelling of --force (still accepted; says so)")


cmd_import.configure = _configure_import
