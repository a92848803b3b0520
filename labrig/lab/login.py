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
"""
from __future__ import annotations

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

    def post(self):
        user = self.get_argument("username", "")[:64]
        password = self.get_argument("password", "")[:1024]
        try:   # (read at each login: a password set while the class runs counts at once)
            hashes = read_passwords(self.room.passwords)
        except LabrigError as exc:   # spoilt since the server started: no one logs in
            self.log(f"refused: a login for {user[:32]!r}: {str(exc).splitlines()[0]}")
            self.redirect("/login?error=The+class's+password+file+is+unreadable;+ask+your+"
                          "instructor.")
            return
        known = self.room.role(user) is not None
        if check_password(password, hashes.get(user)) and known:
            self.set_current_user(user)
            self.log(f"{user} logged in ({self.room.role(user)}) from {client(self)}")
            self.redirect("/")
            return
        shown = user if known else "an unknown name"
        self.log(f"refused: a wrong password for {shown} from {client(self)}")
        self.redirect("/login?error=Wrong+name+or+password.")

    def set_current_user(self, user):
        # a session cookie (gone with the browser); its age is checked on every request;
        # behind an HTTPS proxy it never travels over plain HTTP
        self.set_secure_cookie("user", user, expires_days=None, httponly=True,
                               samesite="Strict", secure=bool(self.room.server.behind_proxy))


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
        return ClassLoginHandler

    @property
    def logout_handler(self):
        return ClassLogoutHandler
