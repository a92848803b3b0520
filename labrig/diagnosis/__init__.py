"""The missing-physics loop: residuals and their noise band, evaluation, the diagnosis
of which effect is missing, cross-validated evidence, re-fits, the error ladder, the
search (``--auto``) and the experiment that decides between two explanations.
"""
