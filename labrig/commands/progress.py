"""A progress bar on stderr (rich), quiet when stderr is not a terminal.

Nothing it shows is cut: the bar's title and note wrap at word boundaries instead of
ending in an ellipsis, and a log line longer than the terminal (100 columns when stderr
is not a terminal) is wrapped with a hanging indent, every word whole.
"""
from __future__ import annotations

import sys
import textwrap

#: log lines are wrapped at this width when stderr is not a terminal
LOG_WIDTH = 100


def wrap_line(line: str, width: int) -> str:
    """``line`` wrapped at word boundaries; continuation lines are indented four spaces
    more than the line itself (a word longer than the width stays whole)."""
    if len(line) <= width:
        return line
    body = line.lstrip(" ")
    lead = line[:len(line) - len(body)]
    return textwrap.fill(body, width=width, initial_indent=lead, subsequent_indent=lead + "    ",
                         break_long_words=False, break_on_hyphens=False)


class Progress:
    def __init__(self, title: str, total: float, unit: str = ""):
        self.title, self.total, self.unit = title, total, unit
        self._bar = None

    def __enter__(self):
        if sys.stderr.isatty():
            from rich.progress import (BarColumn, Progress as RichProgress, TextColumn,
                                       TimeRemainingColumn)
            from rich.console import Console
            from rich.table import Column

            def words():  # wrapped at word boundaries, never cut with an ellipsis
                return Column(no_wrap=False, overflow="fold")

            self._bar = RichProgress(TextColumn("{task.description}", markup=False,
                                                table_column=words()),
                                     BarColumn(),
                                     TextColumn("{task.percentage:>3.0f}%"),
                                     TextColumn("{task.fields[note]}", markup=False,
                                                table_column=words()),
                                     TimeRemainingColumn(),
                                     console=Console(stderr=True), transient=True)
            self._bar.__enter__()
            self._task = self._bar.add_task(self.title, total=self.total, note="")
        return self

    def __exit__(self, *exc):
        if self._bar is not None:
            self._bar.__exit__(*exc)
        return False

    def describe(self, text: str):
        if self._bar is not None:
            self._bar.update(self._task, description=f"{self.title}: {text}")

    def note(self, text: str):
        if self._bar is not None:
            self._bar.update(self._task, note=text)

    def advance(self, n: float = 1):
        if self._bar is not None:
            self._bar.advance(self._task, n)

    def update(self, completed: float):
        if self._bar is not None:
            self._bar.update(self._task, completed=completed)

    def hook(self, event) -> None:
        """A verb's progress (:class:`labrig.core.progress.Event`) on this bar: an
        iteration or a candidate moves it and notes its text, an experiment names it,
        samples advance it, a note is a log line (rungs and written runs: the command
        says what it made)."""
        if event.kind in ("iteration", "candidate"):
            if event.done is not None:
                self.update(event.done)
            self.note(event.text)
        elif event.kind == "experiment":
            self.describe(event.text)
        elif event.kind == "samples":
            self.advance(event.done or 0)
        elif event.kind == "note":
            self.log(event.text)

    def log(self, text: str):
        """One message on stderr, each of its lines wrapped to the terminal's width."""
        if sys.stderr.isatty():
            import shutil

            width = max(shutil.get_terminal_size((LOG_WIDTH, 24)).columns - 1, 40)
        else:
            width = LOG_WIDTH
        print("\n".join(wrap_line(line, width) for line in str(text).splitlines() or [""]),
              file=sys.stderr)
