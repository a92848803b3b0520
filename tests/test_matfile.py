"""MAT files (labrig.io.matfile): channels by name from v4/v5/v7 and v7.3 (HDF5) files; every
bad case is one RunFileError line naming the file and the variable."""
import sys

import numpy as np
import pytest
import scipy.io as sio
from scipy.io.matlab import MatlabObject

from labrig.io import matfile
from labrig.core.errors import RunFileError
from labrig.io.matfile import list_mat_variables, read_mat_columns

RNG_SEED = 20240611


@pytest.fixture
def rng():
    return np.random.default_rng(RNG_SEED)


def save_v5(path, variables, **kw):
    sio.savemat(path, variables, **kw)
    return path


def write_v73(path, variables, header=True):
    """A v7.3 file laid out as MATLAB writes it: HDF5 behind a 512-byte text header,
    arrays transposed (an n x 1 column is HDF5 shape (1, n)), MATLAB_class attributes,
    structs as groups."""
    h5py = pytest.importorskip("h5py")
    classes = {"f": "double", "b": "logical", "i": "int32", "u": "uint16"}

    def put(group, name, value):
        if isinstance(value, dict):
            g = group.create_group(name)
            g.attrs["MATLAB_class"] = np.bytes_("struct")
            for k, v in value.items():
                put(g, k, v)
            return
        if isinstance(value, str):
            ds = group.create_dataset(name, data=np.array([[ord(c) for c in value]],
                                                         dtype=np.uint16).T)
            ds.attrs["MATLAB_class"] = np.bytes_("char")
            return
        a = np.asarray(value)
        a = a.reshape(-1, 1) if a.ndim < 2 else a            # MATLAB keeps two dimensions
        if a.dtype.kind == "c":
            data = np.empty(a.shape, dtype=[("real", "<f8"), ("imag", "<f8")])
            data["real"], data["imag"] = a.real, a.imag
            a, cls = data, "double"
        else:
            cls = classes[a.dtype.kind]
        ds = group.create_dataset(name, data=a.T)             # MATLAB's column-major order
        ds.attrs["MATLAB_class"] = np.bytes_(cls)

    with h5py.File(path, "w", userblock_size=512 if header else 0) as f:
        for name, value in variables.items():
            put(f, name, value)
    if header:
        text = (b"MATLAB 7.3 MAT-file, Platform: GLNXA64, "
                b"Created on: Tue Jun 11 2024 HDF5 schema 1.00 .")
        with open(path, "r+b") as fh:
            fh.write(text.ljust(116) + b"\0" * 8 + b"\x00\x02IM")
    return path


# -- v4 / v5 / v7 ---------------------------------------------------------------------

def test_row_and_column_vectors(tmp_path, rng):
    t = np.arange(200) / 1000.0
    u = rng.normal(size=200)
    path = save_v5(tmp_path / "a.mat", {"t": t[None, :], "u": u[:, None],
                                        "n": np.arange(200, dtype=np.int16),
                                        "on": (u > 0)})
    got = read_mat_columns(path, ["t", "u", "n", "on"])
    assert list(got) == ["t", "u", "n", "on"]
    for v in got.values():
        assert v.dtype == np.float64 and v.shape == (200,)
    np.testing.assert_array_equal(got["t"], t)
    np.testing.assert_array_equal(got["u"], u)
    np.testing.assert_array_equal(got["n"], np.arange(200))
    np.testing.assert_array_equal(got["on"], (u > 0).astype(float))


def test_compressed_and_v4(tmp_path, rng):
    x = rng.normal(size=50)
    for name, kw in (("c.mat", {"do_compression": True}), ("v4.mat", {"format": "4"})):
        got = read_mat_columns(save_v5(tmp_path / name, {"x": x}, **kw), ["x"])
        np.testing.assert_array_equal(got["x"], x)


def test_struct_fields(tmp_path, rng):
    a, b = rng.normal(size=30), rng.normal(size=30)
    path = save_v5(tmp_path / "s.mat", {"rec": {"sig": {"u": a}, "y": b, "note": "bench"},
                                        "t": np.arange(30.0)})
    got = read_mat_columns(path, ["rec.sig.u", "rec.y", "t"])
    np.testing.assert_array_equal(got["rec.sig.u"], a)
    np.testing.assert_array_equal(got["rec.y"], b)
    assert list_mat_variables(path) == ["rec", "rec.sig", "rec.y", "rec.note", "t"]


def test_matrix_column_pick(tmp_path, rng):
    m = rng.normal(size=(40, 3))
    path = save_v5(tmp_path / "m.mat", {"data": m, "v": m[:, 0]})
    got = read_mat_columns(path, ["data[0]", "data[2]", "v[0]"])
    np.testing.assert_array_equal(got["data[0]"], m[:, 0])
    np.testing.assert_array_equal(got["data[2]"], m[:, 2])
    np.testing.assert_array_equal(got["v[0]"], m[:, 0])


# -- v7.3 (HDF5) --------------------------------------------------------------------

@pytest.mark.parametrize("header", [True, False])
def test_v73(tmp_path, rng, header):
    pytest.importorskip("h5py")
    u, y, m = rng.normal(size=60), rng.normal(size=60), rng.normal(size=(60, 2))
    path = write_v73(tmp_path / "h.mat", {"u": u, "rec": {"y": y, "k": np.arange(60)},
                                          "m": m, "row": u[None, :]}, header=header)
    if header:
        assert path.read_bytes().startswith(b"MATLAB 7.3 MAT-file")
    got = read_mat_columns(path, ["u", "rec.y", "rec.k", "m[1]", "row"])
    np.testing.assert_array_equal(got["u"], u)
    np.testing.assert_array_equal(got["rec.y"], y)
    np.testing.assert_array_equal(got["rec.k"], np.arange(60.0))
    np.testing.assert_array_equal(got["m[1]"], m[:, 1])      # the transpose is undone
    np.testing.assert_array_equal(got["row"], u)
    assert list_mat_variables(path) == ["m", "rec", "rec.k", "rec.y", "row", "u"]


def test_v73_without_h5py(tmp_path, monkeypatch):
    path = tmp_path / "h.mat"
    path.write_bytes(b"MATLAB 7.3 MAT-file, Platform: GLNXA64".ljust(512, b"\0") + b"x" * 64)
    monkeypatch.setitem(sys.modules, "h5py", None)            # import h5py -> ImportError
    with pytest.raises(RunFileError) as e:
        read_mat_columns(path, ["u"])
    msg = str(e.value)
    assert str(path) in msg and "v7.3" in msg and "pip install h5py" in msg
    assert "save(..., '-v7')" in msg and "\n" not in msg


# -- errors -------------------------------------------------------------------------

X = np.linspace(0.0, 1.0, 20)


def _v5(variables):
    return lambda p: save_v5(p, variables)


def _text(p):
    p.write_text("t,u\n0,1\n0.001,2\n")
    return p


def _empty(p):
    p.write_bytes(b"")
    return p


def _obj(p):
    return save_v5(p, {"o": MatlabObject(np.array([[(X,)]], dtype=[("f", object)]), "myclass")})


ERRORS = [
    ("not_mat", _text, ["u"], ["not a MAT file", "CSV"]),
    ("empty_file", _empty, ["u"], ["not a MAT file", "empty"]),
    ("missing", _v5({"speed": X, "u": X}), ["sped"], ["'sped' not found", "did you mean 'speed'",
                                                      "speed, u"]),
    ("missing_field", _v5({"s": {"tacho": X}}), ["s.tach"], ["'s.tach' not found",
                                                            "did you mean 's.tacho'"]),
    ("not_struct", _v5({"s": X}), ["s.a"], ["'s.a' not found", "not a struct"]),
    ("text", _v5({"u": "hello"}), ["u"], ["'u' is text", "not numeric"]),
    ("cell", _v5({"u": np.array([X, "a"], dtype=object)}), ["u"], ["'u' is a cell array"]),
    ("struct_leaf", _v5({"s": {"a": X}}), ["s"], ["'s' is a struct", "'s.a'"]),
    ("object", _obj, ["o"], ["'o' is a MATLAB object of class 'myclass'", "not numeric"]),
    ("complex", _v5({"u": X + 1j}), ["u"], ["'u' is complex", "real(u)"]),
    ("empty", _v5({"u": np.zeros((0, 1))}), ["u"], ["'u' is empty"]),
    ("one_sample", _v5({"u": 3.0}), ["u"], ["'u' has only one sample"]),
    ("matrix", _v5({"m": np.ones((20, 3))}), ["m"], ["'m' is a 20x3 matrix", "'m[k]'",
                                                     "k = 0..2"]),
    ("matrix_rows", _v5({"m": np.ones((3, 20))}), ["m"], ["3x20 matrix", "m.'"]),
    ("column_range", _v5({"m": np.ones((20, 3))}), ["m[3]"], ["'m[3]' asks for column 3",
                                                             "columns 0..2"]),
    ("lengths", _v5({"a": X, "b": X[:-1]}), ["a", "b"], ["'a' (20 samples)",
                                                         "'b' (19 samples)", "differ"]),
    ("nan", _v5({"u": np.where(np.arange(20) == 7, np.nan, X)}), ["u"],
     ["'u' has a non-finite value (nan) at index 7"]),
    ("inf", _v5({"u": np.where(np.arange(20) == 3, -np.inf, X)}), ["u"],
     ["'u' has a non-finite value (-inf) at index 3"]),
    ("bad_name", _v5({"u": X}), ["u(:,2)"], ["'u(:,2)' is not a channel name", "var[k]"]),
]


def _assert_refused(path, cols, parts):
    """Reading ``cols`` from ``path`` fails with one line that starts with the path and
    holds each of ``parts``."""
    with pytest.raises(RunFileError) as e:
        read_mat_columns(path, cols)
    msg = str(e.value)
    assert msg.startswith(f"{path}: ") and "\n" not in msg
    for part in parts:
        assert part in msg


@pytest.mark.parametrize("case,make,cols,parts", ERRORS, ids=[e[0] for e in ERRORS])
def test_errors(tmp_path, case, make, cols, parts):
    path = make(tmp_path / f"{case}.mat")
    _assert_refused(path, cols, parts)


def test_missing_file_and_size_limit(tmp_path, monkeypatch):
    with pytest.raises(RunFileError, match="file not found"):
        read_mat_columns(tmp_path / "nope.mat", ["u"])
    path = save_v5(tmp_path / "big.mat", {"u": X})
    monkeypatch.setattr(matfile, "MAX_MAT_BYTES", 100)
    with pytest.raises(RunFileError, match="more than labrig reads") as e:
        read_mat_columns(path, ["u"])
    assert str(e.value).startswith(f"{path}: ")


V73_ERRORS = [
    ("text", {"u": "volts"}, ["u"], ["'u' is text"]),
    ("complex", {"u": X + 2j}, ["u"], ["'u' is complex"]),
    ("nan", {"u": np.where(np.arange(20) == 5, np.nan, X)}, ["u"], ["at index 5"]),
    ("missing", {"speed": X, "s": {"a": X}}, ["sped"], ["did you mean 'speed'", "s, speed"]),
    ("missing_field", {"s": {"tacho": X}}, ["s.tach"], ["did you mean 's.tacho'"]),
    ("matrix", {"m": np.ones((20, 3))}, ["m"], ["'m' is a 20x3 matrix"]),
    ("lengths", {"a": X, "b": X[:5]}, ["a", "b"], ["'b' (5 samples)"]),
]


@pytest.mark.parametrize("case,variables,cols,parts", V73_ERRORS, ids=[e[0] for e in V73_ERRORS])
def test_v73_errors(tmp_path, case, variables, cols, parts):
    path = write_v73(tmp_path / f"{case}.mat", variables)
    _assert_refused(path, cols, parts)


def test_v73_matlab_kinds(tmp_path):
    """Cells (references), objects and empties as MATLAB writes them are refused."""
    h5py = pytest.importorskip("h5py")
    path = tmp_path / "k.mat"
    with h5py.File(path, "w") as f:
        f.create_dataset("x", data=X[None, :]).attrs["MATLAB_class"] = np.bytes_("double")
        refs = f.create_dataset("c", (1, 1), dtype=h5py.ref_dtype)
        refs[0, 0] = f["x"].ref
        refs.attrs["MATLAB_class"] = np.bytes_("cell")
        obj = f.create_dataset("when", data=np.arange(6, dtype=np.uint32)[None, :])
        obj.attrs["MATLAB_class"] = np.bytes_("datetime")
        e = f.create_dataset("e", data=np.array([0, 0], dtype=np.uint64))
        e.attrs["MATLAB_class"] = np.bytes_("double")
        e.attrs["MATLAB_empty"] = np.uint8(1)
    for col, part in (("c", "'c' is a cell array"), ("e", "'e' is empty"),
                      ("when", "'when' is a MATLAB object of class 'datetime'")):
        with pytest.raises(RunFileError, match=part):
            read_mat_columns(path, [col])
    assert list_mat_variables(path) == ["c", "e", "when", "x"]


# -- hostile v7.3 files: declared sizes, links and storage that read other files ------------
# Each file is a plausible recording (t, u as MATLAB writes them) plus one hostile `speed`,
# imported through the real CLI: exit 2, one line naming the file, at once, nothing written.

T20 = np.arange(20) / 1000.0


def _hostile_v73(tmp_path, build, name="h.mat"):
    """A v7.3 file holding t and u (20 samples), then `build(f, tmp_path)` adds the rest."""
    h5py = pytest.importorskip("h5py")
    path = write_v73(tmp_path / name, {"t": T20, "u": np.sin(T20)})
    with h5py.File(path, "r+") as f:
        build(f, tmp_path)
    assert path.read_bytes().startswith(b"MATLAB 7.3 MAT-file")
    return path


def _other_h5(tmp_path):
    """Another HDF5 file on the machine holding plausible data (what a link would pull in)."""
    import h5py

    other = tmp_path / "elsewhere.h5"
    with h5py.File(other, "w") as g:
        g.create_dataset("speed", data=np.cos(T20)[None, :]).attrs["MATLAB_class"] = \
            np.bytes_("double")
        g.create_group("rec").create_dataset("speed", data=np.cos(T20)[None, :])
    return other


def _double(ds):
    ds.attrs["MATLAB_class"] = np.bytes_("double")
    return ds


def _huge_chunked(f, tmp):       # 2e10 doubles (160 GB) declared, one fill value stored
    _double(f.create_dataset("speed", shape=(1, 20_000_000_000), dtype="f8",
                             chunks=(1, 65536), fillvalue=0.5))


def _huge_gzip(f, tmp):
    _double(f.create_dataset("speed", shape=(1, 20_000_000_000), maxshape=(1, None),
                             dtype="f8", chunks=(1, 65536), compression="gzip"))


def _huge_contiguous(f, tmp):    # declared, never written: no space allocated
    _double(f.create_dataset("speed", shape=(20_000_000_000, 1), dtype="f8"))


def _huge_in_struct(f, tmp):
    g = f.create_group("rec")
    g.attrs["MATLAB_class"] = np.bytes_("struct")
    _double(g.create_dataset("speed", shape=(1, 20_000_000_000), dtype="f8",
                             chunks=(1, 65536)))


def _over_bytes(f, tmp):         # 20 channels of 19 million samples: 3 GB, each channel legal
    _double(f.create_dataset("speed", shape=(20, 19_000_000), dtype="f8", chunks=(1, 65536)))


def _external_link(f, tmp):
    f["speed"] = __import__("h5py").ExternalLink(str(_other_h5(tmp)), "/speed")


def _external_link_in_struct(f, tmp):
    g = f.create_group("rec")
    g.attrs["MATLAB_class"] = np.bytes_("struct")
    g["speed"] = __import__("h5py").ExternalLink(str(_other_h5(tmp)), "/speed")


def _external_link_to_struct(f, tmp):
    f["rec"] = __import__("h5py").ExternalLink(str(_other_h5(tmp)), "/rec")


def _dangling_soft_link(f, tmp):
    f["speed"] = __import__("h5py").SoftLink("/nowhere/speed")


def _soft_link_through_external(f, tmp):   # inside the file, then out of it
    import h5py

    f["ext"] = h5py.ExternalLink(str(_other_h5(tmp)), "/rec")
    f["speed"] = h5py.SoftLink("/ext/speed")


def _soft_link_loop(f, tmp):
    import h5py

    f["speed"] = h5py.SoftLink("/again")
    f["again"] = h5py.SoftLink("/speed")


def _external_storage(f, tmp):   # the dataset's bytes live in another file
    raw = tmp / "raw.bin"
    raw.write_bytes(np.cos(T20).tobytes())
    _double(f.create_dataset("speed", shape=(1, 20), dtype="<f8",
                             external=[(str(raw), 0, 20 * 8)]))


def _virtual(f, tmp):            # a virtual dataset maps another file's dataset
    import h5py

    layout = h5py.VirtualLayout(shape=(1, 20), dtype="f8")
    layout[...] = h5py.VirtualSource(str(_other_h5(tmp)), "speed", shape=(1, 20))
    _double(f.create_virtual_dataset("speed", layout, fillvalue=0.0))


HOSTILE_V73 = [
    ("huge_chunked", _huge_chunked, "speed", ["'speed' declares 20,000,000,000 samples",
                                              "(20,000,000)"]),
    ("huge_gzip", _huge_gzip, "speed", ["'speed' declares 20,000,000,000 samples"]),
    ("huge_contiguous", _huge_contiguous, "speed", ["'speed' declares 20,000,000,000 samples"]),
    ("huge_in_struct", _huge_in_struct, "rec.speed", ["'rec.speed' declares 20,000,000,000"]),
    ("over_bytes", _over_bytes, "speed[0]", ["'speed' declares 3.0 GB", "(2 GB)"]),
    ("external_link", _external_link, "speed", ["'speed' is a link to another file",
                                                "elsewhere.h5"]),
    ("external_link_in_struct", _external_link_in_struct, "rec.speed",
     ["'rec.speed' is a link to another file"]),
    ("external_link_to_struct", _external_link_to_struct, "rec.speed",
     ["'rec' is a link to another file"]),
    ("dangling_soft_link", _dangling_soft_link, "speed", ["'speed' is a link to '/nowhere/speed'",
                                                          "not in the file"]),
    ("soft_link_through_external", _soft_link_through_external, "speed",
     ["'speed' is a link to another file"]),
    ("soft_link_loop", _soft_link_loop, "speed", ["'speed' is a chain of more than 16 links"]),
    ("external_storage", _external_storage, "speed", ["'speed' keeps its data in another file",
                                                      "raw.bin"]),
    ("virtual", _virtual, "speed", ["'speed' is a virtual dataset"]),
]


@pytest.mark.parametrize("case,build,speed,parts", HOSTILE_V73, ids=[c[0] for c in HOSTILE_V73])
def test_hostile_v73_import_refused(tmp_path, capsys, case, build, speed, parts):
    """labrig import of a v7.3 file that declares more data than labrig reads, or whose
    channel is a link or storage in another file: exit 2, one line, at once, nothing
    written (was: a 149 GiB allocation, or another file's data silently imported)."""
    import time

    from test_malformed_inputs import _expect_user_error

    path = _hostile_v73(tmp_path, build)
    assert path.stat().st_size < 200_000                 # the declared data is not in it
    out = tmp_path / "out"
    start = time.perf_counter()
    line = _expect_user_error(capsys, ["import", path, "--map", f"t=t,u=u,speed={speed}",
                                       "-o", out], str(path), *parts)
    assert time.perf_counter() - start < 5, line
    assert not out.exists() or not any(out.iterdir())


OTHER_FILES = [c[:2] for c in HOSTILE_V73 if not c[0].startswith(("huge", "over"))]


@pytest.mark.parametrize("case,build", OTHER_FILES, ids=[c[0] for c in OTHER_FILES])
def test_hostile_v73_listing_refused(tmp_path, case, build):
    """Listing the variables follows no link out of the file either."""
    path = _hostile_v73(tmp_path, build)
    with pytest.raises(RunFileError) as e:
        list_mat_variables(path)
    msg = str(e.value)
    assert msg.startswith(f"{path}: ") and "\n" not in msg


def test_v73_declared_size_limits_follow_csv(tmp_path, monkeypatch):
    """The per-channel limit is the CSV reader's (csvfile.MAX_ROWS); a legal file reads."""
    from labrig.io import csvfile

    path = write_v73(tmp_path / "ok.mat", {"t": T20, "u": np.sin(T20)})
    assert read_mat_columns(path, ["t", "u"])["u"].shape == (20,)
    monkeypatch.setattr(csvfile, "MAX_ROWS", 19)
    with pytest.raises(RunFileError, match=r"'t' declares 20 samples, more than labrig "
                                           r"reads in one run \(19\)"):
        read_mat_columns(path, ["t", "u"])


def test_v73_soft_link_inside_the_file_reads(tmp_path):
    """A soft link to a dataset of the same file is followed as before."""
    def build(f, tmp):
        g = f.create_group("rec")
        g.attrs["MATLAB_class"] = np.bytes_("struct")
        g["speed"] = __import__("h5py").SoftLink("/u")
    path = _hostile_v73(tmp_path, build)
    got = read_mat_columns(path, ["t", "rec.speed"])
    np.testing.assert_array_equal(got["rec.speed"], np.sin(T20))
    assert list_mat_variables(path) == ["rec", "rec.speed", "t", "u"]


def test_v73_struct_that_contains_itself(tmp_path):
    """A group hard-linked into itself (a cycle) is refused, not walked forever."""
    def build(f, tmp):
        g = f.create_group("rec")
        g.attrs["MATLAB_class"] = np.bytes_("struct")
        g["speed"] = f["u"]
        g["again"] = g
    path = _hostile_v73(tmp_path, build)
    for call in (lambda: read_mat_columns(path, ["t", "rec.speed"]),
                 lambda: list_mat_variables(path)):
        with pytest.raises(RunFileError, match="'rec.again'") as e:
            call()
        assert str(e.value).startswith(f"{path}: ") and "\n" not in str(e.value)
