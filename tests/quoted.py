"""Figures quoted in the documentation, tied to the command that produces them.

A figure a document quotes (a sheet, its instructor notes, the README) is declared in an
HTML comment beside it, naming the command and where its output holds the figure::

    <!-- check `labrig analyse runs --json`
    km            96.9
    deadband_v    0.130  ±0.005
    tau_s*1000    158    ±2%
    /Fitness\\s+([\\d.]+)/   0.0123
    -->

- the command runs like a sheet's (``labrig ...`` or ``python ...``, in the sheet's
  folder, after the sheet's own commands; a line the sheet itself runs is not run twice);
- each following line is ``WHERE QUOTED [±TOL[%]]``: ``WHERE`` is a dotted path into the
  command's JSON output (list items by number, ``*F`` scales, e.g. ``tau_s*1000`` for ms)
  or ``/REGEX/`` with one group, searched in its text output (``/REGEX/*F`` scales too); ``QUOTED`` is the figure
  exactly as the text writes it (``−51.6``, ``0.130``, ``+13.2``);
- the tolerance, unless given, is one unit in the last quoted digit (``96.9``: ±0.1);
- the quoted figure must appear in the text that follows the comment, up to the next
  ``check`` comment or heading (checks stacked one after another share the text after
  the last): a figure and its command stay together;
- a line ``after: labrig sweep --sim -o runs`` names a command to run first (once per
  folder, in order; a sheet's own commands need none: its checks run after the sheet);
- a line ``given: 0.8 1.2 2.5`` lists settings the text quotes (amplitudes, gains the
  student types): they are inputs to the command, not results, and are not compared.

In a document's measured sections (headings starting "Numbers measured" or "Model
answers"), every decimal figure and every percentage must be one a ``check`` declares, so
no figure there is written by hand. Integers (points, seeds, counts) are free.
"""
from __future__ import annotations

import json
import re
import shlex
from dataclasses import dataclass, field
from pathlib import Path

CHECK = re.compile(r"<!--\s*check\s+`([^`]+)`[ \t]*\n(.*?)-->", re.S)
HEADING = re.compile(r"^#{1,6} ", re.M)
MEASURED = ("Numbers measured", "Model answers")
#: a figure in prose: optional sign, digits with a decimal point, or any number before %
FIGURE = re.compile(r"(?<![\w.])[−+-]?\d+\.\d+(?![\d.]*\w)|(?<![\w.])[−+-]?\d+(?:\.\d+)?(?=\s?%)")
TOL = re.compile(r"±\s*([\d.]+)\s*(%?)$")


def number(text: str) -> float:
    """A figure as the text writes it ('−51.6', '+13.2', '0.130') -> float."""
    return float(text.replace("−", "-").replace("+", "").rstrip("%"))


def default_tolerance(quoted: str) -> float:
    """One unit in the last quoted digit."""
    digits = quoted.replace("−", "-").rstrip("%")
    return 10.0 ** -len(digits.split(".")[1]) if "." in digits else 1.0


@dataclass
class Quote:
    where: str
    quoted: str
    tol: float | None = None
    relative: bool = False
    line_no: int = 0

    def allowed(self) -> float:
        if self.tol is None:
            return default_tolerance(self.quoted)
        return self.tol / 100.0 * abs(number(self.quoted)) if self.relative else self.tol

    def measure(self, stdout: str) -> float:
        """The figure in the command's output (JSON path or /regex/)."""
        if self.where.startswith("/"):
            pattern, _, scale = self.where[1:].rpartition("/")
            m = re.search(pattern, stdout)
            if not m:
                raise LookupError(f"/{pattern}/ not found in the output")
            return number(m.group(1)) * (float(scale[1:]) if scale else 1.0)
        path, _, scale = self.where.partition("*")
        obj = json.loads(stdout)
        for key in path.split("."):
            obj = obj[int(key)] if isinstance(obj, list) else obj[key]
        return float(obj) * (float(scale) if scale else 1.0)


@dataclass
class Check:
    doc: Path
    line_no: int
    command: str
    quotes: list[Quote] = field(default_factory=list)
    given: list[str] = field(default_factory=list)
    after: list[str] = field(default_factory=list)
    region: str = ""

    @property
    def argv(self) -> list[str]:
        return shlex.split(self.command)


def _line_of(text: str, pos: int) -> int:
    return text.count("\n", 0, pos) + 1


def parse(doc: Path, text: str | None = None) -> list[Check]:
    """Every ``check`` comment of ``doc`` (or of ``text``, a part of it) with the text it
    vouches for."""
    text = doc.read_text(encoding="utf-8") if text is None else text
    matches = list(CHECK.finditer(text))
    checks = []
    for k, m in enumerate(matches):
        # checks stacked one after another vouch together for the text after the last
        j, after = k + 1, m.end()
        while j < len(matches) and not text[after:matches[j].start()].strip():
            after, j = matches[j].end(), j + 1
        nxt = matches[j].start() if j < len(matches) else len(text)
        h = HEADING.search(text, m.end())
        end = min(nxt, h.start() if h else len(text))
        c = Check(doc, _line_of(text, m.start()), m.group(1).strip(), region=text[m.end():end])
        for j, raw in enumerate(m.group(2).splitlines(), 1):
            line = raw.strip()
            if not line:
                continue
            if line.startswith("after:"):
                c.after.append(line[len("after:"):].strip())
                continue
            if line.startswith("given:"):
                c.given += line[len("given:"):].split()
                continue
            tol, rel = None, False
            t = TOL.search(line)
            if t:
                tol, rel = float(t.group(1)), bool(t.group(2))
                line = line[:t.start()].strip()
            if line.startswith("/"):  # a regex may hold spaces: it ends at the last '/'
                cut = line.rindex("/")
                where, quoted = line[:cut + 1], line[cut + 1:].strip()
                if quoted.startswith("*"):  # /REGEX/*F: scaled, like a JSON path
                    factor, _, quoted = quoted.partition(" ")
                    where, quoted = where + factor, quoted.strip()
            else:
                where, _, quoted = line.partition(" ")
                quoted = quoted.strip()
            if not quoted or " " in quoted:
                raise ValueError(f"{doc.name}:{c.line_no + j}: expected 'WHERE QUOTED [±TOL]', "
                                 f"got {raw.strip()!r}")
            c.quotes.append(Quote(where, quoted, tol, rel, c.line_no + j))
        checks.append(c)
    return checks


def _norm(s: str) -> str:
    return s.replace("−", "-")


def problems_in_text(check: Check) -> list[str]:
    """Quoted figures missing from the text beside their command."""
    region = _norm(CHECK.sub("", check.region))
    out = []
    for q in check.quotes:
        pat = r"(?<![\w.])" + re.escape(_norm(q.quoted)) + r"(?![\d]|\.\d)"
        if not re.search(pat, region):
            out.append(f"{check.doc.name}:{q.line_no}: '{q.quoted}' is declared but the text "
                       f"after the check does not quote it")
    return out


def problems_in_output(check: Check, stdout: str) -> list[str]:
    """Quoted figures that the command's output no longer gives."""
    out = []
    for q in check.quotes:
        where = f"{check.doc.name}:{q.line_no}: `{check.command}` {q.where}"
        try:
            got = q.measure(stdout)
        except (LookupError, KeyError, IndexError, TypeError, ValueError) as e:
            out.append(f"{where}: cannot read it from the output ({e})")
            continue
        if not abs(got - number(q.quoted)) <= q.allowed() * (1 + 1e-9):
            out.append(f"{where}: the text says {q.quoted}, the command gives {got:.6g} "
                       f"(tolerance ±{q.allowed():.3g}); update the text")
    return out


def sections(text: str) -> list[tuple[str, str]]:
    """(heading, body) of each '## ' section."""
    parts = re.split(r"^## (.*)$", text, flags=re.M)
    return list(zip(parts[1::2], parts[2::2]))


def unchecked_figures(doc: Path, measured: tuple[str, ...] = MEASURED) -> list[str]:
    """Decimal figures and percentages in the sections whose headings start with one of
    ``measured`` that no check in the same section declares."""
    text = doc.read_text(encoding="utf-8")
    out = []
    for heading, body in sections(text):
        if not heading.startswith(measured):
            continue
        checks = parse(doc, body)
        declared = {_norm(q.quoted).lstrip("+") for c in checks for q in c.quotes}
        declared |= {_norm(g).lstrip("+") for c in checks for g in c.given}
        prose = CHECK.sub("", body)
        for m in FIGURE.finditer(prose):
            fig = _norm(m.group(0)).lstrip("+")
            if fig not in declared and fig.lstrip("-") not in declared:
                out.append(f"{doc.name}, '{heading}': {m.group(0)} is quoted but no check "
                           "declares it")
    return out
