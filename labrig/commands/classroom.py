"""``labrig class``: a class on one server (serve it; set its passwords)."""
from __future__ import annotations

import getpass
import sys

from labrig.commands.registry import command
from labrig.core.errors import UserError


@command("class", "a class on one server: benches, seats, logins, the instructor's view")
def cmd_class(args):
    """``labrig class serve CLASS.toml``: serve the class file's benches to the room;
    everyone logs in; a student takes a bench and drives it, the instructor sees every
    bench live, stops any, grades the class. ``labrig class passwd CLASS.toml NAME``:
    set a person's password (stored as an scrypt hash in the class's password file; read
    from the terminal, or one line on standard input)."""
    from labrig.classroom.roster import read_class

    room = read_class(args.class_file)
    if args.action == "passwd":
        return _passwd(room, args)
    from labrig.lab.class_server import ClassServer
    from labrig.lab.serve import LOCAL, serve_class
    from labrig.classroom.passwords import read_passwords

    hashes = read_passwords(room.passwords)
    missing = [p for p in (*room.instructors, *room.students) if p not in hashes]
    if len(missing) == len(room.instructors) + len(room.students):
        raise UserError(f"{room.passwords}: no one has a password yet; set them with "
                        f"labrig class passwd {args.class_file} NAME")
    if missing:
        print(f"labrig class: {len(missing)} of the class have no password yet and cannot "
              f"log in: {', '.join(missing[:10])}", file=sys.stderr)
    if room.server.host not in LOCAL and room.server.certfile is None:
        print(f"labrig class: listening on {room.server.host} over plain HTTP: passwords "
              "cross the network readable; give [server] certfile and keyfile, or put it "
              "behind a reverse proxy with HTTPS (docs/instructor/README.md)", file=sys.stderr)
    server = ClassServer(room, realtime=not args.fast)
    serve_class(server, open_browser=not args.no_browser)
    return 0


def _passwd(room, args) -> int:
    from labrig.classroom.passwords import set_password

    if room.role(args.name) is None:
        raise UserError(f"{room.path}: {args.name} is not in [people]; add them to students "
                        "or instructors first")
    if sys.stdin.isatty():
        password = getpass.getpass(f"password for {args.name}: ")
        if getpass.getpass("again: ") != password:
            raise UserError("the two passwords differ; nothing was changed")
    else:
        password = sys.stdin.readline().rstrip("\r\n")
        if not password:
            raise UserError("no password on standard input; type it at a terminal, or give "
                            "it as one line on standard input")
    path = set_password(room.passwords, args.name, password, force=args.force)
    print(f"{args.name}'s password set (scrypt hash) in {path}", file=sys.stderr)
    return 0


def _configure(p):
    sub = p.add_subparsers(dest="action", required=True, metavar="{serve,passwd}")
    s = sub.add_parser("serve", help="serve the class's benches to the room (logins required)")
    s.add_argument("class_file", help="the class file (TOML): benches, people, server")
    s.add_argument("--no-browser", action="store_true", help="do not open a browser")
    s.add_argument("--fast", action="store_true",
                   help="simulated benches: as fast as they compute, not paced to real time")
    w = sub.add_parser("passwd", help="set a person's password (an scrypt hash)")
    w.add_argument("class_file", help="the class file (TOML)")
    w.add_argument("name", help="a name in the class file's [people]")
    w.add_argument("--force", action="store_true", help="replace a password already set")


cmd_class.configure = _configure
