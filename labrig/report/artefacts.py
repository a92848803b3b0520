"""The JSON artefacts of the earlier stages, validated once where the report reads them.

``analysis.json``, ``identify_all.json`` (and ``model0.json``'s fit record),
``diagnosis.json`` and ``ladder.json`` are parsed into their documents (each defined
once, beside the result that writes it: :mod:`labrig.analysis.doc`,
:mod:`labrig.identification.doc`, :mod:`labrig.diagnosis.results.docs`); a file that does not fit is
ignored with a note on the page, never half-used. The documents are lax about numbers
(an int is a float, ``null`` where a value may be missing) but every key the page reads
has its type. Where the stage has a result object, the record turns into it
(``AnalysisDoc.result()``, ``DiagnosisDoc.result()``, ``LadderDoc.result()``), so the page
renders the same ``table_rows()`` as the CLI.
"""
from __future__ import annotations

import json
from pathlib import Path

from pydantic import ValidationError

from labrig.core.schemas import MAX_JSON_BYTES, JsonDoc, describe
from labrig.verbs.types import (AnalysisDoc, DiagnosisDoc, IdentifyAllDoc,  # noqa: F401
                                IdentRecord, LadderDoc, Regimes)  # (the documents the report reads)


# -- reading --------------------------------------------------------------------------

#: the one-line reasons the page has always given for the two shapes a stage's file
#: is most often wrong in: (schema, key, only when the key itself is wrong)
_REASONS = {(DiagnosisDoc, "regimes"): ("no 'regimes' key", True),
            (LadderDoc, "steps"): ("'steps' is not a list of steps", False)}


def read_artefact(path: Path, schema: type[JsonDoc], notes: list):
    """``path`` validated as ``schema``, or None when it is absent or does not fit
    (then a note on the page says why).

    Parameters
    ----------
    path : Path
        The artefact in the work folder.
    schema : type
        One of the document models above.
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
        return schema.model_validate(data)
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
