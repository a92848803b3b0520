"""A progress bar on stderr (rich), quiet when stderr is not a terminal."""
from __future__ import annotations

import sys


class Progress:
    def __init__(self, title: str, total: float, unit: str = ""):
        self.title, self.total, self.unit = title, total, unit
        self._bar = None

    def __enter__(self):
        if sys.stderr.isatty():
            from rich.progress import (BarColumn, Progress as RichProgress, TextColumn,
                                       TimeRemainingColumn)
            from rich.console import Console

            self._bar = RichProgress(TextColumn("{task.description}"), BarColumn(),
                                     TextColumn("{task.percentage:>3.0f}%"),
                                     TextColumn("{task.fields[note]}"), TimeRemainingColumn(),
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

    def log(self, text: str):
        print(text, file=sys.stderr)
