"""Experiment design, a floor above the diagnosis it reads: the input families a rig can
play, the experiment that best separates two explanations (``propose``), the proposal
and its figure, asking the rig until the data are sure, and the decision a played
experiment makes."""
