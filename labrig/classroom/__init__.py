"""A whole class at once: batches over run folders (joblib or Dask), through the verbs
(mystery rigs with hidden physics live in :mod:`labrig.io.mystery`, their verbs in
:mod:`labrig.verbs.mystery`).
"""
