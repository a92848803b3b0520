"""The DC-servo model: plants, the effect catalogue, effect sets, the simulator and its
numba kernels, and the model file.
"""
