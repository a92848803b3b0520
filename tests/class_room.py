"""What the class server's tests (tests/test_class.py, tests/test_class_browser.py) and
its load benchmark share: a class file written to a folder, its passwords set, and
`labrig class serve` in a subprocess (ended by its PID)."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

from lab_page import free_port, stop_process

ROOT = Path(__file__).resolve().parent.parent

#: the class's people and their passwords (the tests log in with these)
PASSWORDS = {"ana": "ana-secret-1", "ben": "ben-secret-2", "kim": "kim-secret-3"}


def write_class(folder: Path, *, benches=("bench1", "bench2"), kinds=None, port=None,
                extra_class: str = "", extra_server: str = "", watch: bool = True,
                students=("ana", "ben"), instructors=("kim",), passwords=PASSWORDS) -> Path:
    """``folder/class.toml`` and its password file; returns the class file's path."""
    from labrig.classroom.passwords import set_password

    folder.mkdir(parents=True, exist_ok=True)
    kinds = kinds or {}
    lines = ["[class]", 'name = "Servo lab, test"', f"watch = {str(watch).lower()}",
             extra_class, "[server]", 'host = "127.0.0.1"', f"port = {port or free_port()}",
             extra_server]
    for b in benches:
        lines += ["[[bench]]", f'name = "{b}"', f'rig = "{kinds.get(b, "sim")}"']
    lines += ["[people]", f"students = {list(students)!r}".replace("'", '"'),
              f"instructors = {list(instructors)!r}".replace("'", '"')]
    path = folder / "class.toml"
    path.write_text("\n".join(lines) + "\n")
    for name, pw in passwords.items():
        if name in (*students, *instructors):
            set_password(folder / "class_passwords.json", name, pw, force=True)
    return path


class ClassProc:
    """`labrig class serve` in a subprocess; its log (stderr) kept in a file."""

    def __init__(self, class_file: Path, *flags, log: Path | None = None):
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        self.log = log or class_file.parent / "server.log"
        self._err = open(self.log, "w")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "labrig", "class", "serve", str(class_file),
             "--no-browser", *flags],
            stdout=subprocess.PIPE, stderr=self._err, text=True, cwd=class_file.parent,
            env=env)
        line = self.proc.stdout.readline()
        assert line.startswith("http"), line + self.log.read_text()
        self.url = re.search(r"https?://\S+/", line).group(0).rstrip("/")

    def lines(self) -> list[str]:
        return self.log.read_text().splitlines()

    def stop(self) -> int:
        code = stop_process(self.proc)
        self._err.close()
        return code
