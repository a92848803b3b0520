"""Named channels of a MATLAB .mat file, read like ``exportfile.read_csv_columns`` reads a CSV.

MAT v4, v6 and v7 files are read with :func:`scipy.io.loadmat`; v7.3 files are HDF5 and
are read with h5py when it is installed. A channel is a numeric vector named by its
variable: ``s.a.b`` is field ``b`` of field ``a`` of the (scalar) struct ``s``, and
``m[k]`` is column ``k`` (0-based) of the matrix ``m``. Only numeric arrays are read:
nothing in the file can make code run (no pickle; MATLAB objects, function handles, text
and cells are refused as "not numeric"). Nothing outside the file is read either: a v7.3
variable that is an HDF5 external link (or a dangling soft link), stored in an external
file or virtual is refused, and each dataset's declared size is checked against the CSV
reader's limits before its data are read. Every problem is one :class:`RunFileError`
line that names the file, the variable and the fix.
"""
from __future__ import annotations

import difflib
import math
import re
from pathlib import Path

import numpy as np

from labrig.core.fileio import not_regular, size_within
from labrig.core.errors import RunFileError
from labrig.io import csvfile

#: a larger file is refused before reading (the same bound as csvfile.MAX_CSV_BYTES)
MAX_MAT_BYTES = 2_000_000_000
_HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
_SPEC = re.compile(r"([A-Za-z]\w*(?:\.[A-Za-z]\w*)*)(?:\[(\d+)\])?")
_NUMERIC = {"double", "single", "logical", "int8", "uint8", "int16", "uint16",
            "int32", "uint32", "int64", "uint64"}


def read_mat_columns(path: Path | str, columns: list[str]) -> dict[str, np.ndarray]:
    """Named numeric channels of a MAT file, each a 1-D float64 array of the same length.

    Parameters
    ----------
    path : Path or str
        A MATLAB v4, v6, v7 or v7.3 .mat file (v7.3 needs h5py).
    columns : list of str
        ``x``, ``struct.field.field`` or ``matrix[k]`` (column k, 0-based; a row or column
        vector is one column, so only ``[0]`` applies to it).

    Returns
    -------
    dict of str to numpy.ndarray
        Keyed by the names in `columns`.

    Raises
    ------
    RunFileError
        The file or a channel is missing, unreadable, not numeric, complex, shorter than
        two samples or not finite, or the channels differ in length.
    """
    path = Path(path)
    specs = [_parse(path, c) for c in columns]
    root, names = _load(path, list(dict.fromkeys(n.split(".")[0] for n, _ in specs)))
    out = {col: _channel(path, col, name, k, _lookup(path, root, names, col, name))
           for col, (name, k) in zip(columns, specs)}
    for col in columns[1:]:
        if len(out[col]) != len(out[columns[0]]):
            raise RunFileError(f"{path}: channels '{columns[0]}' ({len(out[columns[0]])} "
                               f"samples) and '{col}' ({len(out[col])} samples) differ in "
                               "length; save channels of the same recording")
    return out


def list_mat_variables(path: Path | str) -> list[str]:
    """Top-level variable names of a MAT file (any version), in file order, each struct
    followed by its fields (``s``, ``s.a``, ``s.b``); see :func:`read_mat_columns`."""
    root, names = _load(Path(path), None, read=False)
    out = []
    for name in names:
        out.append(name)
        if isinstance(root.get(name), dict):
            out += [f"{name}.{f}" for f in root[name]]
    return out


def _parse(path: Path, col: str) -> tuple[str, int | None]:
    m = _SPEC.fullmatch(col.strip())
    if m is None:
        raise RunFileError(f"{path}: '{col}' is not a channel name; write 'var', "
                           "'struct.field' or 'var[k]' for column k (0-based)")
    return m.group(1), None if m.group(2) is None else int(m.group(2))


def _load(path: Path, tops: list[str] | None, read: bool = True) -> tuple[dict, list[str]]:
    """(the variables `tops` as trees, all top-level names); `tops` None: the structs."""
    what = not_regular(path)
    if what:
        raise RunFileError(f"{path}: is {what}, not a data file; give a regular file")
    size = size_within(path, MAX_MAT_BYTES, RunFileError, "file not found",
                       lambda size: f"{size / 1e9:.1f} GB is more than labrig reads "
                                    f"({MAX_MAT_BYTES / 1e9:.0f} GB); save fewer or shorter "
                                    "channels")
    if size == 0:
        raise RunFileError(f"{path}: not a MAT file (the file is empty)")
    with path.open("rb") as fh:
        head = fh.read(520)
    # v7.3 is HDF5 behind a 512-byte MATLAB text header; scipy cannot read it
    if not (head.startswith(b"MATLAB 7.3") or _HDF5_MAGIC in (head[:8], head[512:520])):
        from scipy.io import loadmat, whosmat  # ~0.07 s to import; only a .mat import needs it
        try:
            whos = whosmat(str(path), appendmat=False)
            names = [n for n, _, _ in whos]
            if tops is None:
                tops = [n for n, _, cls in whos if cls == "struct"]
            with path.open("rb") as fh:  # struct_as_record=False: structs as attributes
                got = loadmat(fh, appendmat=False, struct_as_record=False,
                              variable_names=tops) if tops else {}
            return {k: _tree_v5(v) for k, v in got.items() if k in names}, names
        except NotImplementedError:
            pass  # scipy says v7.3 (HDF5) despite the header: read it as HDF5 below
        except Exception as exc:  # scipy raises many types for a damaged/foreign file
            if b"\0" not in head[:128]:  # a real header holds binary version bytes
                raise RunFileError(f"{path}: not a MAT file (it is text, e.g. a CSV "
                                   "renamed; import it as a CSV)") from None
            raise RunFileError(f"{path}: not a readable MAT file ({exc}); re-save it in "
                               "MATLAB with save(..., '-v7')") from None
    try:
        import h5py  # only a v7.3 (HDF5) file needs it, and it may be missing (below)
    except ImportError:
        raise RunFileError(f"{path}: the file is MATLAB v7.3 (HDF5); install h5py (pip "
                           "install h5py) or re-save it in MATLAB with save(..., '-v7')") from None
    try:
        with h5py.File(path, "r") as f:
            names = [k for k in f if not k.startswith("#")]  # #refs#, #subsystem#
            tops = names if tops is None else tops
            seen = {"bytes": 0, "groups": {}}  # the data declared so far, the structs walked
            return {t: _tree_h5(path, _h5_node(path, f, t, t), t, read, seen)
                    for t in tops if t in names}, names
    except OSError as exc:
        raise RunFileError(f"{path}: not a readable MATLAB v7.3 (HDF5) file ({exc}); "
                           "re-save it in MATLAB with save(..., '-v7')") from None


def _tree_v5(v):
    """A scipy value as a tree: dict (struct), ndarray (numeric) or str (what it is)."""
    # scipy.sparse and scipy.io: ~0.07 s to import; only a .mat import needs them
    from scipy import sparse
    from scipy.io import matlab as m
    if sparse.issparse(v):
        return "a sparse matrix (save full(x) instead)"
    # the MATLAB wrappers subclass ndarray: test them first
    if isinstance(v, m.MatlabFunction):
        return "a function handle"
    if isinstance(v, m.MatlabObject):
        return f"a MATLAB object of class '{v.classname}'"
    if isinstance(v, m.MatlabOpaque) or not isinstance(v, np.ndarray):
        return "a MATLAB object"
    if v.dtype.kind in "US":
        return "text (a char array)"
    if v.dtype.kind == "O" or v.dtype.names:
        if v.size and isinstance(v.flat[0], m.mat_struct):
            if v.size > 1:
                return f"a {'x'.join(map(str, v.shape))} struct array (not one struct)"
            return {f: _tree_v5(getattr(v.flat[0], f)) for f in v.flat[0]._fieldnames}
        return "a cell array"
    return v


def _tree_h5(path: Path, node, where: str, read: bool, seen: dict):
    """An HDF5 node as a tree like :func:`_tree_v5`, transposed back to MATLAB's shape.

    Nothing is read from another file: links out of the file (and dangling ones) are
    refused by :func:`_h5_node`, datasets stored in other files here; a dataset's declared
    size is checked before its data are read (`seen` holds the bytes declared so far and
    the structs walked, so a struct linked into itself is refused, not walked forever).
    """
    import h5py  # optional: only a v7.3 file reaches here, after _load imported it
    if isinstance(node, h5py.Group):
        first = seen["groups"].setdefault(node.id, where)
        if first != where:
            raise RunFileError(f"{path}: variable '{where}' is '{first}' again (a link "
                               "inside the file); save each struct once")
    if not isinstance(node, (h5py.Group, h5py.Dataset)):
        return "not numeric (an HDF5 named type)"
    cls = node.attrs.get("MATLAB_class", b"")
    cls = cls.decode() if isinstance(cls, bytes) else str(cls)
    if isinstance(node, h5py.Group):
        if "MATLAB_sparse" in node.attrs:
            return "a sparse matrix (save full(x) instead)"
        if cls in ("struct", ""):
            return {k: _tree_h5(path, _h5_node(path, node, k, f"{where}.{k}"), f"{where}.{k}",
                                read, seen) for k in node}
        return f"a MATLAB object of class '{cls}'"
    if node.is_virtual:
        raise RunFileError(f"{path}: variable '{where}' is a virtual dataset (its data come "
                           "from other files); labrig reads only the file it is given: save "
                           "the data themselves in this file")
    if node.external:
        raise RunFileError(f"{path}: variable '{where}' keeps its data in another file "
                           f"('{node.external[0][0]}'); labrig reads only the file it is "
                           "given: save the data themselves in this file")
    kinds = {"char": "text (a char array)", "cell": "a cell array",
             "function_handle": "a function handle"}
    if cls in kinds or (cls and cls not in _NUMERIC):
        return kinds.get(cls, f"a MATLAB object of class '{cls}'")
    if not read:
        return ""
    if node.attrs.get("MATLAB_empty", 0) or node.shape is None:  # MATLAB: the dimensions
        return np.zeros((0, 0))
    _check_declared(path, node, where, seen)
    if node.dtype.names and {"real", "imag"} <= set(node.dtype.names):
        raw = node[()]
        return np.asarray(raw["real"] + 1j * raw["imag"]).T
    if node.dtype.kind not in "biuf":
        return f"not numeric (HDF5 type {node.dtype})"
    return np.asarray(node[()]).T


def _h5_node(path: Path, group, name: str, where: str, soft: str = "", hops: int = 0):
    """``group[name]`` with every link on the way looked at before it is followed: a
    link to another file (``ExternalLink``) or to nothing (a dangling ``SoftLink``) is
    refused, as is a link of another kind; a soft link inside the file is followed."""
    import h5py  # optional: only a v7.3 file reaches here, after _load imported it
    node = group.file if name.startswith("/") else group
    for part in filter(None, name.split("/")):
        if part == ".":
            continue
        try:
            link = node.get(part, getlink=True) if isinstance(node, h5py.Group) else None
        except TypeError:   # h5py: "Unknown link type" (a user-defined link)
            raise RunFileError(f"{path}: variable '{where}' is a link of a kind labrig does "
                               "not follow; re-save the file in MATLAB with save(..., "
                               "'-v7')") from None
        if isinstance(link, h5py.ExternalLink):
            raise RunFileError(f"{path}: variable '{where}' is a link to another file "
                               f"('{link.filename}', object '{link.path}'); labrig reads "
                               "only the file it is given: save the data themselves in "
                               "this file")
        if isinstance(link, h5py.SoftLink):
            if hops >= 16:
                raise RunFileError(f"{path}: variable '{where}' is a chain of more than 16 "
                                   "links; re-save the file in MATLAB with save(..., '-v7')")
            node = _h5_node(path, node, link.path, where, link.path, hops + 1)
        elif isinstance(link, h5py.HardLink):
            node = node.get(part)
        else:
            raise RunFileError(f"{path}: variable '{where}' is a link to '{soft or name}', "
                               "which is not in the file; re-save the file in MATLAB with "
                               "save(..., '-v7')")
    return node


def _check_declared(path: Path, node, where: str, seen: dict) -> None:
    """Refuse a dataset whose declared shape is more than labrig reads in one run (the
    CSV reader's limits: csvfile.MAX_ROWS samples a channel, MAX_MAT_BYTES in all),
    from the file's metadata, before any of its data is read or allocated."""
    samples = max(node.shape, default=1)
    if samples > csvfile.MAX_ROWS:
        raise RunFileError(f"{path}: variable '{where}' declares {samples:,} samples, more "
                           f"than labrig reads in one run ({csvfile.MAX_ROWS:,}); split the "
                           "recording into shorter files")
    nbytes = math.prod(node.shape) * node.dtype.itemsize
    seen["bytes"] += nbytes
    if seen["bytes"] > MAX_MAT_BYTES:
        what = f"declares {nbytes / 1e9:.1f} GB" if nbytes > MAX_MAT_BYTES else \
            f"brings the data read to {seen['bytes'] / 1e9:.1f} GB"
        raise RunFileError(f"{path}: variable '{where}' {what}, more than labrig reads in one "
                           f"run ({MAX_MAT_BYTES / 1e9:.0f} GB); save fewer or shorter "
                           "channels")


def _names(items) -> str:
    items = list(items)
    more = f", ... ({len(items)} in all)" if len(items) > 20 else ""
    return ", ".join(items[:20]) + more if items else "nothing"


def _lookup(path: Path, root: dict, names: list[str], col: str, name: str):
    node, where = root, ""
    for part in name.split("."):
        if not isinstance(node, dict):
            what = node if isinstance(node, str) else "a numeric array"
            raise RunFileError(f"{path}: variable '{col}' not found: '{where}' is {what}, "
                               "not a struct")
        if part not in node:
            have = names if not where else list(node)
            close = difflib.get_close_matches(part, have, n=1, cutoff=0.6)
            hint = f" (did you mean '{where + '.' if where else ''}{close[0]}'?)" if close else ""
            what = f"struct '{where}' has fields" if where else "the file has"
            raise RunFileError(f"{path}: variable '{col}' not found{hint}; {what} "
                               f"{_names(have)}")
        node, where = node[part], f"{where}.{part}" if where else part
    return node


def _channel(path: Path, col: str, name: str, k: int | None, val) -> np.ndarray:
    if isinstance(val, dict):
        val = f"a struct (name a field, e.g. '{name}.{next(iter(val), 'field')}')"
    if isinstance(val, str):
        raise RunFileError(f"{path}: variable '{name}' is {val}, not numeric; save each "
                           "channel as a numeric vector")
    if np.iscomplexobj(val):
        raise RunFileError(f"{path}: variable '{name}' is complex; save real({name}) and "
                           f"imag({name}) as separate channels")
    if val.size == 0:
        raise RunFileError(f"{path}: variable '{name}' is empty")
    if val.ndim > 2:
        raise RunFileError(f"{path}: variable '{name}' is a {'x'.join(map(str, val.shape))}"
                           " array; save one channel per variable")
    arr = val.reshape(-1, 1) if val.ndim < 2 or val.shape[0] == 1 else val  # vector: 1 column
    rows, ncols = arr.shape
    if k is not None and k >= ncols:
        raise RunFileError(f"{path}: '{col}' asks for column {k} but '{name}' is "
                           f"{rows}x{ncols} (columns 0..{ncols - 1}, 0-based)")
    if k is None and ncols > 1:
        rows_hint = f", or save it transposed ({name}.') if the channels are rows" \
            if rows < ncols else ""
        raise RunFileError(f"{path}: variable '{name}' is a {rows}x{ncols} matrix, not one "
                           f"channel; name a column as '{name}[k]' (k = 0..{ncols - 1}, "
                           f"0-based) or save one channel per variable{rows_hint}")
    x = arr[:, k or 0].astype(np.float64)
    if x.size < 2:
        raise RunFileError(f"{path}: variable '{col}' has only one sample; a channel needs "
                           "at least two")
    bad = ~np.isfinite(x)
    if bad.any():
        i = int(np.argmax(bad))
        raise RunFileError(f"{path}: variable '{col}' has a non-finite value ({x[i]}) at "
                           f"index {i} (0-based); fill or trim it before importing")
    return x
