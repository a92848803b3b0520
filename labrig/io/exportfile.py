"""A foreign export to import (``labrig import``): a scope's or logger's CSV, with its
separator and decimal mark found (csv.Sniffer), a UTF-8 BOM dropped, a preamble and unit
rows skipped, read with the run CSV's row/column errors (the file's own line numbers) and
memory bounds (docs/design.md, 'The CSV')."""
from __future__ import annotations

import csv
import difflib
import re
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from labrig.core.errors import RunFileError
from labrig.core.fileio import not_regular
from labrig.io.csvfile import (CHUNK_ROWS, MAX_CSV_BYTES, MAX_ROWS, cell_problem,
                               parse_error)

#: the header row of an export is searched for in its first lines (a scope's preamble
#: comes before it); ``--skip-rows N`` names it when it comes later
HEADER_SEARCH_LINES = 100
#: the search, the separator's sniffing and the unit-row check read at most this much
HEAD_BYTES = 4_000_000
#: lines between the header and the data that may be unit rows or blank
MAX_UNIT_LINES = 10
#: the separators an export may use: comma, semicolon (a European spreadsheet's), tab,
#: and runs of spaces (a last resort, when the others do not split the header)
SEPARATORS = (",", ";", "\t", " ")
_DECIMAL_COMMA = re.compile(r"[+-]?(\d+,\d*|,\d+)([eE][+-]?\d+)?")


@dataclass(frozen=True)
class CsvLayout:
    """Where the numbers of an export are: its separator (``" "`` for runs of spaces),
    decimal mark, header row and first data row (the file's 1-based line numbers), the
    header's names, the first data row's field count and the unit row under the header
    (empty without one)."""

    sep: str
    decimal: str
    header_line: int
    first_row: int
    header: tuple[str, ...]
    nfields: int
    unit_row: tuple[str, ...] = ()

    def unit(self, column: str) -> str:
        """The unit row's cell under ``column`` (``""`` without a unit row)."""
        i = self.header.index(column)
        return self.unit_row[i] if i < len(self.unit_row) else ""


def _split(line: str, sep: str) -> list[str]:
    """One line's cells (stripped, without a BOM), as pandas will split it."""
    if sep == " ":
        return line.replace("\ufeff", "").split()
    try:
        cells = next(csv.reader([line], delimiter=sep, skipinitialspace=True), [])
    except csv.Error:
        cells = line.split(sep)
    return [c.replace("\ufeff", "").strip() for c in cells]


def _head(path: Path, need: int) -> tuple[list[str], bool]:
    """The first ``need`` lines of ``path`` (within its first HEAD_BYTES) without their
    line ends (``\\n``, ``\\r\\n`` or a lone ``\\r``, as pandas counts lines), and whether the
    file ends within them."""
    buf = b""
    ended = False
    lf = cr = 0
    with path.open("rb") as fh:
        while len(buf) < HEAD_BYTES and max(lf, cr) <= need:
            chunk = fh.read(min(1 << 16, HEAD_BYTES - len(buf)))
            if not chunk:
                ended = True
                break
            buf += chunk
            lf, cr = lf + chunk.count(b"\n"), cr + chunk.count(b"\r")
        ended = ended or not fh.read(1)
    if not ended:  # a line cut by the byte limit is not a line
        buf = buf[:max(buf.rfind(b"\n"), buf.rfind(b"\r")) + 1]
    try:
        text = buf.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise RunFileError(f"{path}: not a readable CSV (not UTF-8 text)") from None
    lines = re.split(r"\r\n|\r|\n", text)
    if lines and not lines[-1]:
        lines.pop()  # after the last line end
    if len(lines) > need:
        lines, ended = lines[:need], False
    return lines, ended


def _shown(cells: list[str]) -> str:
    """Header cells for a one-line message (control characters escaped)."""
    return ", ".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii")
                     for c in cells)


def _sniff(lines: list[str]) -> str | None:
    """The separator csv.Sniffer finds in ``lines`` (comma, semicolon or tab; runs of
    spaces if none of those), or None."""
    sample = "\n".join(ln for ln in lines if ln.strip())[:65536]
    for allowed in (",;\t", " "):
        try:
            return csv.Sniffer().sniff(sample, delimiters=allowed).delimiter
        except Exception:  # csv.Error, or worse: only a hint, the header search decides
            continue
    return None


def _is_number(cell: str, sep: str) -> bool:
    text = cell.strip().replace(",", ".") if sep != "," else cell.strip()
    try:
        float(text)
    except ValueError:
        return False
    return True


def _layout_at(path: Path, lines: list[str], ended: bool, i: int, sep: str,
               wanted: list[str]) -> CsvLayout | None:
    """The layout of an export whose header is line ``i`` split at ``sep``, or None when
    the rows under it do not split at ``sep`` (the header and the data disagree)."""
    header = _split(lines[i], sep)
    for c in wanted:
        if header.count(c) > 1:
            raise RunFileError(f"{path}: column '{c}' appears twice in the header; "
                               "rename one of them")
    idx = [header.index(c) for c in wanted]
    unit_row: tuple[str, ...] = ()
    end = min(len(lines), i + 2 + MAX_UNIT_LINES)
    for j in range(i + 1, end):
        if not lines[j].strip():
            continue
        row = _split(lines[j], sep)
        if len(row) == 1 and len(header) > 1:
            return None
        if any(k < len(row) and _is_number(row[k], sep) for k in idx):
            break  # the first data row
        unit_row = unit_row or tuple(row)  # a unit row (Volt, (ms), second, Sequence)
    else:
        if end == len(lines) and ended:
            raise RunFileError(f"{path}: fewer than two data rows")
        raise RunFileError(f"{path}: no line of numbers in the {MAX_UNIT_LINES + 1} lines "
                           f"after the header (line {i + 1}); the data must follow the "
                           "header, with at most a unit row and blank lines between")
    short = [c for c, k in zip(wanted, idx) if k >= len(row)]
    if short:
        raise RunFileError(f"{path}: row {j + 1}, column '{short[0]}': "
                           f"{cell_problem(None)}; every sample must be a finite number")
    decimal = "."
    if sep != ",":
        data = [_split(ln, sep) for ln in lines[j:j + 50] if ln.strip()]
        if any(k < len(r) and _DECIMAL_COMMA.fullmatch(r[k]) for r in data for k in idx):
            decimal = ","
    return CsvLayout(sep=sep, decimal=decimal, header_line=i + 1, first_row=j + 1,
                     header=tuple(header), nfields=len(row), unit_row=unit_row)


def _no_header(path: Path, lines: list[str], ended: bool, wanted: list[str],
               window: list[int], sniffed: str | None, skip_rows: int | None,
               rejected: tuple[int, str] | None,
               best: tuple[int, int, str] | None) -> RunFileError:
    """The one line that says why no header naming ``wanted`` was found."""
    if rejected is not None:  # the header splits, its rows do not: one separator each
        i, held = rejected
        below = next((ln for ln in lines[i + 1:] if ln.strip()), "")
        sep = next((s for s in SEPARATORS if s != held and len(_split(below, s)) > 1), ",")
        return RunFileError(f"{path}: the header did not split into columns with {sep!r}, "
                            f"the separator of the rows under it (it holds {held!r}); save "
                            f"the export with one separator throughout, or fix line {i + 1}")
    if skip_rows is not None:
        i = skip_rows
        if not lines[i].strip():
            return RunFileError(f"{path}: `skip_rows={skip_rows}`: line {i + 1} is blank; give "
                                "the number of lines before the header row")
        sep = max(dict.fromkeys([sniffed or ",", *SEPARATORS]),
                  key=lambda s: len(_split(lines[i], s)))
    elif best is not None:
        _, i, sep = best
    else:
        i = next(k for k in window if lines[k].strip())
        sep = sniffed or ","
    cells = _split(lines[i], sep)
    held = [s for s in (";", "\t") if s != sep and s in lines[i]]
    if held or (len(cells) == 1 and len(wanted) > 1):
        what = f"it holds {held[0]!r}" if held else "nor with ';', a tab or spaces"
        return RunFileError(f"{path}: the header did not split into columns with {sep!r} "
                            f"({what}); save the export with ',' or ';' between columns "
                            "(one separator throughout) and the `mapping` names in its header")
    missing = next(c for c in wanted if c not in cells)
    close = difflib.get_close_matches(missing, cells, n=1, cutoff=0.6)
    hint = f" (did you mean '{close[0]}'?)" if close else ""
    where = "the header" if i == 0 else f"the header (line {i + 1})"
    text = f"{path}: column '{missing}' not found{hint}; {where} has {_shown(cells)}"
    if skip_rows is not None:
        text += (f"; `skip_rows={skip_rows}` makes line {i + 1} the header: give the number "
                 "of lines before the header row")
    elif best is None and (len(lines) > len(window) or not ended):
        text += (f"; no line of the first {len(window)} names {', '.join(wanted)}: give "
                 "`skip_rows=N`, the number of lines before the header row")
    return RunFileError(text)


def scan_export(path: Path | str, columns: list[str],
                skip_rows: int | None = None) -> CsvLayout:
    """Find where the numbers of a foreign export are: the header is the first line (of
    the first HEADER_SEARCH_LINES, or line ``skip_rows + 1``) that names every one of
    ``columns``, split at the separator csv.Sniffer finds (else a comma, a semicolon, a
    tab or runs of spaces, whichever names them and splits the rows under it too); unit
    rows and blank lines under it are skipped; numbers with a decimal comma under a
    separator that is not a comma read as such."""
    path = Path(path)
    size = path.stat().st_size
    if size > MAX_CSV_BYTES:
        raise RunFileError(f"{path}: {size / 1e9:.1f} GB is more than labrig reads in one "
                           f"run ({MAX_CSV_BYTES / 1e9:.0f} GB); split the recording")
    if skip_rows is not None and skip_rows < 0:
        raise RunFileError(f"`skip_rows`: {skip_rows} is not a number of lines; give 0 or "
                           "more, the number of lines before the header row")
    top = HEADER_SEARCH_LINES if skip_rows is None else skip_rows + 1
    lines, ended = _head(path, top + MAX_UNIT_LINES + 50)
    if ended and not any(ln.strip() for ln in lines):
        raise RunFileError(f"{path}: file is empty")
    if skip_rows is not None and skip_rows >= len(lines):
        where = f"{path} has only {len(lines)} lines" if ended else \
            f"the header must be within the first {HEAD_BYTES / 1e6:.0f} MB of {path}"
        raise RunFileError(f"`skip_rows={skip_rows}`: {where}; give the number of lines "
                           "before the header row")
    window = [skip_rows] if skip_rows is not None else list(range(min(top, len(lines))))
    if skip_rows is None and not any(lines[i].strip() for i in window):
        raise RunFileError(f"{path}: no header in the first {top} lines (they "
                           f"are blank, or longer than {HEAD_BYTES / 1e6:.0f} MB); give "
                           "`skip_rows=N`, the number of lines before the header row")
    wanted = list(dict.fromkeys(columns))
    sniffed = _sniff(lines[window[0]:])
    rejected = best = None
    for sep in dict.fromkeys([sniffed or ",", *SEPARATORS]):
        for i in window:
            if not lines[i].strip():
                continue
            cells = _split(lines[i], sep)
            have = sum(c in cells for c in wanted)
            if have == len(wanted):
                layout = _layout_at(path, lines, ended, i, sep, wanted)
                if layout is not None:
                    return layout
                rejected = rejected or (i, sep)
            elif have and (best is None or have > best[0]):
                best = (have, i, sep)
    raise _no_header(path, lines, ended, wanted, window, sniffed, skip_rows, rejected, best)


def _export_options(layout: CsvLayout) -> dict:
    return dict(header=None, skiprows=layout.first_row - 1, encoding="utf-8-sig",
                sep=r"\s+" if layout.sep == " " else layout.sep, skipinitialspace=True,
                keep_default_na=False, engine="c")


def _locate_export_cell(path: Path, layout: CsvLayout, idx: dict[str, int]) -> RunFileError:
    """Stream the export as text to name the first cell of a mapped column that is not a
    finite number, by the file's own line number."""
    row0 = layout.first_row
    try:
        for chunk in pd.read_csv(path, dtype=str, skip_blank_lines=False, chunksize=CHUNK_ROWS,
                                 **_export_options(layout)):
            cells = chunk.apply(lambda col: col.str.strip())
            blank = (cells.fillna("") == "").all(axis=1).to_numpy()
            first = None
            for c, k in idx.items():
                col = cells[k] if k in cells else pd.Series([None] * len(chunk), dtype=object)
                text = col
                dot = np.zeros(len(chunk), bool)
                if layout.decimal == ",":
                    dot = col.str.contains(".", regex=False).fillna(False).to_numpy(bool)
                    text = col.str.replace(",", ".", regex=False)
                values = pd.to_numeric(text, errors="coerce").to_numpy(float)
                bad = (~np.isfinite(values) | dot) & ~blank
                if bad.any() and (first is None or int(np.argmax(bad)) < first[0]):
                    i = int(np.argmax(bad))
                    problem = (f"{col.iloc[i]!r} has a decimal point where this file's "
                               "numbers have a decimal comma") if dot[i] else \
                        cell_problem(col.iloc[i])
                    first = (i, c, problem)
            if first is not None:
                i, c, problem = first
                return RunFileError(f"{path}: row {row0 + i}, column '{c}': {problem}; every "
                                    "sample must be a finite number")
            row0 += len(chunk)
    except (pd.errors.ParserError, ValueError) as exc:
        return parse_error(path, exc, layout.nfields)
    return RunFileError(f"{path}: a cell is not a finite number")


def read_export(path: Path | str, columns: list[str],
                skip_rows: int | None = None) -> tuple[dict[str, np.ndarray], CsvLayout]:
    """Named numeric columns of a foreign CSV (an export to import) and where they were
    found (:func:`scan_export`), with the same row/column errors (the file's own line
    numbers) and memory bounds as a run file."""
    path = Path(path)
    what = not_regular(path)
    if what:
        raise RunFileError(f"{path}: is {what}, not a data file; give a regular file")
    if not path.is_file():
        raise RunFileError(f"{path}: file not found")
    layout = scan_export(path, columns, skip_rows)
    idx = {c: layout.header.index(c) for c in columns}
    dtypes = defaultdict(lambda: str, {k: "float64" for k in idx.values()})
    try:
        raw = pd.read_csv(path, dtype=dtypes, na_values=[""], nrows=MAX_ROWS + 1,
                          decimal=layout.decimal, **_export_options(layout))
    except pd.errors.ParserError as exc:
        raise parse_error(path, exc, layout.nfields) from None
    except UnicodeDecodeError:
        raise RunFileError(f"{path}: not a readable CSV (not UTF-8 text)") from None
    except ValueError:  # a cell that is not a number
        raise _locate_export_cell(path, layout, idx) from None
    if len(raw) > MAX_ROWS:
        raise RunFileError(f"{path}: more than {MAX_ROWS:,} rows; labrig reads at most that "
                           "many samples in one run: split the recording")
    out = {}
    for c, k in idx.items():
        values = raw[k].to_numpy(float) if k in raw else np.full(len(raw), np.nan)
        if not np.isfinite(values).all():
            raise _locate_export_cell(path, layout, idx)
        out[c] = values
    if len(raw) < 2:
        raise RunFileError(f"{path}: fewer than two data rows")
    return out, layout


def read_csv_columns(path: Path | str, columns: list[str],
                     skip_rows: int | None = None) -> dict[str, np.ndarray]:
    """Named numeric columns of a foreign CSV (an export to import): :func:`read_export`
    without the layout."""
    return read_export(path, columns, skip_rows)[0]
