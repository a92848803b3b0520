"""A whole class at once: batches over run folders (joblib or Dask) and mystery rigs
with hidden physics for the missing-physics lab.
"""
