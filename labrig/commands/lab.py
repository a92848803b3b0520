"""``labrig lab``: the lab station in the browser."""
from __future__ import annotations

from pathlib import Path

from labrig.commands.registry import command
from labrig.core.errors import UserError


@command("lab", "the lab station in the browser: watch runs come in, close the loop, ask the rig")
def cmd_lab(args):
    """Serve the lab page: acquire on the simulated rig (default), the board (--port) or
    the emulated board (--emulate) and watch each run come in; fit the linear model, see
    where it fails, add, remove or replace effects and watch the error fall; ask the rig
    to decide between two explanations. Runs and models are the CLI's own files in DIR.
    Binds to 127.0.0.1 and nowhere else (no one logs in here: a room is served by
    ``labrig class serve``); Ctrl-C stops it and leaves the rig at 0 V."""
    from labrig.lab.serve import LOCAL, make_station, serve

    if args.host not in LOCAL:   # before a rig or an emulator is started
        raise UserError(f"--host: {args.host} is beyond this machine, and this page asks no "
                        "one to log in; serve the bench to a class instead (labrig class "
                        "serve CLASS.toml), where everyone logs in")

    if sum(map(bool, (args.sim, args.port, args.emulate))) > 1:
        raise UserError("give one of --sim, --port DEV or --emulate")
    if not 0 < args.http_port < 65536:
        raise UserError(f"--http-port: {args.http_port} is not a port (1-65535)")
    folder = Path(args.folder)
    if folder.exists() and not folder.is_dir():
        raise UserError(f"{folder}: not a folder; give a folder for the runs (it may be new)")
    folder.mkdir(parents=True, exist_ok=True)
    station = make_station(folder, rig_path=args.rig, port=args.port, emulate=args.emulate,
                           realtime=not args.fast)
    serve(station, host=args.host, port=args.http_port, open_browser=not args.no_browser)
    return 0


def _configure(p):
    p.add_argument("folder", nargs="?", default="lab_runs",
                   help="folder of runs: read from it, new sweeps written to it "
                        "(default lab_runs/)")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--sim", action="store_true", help="the simulated rig (the default)")
    src.add_argument("--port", help="serial device of the bridge, e.g. /dev/ttyACM0")
    src.add_argument("--emulate", action="store_true",
                     help="the real firmware in simavr (needs the AVR toolchain and simavr)")
    p.add_argument("--rig", help="rig file (TOML or mystery rig); default configs/rig_default.toml")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on: this machine only (127.0.0.1, the default, "
                        "localhost or ::1); for a room, where everyone logs in: labrig class "
                        "serve")
    p.add_argument("--http-port", type=int, default=5006, help="port of the page (default 5006)")
    p.add_argument("--no-browser", action="store_true", help="do not open a browser")
    p.add_argument("--fast", action="store_true",
                   help="simulated rig: as fast as it computes, not paced to real time")


cmd_lab.configure = _configure
