"""Everyday scope and logger exports come in with ``labrig import``: the separator and a
decimal comma found (csv.Sniffer), a UTF-8 BOM dropped, preambles and unit rows skipped
(Rigol, Keysight, Tektronix, PicoScope, a European spreadsheet export, a tab-separated
logger). Each file goes through the real CLI in-process and the imported numbers are read
back and compared to the ones written; bad inputs are exit 2 and one line."""
from __future__ import annotations

import math

import numpy as np
import pytest

from labrig.cli import main
from labrig.io.runs import read_run
from test_malformed_inputs import _expect_user_error

N = 40
K = np.arange(N)
U = np.where((K // 10) % 2 == 0, 1.25, -0.5)             # volts, square-ish
SPEED = np.round(3.0 * np.sin(K / 6.0), 4)                # rad/s


def _rows(sep=",", dec=".", t_scale=1e-3, t0=0.0, tfmt="{:.6e}", tail=""):
    """N data lines: t (in the file's unit), u, speed."""
    out = []
    for k, u, w in zip(K, U, SPEED):
        cells = [tfmt.format(t0 + k * t_scale), f"{u:.4f}", f"{w:.4f}"]
        out.append(sep.join(c.replace(".", dec) for c in cells) + tail)
    return out


RIGOL = "\n".join(["X,CH1,CH2,Start,Increment,",
                   "Sequence,Volt,Volt,-2.000000e-02,1.000000e-03",
                   *[f"{k},{u:.4e},{w:.4e}," for k, u, w in zip(K, U, SPEED)]]) + "\n"

KEYSIGHT = "\n".join(["Model Number,DSO-X 2024A", "Serial Number,MY52160000",
                      "Date,2024-03-01", "Time,10:15:00", "Averages,1", "",
                      "x-axis,1,2", "second,Volt,Volt",
                      *_rows(t0=-5e-3, tfmt="{:.6E}")]) + "\n"

TEK = "\n".join(["Model,MDO3024", "Firmware Version,1.26", ",", "Waveform Type,ANALOG",
                 "Point Format,Y", "Horizontal Units,s", "Horizontal Scale,0.004",
                 "Horizontal Delay,0", "Sample Interval,0.001", f"Record Length,{N}",
                 "Gating,0.0% to 100.0%", "Probe Attenuation,10,10", "Vertical Units,V,V",
                 "Vertical Offset,0,0", "Vertical Scale,0.5,0.5", "Vertical Position,0,0",
                 ",,", ",,", "Label,,", "TIME,CH1,CH2",
                 *_rows(t0=-0.02, tfmt="{:.7e}")]) + "\n"

PICO = "\r\n".join(["Time,Channel A,Channel B", "(ms),(V),(V)", "",
                    *_rows(t_scale=1.0, t0=-10.0, tfmt="{:.8f}")]) + "\r\n"

EUROPE = "\ufeff" + "\r\n".join(["Time;CH1;CH2", *_rows(sep=";", dec=",")]) + "\r\n"

TABS = "\n".join(["Time\tCH1\tCH2", *_rows(sep="\t")]) + "\n"

TABS_COMMA = "\n".join(["Time\tCH1\tCH2", *_rows(sep="\t", dec=",")]) + "\n"

CASES = {  # name: (file text, --map, extra options)
    "rigol": (RIGOL, "t=X,u=CH1,speed=CH2", []),
    "keysight": (KEYSIGHT, "t=x-axis,u=1,speed=2", []),
    "tektronix": (TEK, "t=TIME,u=CH1,speed=CH2", []),
    "picoscope": (PICO, "t=Time,u=Channel A,speed=Channel B", []),
    "picoscope, ms said": (PICO, "t=Time,u=Channel A,speed=Channel B", ["--time-unit", "ms"]),
    "european with BOM": (EUROPE, "t=Time,u=CH1,speed=CH2", []),
    "tab separated": (TABS, "t=Time,u=CH1,speed=CH2", []),
    "tab and decimal comma": (TABS_COMMA, "t=Time,u=CH1,speed=CH2", []),
    "plain comma": ("\n".join(["Time,CH1,CH2", *_rows()]) + "\n", "t=Time,u=CH1,speed=CH2", []),
}


def _import(tmp_path, capsys, text, mapping, *opts, name="scope.csv"):
    src = tmp_path / name
    src.write_bytes(text.encode("utf-8"))
    out = tmp_path / "out"
    code = main(["import", str(src), "--map", mapping, "-o", str(out), *map(str, opts)])
    err = capsys.readouterr().err
    return code, err, out


@pytest.mark.parametrize("case", sorted(CASES))
def test_scope_exports_import_with_their_numbers(tmp_path, capsys, case):
    text, mapping, opts = CASES[case]
    code, err, out = _import(tmp_path, capsys, text, mapping, *opts)
    assert code == 0, err
    assert err == "", err
    run = read_run(out / "scope.csv")
    np.testing.assert_allclose(run.u, U, rtol=1e-6)
    np.testing.assert_allclose(run.speed, SPEED, rtol=1e-6, atol=1e-9)
    assert run.fs == 1000.0                       # t in seconds, whatever the file's unit
    np.testing.assert_allclose(run.t, K * 1e-3, atol=1e-9)


def test_skip_rows_names_a_header_after_a_long_preamble(tmp_path, capsys):
    preamble = [f"Setting {i},{i}" for i in range(120)]
    text = "\n".join([*preamble, "Time,CH1,CH2", *_rows()]) + "\n"
    src = tmp_path / "long.csv"
    src.write_text(text)
    # beyond the automatic search: one line that says how to fix it
    _expect_user_error(capsys, ["import", src, "--map", "t=Time,u=CH1,speed=CH2",
                                "-o", tmp_path / "o"], "long.csv", "--skip-rows")
    code = main(["import", str(src), "--map", "t=Time,u=CH1,speed=CH2", "-o",
                 str(tmp_path / "o"), "--skip-rows", "120"])
    assert code == 0, capsys.readouterr().err
    run = read_run(tmp_path / "o" / "long.csv")
    np.testing.assert_allclose(run.u, U, rtol=1e-6)
    np.testing.assert_allclose(run.speed, SPEED, rtol=1e-6, atol=1e-9)


def test_row_numbers_are_the_files_lines(tmp_path, capsys):
    rows = _rows(sep=";", dec=",")
    rows[5] = rows[5].replace("1,2500", "1,2x")           # line 6 of the data
    text = "\n".join(["Model;X", "", "Time;CH1;CH2", "(s);(V);(V)", *rows]) + "\n"
    src = tmp_path / "scope.csv"
    src.write_text(text)
    # header on line 3, unit row on line 4: the data's 6th row is line 10
    _expect_user_error(capsys, ["import", src, "--map", "t=Time,u=CH1,speed=CH2",
                                "-o", tmp_path / "o"], "row 10, column 'CH1'", "'1,2x'")
    rows = _rows()
    rows[7] = rows[6]                                       # time repeats on line 10
    src.write_text("\n".join(["Model,X", "", "Time,CH1,CH2", *rows]) + "\n")
    _expect_user_error(capsys, ["import", src, "--map", "t=Time,u=CH1,speed=CH2",
                                "-o", tmp_path / "o"], "row 11, column 'Time'",
                       "not increasing")


@pytest.mark.parametrize("text,seen,held", [
    # a header typed with ';' over rows separated by ','
    ("Time;CH1;CH2\n" + "\n".join(_rows()) + "\n", "','", "';'"),
    ("Time\tCH1\tCH2\n" + "\n".join(_rows()) + "\n", "','", "'\\t'"),
])
def test_a_header_that_does_not_split_names_the_separator(tmp_path, capsys, text, seen, held):
    src = tmp_path / "scope.csv"
    src.write_text(text)
    line = _expect_user_error(capsys, ["import", src, "--map", "t=Time,u=CH1,speed=CH2",
                                       "-o", tmp_path / "o"], "scope.csv",
                              "did not split into columns with " + seen, "holds " + held)
    assert not (tmp_path / "o" / "scope.csv").exists(), line


def test_a_mapped_column_missing_from_a_split_header_is_named(tmp_path, capsys):
    src = tmp_path / "scope.csv"
    src.write_text("\n".join(["Time;CH1;CH2", *_rows(sep=";", dec=",")]) + "\n")
    _expect_user_error(capsys, ["import", src, "--map", "t=Time,u=CH1,speed=CH3",
                                "-o", tmp_path / "o"], "column 'CH3' not found",
                       "did you mean 'CH2'", "Time, CH1, CH2")


@pytest.mark.parametrize("skip,msg", [("-1", "--skip-rows"), ("500", "--skip-rows 500"),
                                      ("2", "--skip-rows")])
def test_bad_skip_rows(tmp_path, capsys, skip, msg):
    src = tmp_path / "scope.csv"
    src.write_text("\n".join(["Time,CH1,CH2", *_rows()]) + "\n")
    _expect_user_error(capsys, ["import", src, "--map", "t=Time,u=CH1,speed=CH2",
                                "-o", tmp_path / "o", "--skip-rows", skip], msg)


def test_counts_without_gear_ratio_warn_in_one_line(tmp_path, capsys):
    counts = (7 * K).astype(int)
    text = "ms,u_V,count\n" + "".join(f"{k * 5},{u:g},{c}\n" for k, u, c in zip(K, U, counts))
    args = ("t=ms,u=u_V,pos=count", "--time-unit", "ms", "--pos-unit", "counts:1320")
    code, err, out = _import(tmp_path, capsys, text, *args, name="enc.csv")
    assert code == 0, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("labrig: warning: "), err
    assert "--gear-ratio" in lines[0] and "counts:1320" in lines[0]
    run = read_run(out / "enc.csv")
    np.testing.assert_allclose(run.position, counts * 2 * math.pi / 1320, rtol=1e-6)
    assert run.gear_ratio == 1.0
    # the same with the gear ratio said: no warning
    code, err, _ = _import(tmp_path, capsys, text, *args, "--gear-ratio", "30", "--force",
                           name="enc.csv")
    assert code == 0 and err == "", err


def test_a_long_file_name_is_shortened_not_refused(tmp_path, capsys):
    # a file system holds 255 bytes in a name: a 250-character stem, over the 100 of a run
    stems = ["a" * 250, "a" * 249 + "b"]
    text = "\n".join(["Time,CH1,CH2", *_rows()]) + "\n"
    names = []
    for stem in stems:
        code, err, out = _import(tmp_path, capsys, text, "t=Time,u=CH1,speed=CH2",
                                 name=stem + ".csv")
        assert code == 0, err
        names.append(next(p for p in sorted(out.glob("*.csv")) if p.stem not in names).stem)
    assert all(len(n) <= 100 and n.startswith("a" * 80) for n in names), names
    assert names[0] != names[1]                            # unique per source file
    for n in names:
        np.testing.assert_allclose(read_run(out / f"{n}.csv").u, U, rtol=1e-6)
    # an explicit --name over the limit is still refused
    _expect_user_error(capsys, ["import", tmp_path / (stems[0] + ".csv"), "--map",
                                "t=Time,u=CH1,speed=CH2", "-o", tmp_path / "o2",
                                "--name", "b" * 150], "--name")


def test_a_fixed_rate_log_without_a_time_column_imports_at_its_rate(tmp_path, capsys):
    """A sketch that prints ``u,count`` at 200 Hz has no time column: ``--rate 200`` puts
    sample k at k/200 s. Without t= or --rate, with both, or with --time-unit beside
    --rate: one line naming the options, exit 2. The run is replaced only with --force;
    the old --overwrite still works and says once that it is --force's old spelling."""
    counts = np.cumsum(np.r_[np.zeros(20), np.full(180, 3.0)]).astype(int)
    text = "u,count\n" + "".join(f"{0.0 if k < 20 else 6.0:.2f},{c}\n"
                                 for k, c in enumerate(counts))
    args = ("u=u,pos=count", "--pos-unit", "counts:1320", "--gear-ratio", "30")
    code, err, out = _import(tmp_path, capsys, text, *args, "--rate", "200", name="log.csv")
    assert code == 0 and err == "", err
    run = read_run(out / "log.csv")
    np.testing.assert_allclose(run.t, np.arange(200) / 200.0, atol=1e-9)
    np.testing.assert_allclose(run.position, counts * 2 * math.pi / 1320, rtol=1e-6)
    for extra, words in ((("--force",), ("--map", "t=", "--rate")),
                         (("--rate", "200", "--time-unit", "ms", "--force"), ("--time-unit",)),
                         (("--rate", "0", "--force"), ("--rate", "sample rate"))):
        code, err, _ = _import(tmp_path, capsys, text, *args, *extra, name="log.csv")
        assert code == 2 and len(err.strip().splitlines()) == 1, err
        assert "Traceback" not in err and all(w in err for w in words), err
    both = "t,u,count\n" + "".join(f"{k / 200:.3f},1.0,{k}\n" for k in range(50))
    code, err, _ = _import(tmp_path, capsys, both, "t=t,u=u,pos=count", "--pos-unit",
                           "counts:1320", "--gear-ratio", "30", "--rate", "200", name="both.csv")
    assert code == 2 and "--rate" in err and "t=t" in err, err
    # an existing run: refused without --force, replaced with it or with the old spelling
    code, err, _ = _import(tmp_path, capsys, text, *args, "--rate", "200", name="log.csv")
    assert code == 2 and "already exists" in err and "add --force to replace it" in err, err
    code, err, _ = _import(tmp_path, capsys, text, *args, "--rate", "100", "--overwrite",
                           name="log.csv")
    assert code == 0 and err.count("\n") == 1 and "--overwrite is the old spelling of --force" in err
    assert read_run(out / "log.csv").t[1] == pytest.approx(0.01)
