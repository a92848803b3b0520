"""Render a :class:`~labrig.report.story.Story` to one self-contained HTML page.

The page comes from ``templates/report.html.j2`` through jinja2 with autoescape on:
every value is escaped (quotes as ``&quot;``, like :func:`html.escape`) unless it is
:class:`markupsafe.Markup` made by :func:`labrig.report.blocks.markup`. Figures are
embedded as base64 PNG, so the file needs nothing beside it.
"""
from __future__ import annotations

import base64
import html
from datetime import datetime, timezone
from functools import lru_cache
from pathlib import Path

import jinja2
from markupsafe import Markup

from labrig.core.version import __version__
from labrig.report.sections import cards, sections
from labrig.report.story import Story
from labrig.core.fileio import atomic_write

TEMPLATES = Path(__file__).resolve().parent / "templates"


def png_uri(data: bytes) -> str:
    """PNG bytes as a ``data:`` URI for an ``<img src>``."""
    return "data:image/png;base64," + base64.b64encode(data).decode("ascii")


def _escape(value) -> Markup:
    # html.escape rather than markupsafe's: quotes as &quot; / &#x27;, as the page
    # always wrote them
    if hasattr(value, "__html__"):
        return Markup(value)
    return Markup(html.escape("" if value is None else str(value), quote=True))


@lru_cache(maxsize=1)
def environment() -> jinja2.Environment:
    """The jinja2 environment of the report (autoescape on, undefined is an error)."""
    env = jinja2.Environment(loader=jinja2.FileSystemLoader(str(TEMPLATES)),
                             autoescape=True, undefined=jinja2.StrictUndefined,
                             finalize=_escape, keep_trailing_newline=True)
    env.filters["png_uri"] = png_uri
    return env


def render(story: Story, created: datetime | None = None) -> str:
    """The page of ``story`` as HTML text.

    Parameters
    ----------
    story : Story
        What to show (:func:`labrig.report.gather.gather`).
    created : datetime, optional
        The time stamp in the header and footer (default: now, UTC).
    """
    created = created or datetime.now(timezone.utc)
    rig = (story.runs[0].meta.get("rig", {}) or {}).get("name") if story.runs else None
    return environment().get_template("report.html.j2").render(
        story=story, sections=sections(story), cards=cards(story), rig=rig,
        created=created, version=__version__)


def write(page: str, output) -> Path:
    """Write ``page`` to ``output`` atomically (its folder is made if needed), with the
    user's usual file mode: a report is for sharing."""
    out = Path(output)
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(out, page)
    return out
