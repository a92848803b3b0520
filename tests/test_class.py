"""A class on one server, without a browser: the class file, the passwords, the seats,
the bookings' ends on a real (simulated) rig, and the server's trust boundary tried over
HTTP and the websocket as a stranger would (tests/test_class_browser.py drives it with
logged-in Chromium pages)."""
from __future__ import annotations

import asyncio
import gc
import json
import re
import time
from pathlib import Path

import pytest
import requests

from class_room import PASSWORDS, ClassProc, write_class
from conftest import labrig


# -- the class file --------------------------------------------------------------------

@pytest.mark.parametrize("body, words", [
    ('[[bench]]\nname = "b1"\n[people]\ninstructors = ["kim"]\nstudents = ["../x"]\n',
     "key 'people.students"),
    ('[[bench]]\nname = "b1"\n[people]\ninstructors = ["kim"]\nstudents = ["kim"]\n',
     "both a student and an instructor"),
    ('[[bench]]\nname = "b1"\nrig = "board"\n[people]\ninstructors = ["kim"]\n',
     "needs its port"),
    ('[[bench]]\nname = "b1"\n[[bench]]\nname = "b1"\n[people]\ninstructors = ["kim"]\n',
     "listed twice"),
    ('[[bench]]\nname = "b1"\n[people]\ninstructors = ["kim"]\n[server]\ncertfile = "c.pem"\n',
     "certfile and keyfile together"),
    ('[[bench]]\nname = "b1"\n[people]\ninstructors = ["kim"]\n[clas]\nname = "x"\n',
     "clas"),
    ('[[bench]]\nname = "b1"\n[people]\ninstructors = []\n', "people.instructors"),
    ('[[bench]]\nname = "b1"\n[people]\ninstructors = ["kim"]\n[server]\nhost = "0.0.0.0"\n'
     'behind_proxy = true\n', "forge the address it forwards"),
    ('[[bench]]\nname = "b1"\n[people]\ninstructors = ["kim"]\n[server]\ncertfile = "c.pem"\n'
     'keyfile = "c.key"\nbehind_proxy = true\n', "the proxy holds the TLS"),
])
def test_a_bad_class_file_is_one_line_naming_the_key(tmp_path, body, words):
    f = tmp_path / "class.toml"
    f.write_text(body)
    for action in (("serve", f), ("passwd", f, "kim")):
        p = labrig("class", *action, input="a-password-9\n", timeout=60)
        assert p.returncode == 2, p.stderr
        lines = p.stderr.strip().splitlines()
        assert len(lines) == 1 and "Traceback" not in p.stderr, p.stderr
        assert str(f) in lines[0] and words in lines[0], lines[0]


def test_a_student_folder_cannot_leave_the_class_folder(tmp_path):
    from labrig.classroom.roster import read_class

    room = read_class(write_class(tmp_path))
    assert room.seat_folder("ana", "bench1") == tmp_path / "class_runs" / "ana" / "bench1"
    for bad in ("..", "../ana", "/etc", "Ana", "a b", ""):
        with pytest.raises(ValueError):
            room.seat_folder(bad, "bench1")
        with pytest.raises(ValueError):
            room.seat_folder("ana", bad)


# -- passwords -------------------------------------------------------------------------

def test_passwords_are_stored_as_scrypt_hashes_only_their_owner_reads(tmp_path):
    f = write_class(tmp_path)
    pw_file = tmp_path / "class_passwords.json"
    text = pw_file.read_text()
    assert all(pw not in text for pw in PASSWORDS.values())
    hashes = json.loads(text)
    assert sorted(hashes) == ["ana", "ben", "kim"]
    assert all(h.startswith("scrypt$16384$8$1$") for h in hashes.values())
    assert pw_file.stat().st_mode & 0o077 == 0
    from labrig.classroom.passwords import check_password

    assert check_password("ana-secret-1", hashes["ana"])
    assert not check_password("ana-secret-2", hashes["ana"])
    assert not check_password("ana-secret-1", hashes["ben"])
    assert not check_password("ana-secret-1", None)
    # the tool: from standard input; a second time only with --force; a short one refused
    p = labrig("class", "passwd", f, "ana", input="a-new-password\n")
    assert p.returncode == 2 and "--force" in p.stderr and "a-new-password" not in p.stderr
    p = labrig("class", "passwd", f, "ana", "--force", input="a-new-password\n", check=0)
    assert "a-new-password" not in p.stderr + p.stdout
    assert check_password("a-new-password", json.loads(pw_file.read_text())["ana"])
    p = labrig("class", "passwd", f, "ben", "--force", input="short\n")
    assert p.returncode == 2 and "at least 8" in p.stderr
    p = labrig("class", "passwd", f, "zed", input="long-enough-1\n")
    assert p.returncode == 2 and "zed is not in [people]" in p.stderr


# -- seats and bookings ----------------------------------------------------------------

def test_one_bench_per_student_one_student_per_bench():
    from labrig.classroom.seats import Seats, SeatTaken

    t = [1000.0]
    seats = Seats(["b1", "b2"], minutes=10, clock=lambda: t[0])
    assert seats.take("ana").bench == "b1"
    assert seats.take("ana").bench == "b1"          # taking again keeps the booking
    with pytest.raises(SeatTaken, match="b1 is taken"):
        seats.take("ben", "b1")
    with pytest.raises(SeatTaken, match="you hold b1"):
        seats.take("ana", "b2")
    assert seats.take("ben").bench == "b2"
    with pytest.raises(SeatTaken, match="every bench is taken"):
        seats.take("cem")
    t[0] += 599
    assert seats.expired() == []
    t[0] += 1
    assert sorted(b.student for b in seats.expired()) == ["ana", "ben"]
    assert seats.free() == ["b1", "b2"]


def _plan(folder: Path, rig, amplitudes="0.8, 1.0, 1.2"):
    import labrig.verbs as lr

    f = folder / "plan.toml"
    f.write_text('[[experiment]]\nwaveform = "square"\n'
                 f"amplitudes_v = [{amplitudes}]\nfrequency_hz = 0.5\nperiods = 1\n"
                 "sample_rate_hz = 500\nlead_in_s = 0.5\n")
    return lr.load_plan(f, rig)


def _wait(cond, timeout, what):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if cond():
            return
        time.sleep(0.05)
    raise AssertionError(f"waited {timeout} s for {what}")


def test_a_booking_that_ends_mid_run_stops_the_rig_and_keeps_the_finished_runs(tmp_path):
    """The booking's time runs out during the second run (the simulated rig paced to real
    time): the sweep stops as Ctrl-C stops it (STOP, ZERO: the output at 0 V), the first
    run is on disk whole, the second is not written, the bench is free again; the
    instructor's Stop does the same without ending the booking."""
    from labrig.classroom.roster import read_class
    from labrig.io.runs import read_run
    from labrig.lab.class_server import ClassServer

    t = [0.0]
    lines = []
    srv = ClassServer(read_class(write_class(tmp_path)), realtime=True, log=lines.append,
                      clock=lambda: t[0])
    try:
        st = srv.take("ana")
        assert st.folder == tmp_path / "class_runs" / "ana" / "bench1"
        st.start_sweep(_plan(tmp_path, st.rig))
        _wait(lambda: len(st.written) == 1 and st.live.samples > 100, 30, "the second run")
        t[0] = srv.room.booking_minutes * 60          # the booking's time is up
        srv.start_timer(0.05)   # (as served: the expiry in the timer's thread, off the loop)
        _wait(lambda: "the booking's time ended" in srv.benches["bench1"].note, 30,
              "the timer's expiry")
        assert not st.sweeping and "0 V" in st.sweep_note, st.sweep_note
        assert srv.seats.of("ana") is None and srv.benches["bench1"].station is None
        assert "the booking's time ended; 1 run(s) kept" in srv.benches["bench1"].note
        on_disk = sorted(p.name for p in st.folder.iterdir())
        assert on_disk == ["sq_0.80V.csv", "sq_0.80V.json"], on_disk
        assert len(read_run(st.folder / "sq_0.80V.csv")) == 1250
        assert any("ana's booking of bench1 ended: the booking's time ended (rig at 0 V)"
                   in line for line in lines)
        # the instructor's Stop: the sweep stops at 0 V, the booking stays
        st2 = srv.take("ben")
        st2.start_sweep(_plan(tmp_path, st2.rig, "1.0"))
        _wait(lambda: st2.live.samples > 100, 30, "ben's run")
        srv.stop_bench("bench1", by="kim")
        assert not st2.sweeping and "0 V" in st2.sweep_note
        assert srv.seats.of("ben").bench == "bench1" and srv.station_of("ben") is st2
        assert not list((tmp_path / "class_runs" / "ben" / "bench1").glob("*.csv"))
        row = srv.overview()[0]
        assert row["student"] == "ben" and row["state"] == "idle"
    finally:
        srv.close()


# -- the server's trust boundary -------------------------------------------------------

def test_the_lab_page_without_logins_refuses_to_listen_beyond_this_machine(tmp_path):
    for host in ("0.0.0.0", "192.168.1.20", "::"):
        p = labrig("lab", tmp_path / "runs", "--no-browser", "--host", host, timeout=60)
        assert p.returncode == 2, p.stderr
        assert len(p.stderr.strip().splitlines()) == 1
        assert "labrig class serve" in p.stderr and "log in" in p.stderr
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


def _login(url, user, password, session=None):
    s = session or requests.Session()
    form = s.get(f"{url}/login", timeout=30)
    xsrf = s.cookies.get("_xsrf")
    assert xsrf and 'name="_xsrf"' in form.text
    r = s.post(f"{url}/login", data={"username": user, "password": password, "_xsrf": xsrf},
               allow_redirects=False, timeout=30)
    return s, r


def _token(page: str) -> str:
    """The Bokeh session token a served page carries (signed by the server)."""
    return re.findall(r'token[^:]{0,3}:\s*\\?"([^"\\]+)', page)[0]


async def _ws(url, cookies: str, token: str = "x"):
    """``ack`` when the server takes the websocket (its first message acknowledges the
    session), else how it refused."""
    from tornado.httpclient import HTTPRequest
    from tornado.websocket import websocket_connect

    req = HTTPRequest(url.replace("http", "ws") + "/ws", headers={
        "Cookie": cookies, "Origin": url})
    try:
        conn = await websocket_connect(req, subprotocols=["bokeh", token])
        msg = await asyncio.wait_for(conn.read_message(), 30)
    except Exception as exc:
        return f"refused: {exc}"
    conn.close()
    return "ack" if msg and '"ACK"' in msg else f"closed: {msg}"


def test_strangers_forged_cookies_and_old_logins_are_refused_each_in_one_log_line(tmp_path):
    """No page, websocket or login without the right password, XSRF token and a young
    enough login; each refusal a line in the server's log; no password in it."""
    f = write_class(tmp_path, extra_server="session_hours = 0.002")   # 7.2 s
    server = ClassProc(f)
    url = server.url
    try:
        # no login: the page sends to the login form; the websocket is refused
        r = requests.get(url + "/", allow_redirects=False, timeout=30)
        assert r.status_code == 302 and "/login" in r.headers["Location"]
        assert asyncio.run(_ws(url, "")).startswith("refused")
        # a wrong password, an unknown name, a form without its XSRF token
        s, r = _login(url, "ana", "ben-secret-2")
        assert r.status_code == 302 and "error" in r.headers["Location"]
        assert "user" not in s.cookies
        s, r = _login(url, "mallory", "ana-secret-1")
        assert "error" in r.headers["Location"]
        r = requests.post(url + "/login", data={"username": "ana", "password": "ana-secret-1"},
                          allow_redirects=False, timeout=30)
        assert r.status_code == 403
        # a forged cookie (a user named without the server's signature)
        r = requests.get(url + "/", cookies={"user": "kim"}, allow_redirects=False, timeout=30)
        assert r.status_code == 302
        # the right password: the page; then, once the login is older than
        # session_hours, the page and the websocket are refused again
        s, r = _login(url, "ana", "ana-secret-1")
        assert r.status_code == 302 and r.headers["Location"] == "/"
        page = s.get(url + "/", allow_redirects=False, timeout=60)
        assert page.status_code == 200 and "bokeh" in page.text.lower()
        assert s.cookies.get("user") and "ana-secret-1" not in str(s.cookies)
        cookie = "; ".join(f"{k}={v}" for k, v in s.cookies.items())
        token = _token(page.text)
        assert asyncio.run(_ws(url, cookie, token)) == "ack"     # the page's own socket
        assert asyncio.run(_ws(url, "", token)).startswith("refused")   # without the login
        forged = token[:-4] + ("AAAA" if not token.endswith("AAAA") else "BBBB")
        assert asyncio.run(_ws(url, cookie, forged)) != "ack"    # a session id not signed
        time.sleep(8)
        r = s.get(url + "/", allow_redirects=False, timeout=30)
        assert r.status_code == 302 and "/login" in r.headers["Location"]
        assert asyncio.run(_ws(url, cookie, token)).startswith("refused")
    finally:
        server.stop()
    log = server.log.read_text()
    refused = [line for line in log.splitlines() if "refused:" in line]
    assert sum("a wrong password for ana" in line for line in refused) == 1
    assert sum("a wrong password for an unknown name" in line for line in refused) == 1
    assert sum("without a valid XSRF token" in line for line in refused) == 1
    assert sum("an expired or invalid login" in line for line in refused) >= 3
    assert "ana logged in (student)" in log
    assert all(pw not in log for pw in PASSWORDS.values())
    assert "mallory" not in log          # an unknown name is not written down either


def test_a_login_flood_is_throttled_per_name_and_per_address_each_refusal_in_one_line(tmp_path):
    """Past 5 failed logins for one name within a minute, that name's logins are refused
    unheard, even with its right password, while another name still logs in from the same
    address; past 20 failed logins from one address, every login from it is refused. Each
    refusal is one line in the log, naming the rule; no password and no unknown name in it.
    Of thirty logins posted at once, exactly as many are heard as the address had failures
    left: each is counted before the next is checked."""
    from concurrent.futures import ThreadPoolExecutor

    from labrig.lab.login import FAILED_PER_ADDRESS, FAILED_PER_NAME

    server = ClassProc(write_class(tmp_path))
    url = server.url
    try:
        for _ in range(FAILED_PER_NAME):
            _, r = _login(url, "ana", "not-her-password")
            assert "Wrong+name+or+password" in r.headers["Location"]
        s, r = _login(url, "ana", "ana-secret-1")          # right, but too late
        assert "Too+many+failed+logins" in r.headers["Location"] and "user" not in s.cookies
        s, r = _login(url, "ben", "ben-secret-2")          # another name, the same address
        assert r.headers["Location"] == "/" and s.cookies.get("user")
        sessions = [requests.Session() for _ in range(30)]
        for sess in sessions:
            sess.get(f"{url}/login", timeout=30)

        def post(k):   # thirty at once, names the class does not have
            sess = sessions[k]
            return sess.post(f"{url}/login", data={"username": f"mallory{k}", "password": "x",
                                                   "_xsrf": sess.cookies.get("_xsrf")},
                             allow_redirects=False, timeout=60).headers["Location"]

        with ThreadPoolExecutor(30) as pool:
            answers = list(pool.map(post, range(30)))
        assert all("error=" in a for a in answers)
        heard = sum("Wrong+name" in a for a in answers)
        assert heard == FAILED_PER_ADDRESS - FAILED_PER_NAME, answers   # the rest unheard
        s, r = _login(url, "kim", "kim-secret-3")          # the address is now refused
        assert "Too+many+failed+logins" in r.headers["Location"]
    finally:
        server.stop()
    lines = server.log.read_text().splitlines()
    assert sum("refused: a login for ana from " in x and "too many failed logins for ana "
               "(5 in 60 s)" in x for x in lines) == 1
    assert sum("too many failed logins from " in x for x in lines) == 30 - heard + 1
    assert "ben logged in" in server.log.read_text()
    assert not any("mallory" in x or "secret" in x or "not-her" in x for x in lines)


def test_behind_a_proxy_the_login_cookie_is_https_only_and_the_log_names_the_forwarded_client(
        tmp_path):
    """`[server] behind_proxy = true` (the server on 127.0.0.1, an HTTPS proxy before it):
    the login cookie is marked Secure, and the log names the client the proxy forwards
    (X-Real-IP), not the proxy; without the key the cookie is not Secure and a forwarded
    address is not believed."""
    for proxy in (True, False):
        folder = tmp_path / f"proxy_{proxy}"
        f = write_class(folder, extra_server=f"behind_proxy = {str(proxy).lower()}")
        server = ClassProc(f)
        try:
            s = requests.Session()
            s.headers["X-Real-IP"] = "10.1.2.3"
            form = s.get(f"{server.url}/login", timeout=30)
            assert form.status_code == 200
            r = s.post(f"{server.url}/login", data={"username": "ana", "password": "ana-secret-1",
                                                    "_xsrf": s.cookies.get("_xsrf")},
                       allow_redirects=False, timeout=30)
            assert r.status_code == 302 and r.headers["Location"] == "/"
            set_cookie = r.headers["Set-Cookie"]   # (the login's only cookie: the user's)
            assert set_cookie.startswith("user=") and ("Secure" in set_cookie) is proxy, set_cookie
        finally:
            server.stop()
        said = [line for line in server.log.read_text().splitlines() if "ana logged in" in line]
        assert len(said) == 1, said
        assert ("from 10.1.2.3" in said[0]) is proxy, said[0]


# -- a bench on another PC -------------------------------------------------------------

@pytest.mark.slow
def test_a_bench_on_another_pc_plays_stops_and_goes_away_over_tls(tmp_path):
    """A bench PC (here a subprocess: `labrig class bench --sim`, paced to real time)
    serves its rig through the class's TLS-only Dask scheduler: a student's sweep on it
    streams in and lands whole in her folder; Stop reaches it (0 V, finished runs kept);
    killed mid-run, the bench is said to be gone and the runs it finished are kept. A
    client without the class's certificate, or with another authority's, is refused."""
    import subprocess
    import sys

    from distributed import Client
    from distributed.security import Security

    from class_room import ROOT
    from labrig.classroom.certs import make_certs, security
    from labrig.classroom.roster import read_class
    from labrig.lab.class_server import ClassServer
    from lab_page import free_port

    f = write_class(tmp_path, benches=("far",), kinds={"far": "remote"},
                    extra_server=f"dask_port = {free_port()}")
    p = labrig("class", "certs", f, check=0)
    assert "one per bench PC (far)" in p.stderr
    assert labrig("class", "certs", f).returncode == 2          # nothing overwritten
    assert (tmp_path / "certs" / "far.key").stat().st_mode & 0o077 == 0
    lines = []
    srv = ClassServer(read_class(f), log=lines.append)
    bench = None
    try:
        assert srv.overview()[0]["state"] == "not connected"
        address = srv.scheduler.address
        assert address.startswith("tls://")
        # strangers: no certificate, or another class's
        make_certs(tmp_path / "other", ["far"], ["127.0.0.1"])
        for sec in (None, Security(), security(tmp_path / "other", "far")):
            with pytest.raises(Exception):
                Client(address, security=sec, timeout=5).close()
            # the refused Client is garbage (its traceback's frames hold it in a cycle):
            # collect it now. Collected inside the next Client's start, its __del__ closed
            # its loop under the lock distributed's LoopRunner.start holds: the worker hung
            # for good (seen once in a full run, py-spy on the stuck worker)
            gc.collect()
        bench = subprocess.Popen(
            [sys.executable, "-m", "labrig", "class", "bench", "far", "--scheduler", address,
             "--certs", str(tmp_path / "certs"), "--sim"], cwd=ROOT,
            stderr=subprocess.PIPE, text=True)
        _wait(lambda: "far" in srv.online(), 60, "the bench PC")
        assert srv.overview()[0]["state"] == "free"
        st = srv.take("ana")
        st.start_sweep(_plan(tmp_path, st.rig, "1.0, 1.5"))
        _wait(lambda: st.live.samples > 100, 30, "the first samples")
        assert st.live.samples < 1250                  # streamed as it plays, not at the end
        _wait(lambda: not st.sweeping, 60, "the sweep")
        assert st.sweep_note.startswith("2 run(s) written"), st.sweep_note
        from labrig.io.runs import read_run

        for name in ("sq_1.00V", "sq_1.50V"):
            assert len(read_run(st.folder / f"{name}.csv")) == 1250
        # the same runs again: refused, nothing overwritten
        st.start_sweep(_plan(tmp_path, st.rig, "1.0"))
        _wait(lambda: not st.sweeping, 30, "the refusal")
        assert "exists" in st.sweep_note
        # Stop during the second run: at 0 V on the bench, the first run kept
        st.start_sweep(_plan(tmp_path, st.rig, "0.5, 0.7, 0.9"))
        _wait(lambda: len(st.written) == 1 and st.live.samples > 100, 30, "the second run")
        st.stop()
        assert "output is at 0 V" in st.sweep_note and "1 run(s) written" in st.sweep_note
        # the bench PC goes away mid-run
        st.start_sweep(_plan(tmp_path, st.rig, "0.6, 0.8, 1.1"))
        _wait(lambda: len(st.written) == 1 and st.live.samples > 100, 30, "the second run")
        bench.kill()
        bench.wait(10)
        _wait(lambda: not st.sweeping, 60, "the bench's absence noticed")
        assert "far went away mid-run" in st.sweep_note and "kept" in st.sweep_note
        _wait(lambda: srv.overview()[0]["state"] == "not connected", 10, "the overview")
    finally:
        if bench is not None and bench.poll() is None:
            bench.kill()
            bench.wait(10)
        srv.close()
    runs = sorted(p.name for p in (tmp_path / "class_runs" / "ana" / "far").glob("*.csv"))
    assert runs == ["sq_0.50V.csv", "sq_0.60V.csv", "sq_1.00V.csv", "sq_1.50V.csv"]
    assert not list((tmp_path / "class_runs").rglob("*.tmp"))


def test_the_server_speaks_https_with_the_certificate_the_class_file_gives(tmp_path):
    """``[server] certfile/keyfile``: the login page and the websocket over TLS only,
    the certificate checked by the client against the authority that signed it; the
    login cookie marked Secure (never sent over plain HTTP)."""
    from labrig.classroom.certs import make_certs

    make_certs(tmp_path / "tls", [], ["127.0.0.1", "localhost"])
    f = write_class(tmp_path, extra_server='certfile = "tls/server.pem"\n'
                                           'keyfile = "tls/server.key"')
    server = ClassProc(f)
    try:
        assert server.url.startswith("https://127.0.0.1:")
        ca = str(tmp_path / "tls" / "ca.pem")
        r = requests.get(server.url + "/", allow_redirects=False, timeout=30, verify=ca)
        assert r.status_code == 302 and "/login" in r.headers["Location"]
        with pytest.raises(requests.exceptions.SSLError):   # not a certificate it trusts
            requests.get(server.url + "/login", timeout=30)
        with pytest.raises(requests.exceptions.ConnectionError):   # no plain HTTP
            requests.get(server.url.replace("https", "http") + "/login", timeout=30)
        s = requests.Session()   # (verify per request: a session's own yields to the
        s.get(server.url + "/login", timeout=30, verify=ca)   # environment's CA bundle)
        r = s.post(server.url + "/login", data={"username": "kim", "password": PASSWORDS["kim"],
                                                "_xsrf": s.cookies.get("_xsrf")},
                   allow_redirects=False, timeout=30, verify=ca)
        assert r.status_code == 302 and r.headers["Location"] == "/"
        assert "Secure" in r.headers["Set-Cookie"], r.headers["Set-Cookie"]   # HTTPS only
    finally:
        server.stop()


def test_a_password_file_spoilt_while_the_class_runs_refuses_logins_in_one_line(tmp_path):
    server = ClassProc(write_class(tmp_path))
    try:
        (tmp_path / "class_passwords.json").write_text("{not json")
        s, r = _login(server.url, "ana", PASSWORDS["ana"])
        assert r.status_code == 302 and "unreadable" in r.headers["Location"]
        assert "user" not in s.cookies
    finally:
        server.stop()
    log = server.log.read_text()
    assert "password file is not valid JSON" in log and "Traceback" not in log


def test_the_class_pages_built_in_process_a_student_drives_an_instructor_watches(tmp_path):
    """The class's pages as the server builds them, without a server or a browser (the
    browser tests drive the same pages served): ana takes bench1 and her lab page drives
    it; kim's page watches it read-only, his Stop on the watched page is refused and
    logged, the rig untouched; a signed login cookie names its user, a forged or stale one
    nobody."""
    import time as _time

    from tornado.web import create_signed_value

    from labrig.classroom.roster import read_class
    from labrig.lab.class_page import InstructorPage, StudentPage
    from labrig.lab.class_server import ClassServer
    from labrig.lab.login import user_of

    lines = []
    srv = ClassServer(read_class(write_class(tmp_path)), log=lines.append)
    try:
        ana = StudentPage(srv, "ana", "s-ana")
        ana.bench_pick.value = "bench1"
        ana.take_btn.clicks += 1
        assert ana.lab is not None and ana.lab.owner, ana.error.object
        ana.refresh()
        assert ana.release_btn.disabled is False and ana.take_btn.disabled is True
        kim = InstructorPage(srv, "kim", "s-kim")
        kim.watch("bench1")
        assert kim.watched is not None and not kim.watched.owner
        kim.watched.stop.clicks += 1        # an edited page's click reaches the server
        assert any("refused: kim asked to stop" in line for line in lines), lines
        st = srv.station_of("ana")
        assert st is not None and not st.sweeping
        ana.refresh()
        kim.refresh()
        assert "ana" in ana.header.object and "kim" in kim.header.object
    finally:
        srv.close()

    secret = "x" * 32
    cookie = create_signed_value(secret, "user", "ana").decode()
    assert user_of(cookie, secret, max_age_days=1) == "ana"
    assert user_of(cookie, "y" * 32, max_age_days=1) is None          # forged
    assert user_of(cookie[:-2] + "00", secret, max_age_days=1) is None
    old = create_signed_value(secret, "user", "ana", clock=lambda: _time.time() - 3 * 86400)
    assert user_of(old.decode(), secret, max_age_days=1) is None      # too old
    assert user_of(None, secret, max_age_days=1) is None


def test_an_expired_page_stops_for_good_and_never_claims_the_bench_again(tmp_path):
    """A student's login grows too old while her page drives a bench: the page stops its
    refresh once, lets the rig go at 0 V and says so once in the log; however often its
    callback would still fire, it never claims the bench again, and an action sent from
    it (a take, a Start) is refused and logged. Her new login's page drives the bench."""
    from labrig.classroom.roster import read_class
    from labrig.lab.class_page import StudentPage
    from labrig.lab.class_server import ClassServer

    lines = []
    srv = ClassServer(read_class(write_class(tmp_path)), log=lines.append)
    try:
        alive, stopped = [True], []
        ana = StudentPage(srv, "ana", "s-old", lambda: alive[0])
        ana.stop_refresh = lambda: stopped.append(1)
        ana.bench_pick.value = "bench1"
        ana.take_btn.clicks += 1
        st = srv.station_of("ana")
        assert ana.lab.owner and st.owner == "s-old"
        alive[0] = False
        for _ in range(12):
            ana.refresh()
        assert ana.expired and stopped == [1] and not ana.lab.owner
        _wait(lambda: st.owner is None, 10, "the bench let go (on the server's change thread)")
        assert not st.sweeping
        ana.take_btn.clicks += 1        # sent from the old page: refused
        ana.lab.start.clicks += 1
        new = StudentPage(srv, "ana", "s-new")         # she logs in again
        assert new.lab is not None and new.lab.owner and st.owner == "s-new"
        for _ in range(12):
            ana.refresh()
        assert st.owner == "s-new" and not ana.lab.owner
    finally:
        srv.close()
    assert sum("login expired; the page is closed" in x for x in lines) == 1, lines
    assert any("refused: ana asked to take a bench after the login expired" in x
               for x in lines), lines
    assert any("refused: ana asked to start" in x for x in lines), lines


def test_the_class_cores_are_shared_first_come_first_served_by_fits_and_grading(tmp_path):
    """The class file's `cores` is the budget: a booking's fit process runs its fits and
    numba's kernels on one thread; a grading holds two cores while it runs, waits for
    both, and no fit asked after it overtakes it."""
    import threading

    import numba

    from labrig.classroom.roster import read_class
    from labrig.core.parallel import jobs
    from labrig.lab.class_server import ClassServer, _Turn
    from labrig.lab.turns import Turns

    class Job:   # a job in the turns, running until told it is done
        def __init__(self, cores=1):
            self.busy, self.started, self.cores_held = True, False, cores
            self.worker = self

        def start_waiting(self):
            self.started = True
            return True

    turns = Turns(2)
    fit, grading, later = Job(), Job(2), Job()
    for job in (fit, grading, later):
        turns.ask(job)
    assert fit.started and not grading.started and not later.started
    fit.busy = False
    turns.tick()
    assert grading.started and not later.started and turns.ahead(later) == 1
    grading.busy = False
    turns.tick()
    assert later.started
    gate = threading.Event()        # the server's own grading turn: busy while it runs
    turn = _Turn(gate.wait, 2)
    assert not turn.busy and turn.start_waiting() and turn.busy and turn.cores_held == 2
    gate.set()
    _wait(lambda: not turn.busy, 10, "the grading's end")

    srv = ClassServer(read_class(write_class(tmp_path, extra_server="cores = 3")),
                      log=lambda line: None)
    try:
        assert srv.turns.slots == 3
        st = srv.take("ana")

        def result(name, fn):
            st.worker.submit(name, fn)
            got = []
            _wait(lambda: got.append(st.worker.poll()) or got[-1] is not None, 60, name)
            return got[-1][1]

        assert result("fits at once", jobs) == 1
        assert result("numba's threads", numba.get_num_threads) == 1
    finally:
        srv.close()


def test_a_secret_is_never_readable_by_others_not_even_while_it_is_written(tmp_path, monkeypatch):
    """The class's keys and password file are 0600 from the moment their file exists
    (before its first byte, under any umask), and written whole or not at all; public
    certificates 0644."""
    import os
    import stat

    from labrig.classroom.certs import make_certs
    from labrig.classroom.passwords import set_password
    from labrig.core import fileio

    modes = []
    real = fileio.os.fdopen

    def watched(fd, *a, **kw):
        modes.append(stat.S_IMODE(fileio.os.fstat(fd).st_mode))
        return real(fd, *a, **kw)

    monkeypatch.setattr(fileio.os, "fdopen", watched)
    old = os.umask(0)
    try:
        set_password(tmp_path / "passwords.json", "ana", "a good long password")
        make_certs(tmp_path / "certs", ["bench1"], ["127.0.0.1"])
    finally:
        os.umask(old)
    assert modes and set(modes) <= {0o600, 0o644}, modes
    assert stat.S_IMODE((tmp_path / "passwords.json").stat().st_mode) == 0o600
    for key in (tmp_path / "certs").glob("*.key"):
        assert stat.S_IMODE(key.stat().st_mode) == 0o600, key
    assert not list(tmp_path.rglob(".*.tmp"))
