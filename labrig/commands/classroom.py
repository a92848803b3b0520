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
    from the terminal, or one line on standard input). ``labrig class certs CLASS.toml``:
    the class's TLS certificates for bench PCs. ``labrig class bench NAME --scheduler
    tls://HOST:PORT``: on a bench PC, serve its board to the class server."""
    from labrig.classroom.roster import read_class

    if args.action == "bench":
        return _bench(args)
    room = read_class(args.class_file)
    if args.action == "passwd":
        return _passwd(room, args)
    if args.action == "certs":
        return _certs(room, args)
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


def _certs(room, args) -> int:
    import socket

    from labrig.classroom.certs import make_certs

    remote = [b.name for b in room.benches if b.rig == "remote"]
    hosts = args.host or sorted({"127.0.0.1", "localhost", socket.gethostname(),
                                 socket.getfqdn(), room.server.host} - {"0.0.0.0", "::"})
    folder = room.resolve(room.server.certs)
    make_certs(folder, remote, hosts, force=args.force)
    print(f"the class's certificates in {folder}: the authority (ca.pem; ca.key stays on "
          f"this PC), the server's for {', '.join(hosts)}"
          + (f", and one per bench PC ({', '.join(remote)}): copy ca.pem, NAME.pem and "
             "NAME.key to each" if remote else ""), file=sys.stderr)
    return 0


def _bench(args) -> int:
    import labrig.verbs as lr
    from labrig.classroom.certs import security
    from labrig.classroom.remote import serve_bench
    from labrig.classroom.roster import NAME_RE

    if not NAME_RE.fullmatch(args.name):
        raise UserError(f"{args.name!r}: not a bench name of the class file")
    if not args.scheduler.startswith("tls://"):
        raise UserError(f"--scheduler: {args.scheduler}; give the class server's "
                        "tls://HOST:PORT (the class's scheduler takes TLS only)")
    sec = security(args.certs, args.name)
    rig = lr.load_rig(args.rig)
    board_id = lr.board_id(args.board_id) if args.board_id else None
    if board_id is not None and not args.port and not args.emulate:
        args.port = lr.find_board(board_id)   # several or none: it says which
    make, name, close = lr.open_bridge(rig, port=args.port, emulate=args.emulate,
                                       board_id=board_id)
    print(f"labrig class bench: {args.name} is {name}", file=sys.stderr)
    serve_bench(args.scheduler, args.name, rig, make, close, sec,
                realtime=not args.port and not args.emulate, log=lambda line: print(f"labrig class bench: {line}", file=sys.stderr,
                                       flush=True))
    return 0


def _configure(p):
    sub = p.add_subparsers(dest="action", required=True,
                           metavar="{serve,passwd,certs,bench}")
    s = sub.add_parser("serve", help="serve the class's benches to the room (logins required)")
    s.add_argument("class_file", help="the class file (TOML): benches, people, server")
    s.add_argument("--no-browser", action="store_true", help="do not open a browser")
    s.add_argument("--fast", action="store_true",
                   help="simulated benches: as fast as they compute, not paced to real time")
    w = sub.add_parser("passwd", help="set a person's password (an scrypt hash)")
    w.add_argument("class_file", help="the class file (TOML)")
    w.add_argument("name", help="a name in the class file's [people]")
    w.add_argument("--force", action="store_true", help="replace a password already set")
    c = sub.add_parser("certs", help="make the class's TLS certificates (bench PCs)")
    c.add_argument("class_file", help="the class file (TOML)")
    c.add_argument("--host", action="append",
                   help="a name or address bench PCs reach the server by (repeat; default "
                        "this PC's names)")
    c.add_argument("--force", action="store_true", help="make them again")
    b = sub.add_parser("bench", help="on a bench PC: serve its board to the class server")
    b.add_argument("name", help="the bench's name in the class file")
    b.add_argument("--scheduler", required=True,
                   help="the class server's scheduler, tls://HOST:PORT")
    b.add_argument("--certs", default="certs",
                   help="folder with ca.pem, NAME.pem and NAME.key (default certs/)")
    b.add_argument("--rig", help="rig file (TOML or mystery rig); default configs/rig_default.toml")
    src = b.add_mutually_exclusive_group()
    src.add_argument("--sim", action="store_true", help="the simulated rig (the default)")
    src.add_argument("--port", help="serial device of the bench's board, e.g. /dev/ttyACM0")
    src.add_argument("--emulate", action="store_true", help="the real firmware in simavr")
    b.add_argument("--board-id", metavar="ID",
                   help="the bench's board (its id, as labrig ports shows it): found on "
                        "whatever port it is, and any other board refused")


cmd_class.configure = _configure
