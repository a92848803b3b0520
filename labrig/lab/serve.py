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
from labrig.lab.station import Station

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

    if host not in ("127.0.0.1", "localhost", "::1"):
        log(f"labrig lab: warning: listening on {host}: anyone on the network who can reach "
            "this machine can drive the rig")
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
    if open_browser:
        import webbrowser

        server.io_loop.add_callback(lambda: webbrowser.open(url))
    try:
        server.start()
        server.io_loop.start()
    finally:
        station.close()
        server.stop()
