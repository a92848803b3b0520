"""Defaults that more than one layer needs, in one place.

``LOOP_GAINS``: the lab's standard position loop with tacho feedback (amplifier input
= Kp (ref - pos) - Kv tacho), as in the default plan. A closed-loop experiment that
gives no gains runs with these; the step metrics of a model identified on open-loop
runs only are computed for this loop. A closed-loop *run* on disk must state its own
gains (a run without them is a user error, not a default).

``METHOD``: the identifier every command and the Python API use unless told otherwise
(CO: local least squares from scanned starts, the fastest of the three and the one
the loop's re-fits use). ``SEED``: the random seed of the loop's re-fits and proposals.
"""
from __future__ import annotations

LOOP_GAINS = {"position_gain": 2.0, "velocity_gain": 0.15}

METHOD = "co"
SEED = 0
