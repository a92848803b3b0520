"""``labrig emulate``: the real firmware under simavr, its UART on a pseudo-terminal;
``labrig wiring``: how to wire a rig's bridge, drawn; ``labrig ports`` and ``labrig flash``:
finding the board and putting the firmware on it."""
from __future__ import annotations

import signal
import sys
import time

from labrig.commands.registry import command, emit_json, refuse_existing
import labrig.verbs as lr


@command("emulate", "run the real firmware under simavr and serve it on a pty")
def cmd_emulate(args):
    """Build (if needed) and run the compiled bridge firmware in simavr, with the ADC fed
    by a plant model of the rig. Prints the pty path as the first line of stdout, then
    serves until interrupted: `labrig sweep --port <pty> -o DIR` runs the whole lab on it."""

    emu = lr.emulator(lr.load_rig(args.rig), board=args.board, speed=args.speed,
                      eeprom=args.eeprom)
    pty = emu.start()
    print(pty, flush=True)
    print(f"labrig emulate: {emu.board} {emu.rig.bridge.firmware} firmware in simavr on {pty}; "
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
    p.add_argument("--board", default=None, choices=["uno", "nano", "mega"],
                   help="the firmware's board: uno or nano (ATmega328P) or mega (ATmega2560) "
                        "(default: the rig file's bridge.board, else uno)")
    p.add_argument("--rig", help="rig file: its [bridge] firmware (ms150 or hbridge, with its "
                                 "options) is built and played against a plant of its values "
                                 "(default configs/rig_default.toml)")
    p.add_argument("--speed", type=float, default=1.0,
                   help="1 = real time (default, timeouts as on the bench); 0 = as fast as possible")
    p.add_argument("--eeprom", metavar="FILE",
                   help="keep the chip's EEPROM (the board's id) in FILE across runs, as a "
                        "board keeps it (default: erased at each start)")


cmd_emulate.configure = _configure


@command("wiring", "how to wire a rig's bridge: the table, the schematic and the parts")
def cmd_wiring(args):
    """Print the wiring table of the rig file's bridge on the board; with -o, write the
    schematic (SVG and PNG), the table and the bill of materials (CSV) into a folder."""

    w = lr.wiring(lr.load_rig(args.rig), board=args.board)
    names = ("schematic.svg", "schematic.png", "wiring.csv", "bom.csv")
    if args.output:
        from pathlib import Path

        refuse_existing([args.output] + [Path(args.output) / n for n in names],
                        force=args.force, what="folder")
    table, bom = w.to_pandas(), w.bom()
    if args.json:
        emit_json({"rig": w.rig_kind, "board": w.board, "options": w.options,
                   "wiring": table.to_dict("records"), "bom": bom.to_dict("records")})
    else:
        print(f"{w.rig_kind} bridge on the {w.board}:")
        print(table[["signal", "pin", "function", "to"]].to_string(index=False))
        print("\nparts:")
        print(bom.to_string(index=False))
    if args.output:
        for path in w.save(args.output).values():
            print(f"wrote {path}", file=sys.stderr)
    return 0


def _configure_wiring(p):
    p.add_argument("--rig", help="rig file: its [bridge] firmware (ms150 or hbridge) and "
                                 "options say what is wired (default configs/rig_default.toml)")
    p.add_argument("--board", default=None, choices=["uno", "nano", "mega"],
                   help="the Arduino (default: the rig file's bridge.board, else uno)")
    p.add_argument("-o", "--output", metavar="DIR",
                   help="write schematic.svg, schematic.png, wiring.csv and bom.csv here")
    p.add_argument("--force", action="store_true", help="replace those files in DIR")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")


cmd_wiring.configure = _configure_wiring


@command("ports", "list the serial ports and the labrig boards on them")
def cmd_ports(args):
    """List every serial port (device, USB VID:PID, description, serial number), greet the
    Arduino-class ones (opening such a port resets the board) and mark the labrig bridges
    (firmware, board, rig). --probe PATH greets a port no USB listing shows (an emulator's
    pty) or one labrig does not know."""
    ports = lr.ports(args.probe)
    if args.json:
        emit_json({"ports": [{"device": p.device, "usb_id": p.usb_id, "kind": p.kind,
                              "description": p.description, "serial_number": p.serial_number,
                              "labrig": ({**p.hello, "board_id": lr.format_board_id(p.hello.get("board_id"))}
                                         if p.hello else None),
                              "note": p.note} for p in ports]})
        return 0
    if not ports:
        print("no serial ports (plug the board in; on Linux it appears as /dev/ttyACM0 or "
              "/dev/ttyUSB0)")
    for p in ports:
        what = (f"labrig {p.hello.get('firmware')} (protocol {p.hello.get('protocol')}), "
                f"id {lr.format_board_id(p.hello.get('board_id'))}" if p.is_labrig else p.note)
        print(f"{p.device:<16} {p.usb_id:<10} {(p.kind or p.description or '-')[:34]:<34} "
              f"serial {p.serial_number or '-':<12} {what}")
    return 0


def _configure_ports(p):
    p.add_argument("--probe", action="append", default=[], metavar="PATH",
                   help="also greet this device (an emulator's pty, or a board behind an "
                        "adapter labrig does not know); repeat for more")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")


cmd_ports.configure = _configure_ports


@command("flash", "upload the bridge firmware to the board (avrdude) and greet it")
def cmd_flash(args):
    """Upload the labrig firmware for the board and the rig file's bridge through avrdude:
    built from firmware/ when the AVR toolchain is installed, else the image shipped in the
    package; then greet the board and check it runs what was written. The port defaults to
    the one Arduino-class USB port connected."""
    res = lr.flash(args.board, lr.load_rig(args.rig) if args.rig else None, port=args.port,
                   programmer=args.programmer,
                   build={"auto": None, "yes": True, "no": False}[args.build])
    print(f"{' '.join(res.command)}", file=sys.stderr)
    image = f"{res.image} ({'built from firmware/' if res.source == 'built' else 'packaged'})"
    if res.hello:
        print(f"flashed {image}; the board greets: {res.hello.get('firmware')} "
              f"(protocol {res.hello.get('protocol')})")
    else:
        print(f"flashed {image}")
    return 0


def _configure_flash(p):
    p.add_argument("--board", required=True, choices=["uno", "nano", "nano-old", "mega"],
                   help="the Arduino: uno, nano (new bootloader, 115200 baud), nano-old (the "
                        "old 57600-baud bootloader of many clones; built without the AVR "
                        "watchdog) or mega")
    p.add_argument("--rig", help="rig file whose [bridge] firmware is written (ms150 or "
                                 "hbridge with its options; default the MS150 bridge)")
    p.add_argument("--port", help="the board's serial device (default: the one Arduino-class "
                                  "USB port connected, see labrig ports)")
    p.add_argument("--programmer", metavar="NAME",
                   help="an avrdude programmer instead of the bootloader (e.g. usbasp)")
    p.add_argument("--build", choices=["auto", "yes", "no"], default="auto",
                   help="build the image from firmware/ (yes), take the packaged one (no), "
                        "or build when the AVR toolchain is installed (auto, default)")


cmd_flash.configure = _configure_flash


@command("doctor", "check the chain to the board: port, permissions, greeting, firmware, sensors")
def cmd_doctor(args):
    """Check the chain from this PC to the rig's sensors, a line per check: the port and
    its permissions, who holds it, the greeting and its baud rate, the firmware against
    this labrig, the board against the rig file, the board's id, 0 V out with every sensor
    at rest in its range, and the sample rate over 2 s at 0 V. Exit 0 when every check
    passes, 1 when one fails (it says what to do)."""
    report = lr.doctor(args.port, lr.load_rig(args.rig) if args.rig else None, baud=args.baud,
                       board_id=lr.board_id(args.board_id) if args.board_id else None)
    if args.json:
        emit_json(report.to_json())
    else:
        print(report)
    return 0 if report.ok else 1


def _configure_doctor(p):
    p.add_argument("--port", help="the board's serial device (default: the one labrig board "
                                  "connected, see labrig ports)")
    p.add_argument("--rig", help="the rig file the board should match (default "
                                 "configs/rig_default.toml)")
    p.add_argument("--baud", type=int, default=500000,
                   help="the serial speed the firmware was built for (make -C firmware "
                        "BAUD=...; default 500000)")
    p.add_argument("--board-id", metavar="ID", help="the board this bench is bound to")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")


cmd_doctor.configure = _configure_doctor
