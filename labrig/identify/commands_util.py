"""Small parsers shared by the commands that fit models."""
from __future__ import annotations


def parse_fixed(text):
    from ..commands.identification import parse_assignments

    return parse_assignments(text, "--fix")
