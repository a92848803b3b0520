"""``labrig emulate``: the real firmware under simavr, its UART on a pseudo-terminal."""
from __future__ import annotations

import signal
import sys
import time

from labrig.commands.registry import command
import labrig.verbs as lr


@command("emulate", "run the real firmware under simavr and serve it on a pty")
def cmd_emulate(args):
    """Build (if needed) and run the compiled bridge firmware in simavr, with the ADC fed
    by a plant model of the rig. Prints the pty path as the first line of stdout, then
    serves until interrupted: `labrig sweep --port <pty> -o DIR` runs the whole lab on it."""

    emu = lr.emulator(lr.load_rig(args.rig), board=args.board, speed=args.speed)
    pty = emu.start()
    print(pty, flush=True)
    print(f"labrig emulate: {args.board} {emu.rig.bridge.firmware} firmware in simavr on {pty}; "
          "Ctrl-C to stop",
          file=sys.stderr, flush=True)
    signal.signal(signal.SIGTERM, lambda *a: (_ for _ in ()).throw(KeyboardInterrupt()))
    try:
        while emu.alive():
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        emu.stop()
    return 0


def _configure(p):
    p.add_argument("--board", default="uno", choices=["uno", "nano", "mega"],
                   help="the firmware's board: uno or nano (ATmega328P) or mega (ATmega2560) "
                        "(default uno)")
    p.add_argument("--rig", help="rig file: its [bridge] firmware (ms150 or hbridge, with its "
                                 "options) is built and played against a plant of its values "
                                 "(default configs/rig_default.toml)")
    p.add_argument("--speed", type=float, default=1.0,
                   help="1 = real time (default, timeouts as on the bench); 0 = as fast as possible")


cmd_emulate.configure = _configure
