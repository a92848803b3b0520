"""Serving the lab page with Panel's server (Bokeh/Tornado): one station, one page per
browser session, the first session owning the rig.

Safe by default: bound to 127.0.0.1; every script, style and font comes from this server
(Panel serves its own bundle; the page uses no template, icon set or web font that would
reach out); a closed page, a lost connection or Ctrl-C on the server stops the rig (STOP
and ZERO) and keeps the finished runs.
"""
from __future__ import annotations

import sys

import labrig.verbs as lr
from labrig.core.errors import UserError
from labrig.lab.station import Station

#: the addresses of this machine only: the one page without logins listens on no other
LOCAL = ("127.0.0.1", "localhost", "::1")

#: how often the server looks for sessions without a connection, and how long it keeps one
#: (a page reloaded or a connection back within this keeps its session and the rig)
CHECK_UNUSED_MS, UNUSED_LIFETIME_MS = 1000, 5000


def make_station(folder, *, rig_path=None, port=None, emulate=False, realtime=True) -> Station:
    """A station on the simulated rig (default), the board at ``port``, or the emulated
    board (the real firmware in simavr)."""
    rig = lr.load_rig(rig_path)
    make, name, close = lr.open_bridge(rig, port=port, emulate=emulate)
    station = Station(folder, rig, make, realtime=realtime and not port and not emulate,
                      rig_name=name)
    station.on_close.append(close)   # the emulator ends with the station
    return station


def serve(station: Station, *, host: str = "127.0.0.1", port: int = 5006,
          open_browser: bool = True, log=print) -> None:
    """Serve the lab page until Ctrl-C; the rig is left at 0 V on every way out."""
    import panel as pn

    from labrig.lab.page import REFRESH_MS, LabPage

    pn.extension(notifications=False)

    def page():
        doc = pn.state.curdoc
        sid = doc.session_context.id if doc and doc.session_context else "local"
        view = LabPage(station, sid)
        pn.state.add_periodic_callback(view.refresh, period=REFRESH_MS)
        pn.state.on_session_destroyed(lambda ctx: station.release(ctx.id))
        return view.view

    if host not in LOCAL:   # (the command refuses it first; a caller of serve() too)
        raise UserError(f"`host`: {host} is beyond this machine, and this page asks no one "
                        "to log in; serve the bench to a class instead (labrig class "
                        "serve CLASS.toml), where everyone logs in")
    origins = [f"{h}:{port}" for h in ("127.0.0.1", "localhost", host)]
    # a page closed or cut off loses its session (and the rig stops) within ~6 s, where
    # Bokeh's defaults (checked every 17 s, kept 15 s) left a rig running for ~35 s
    server = pn.serve({"/": page}, port=port, address=host, websocket_origin=origins,
                      show=False, start=False, title="labrig lab", verbose=False,
                      check_unused_sessions_milliseconds=CHECK_UNUSED_MS,
                      unused_session_lifetime_milliseconds=UNUSED_LIFETIME_MS)
    url = f"http://{'127.0.0.1' if host in ('0.0.0.0', '::') else host}:{port}/"
    log(f"labrig lab: {url} (Ctrl-C stops it; the rig is left at 0 V)")
    sys.stdout.flush()
    # the loop's modules imported now, in the background: a sweep started as the page
    # opens waited for them (its live view 0.76 s behind, not 0.5); the kernels load with
    # the first job (Station.submit), the worker warms its own
    import threading

    threading.Thread(target=lr.warm_up, kwargs={"load": False}, name="labrig-import",
                     daemon=True).start()
    run(server, url, open_browser, station.close)


def run(app, url: str, open_browser: bool, close) -> None:
    """Start the Panel server ``app`` and its IO loop until Ctrl-C (or the loop is
    stopped); ``close()`` then leaves the rigs at 0 V, before the server stops."""
    if open_browser:
        import webbrowser

        app.io_loop.add_callback(lambda: webbrowser.open(url))
    try:
        app.start()
        app.io_loop.start()
    finally:
        close()
        app.stop()


def class_app(server, *, log=None):
    """The class's Panel server, built but not started: ``(bokeh_server, url)``.

    Everyone logs in (:mod:`labrig.lab.login`); a student gets the seat page, an
    instructor the view of every bench; ``?watch=BENCH`` opens a bench read-only where
    the class allows watching (asked as the Watch button asks: refused and logged where
    it may not). Built on Panel's server: its auth provider hooks (the login handler
    checking scrypt hashes), Tornado's XSRF cookies, Bokeh's signed session ids,
    websocket connections only from the origins the page is served under, and its own
    TLS when the class file gives a certificate (else plain HTTP, for this machine or
    behind a reverse proxy). Built on the calling thread's IO loop.
    """
    import secrets
    import socket

    import panel as pn

    from labrig.lab.class_page import InstructorPage, StudentPage
    from labrig.lab.login import ClassAuth, user_of
    from labrig.lab.page import REFRESH_MS

    room, log = server.room, log or server.log
    cfg = room.server
    pn.extension(notifications=False)
    secret = secrets.token_urlsafe(48)   # a restart logs everyone out
    auth = ClassAuth(room, secret, log)

    def page():
        doc = pn.state.curdoc
        ctx = doc.session_context
        cookie = ctx.request.cookies.get("user") if ctx and ctx.request else None
        user = user_of(cookie, secret, auth.max_age_days)
        sid = ctx.id if ctx else "local"
        if user is None or room.role(user) is None:   # (the provider refused it already)
            return pn.pane.Markdown("Log in first: [log in](/login)")

        def alive():   # the login still young enough (a page outlives no login)
            return user_of(cookie, secret, auth.max_age_days) == user

        kind = InstructorPage if room.role(user) == "instructor" else StudentPage
        view = kind(server, user, sid, alive)
        watch = pn.state.session_args.get("watch")
        if watch:
            view.watch(watch[0].decode("utf-8", "replace")[:40])
        view.stop_refresh = pn.state.add_periodic_callback(view.refresh, period=REFRESH_MS).stop
        pn.state.on_session_destroyed(lambda _ctx: view.closed())
        return view.view

    host, port = cfg.host, cfg.port
    names = {"127.0.0.1", "localhost", host, socket.gethostname(), socket.getfqdn()}
    origins = sorted({f"{n}:{port}" for n in names if n not in ("0.0.0.0", "::")}
                     | set(cfg.origins))
    tls = {}
    if cfg.certfile:
        tls = {"ssl_certfile": str(room.resolve(cfg.certfile)),
               "ssl_keyfile": str(room.resolve(cfg.keyfile))}
    app = pn.serve({"/": page}, port=port, address=host, websocket_origin=origins,
                   show=False, start=False, title=room.name, verbose=False,
                   auth_provider=auth, cookie_secret=secret, xsrf_cookies=True,
                   sign_sessions=True, secret_key=secrets.token_urlsafe(48),
                   check_unused_sessions_milliseconds=CHECK_UNUSED_MS,
                   unused_session_lifetime_milliseconds=UNUSED_LIFETIME_MS,
                   use_xheaders=cfg.behind_proxy, **tls)
    shown = "127.0.0.1" if host in ("0.0.0.0", "::") else host
    return app, f"{'https' if tls else 'http'}://{shown}:{port}/"


def serve_class(server, *, open_browser: bool = False, log=None) -> None:
    """Serve a class (:class:`~labrig.lab.class_server.ClassServer`, :func:`class_app`)
    until Ctrl-C or SIGTERM; on the way out every bench is left at 0 V."""
    import signal

    log = log or server.log
    app, url = class_app(server, log=log)
    log(f"serving {server.room.name!r} on {url} ({len(server.benches)} benches; Ctrl-C stops "
        "it, every bench left at 0 V)")
    print(url, flush=True)
    server.start_timer()   # expiry off the pages' event loop
    # SIGTERM (a service manager's stop) ends the server as Ctrl-C does: benches at 0 V
    signal.signal(signal.SIGTERM, lambda *_: app.io_loop.add_callback_from_signal(
        app.io_loop.stop))
    run(app, url, open_browser, server.close)
