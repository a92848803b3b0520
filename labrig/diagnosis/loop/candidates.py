"""Which effects a model could take next: the one rule ``diagnose``, ``--auto`` and their
pairs share (not a second member of a family, nothing the runs' input cannot have, an
open-ended effect only where the data show what it adds)."""
from __future__ import annotations

from labrig.model.effects import CATALOGUE, catalogue_name, get_effect, input_can_have
from labrig.model.model import Model


def candidate_names(base: Model, candidates=None, runs=(), evaluation=None) -> list[str]:
    """Catalogue effects ``base`` could take: not already in it, not a second friction
    law, output map or delay, not a second member of a family (a second dead zone), and
    none the ``runs``' input cannot have (:func:`labrig.model.effects.input_can_have`). An
    open-ended effect is a candidate only when named or when the ``evaluation`` of
    ``base`` shows what it adds (``Effect.offered``)."""
    names = [catalogue_name(n) for n in candidates] if candidates else \
        [n for n in CATALOGUE if n not in base.names]
    taken = {e.stage for e in base.effects if e.stage in ("friction", "output", "delay")}
    families = {e.family_name for e in base.effects}
    out = []
    for n in names:
        eff = get_effect(n)
        if eff.stage in taken or eff.family_name in families or not input_can_have(eff, runs):
            continue
        if eff.open_ended and not candidates and not eff.offered(evaluation, runs):
            continue
        out.append(n)
    return out


def refinements(base: Model, runs) -> list[tuple[str, str, list]]:
    """``(old, new, starts)`` for each catalogue effect ``new`` that refines an effect
    ``old`` of ``base`` on these ``runs`` (``old`` in its ``extends``), with starts for
    ``new``'s parameters from ``old``'s fitted ones (``Effect.from_simpler``): tried in its
    place, from there."""
    out = []
    for old in base.names:
        for n in CATALOGUE:
            eff = get_effect(n)
            if old in eff.extends and n not in base.names:
                starts = eff.from_simpler(old, base.effect_params[old], runs)
                if starts:
                    out.append((old, n, starts))
    return out
