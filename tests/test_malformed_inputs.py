"""Every malformed file a user can hand in is a user error: exit 2, one line naming the
file (or option) and what to fix, never a traceback or an "internal error".

One parametrised matrix across run sidecars, run CSVs, rig files, plan files, model
files, identify configs, mystery files and imports. Each case writes the bad input into
a fresh folder and runs the real CLI in-process.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from labrig.cli import main

ROOT = Path(__file__).resolve().parent.parent
GOOD = ROOT / "data" / "sweep_default"
SIDE = json.loads((GOOD / "sq_1.20V.json").read_text())
CSV_TEXT = (GOOD / "sq_1.20V.csv").read_text()
GOOD_MODEL = {"format": "labrig-model/1", "structure": "dc-servo", "effects": [],
              "params": {"R": 8.0, "L": 0.0085, "J": 5.2e-5, "B": 1e-5, "K": 0.05},
              "effect_params": {}, "constants": {"Ka": 5.0, "N": 30.0, "Kt": 0.026,
                                                 "Kpot": 0.5, "kp": 2.0, "kv": 0.15}}


def _set(doc: dict, dotted: str, value):
    doc = json.loads(json.dumps(doc))
    *head, last = dotted.split(".")
    d = doc
    for h in head:
        d = d.setdefault(h, {})
    if value is _DEL:
        d.pop(last, None)
    else:
        d[last] = value
    return doc


_DEL = object()
DEEP = "[" * 100_000 + "]" * 100_000


# -- run sidecars: analyse DIR with one run whose sidecar is broken --------------------

SIDECAR_CASES = {
    "pos_offset null": ("sensors.pos_offset_v", None),
    "pos_offset text": ("sensors.pos_offset_v", "x"),
    "pos_offset huge": ("sensors.pos_offset_v", 1e300),
    "tacho gain tiny": ("sensors.tacho_v_per_rad_s", 1e-300),
    "tacho gain zero": ("sensors.tacho_v_per_rad_s", 0),
    "tacho gain text": ("sensors.tacho_v_per_rad_s", "0.026"),
    "tacho gain bool": ("sensors.tacho_v_per_rad_s", True),
    "tacho gain list": ("sensors.tacho_v_per_rad_s", [0.026]),
    "tacho gain missing": ("sensors.tacho_v_per_rad_s", _DEL),
    "pot gain null": ("sensors.pos_v_per_rad", None),
    "pot gain huge": ("sensors.pos_v_per_rad", 1e12),
    "pot gain missing": ("sensors.pos_v_per_rad", _DEL),
    "amp gain text": ("rig.amplifier_gain", "five"),
    "amp gain negative": ("rig.amplifier_gain", -5),
    "amp gain zero": ("rig.amplifier_gain", 0),
    "amp gain null": ("rig.amplifier_gain", None),
    "gear text": ("rig.gear_ratio", "30"),
    "gear zero": ("rig.gear_ratio", 0),
    "gear negative": ("rig.gear_ratio", -30),
    "gear bool": ("rig.gear_ratio", False),
    "rate zero": ("sample_rate_hz", 0),
    "rate negative": ("sample_rate_hz", -200),
    "rate text": ("sample_rate_hz", "200"),
    "rate null": ("sample_rate_hz", None),
    "rate huge": ("sample_rate_hz", 1e12),
    "rate missing": ("sample_rate_hz", _DEL),
    "format missing": ("format", _DEL),
    "format other": ("format", "labrig-run/2"),
    "format number": ("format", 1),
    "experiment list": ("experiment", []),
    "experiment missing": ("experiment", _DEL),
    "sensors text": ("sensors", "none"),
    "rig null": ("rig", None),
    "loop sideways": ("experiment.loop", "sideways"),
    "loop missing": ("experiment.loop", _DEL),
    "loop number": ("experiment.loop", 1),
    "amplitude text": ("experiment.amplitude_v", "1.2"),
    "amplitude huge": ("experiment.amplitude_v", 1e9),
    "frequency zero": ("experiment.frequency_hz", 0),
    "levels text": ("experiment.levels", ["a", "b"]),
    "kp negative": ("experiment.position_gain", -1),
    "kv text": ("experiment.velocity_gain", "0.1"),
    "bridge text": ("bridge", "serial"),
    # misspelt or unknown keys are refused with the labrig spelling, never ignored
    "amplitude misspelt": ("experiment.amplitud_v", 1.2),
    "bridge misspelt": ("brige", {"dropped_samples": 0}),
    "tacho key misspelt": ("sensors.tacho_gain", 0.026),
    "gear key misspelt": ("rig.gear", 30.0),
    "unknown top-level key": ("colour", "red"),
}


def _run_dir(tmp_path, sidecar=None, csv_text=None, sidecar_text=None) -> Path:
    d = tmp_path / "runs"
    d.mkdir(exist_ok=True)
    (d / "r.csv").write_text(CSV_TEXT if csv_text is None else csv_text)
    text = sidecar_text if sidecar_text is not None else json.dumps(sidecar or SIDE)
    (d / "r.json").write_text(text)
    return d


def _expect_user_error(capsys, argv, *must_contain: str):
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err.strip()
    lines = err.splitlines()
    assert code == 2, f"exit {code}: {err}"
    assert len(lines) == 1, f"not one line: {err!r}"
    assert lines[0].startswith("labrig: error: "), err
    assert "internal error" not in err and "Traceback" not in err
    for s in must_contain:
        assert s in lines[0], f"{s!r} not in {lines[0]!r}"
    return lines[0]


def _expect_bad_file(capsys, path: Path, text: str, command: str, option: str):
    """``labrig COMMAND RUNS OPTION PATH`` on a good run folder, ``text`` in ``path``: a
    user error that names the file."""
    d = _run_dir(path.parent)
    path.write_text(text)
    _expect_user_error(capsys, [command, d, option, path], path.name)


@pytest.mark.parametrize("case", sorted(SIDECAR_CASES))
def test_bad_sidecar(tmp_path, capsys, case):
    key, value = SIDECAR_CASES[case]
    d = _run_dir(tmp_path, _set(SIDE, key, value))
    _expect_user_error(capsys, ["analyse", d], "r.json", key.split(".")[-1])


SIDECAR_TEXT_CASES = {
    "not json": "{sample_rate_hz: 200",
    "empty": "",
    "array": "[1, 2, 3]",
    "nested deep": DEEP,
    "nan literal rate": json.dumps(SIDE).replace('"sample_rate_hz": 200.0', '"sample_rate_hz": NaN'),
    "infinity gain": json.dumps(SIDE).replace('"tacho_v_per_rad_s": 0.026',
                                              '"tacho_v_per_rad_s": Infinity'),
    "binary": "\udcff",
}


@pytest.mark.parametrize("case", sorted(SIDECAR_TEXT_CASES))
def test_bad_sidecar_text(tmp_path, capsys, case):
    text = SIDECAR_TEXT_CASES[case]
    d = _run_dir(tmp_path)
    if case == "binary":
        (d / "r.json").write_bytes(b"\xff\xfe\x00garbage")
    else:
        (d / "r.json").write_text(text)
    _expect_user_error(capsys, ["analyse", d], "r.json")


# -- run CSVs --------------------------------------------------------------------------

HEAD, *ROWS = CSV_TEXT.splitlines()


def _csv(header=HEAD, rows=None, edit=None):
    rows = list(ROWS if rows is None else rows)
    if edit:
        for i, text in edit.items():
            rows[i] = text
    return "\n".join([header, *rows]) + "\n"


CSV_CASES = {
    "Tacho capital": (_csv("t,u,Tacho,pos"), "'Tacho' in the header looks like 'tacho'"),
    "speed without its unit": (_csv("t,u,speed,pos"), "key 'sensors.speed_unit' missing"),
    "Time for t": (_csv("Time,u,tacho,pos"), "looks like 't'"),
    "position for pos": (_csv("t,u,tacho,position"), "looks like 'pos'"),
    "U capital": (_csv("t,U,tacho,pos"), "looks like 'u'"),
    "tach typo": (_csv("t,u,tach,pos"), "looks like 'tacho'"),
    "duplicate column": (_csv("t,u,tacho,tacho"), "appears twice"),
    "extra field": (_csv(edit={5: ROWS[5] + ",7"}), "row 7 has 5 fields"),
    "missing field": (_csv(edit={5: ROWS[5].rsplit(",", 1)[0]}), "row 7"),
    "empty cell": (_csv(edit={3: "0.015,,0,-4"}), "row 5, column 'u': an empty cell"),
    "nan cell": (_csv(edit={3: "0.015,0,nan,-4"}), "row 5, column 'tacho': NaN"),
    "inf cell": (_csv(edit={3: "0.015,0,0,inf"}), "row 5, column 'pos': NaN or inf"),
    "text cell": (_csv(edit={100: "0.505,abc,0,-4"}), "row 102, column 'u'"),
    "decreasing t": (_csv(edit={10: "0.01,0,0,-4"}), "strictly increasing"),
    "rate change": (_csv(rows=[f"{i * 0.005:.4f},0,0,-4" for i in range(500)]
                         + [f"{2.5 + i * 0.01:.4f},0,0,-4" for i in range(1, 400)]),
                    "row 502, column 't'"),
    "whole file at other rate": (_csv(rows=[f"{i * 0.01:.4f},0,0,-4" for i in range(900)]),
                                 "sample_rate_hz"),
    "only header": (HEAD + "\n", "data row"),
    "one row": (_csv(rows=ROWS[:1]), "data row"),
    "empty": ("", "empty"),
    "blank lines": ("\n\n\n", "empty"),
    "no header": (_csv(header=ROWS[0]), "no header"),
    "no sensors": ("t,u\n0,0\n0.005,1\n0.01,1\n", "no sensor column"),
    "no u": ("t,tacho,pos\n0,0,0\n0.005,1,0\n", "column 'u' missing"),
}


@pytest.mark.parametrize("case", sorted(CSV_CASES))
def test_bad_csv(tmp_path, capsys, case):
    text, msg = CSV_CASES[case]
    d = _run_dir(tmp_path, csv_text=text)
    _expect_user_error(capsys, ["analyse", d], msg)


def test_binary_csv(tmp_path, capsys):
    d = _run_dir(tmp_path)
    (d / "r.csv").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 20)
    _expect_user_error(capsys, ["analyse", d], "r.csv")


# -- rig files: sweep --sim --rig FILE (refused before anything runs) ----------------

RIG_CASES = {
    "R negative": ("[plant]\nR_ohm = -1.0\n", "plant.R_ohm"),
    "R text": ("[plant]\nR_ohm = \"8\"\n", "plant.R_ohm"),
    "R inf": ("[plant]\nR_ohm = inf\n", "plant.R_ohm"),
    "R nan": ("[plant]\nR_ohm = nan\n", "plant.R_ohm"),
    "L zero": ("[plant]\nL_h = 0.0\n", "plant.L_h"),
    "J huge": ("[plant]\nJ_kgm2 = 1e9\n", "plant.J_kgm2"),
    "K bool": ("[plant]\nK_nm_per_a = true\n", "plant.K_nm_per_a"),
    "plant key typo": ("[plant]\nR = 8.0\n", "unknown key 'plant.R'"),
    "section typo": ("[planet]\nR_ohm = 8.0\n", "unknown section [planet]"),
    "plant not table": ("plant = 3\n", "plant"),
    "gear zero": ("[rig]\ngear_ratio = 0\n", "rig.gear_ratio"),
    "name number": ("[rig]\nname = 5\n", "rig.name"),
    "amp gain text": ("[amplifier]\ngain = \"five\"\n", "amplifier.gain"),
    "amp limit negative": ("[amplifier]\noutput_limit_v = -13\n", "amplifier.output_limit_v"),
    "tacho negative": ("[sensors]\ntacho_v_per_rad_s = -0.026\n", "sensors.tacho_v_per_rad_s"),
    "pot offset huge": ("[sensors]\npos_offset_v = 1e6\n", "sensors.pos_offset_v"),
    "rate text": ("[bridge]\nsample_rate_hz = \"1k\"\n", "bridge.sample_rate_hz"),
    "dac bits float": ("[bridge]\ndac_bits = 12.5\n", "bridge.dac_bits"),
    "adc bits huge": ("[bridge]\nadc_bits = 64\n", "bridge.adc_bits"),
    "adc range reversed": ("[bridge]\nadc_range_v = [5, -5]\n", "bridge.adc_range_v"),
    "adc range short": ("[bridge]\nadc_range_v = [5]\n", "bridge.adc_range_v"),
    "adc range text": ("[bridge]\nadc_range_v = [\"a\", \"b\"]\n", "bridge.adc_range_v"),
    "calibration typo": ("[bridge.calibration]\ndac_gian = 1.0\n", "bridge.calibration.dac_gian"),
    "watchdog zero": ("[bridge]\nwatchdog_ms = 0\n", "bridge.watchdog_ms"),
    "watchdog a minute": ("[bridge]\nwatchdog_ms = 60000\n", "bridge.watchdog_ms"),
    "lost fraction above one": ("[bridge]\nmax_lost_fraction = 1.5\n", "bridge.max_lost_fraction"),
    "limit above the rail": ("[bridge]\noutput_limit_v = 3.0\n", "bridge.output_limit_v"),
    "trip speed negative": ("[bridge]\ntrip_speed = -5.0\n", "bridge.trip_speed"),
    "trip speed past the tacho": ("[bridge]\ntrip_speed = 1000.0\n", "bridge.trip_speed"),
    "trip speed without tacho": ("[sensors]\ntacho_v_per_rad_s = 0.0\n[bridge]\ntrip_speed = 9.0\n",
                                 "bridge.trip_speed"),
    "estop text": ("[bridge]\nestop = \"yes\"\n", "bridge.estop"),
    "trip window reversed": ("[bridge]\ntrip_position = [1.0, -1.0]\n", "bridge.trip_position"),
    "trip window past the pot": ("[bridge]\ntrip_position = [-100.0, 100.0]\n",
                                 "bridge.trip_position"),
    "noise negative": ("[noise]\ntacho_v = -0.01\n", "noise.tacho_v"),
    "seed float": ("[noise]\nseed = 1.5\n", "noise.seed"),
    "seed negative": ("[noise]\nseed = -1\n", "noise.seed"),
    "effect unknown": ("[effects.gremlins]\nx = 1.0\n", "unknown effect 'gremlins'"),
    "effect param typo": ("[effects.deadband]\nwidth = 1.0\n", "effects.deadband.width"),
    "effect param missing": ("[effects.deadband]\n", "missing 'd_v'"),
    "effect param text": ("[effects.deadband]\nd_v = \"0.3\"\n", "effects.deadband.d_v"),
    "effect param range": ("[effects.deadband]\nd_v = 99.0\n", "effects.deadband.d_v"),
    "effects not table": ("effects = 3\n", "effects"),
    "bad toml": ("[plant\nR_ohm = 8\n", "not valid TOML"),
    "not text": (None, "not a text TOML file"),
}


@pytest.mark.parametrize("case", sorted(RIG_CASES))
def test_bad_rig(tmp_path, capsys, case):
    text, msg = RIG_CASES[case]
    rig = tmp_path / "rig.toml"
    if text is None:
        rig.write_bytes(b"\xff\xfe[plant]\x00")
    else:
        rig.write_text(text)
    _expect_user_error(capsys, ["sweep", "--sim", "--rig", rig, "-o", tmp_path / "out"],
                       "rig.toml", msg)
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


# -- plan files: sweep --sim --plan FILE -----------------------------------------------

EXP = "[[experiment]]\n"
PLAN_CASES = {
    "name climbs out": (EXP + 'name = "../../x"\n', "not a valid run name"),
    "name absolute": (EXP + 'name = "/tmp/evil"\n', "name"),
    "name hidden": (EXP + 'name = ".hidden"\n', "name"),
    "name empty": (EXP + 'name = ""\n', "name"),
    "name slash": (EXP + 'name = "a/b"\n', "name"),
    "name number": (EXP + "name = 5\n", "name"),
    "amplitudes scalar": (EXP + "amplitudes_v = 1.0\n", "amplitudes_v"),
    "amplitudes text": (EXP + 'amplitudes_v = "1.0"\n', "amplitudes_v"),
    "amplitudes empty": (EXP + "amplitudes_v = []\n", "amplitudes_v"),
    "amplitudes text items": (EXP + 'amplitudes_v = ["1", "2"]\n', "amplitudes_v"),
    "amplitude list": (EXP + "amplitude_v = [-1, 1.5]\n", "amplitude_v"),
    "amplitude text": (EXP + 'amplitude_v = "1.5"\n', "amplitude_v"),
    "amplitude nan": (EXP + "amplitude_v = nan\n", "amplitude_v"),
    "square zero amplitude": (EXP + "amplitude_v = 0.0\n", "amplitude_v > 0"),
    "square negative amplitude": (EXP + "amplitude_v = -1.0\n", "amplitude_v > 0"),
    "frequency above fs/10": (EXP + "frequency_hz = 200.0\n", "a tenth of the sample rate"),
    "frequency zero": (EXP + "frequency_hz = 0.0\n", "frequency_hz"),
    "levels text": (EXP + 'waveform = "staircase"\nlevels = ["1", "2"]\n', "levels"),
    "levels scalar": (EXP + 'waveform = "staircase"\nlevels = 1.0\n', "levels"),
    "staircase no levels": (EXP + 'waveform = "staircase"\n', "needs 'levels'"),
    "waveform sine": (EXP + 'waveform = "sine"\n', "waveform"),
    "loop sideways": (EXP + 'loop = "sideways"\n', "loop"),
    "unknown key": (EXP + "amplitude = 1.0\n", "unknown key 'amplitude'"),
    "seed float": (EXP + "seed = 1.5\n", "unknown key 'seed'"),
    "too many samples": (EXP + "duration_s = 3600.0\nsample_rate_hz = 100000.0\n",
                         "samples"),
    "rate text": (EXP + 'sample_rate_hz = "1000"\n', "sample_rate_hz"),
    "rate zero": (EXP + "sample_rate_hz = 0.0\n", "sample_rate_hz"),
    "lead-in negative": (EXP + "lead_in_s = -1.0\n", "lead_in_s"),
    "periods zero": (EXP + "periods = 0\n", "periods"),
    "duration tiny": (EXP + "duration_s = 0.0001\n", "duration_s"),
    "gain negative": (EXP + 'loop = "closed"\nposition_gain = -1.0\n', "position_gain"),
    "no experiments": ("[defaults]\namplitude_v = 1.0\n", "no [[experiment]]"),
    "experiment not table": ("experiment = 3\n", "experiment"),
    "top-level typo": (EXP + "amplitude_v = 1.0\n[defualts]\n", "defualts"),
    "defaults typo": ("[defaults]\namplitud_v = 1.0\n" + EXP, "amplitud_v"),
    "duplicate names": (EXP + 'name = "a"\n' + EXP + 'name = "a"\n', "used twice"),
    "beyond output limit": (EXP + "amplitude_v = 20.0\n", "output limit"),
}


@pytest.mark.parametrize("case", sorted(PLAN_CASES))
def test_bad_plan(tmp_path, capsys, case):
    text, msg = PLAN_CASES[case]
    plan = tmp_path / "plan.toml"
    plan.write_text(text)
    out = tmp_path / "out"
    _expect_user_error(capsys, ["sweep", "--sim", "--plan", plan, "-o", out], msg)
    assert not list(tmp_path.parent.glob("x.csv"))
    assert not out.exists() or not any(out.iterdir())


# -- model files: compare DIR --model FILE ---------------------------------------------

MODEL_CASES = {
    "R negative": ("params.R", -8.0),
    "R text": ("params.R", "8"),
    "R null": ("params.R", None),
    "R missing": ("params.R", _DEL),
    "B zero": ("params.B", 0.0),
    "params list": ("params", [1, 2, 3]),
    "params missing": ("params", _DEL),
    "format other": ("format", "labrig-model/9"),
    "format missing": ("format", _DEL),
    "effects text": ("effects", "deadband"),
    "effects numbers": ("effects", [1, 2]),
    "effect unknown": ("effects", ["gremlins"]),
    "effect twice": ("effects", ["deadband", "deadband"]),
    "two frictions": ("effects", ["coulomb_friction", "stiction"]),
    "effect params missing": ("effects", ["deadband"]),
    "effect params text": ("effect_params", {"deadband": {"d_v": "0.3"}}),
    "effect params orphan": ("effect_params", {"gremlins": {"x": 1.0}}),
    "constants text": ("constants.Ka", "five"),
    "constants negative": ("constants.N", -30.0),
    "constants zero gain": ("constants.Kt", 0.0),
    "user effect in data": ("effects", ["evil.py:Evil"]),
    "effects key misspelt": ("efects", ["deadband"]),
    "unknown top-level key": ("colour", "red"),
    "params unknown key": ("params.Rm", 8.0),
    "constants unknown key": ("constants.Kb", 1.0),
    "structure disagrees with params": ("structure", "torque"),
}


@pytest.mark.parametrize("case", sorted(MODEL_CASES))
def test_bad_model(tmp_path, capsys, case):
    key, value = MODEL_CASES[case]
    _expect_bad_file(capsys, tmp_path / "model.json", json.dumps(_set(GOOD_MODEL, key, value)),
                     "compare", "--model")


MODEL_TEXT_CASES = {"not json": "{params:", "empty": "", "array": "[]", "deep": DEEP,
                    "number": "3", "nan param": json.dumps(GOOD_MODEL).replace("8.0", "NaN")}


@pytest.mark.parametrize("case", sorted(MODEL_TEXT_CASES))
def test_bad_model_text(tmp_path, capsys, case):
    _expect_bad_file(capsys, tmp_path / "model.json", MODEL_TEXT_CASES[case], "compare", "--model")


def test_missing_model_and_folder(tmp_path, capsys):
    d = _run_dir(tmp_path)
    _expect_user_error(capsys, ["compare", d, "--model", tmp_path / "nope.json"], "nope.json")
    _expect_user_error(capsys, ["analyse", tmp_path / "nowhere"], "nowhere")


# -- identify configs and options -----------------------------------------------------

IDCONFIG_CASES = {
    "unknown key": "bound = 1\n",
    "bounds reversed": "[bounds]\nR = [20.0, 1.0]\n",
    "bounds text": "[bounds]\nR = \"1:20\"\n",
    "bounds inf": "[bounds]\nR = [1.0, inf]\n",
    "fixed text": "[fixed]\nR = \"8\"\n",
    "fixed nan": "[fixed]\nR = nan\n",
    "effects text": "effects = \"deadband\"\n",
    "effect unknown": "effects = [\"gremlins\"]\n",
    "user effect": "effects = [\"evil.py:Evil\"]\n",
    "bad toml": "[bounds\n",
}


@pytest.mark.parametrize("case", sorted(IDCONFIG_CASES))
def test_bad_identify_config(tmp_path, capsys, case):
    _expect_bad_file(capsys, tmp_path / "id.toml", IDCONFIG_CASES[case], "identify", "--config")


@pytest.mark.parametrize("opt", [["--fix", "R=nan"], ["--fix", "R=inf"], ["--fix", "R"],
                                 ["--bounds", "R=1:inf"], ["--bounds", "R=1"],
                                 ["--weights", "p=nan"], ["--effects", "gremlins"],
                                 ["--effects", "deadband,deadband"],
                                 ["--effects", "missing.py:Nope"]])
def test_bad_identify_options(tmp_path, capsys, opt):
    d = _run_dir(tmp_path)
    _expect_user_error(capsys, ["identify", d, *opt])


# -- mystery files --------------------------------------------------------------------

def _craft_mystery(path: Path, rig_doc: dict, seed=1) -> Path:
    """A mystery file with any content, encoded as labrig would (bypassing its checks):
    what someone who read the source could hand an instructor."""
    from labrig.io.mysteryfile import encode

    path.write_text(encode({"rig": rig_doc, "seed": seed}))
    return path


MYSTERY_CASES = {
    "user effect": ({"effects": {"evil.py:Evil": {}}}, 1, "Python code"),
    "R negative": ({"plant": {"R_ohm": -1.0}}, 1, "plant.R_ohm"),
    "R text": ({"plant": {"R_ohm": "8"}}, 1, "plant.R_ohm"),
    "unknown section": ({"gremlins": {}}, 1, "unknown section"),
    "effect out of range": ({"effects": {"deadband": {"d_v": 50.0}}}, 1, "d_v"),
    "seed float": ({}, 1.5, "seed"),
    "seed text": ({}, "one", "seed"),
}


@pytest.mark.parametrize("case", sorted(MYSTERY_CASES))
@pytest.mark.parametrize("command", ["reveal", "sweep"])
def test_bad_mystery(tmp_path, capsys, case, command):
    doc, seed, msg = MYSTERY_CASES[case]
    path = _craft_mystery(tmp_path / "m.mystery", doc, seed)
    argv = (["mystery", "reveal", path] if command == "reveal"
            else ["sweep", "--sim", "--rig", path, "-o", tmp_path / "out"])
    _expect_user_error(capsys, argv, "m.mystery", msg)


@pytest.mark.parametrize("case", ["header", "truncated", "empty", "binary"])
def test_damaged_mystery(tmp_path, capsys, case):
    from labrig.io.mystery import new_mystery, write_mystery

    path = write_mystery(new_mystery(3), tmp_path / "m.mystery", seed=3)
    lines = path.read_text().splitlines()
    if case == "header":
        path.write_text("\n".join(["labrig-mystery/9", *lines[1:]]))
    elif case == "truncated":
        path.write_text("\n".join(lines[:3]))
    elif case == "empty":
        path.write_text("")
    else:
        path.write_bytes(b"\x00\xff" * 40)
    _expect_user_error(capsys, ["mystery", "reveal", path], "m.mystery")


@pytest.mark.parametrize("case", ["R text", "not json", "deep", "format", "params list"])
def test_mystery_check_bad_model(tmp_path, capsys, case):
    from labrig.io.mystery import new_mystery, write_mystery

    path = write_mystery(new_mystery(3), tmp_path / "m.mystery", seed=3)
    m = tmp_path / "student.json"
    text = {"R text": json.dumps(_set(GOOD_MODEL, "params.R", "8")), "not json": "{",
            "deep": DEEP, "format": json.dumps(_set(GOOD_MODEL, "format", "x")),
            "params list": json.dumps(_set(GOOD_MODEL, "params", []))}[case]
    m.write_text(text)
    _expect_user_error(capsys, ["mystery", "check", path, m], "student.json")


# -- imports ----------------------------------------------------------------------------

SRC = "Time,CH1,CH2\n" + "".join(f"{i * 0.001:.3f},{i % 7},{i % 5}\n" for i in range(50))
IMPORT_CASES = {
    "name climbs out": (SRC, ["--map", "t=Time,u=CH1,speed=CH2", "--name", "../x"], "--name"),
    "name absolute": (SRC, ["--map", "t=Time,u=CH1,speed=CH2", "--name", "/tmp/x"], "--name"),
    "name hidden": (SRC, ["--map", "t=Time,u=CH1,speed=CH2", "--name", ".x"], "--name"),
    "name empty": (SRC, ["--map", "t=Time,u=CH1,speed=CH2", "--name", ""], "--name"),
    "map column typo": (SRC, ["--map", "t=Time,u=CH1,speed=CH3"], "did you mean 'CH2'"),
    "map no equals": (SRC, ["--map", "t=Time,u,speed=CH2"], "--map"),
    "map target typo": (SRC, ["--map", "t=Time,u=CH1,sped=CH2"], "unknown target"),
    "text cell": (SRC.replace("\n0.010,3,0", "\n0.010,x,0"), ["--map", "t=Time,u=CH1,speed=CH2"],
                  "column 'CH1'"),
    "empty cell": (SRC.replace("\n0.010,3,0", "\n0.010,,0"), ["--map", "t=Time,u=CH1,speed=CH2"],
                   "an empty cell"),
    "time repeats": (SRC.replace("0.011,", "0.010,"), ["--map", "t=Time,u=CH1,speed=CH2"],
                     "not increasing"),
    "empty source": ("", ["--map", "t=Time,u=CH1,speed=CH2"], "empty"),
    "tacho gain nan": (SRC, ["--map", "t=Time,u=CH1,tacho=CH2", "--tacho-gain", "nan"],
                       "--tacho-gain"),
    "gear zero": (SRC, ["--map", "t=Time,u=CH1,speed=CH2", "--gear-ratio", "0"], "gear"),
    "amp gain inf": (SRC, ["--map", "t=Time,u=CH1,speed=CH2", "--amplifier-gain", "inf"],
                     "amplifier"),
    "unit unknown": (SRC, ["--map", "t=Time,u=CH1,speed=CH2", "--speed-unit", "mph"],
                     "unknown unit"),
}


@pytest.mark.parametrize("case", sorted(IMPORT_CASES))
def test_bad_import(tmp_path, capsys, case):
    text, opts, msg = IMPORT_CASES[case]
    src = tmp_path / "scope.csv"
    src.write_text(text)
    out = tmp_path / "out"
    _expect_user_error(capsys, ["import", src, "-o", out, *opts], msg)
    assert not list(tmp_path.parent.glob("x.*"))
    assert not Path("/tmp/x.csv").exists() or Path("/tmp/x.csv").stat().st_mtime < 0


def matrix_size() -> int:
    """How many malformed inputs this file runs (each parametrised case, and each
    command of the two-command tests)."""
    return (len(SIDECAR_CASES) + len(SIDECAR_TEXT_CASES) + len(CSV_CASES) + 1
            + len(RIG_CASES) + len(PLAN_CASES) + len(MODEL_CASES) + len(MODEL_TEXT_CASES)
            + 2 + len(IDCONFIG_CASES) + 9 + 2 * len(MYSTERY_CASES) + 4 + 5
            + len(IMPORT_CASES) + 4 + 1 + 4 + 2 + 5)


def test_matrix_size_and_readme():
    """The issue asks for at least 150 malformed inputs; the trust page quotes the count."""
    n = matrix_size()
    assert n >= 150, n
    readme = (ROOT / "docs" / "reference" / "trust.md").read_text()
    assert f"runs {n} such inputs" in " ".join(readme.split()), n


# -- data that cannot show dynamics ---------------------------------------------------

ZERO_ROWS = [f"{i * 0.005:.3f},0,0,0" for i in range(1700)]
FLAT_ROWS = [f"{i * 0.005:.3f},{1.2 if (i // 200) % 2 else -1.2},0.1,-4" for i in range(1700)]


@pytest.mark.parametrize("command", ["diagnose", "identify"])
@pytest.mark.parametrize("rows,msg", [(ZERO_ROWS, "input u is constant"),
                                      (FLAT_ROWS, "tacho and pos are constant")])
def test_data_without_dynamics(tmp_path, capsys, command, rows, msg):
    d = _run_dir(tmp_path, csv_text=_csv(rows=rows))
    _expect_user_error(capsys, [command, d], msg)


# -- closed-loop runs must state their controller ---------------------------------------

def test_closed_loop_run_without_gains_is_refused(tmp_path, capsys):
    side = _set(_set(_set(SIDE, "experiment.loop", "closed"), "experiment.position_gain", _DEL),
                "experiment.velocity_gain", _DEL)
    d = _run_dir(tmp_path, side)
    line = _expect_user_error(capsys, ["analyse", d], "r.json", "position_gain")
    assert "--loop closed" in line


@pytest.mark.parametrize("opts,msg", [
    (["--loop", "closed"], "--position-gain"),
    (["--loop", "closed", "--position-gain", "2"], "--velocity-gain"),
    (["--loop", "closed", "--position-gain", "-2", "--velocity-gain", "0.1"], "--position-gain"),
    (["--position-gain", "2", "--velocity-gain", "0.1"], "only with --loop closed"),
])
def test_closed_loop_import_needs_its_gains(tmp_path, capsys, opts, msg):
    src = tmp_path / "scope.csv"
    src.write_text(SRC)
    _expect_user_error(capsys, ["import", src, "-o", tmp_path / "out",
                                "--map", "t=Time,u=CH1,pos=CH2", *opts], msg)


def test_closed_loop_import_records_the_gains(tmp_path, capsys):
    from labrig.io.runs import read_run

    src = tmp_path / "scope.csv"
    src.write_text(SRC)
    assert main(["import", str(src), "-o", str(tmp_path / "out"), "--map", "t=Time,u=CH1,pos=CH2",
                 "--loop", "closed", "--position-gain", "2", "--velocity-gain", "0.15"]) == 0
    run = read_run(tmp_path / "out" / "scope.csv")
    assert run.gains == {"kp": 2.0, "kv": 0.15} and run.loop == "closed"
    assert run.constants == {"Ka": 1.0, "N": 1.0, "Kt": 1.0, "Kpot": 1.0}


@pytest.mark.parametrize("rounds", ["0", "-1"])
def test_diagnose_auto_needs_a_round(tmp_path, capsys, rounds):
    d = _run_dir(tmp_path)
    _expect_user_error(capsys, ["diagnose", d, "--auto", "--max-rounds", rounds], "--max-rounds")


@pytest.mark.parametrize("weights", ["p=-1", "x=1", "p=abc", "p=0,q=0", "p=nan"])
def test_diagnose_weights_are_checked(tmp_path, capsys, weights):
    d = _run_dir(tmp_path)
    _expect_user_error(capsys, ["diagnose", d, "--auto", "--weights", weights], "--weights")
