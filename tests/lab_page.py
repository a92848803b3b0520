"""What the lab page's browser tests (tests/test_lab.py, tests/test_class_browser.py) and
its benchmark (benchmarks/bench_lab.py) need: a port to serve on, headless Chromium, a
page that refuses every request leaving the machine, and the words an element shows."""
from __future__ import annotations

import re
import shutil
import signal
import socket
import subprocess
import time
from pathlib import Path

import pytest

ARTEFACTS = Path(__file__).resolve().parent / "artefacts"
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
LOCAL = ("http://127.0.0.1", "ws://127.0.0.1", "data:", "blob:", "about:")

#: the words of an element and its shadow root, text nodes joined by spaces (no styles)
WORDS = r"""e => { const out = [];
  const walk = n => { if (n.nodeType === 3) out.push(n.textContent);
    else if (n.nodeName !== 'STYLE' && n.nodeName !== 'SCRIPT') {
      if (n.shadowRoot) walk(n.shadowRoot); n.childNodes.forEach(walk); } };
  walk(e); return out.join(' ').replace(/\s+/g, ' '); }"""


#: what the overlay's speed figure draws (its Bokeh models, by name): the time in view
#: (start, end), the number of points drawn, the time between two of them and the sum
#: of the model's drawn values
#: whether that figure is in the page yet
DRAWN_READY = r"""() => !!(window.Bokeh && Bokeh.documents.find(
  d => d.get_model_by_name("run-view-speed") && d.get_model_by_name("run-view-time")))"""
DRAWN = r"""() => { const doc = Bokeh.documents.find(d => d.get_model_by_name("run-view-speed"));
  const src = doc.get_model_by_name("run-view-speed"), x = doc.get_model_by_name("run-view-time");
  const col = k => src.data.get ? src.data.get(k) : src.data[k];
  const t = col("t"), m = col("model");
  return [x.start, x.end, t.length, t[1] - t[0], Array.from(m).reduce((a, b) => a + b, 0)]; }"""


def stop_process(proc) -> int:
    """End a server we started, by its PID: Ctrl-C (SIGINT), then SIGKILL after 30 s."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
    return proc.returncode


def free_port() -> int:
    """A TCP port on 127.0.0.1 that is free now (the system picks it)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def launch():
    """Headless Chromium (Debian's, driven by Playwright), for conftest's ``browser``
    fixture; the test is skipped where Chromium or Playwright is missing."""
    sync_api = pytest.importorskip("playwright.sync_api")
    if not Path(CHROMIUM).exists():
        pytest.skip("Chromium is not installed (CI installs Debian's chromium)")
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=[
            "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
            "--disable-background-networking", "--disable-component-update", "--disable-sync"])
        yield b
        b.close()


class Page:
    """A browser page on the lab that records every request leaving the machine."""

    def __init__(self, browser, url, *, login: tuple | None = None, ready: str = ".lab-start"):
        """``login``: (name, password) typed into a class server's login form, in a
        browser context of its own (its own cookies: another person at another PC)."""
        self.outside = []
        size = {"viewport": {"width": 1400, "height": 1000}}
        self._context = browser.new_context(**size) if login else None
        self.page = self._context.new_page() if login else browser.new_page(**size)
        self.page.route("**/*", self._route)
        self.page.goto(url)
        if login:
            self.page.fill("input[name=username]", login[0])
            self.page.fill("input[name=password]", login[1])
            self.page.click("button[type=submit]")
        self.page.wait_for_selector(ready, timeout=60000)

    def fit_the_linear_model(self):
        """The loop's tab, then its first button, as a student starts the loop."""
        self.page.get_by_text("The loop", exact=True).click()
        self.click(".lab-fit")
        self.idle()

    def _route(self, route):
        if route.request.url.startswith(LOCAL):
            route.continue_()
        else:
            self.outside.append(route.request.url)
            route.abort()

    def text(self, css: str) -> str:
        """The text of a Panel pane (it renders inside the element's shadow root)."""
        try:
            return self.page.locator(css).first.evaluate(WORDS)
        except Exception:
            return ""

    def click(self, css: str) -> None:
        self.page.locator(f"{css} button").first.click()

    def wait(self, cond, timeout: float = 300, what: str = "") -> None:
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout:
            if cond():
                return
            time.sleep(0.25)
        self.shot("timeout")
        raise AssertionError(f"waited {timeout:.0f} s for {what}")

    def idle(self) -> None:
        """No job running: the status says no "working" three looks in a row (a pane read
        while the page redraws it reads empty, which alone proves nothing)."""
        time.sleep(1.0)
        quiet = []
        self.wait(lambda: quiet.append("working" not in self.text(".lab-status"))
                  or quiet[-3:] == [True] * 3, 600, "the fits to finish")

    def number(self, css: str, pattern: str) -> float:
        return float(re.search(pattern, self.text(css)).group(1))

    def shot(self, name: str) -> Path:
        ARTEFACTS.mkdir(exist_ok=True)
        path = ARTEFACTS / f"lab_{name}.png"
        self.page.screenshot(path=str(path), full_page=True)
        return path

    def close(self) -> None:
        self.page.close()
        if self._context is not None:
            self._context.close()
        assert self.outside == [], f"requests left the machine: {self.outside}"
