"""The simulator's numerics, apart from the physics: numba kernels that step every
candidate's plant exactly between samples (zero-order hold, ``expm``), with friction,
the position loop and the parameter layout they share (``layout``), and the install step
that compiles them (``warm``). :mod:`labrig.model.simulate` turns a model's plant and
effects into their parameter columns; nothing here knows an effect by name."""
