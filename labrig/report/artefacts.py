"""The JSON artefacts of the earlier stages, validated once where the report reads them.

``analysis.json``, ``diagnosis.json`` and ``ladder.json`` are read back into the results
that wrote them (``AnalysisResult.from_json``, ``Diagnosis.from_json``,
``Ladder.from_json``: each result declared once, :mod:`labrig.core.record`), so the page
renders the same ``table_rows()`` as the CLI; ``identify_all.json`` (and ``model0.json``'s
fit record) into the fit's record (:mod:`labrig.identification.doc`). A file that does not
fit is ignored with a note on the page, never half-used. The reading is lax about numbers
(an int is a float, ``null`` where a value may be missing) but every key the page reads
has its type.
"""
from __future__ import annotations

import json
from pathlib import Path

from pydantic import ValidationError

from labrig.core.schemas import MAX_JSON_BYTES, describe
from labrig.verbs.types import Diagnosis, Ladder


# -- reading --------------------------------------------------------------------------

#: the one-line reasons the page has always given for the two shapes a stage's file
#: is most often wrong in: (schema, key, only when the key itself is wrong)
_REASONS = {(Diagnosis, "regimes"): ("no 'regimes' key", True),
            (Ladder, "steps"): ("'steps' is not a list of steps", False)}


def read_artefact(path: Path, schema: type, notes: list):
    """``path`` validated as ``schema``, or None when it is absent or does not fit
    (then a note on the page says why).

    Parameters
    ----------
    path : Path
        The artefact in the work folder.
    schema : type
        A result declared as a :class:`~labrig.core.record.Record` (read with its
        ``from_json``) or the fit's record (a pydantic model).
    notes : list of str
        Receives one sentence per ignored file.
    """
    if not path.is_file():
        return None
    try:
        if path.stat().st_size > MAX_JSON_BYTES:
            raise ValueError(f"larger than {MAX_JSON_BYTES // 2 ** 20} MiB")
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError, RecursionError) as exc:
        notes.append(f"{path} was ignored: not valid JSON ({exc}).")
        return None
    if not isinstance(data, dict):
        notes.append(f"{path} was ignored: not a JSON object.")
        return None
    try:
        read = getattr(schema, "from_json", None) or schema.model_validate
        return read(data)
    except ValidationError as exc:
        loc = exc.errors()[0]["loc"]
        why, whole = _REASONS.get((schema, loc[0] if loc else None), (None, False))
        if why is None or (whole and len(loc) > 1):
            why = describe(schema, exc)
        notes.append(f"{path} was ignored: {why}.")
        return None
    except RecursionError:
        notes.append(f"{path} was ignored: nested too deeply.")
        return None
