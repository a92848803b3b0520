"""A Sphinx directive that writes the effect catalogue from the catalogue itself
(``labrig.model.effects.CATALOGUE``): each effect's stage, parameters with their units
and ranges, what it is in the rig, where it shows in the residuals and the experiment
that confirms it. The page can never list an effect the code does not have."""
from __future__ import annotations

import inspect

from docutils import nodes
from docutils.statemachine import StringList
from sphinx.util.docutils import SphinxDirective


class EffectCatalogue(SphinxDirective):
    """A ```{effect-catalogue}``` fence in a MyST page."""

    has_content = False

    def run(self):
        from labrig.model.effects import CATALOGUE

        # (the page is MyST: the nested content is parsed as Markdown)
        lines = []
        for name, eff in CATALOGUE.items():
            lines += [f"## {name}", ""]
            if eff.summary:
                lines += [f"**{eff.summary}**", ""]
            lines += [f"*Stage*: `{eff.stage}`" + (f"; *family*: `{eff.family}`"
                                                  if eff.family else ""), ""]
            if eff.params:
                lines += ["| parameter | unit | range | meaning |", "|---|---|---|---|"]
                for p in eff.params:
                    doc = (p.doc or "").replace("|", "\\|")
                    lines += [f"| `{p.name}` | {p.unit or '-'} | {p.lower:g} to {p.upper:g} "
                              f"| {doc} |"]
                lines += [""]
            for label, text in (("Where it shows", eff.signature),
                                ("The experiment that confirms it", eff.experiment)):
                if text:
                    lines += [f"*{label}*: {text}", ""]
            doc = inspect.getdoc(eff)
            if doc:
                lines += ["```text"] + doc.splitlines() + ["```", ""]
        node = nodes.section()
        node.document = self.state.document
        self.state.nested_parse(StringList(lines, source="labrig.model.effects.CATALOGUE"),
                                self.content_offset, node)
        return node.children


def setup(app):
    app.add_directive("effect-catalogue", EffectCatalogue)
    return {"version": "1", "parallel_read_safe": True}
