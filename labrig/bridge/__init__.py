"""The rig: one bridge interface with the simulated rig, the serial bridge and the
emulated board behind it, the wire protocol, and the sweep that plays a plan.
"""
