"""Logins for a class server: Panel's auth provider and login handler, checking scrypt
hashes.

Panel's own basic auth compares passwords in clear; this provider keeps its login flow
(Tornado's signed ``user`` cookie, the login and logout pages, Bokeh refusing a page or
websocket without a user) and checks the password against the class's scrypt hash. A
login lasts the class file's ``session_hours``: the cookie's signature carries its time,
and an older one is refused on every request and websocket (the page that holds it ends
itself, :mod:`labrig.lab.class_page`). The login form carries Tornado's XSRF token; the
server runs with XSRF cookies on. Every refusal is one line in the server's log; a
password is never logged.

A password is hashed off the event loop (scrypt costs ~35 ms and 16 MiB; on the loop, 30
students logging in at once froze every page for a second and a script posting logins
froze it at will), at most :data:`HASHING_AT_ONCE` at a time, and failed logins are
throttled (:class:`Throttle`): past :data:`FAILED_PER_NAME` for one name or
:data:`FAILED_PER_ADDRESS` from one address within :data:`WINDOW_S`, a login is refused
unheard (nothing hashed) until the window has moved on, each refusal one line in the log.
"""
from __future__ import annotations

import asyncio
import collections
import time
from concurrent.futures import ThreadPoolExecutor
from html import escape

from panel.auth import BasicAuthProvider, BasicLoginHandler, LogoutHandler
from panel.io.state import state
from tornado.web import decode_signed_value
from tornado.websocket import WebSocketHandler

from labrig.classroom.passwords import check_password, read_passwords
from labrig.core.errors import LabrigError

_PAGE = """<!DOCTYPE html><html><head><meta charset="utf-8"><title>labrig class: {title}</title>
<style>body{{font-family:sans-serif;max-width:26em;margin:4em auto;color:#222}}
input{{display:block;width:100%;margin:.3em 0 1em;padding:.4em;font-size:1em}}
button{{padding:.5em 1.5em;font-size:1em}} .error{{color:#b00020}}</style></head>
<body><h2>labrig class: {title}</h2>{body}</body></html>"""

_FORM = """<p>{cls}</p><p class="error">{error}</p>
<form action="/login" method="post">{xsrf}
<label>name<input name="username" autocomplete="username" autofocus></label>
<label>password<input name="password" type="password" autocomplete="current-password"></label>
<button type="submit">Log in</button></form>"""


#: failed logins allowed for one name, and from one address (a room behind one NAT
#: address shares it: students' typos), within WINDOW_S seconds
FAILED_PER_NAME, FAILED_PER_ADDRESS, WINDOW_S = 5, 20, 60.0
#: passwords hashed at once, in threads off the event loop (scrypt releases the GIL)
HASHING_AT_ONCE = 2


class Throttle:
    """Failed logins per name and per address over the last ``window_s`` seconds.

    A name is counted only when the class has it (an unknown name is never written down);
    an attempt counts as failed from the moment it is heard until it succeeds, and a login
    that succeeds forgets its name's failures. Throttling a name lets whoever
    guesses at it keep its owner out for a window: the price of making guessing slow,
    said in the log line the owner's instructor reads.
    """

    def __init__(self, per_name: int = FAILED_PER_NAME, per_address: int = FAILED_PER_ADDRESS,
                 window_s: float = WINDOW_S, clock=time.monotonic):
        self.limits = {"name": per_name, "address": per_address}
        self.window_s, self.clock = window_s, clock
        self._failed: dict = collections.defaultdict(collections.deque)

    def _keys(self, name, address):
        return [("name", name)] * (name is not None) + [("address", address)]

    def _recent(self, key) -> int:
        times, old = self._failed[key], self.clock() - self.window_s
        while times and times[0] < old:
            times.popleft()
        if not times:
            del self._failed[key]   # (forgotten: a flood of addresses does not pile up)
            return 0
        return len(times)

    def refusal(self, name: str | None, address: str) -> str:
        """Why a login for ``name`` (None: a name the class does not have) from ``address``
        is refused unheard, or '' when it may be checked."""
        for kind, value in self._keys(name, address):
            if self._recent((kind, value)) >= self.limits[kind]:
                who = f"for {value}" if kind == "name" else f"from {value}"
                return (f"too many failed logins {who} ({self.limits[kind]} in "
                        f"{self.window_s:.0f} s)")
        return ""

    def failed(self, name: str | None, address: str) -> None:
        for key in self._keys(name, address):
            self._failed[key].append(self.clock())

    def succeeded(self, name: str, address: str) -> None:
        """A login that passed: its name's failures forgotten, and its own attempt
        (counted as failed while it was checked) taken back from its address."""
        self._failed.pop(("name", name), None)
        times = self._failed.get(("address", address))
        if times:
            times.pop()


def client(handler) -> str:
    """Who asked, for the log: the client's address."""
    return handler.request.remote_ip or "?"


def user_of(cookie: str | None, secret: str, max_age_days: float) -> str | None:
    """The user a signed ``user`` cookie names, or None when it is forged or too old."""
    if not cookie:
        return None
    value = decode_signed_value(secret, "user", cookie, max_age_days=max_age_days)
    return None if value is None else value.decode("utf-8")


class ClassLoginHandler(BasicLoginHandler):
    """The login page and its form: the name and password checked against the scrypt
    hash (set by :class:`ClassAuth`)."""

    room = None
    log = None
    throttle = None
    hashing = None

    def get(self):
        error = self.get_argument("error", "")
        self.write(_PAGE.format(title="log in", body=_FORM.format(
            cls=escape(self.room.name), error=escape(error[:100]),
            xsrf=self.xsrf_form_html())))

    def check_xsrf_cookie(self):
        try:
            super().check_xsrf_cookie()
        except Exception:
            self.log(f"refused: a login form without a valid XSRF token from {client(self)}")
            raise

    async def post(self):
        user = self.get_argument("username", "")[:64]
        password = self.get_argument("password", "")[:1024]
        address = client(self)
        try:   # (read at each login: a password set while the class runs counts at once)
            hashes = read_passwords(self.room.passwords)
        except LabrigError as exc:   # spoilt since the server started: no one logs in
            self.log(f"refused: a login for {user[:32]!r}: {str(exc).splitlines()[0]}")
            self.redirect("/login?error=The+class's+password+file+is+unreadable;+ask+your+"
                          "instructor.")
            return
        known = self.room.role(user) is not None
        name = user if known else None
        why = self.throttle.refusal(name, address)
        if why:
            self.log(f"refused: a login for {user if known else 'an unknown name'} from "
                     f"{address}: {why}")
            self.redirect("/login?error=Too+many+failed+logins:+wait+a+minute,+or+ask+your+"
                          "instructor.")
            return
        # counted as failed until it succeeds: logins posted at once are each checked
        # against those before them, not all against the count before any was hashed
        self.throttle.failed(name, address)
        ok = await asyncio.get_running_loop().run_in_executor(
            self.hashing, check_password, password, hashes.get(user))
        if ok and known:
            self.throttle.succeeded(user, address)
            self.set_current_user(user)
            self.log(f"{user} logged in ({self.room.role(user)}) from {address}")
            self.redirect("/")
            return
        shown = user if known else "an unknown name"
        self.log(f"refused: a wrong password for {shown} from {address}")
        self.redirect("/login?error=Wrong+name+or+password.")

    def set_current_user(self, user):
        # a session cookie (gone with the browser); its age is checked on every request;
        # served over TLS, by the server or an HTTPS proxy, it never travels over plain HTTP
        cfg = self.room.server
        self.set_secure_cookie("user", user, expires_days=None, httponly=True,
                               samesite="Strict", secure=bool(cfg.behind_proxy or cfg.certfile))


class ClassLogoutHandler(LogoutHandler):
    log = None

    def get(self):
        self.clear_cookie("user")
        self.write(_PAGE.format(title="logged out",
                                body='<p>You are logged out. <a href="/login">Log in</a></p>'))


class ClassAuth(BasicAuthProvider):
    """Panel's basic auth provider with the class's people, scrypt hashes and expiry.

    Parameters
    ----------
    room : ClassRoom
    secret : str
        The cookie secret (the server's; a fresh one each start logs everyone out).
    log : callable
        One line per refusal and login.
    """

    def __init__(self, room, secret: str, log):
        self.room, self.secret, self.log = room, secret, log
        self.throttle = Throttle()
        self.hashing = ThreadPoolExecutor(HASHING_AT_ONCE, thread_name_prefix="labrig-login")
        self.max_age_days = room.server.session_hours / 24
        super().__init__(login_endpoint="/login", logout_endpoint="/logout")

    @property
    def get_user(self):
        def get_user(handler):
            cookie = handler.get_cookie("user")
            user = user_of(cookie, self.secret, self.max_age_days)
            if user is not None and self.room.role(user) is None:
                user = None
            if user is None and cookie:
                self.log(f"refused: an expired or invalid login from {client(handler)} "
                         f"({handler.request.path})")
            if user and isinstance(handler, WebSocketHandler):
                state._active_users[user] += 1   # as Panel's own provider counts them
            return user
        return get_user

    @property
    def login_handler(self):
        ClassLoginHandler.room, ClassLoginHandler.log = self.room, staticmethod(self.log)
        ClassLoginHandler.throttle, ClassLoginHandler.hashing = self.throttle, self.hashing
        return ClassLoginHandler

    @property
    def logout_handler(self):
        return ClassLogoutHandler
