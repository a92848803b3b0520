"""What a test's numbers were, bit for bit: the measurement behind the kernels' reruns.

With ``LABRIG_RECORD_OUTPUTS=DIR`` set, every ``pytest.approx`` comparison records the
actual value it was handed (a hash of its exact bits and a short repr) and the sheets'
commands record their outputs, per test, into ``DIR/<worker>.json`` at the end of the
session. Run the kernels-marked tests so under the default kernel and under another
(``OPENBLAS_CORETYPE=Prescott``) and compare the two records
(``python tests/outputs_record.py DIR_A DIR_B``): a test whose every recorded value is
the same bits under both kernels is not reached by the BLAS's rounding, and re-running it
under that kernel proves nothing the default run does not. Off (and free) by default.
"""
from __future__ import annotations

import hashlib
import json
import os
import pickle
import sys
from pathlib import Path

import pytest

DIR = os.environ.get("LABRIG_RECORD_OUTPUTS")
_RECORD: dict[str, list[list[str]]] = {}


def _test() -> str:
    return os.environ.get("PYTEST_CURRENT_TEST", "?").rsplit(" (", 1)[0]


def record(value) -> None:
    """Record ``value`` (exactly) under the running test; nothing when off."""
    if not DIR:
        return
    try:
        blob = pickle.dumps(value, protocol=4)
    except Exception:   # an object that does not pickle: its repr stands for it
        blob = repr(value).encode()
    _RECORD.setdefault(_test(), []).append([hashlib.sha1(blob).hexdigest()[:16],
                                            repr(value)[:120]])


class _Recorded:
    """``pytest.approx(expected)`` that records what it is compared with."""
    __array_ufunc__ = None
    __array_priority__ = 100
    __hash__ = None

    def __init__(self, inner):
        self.inner = inner

    def __eq__(self, actual):
        record(actual)
        return self.inner == actual

    def __ne__(self, actual):
        return not self.__eq__(actual)

    def __repr__(self):
        return repr(self.inner)


def install() -> None:
    if not DIR:
        return
    approx = pytest.approx

    def recording_approx(*args, **kw):
        return _Recorded(approx(*args, **kw))

    pytest.approx = recording_approx


def write() -> None:
    if not DIR or not _RECORD:
        return
    Path(DIR).mkdir(parents=True, exist_ok=True)
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    (Path(DIR) / f"{worker}.json").write_text(json.dumps(_RECORD, indent=0))


def compare(a: Path, b: Path) -> int:
    def load(d):
        out = {}
        for f in sorted(Path(d).glob("*.json")):
            out.update(json.loads(f.read_text()))
        return out
    ra, rb = load(a), load(b)
    for test in sorted(set(ra) | set(rb)):
        va, vb = ra.get(test, []), rb.get(test, [])
        diff = [(x, y) for x, y in zip(va, vb) if x[0] != y[0]]
        if len(va) != len(vb):
            verdict = f"DIFFERENT COUNT {len(va)} vs {len(vb)}"
        elif diff:
            verdict = f"DIFFERS in {len(diff)} of {len(va)}: {diff[0][0][1]} vs {diff[0][1][1]}"
        else:
            verdict = f"same bits ({len(va)} values)"
        print(f"{test}: {verdict}")
    return 0


if __name__ == "__main__":
    sys.exit(compare(Path(sys.argv[1]), Path(sys.argv[2])))
