"""The missing-physics loop, grouped so a reader finds each part by name:

- :mod:`labrig.diagnosis.loop`: the round (``diagnose``: candidates re-fitted from their
  starts, judged, the verdict) and the search that plays rounds (``--auto``);
- :mod:`labrig.diagnosis.evidence`: what a model is judged by: evaluation against the runs,
  residuals by regime against their noise band, cross-validation, the criteria, when an
  effect is resolved;
- :mod:`labrig.diagnosis.words`: what the numbers mean in plain words (the verdicts);
- :mod:`labrig.diagnosis.results`: what a round and a search return (:class:`Diagnosis`
  in ``results/diagnosis.py``, the ladder), their JSON documents and their figures.

The experiment that decides between two explanations lives a floor up, in
:mod:`labrig.design`.
"""
