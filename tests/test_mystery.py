"""Mystery rigs: drawing, the obfuscated file, sweeps on it, reveal and grading."""
from __future__ import annotations

import json
import math

import pytest

from labrig.io.config import load_rig, rig_from_dict
from labrig.core.errors import UserError
from labrig.io.mystery import HIDDEN_EFFECTS, PLANT_SPREAD, check, load_mystery, new_mystery, read_mystery, reveal, write_mystery, _default_doc, _derived

from conftest import labrig

SHORT_PLAN = """
[defaults]
sample_rate_hz = 200.0
lead_in_s = 0.2

[[experiment]]
loop = "open"
waveform = "square"
amplitudes_v = [1.5, 2.5]
frequency_hz = 0.5
periods = 1
"""


@pytest.fixture
def mfile(tmp_path):
    doc = new_mystery(3)
    return write_mystery(doc, tmp_path / "lab.mystery", seed=3), doc


def test_same_seed_same_rig_and_seeds_differ():
    assert new_mystery(11) == new_mystery(11)
    docs = [new_mystery(s) for s in range(12)]
    assert len({json.dumps(d, sort_keys=True) for d in docs}) == 12


@pytest.mark.parametrize("seed", range(25))
def test_drawn_rigs_are_plausible_and_detectable(seed):
    doc = new_mystery(seed)
    rig_from_dict(doc)  # valid as a rig document
    base = _default_doc()
    for key, v in doc["plant"].items():
        assert abs(v / base["plant"][key] - 1) <= PLANT_SPREAD + 1e-3, key
    assert doc["amplifier"] == base["amplifier"] and doc["sensors"] == base["sensors"]
    # the default plan (2.5 V max) stays inside the amplifier rail
    assert doc["amplifier"]["gain"] * doc["bridge"]["output_limit_v"] <= doc["amplifier"]["output_limit_v"]
    d, d0 = _derived(doc["plant"], doc), _derived(base["plant"], base)
    assert abs(d["km_rad_s_per_v"] / d0["km_rad_s_per_v"] - 1) <= 0.25
    assert abs(d["tau_m_s"] / d0["tau_m_s"] - 1) <= 0.25
    assert 1 <= len(doc["effects"]) <= 2
    for name, ps in doc["effects"].items():
        pname, lo, hi = HIDDEN_EFFECTS[name]
        if name == "saturation":  # a share of the largest drive of the plan: 5 x 2.5 V
            lo, hi = 12.5 * lo, 12.5 * hi
        assert set(ps) == {pname}
        assert lo * 0.995 <= ps[pname] <= hi * 1.005
    assert doc["rig"]["name"] == f"mystery rig {seed}"


def test_every_hidden_effect_occurs():
    seen = {n for s in range(40) for n in new_mystery(s)["effects"]}
    assert seen == set(HIDDEN_EFFECTS)


def test_round_trip_and_load_rig(mfile):
    path, doc = mfile
    got = read_mystery(path)  # the rig as drawn, keys it left out filled with defaults
    assert all(got[sec][k] == v for sec, body in doc.items() for k, v in body.items())
    assert got["rig"]["drive"] == "voltage" and got["sensors"]["encoder_counts_per_unit"] == 0
    assert load_mystery(path)["seed"] == 3
    rig = load_rig(path)
    assert rig.effects == {k: {p: float(v) for p, v in ps.items()} for k, ps in doc["effects"].items()}
    assert rig.plant.R == doc["plant"]["R_ohm"] and rig.name == "mystery rig 3"


def test_file_is_not_plain_text(mfile):
    path, doc = mfile
    text = path.read_text()
    lines = text.splitlines()
    assert lines[0] == "labrig-mystery/1"
    low = text.lower()
    for word in list(HIDDEN_EFFECTS) + ["d_v", "tc_v", "vmax_v", "a_rad", "td_s", "plant",
                                        "effects", "r_ohm", "mystery rig"]:
        assert word not in low, word
    for ps in doc["effects"].values():
        for v in ps.values():
            assert f"{v:g}" not in text
    # base64 of zlib alone would still be readable with one command: the XOR layer is there
    import base64
    import zlib
    with pytest.raises(zlib.error):
        zlib.decompress(base64.b64decode("".join(lines[2:])))


def test_write_refuses_overwrite_and_bad_suffix(tmp_path, mfile):
    path, doc = mfile
    with pytest.raises(UserError, match="already exists"):
        write_mystery(doc, path)
    write_mystery(doc, path, overwrite=True)
    with pytest.raises(UserError, match=r"\.mystery"):
        write_mystery(doc, tmp_path / "lab.toml")


def test_cli_new_reveal(tmp_path):
    f = tmp_path / "m.mystery"
    p = labrig("mystery", "new", "--seed", "5", "-o", f, check=0)
    assert "wrote" in p.stdout and f.exists()
    again = labrig("mystery", "new", "--seed", "5", "-o", f, check=2)
    assert len(again.stderr.strip().splitlines()) == 1
    doc = new_mystery(5)
    p = labrig("mystery", "reveal", f, check=0)
    for name, ps in doc["effects"].items():
        assert name in p.stdout
        assert all(f"{v:g}" in p.stdout for v in ps.values())
    js = json.loads(labrig("mystery", "reveal", f, "--json", check=0).stdout)
    assert js["seed"] == 5 and set(js["effects"]) == set(doc["effects"])
    assert js["derived"]["km_rad_s_per_v"] > 0


def test_sweep_on_a_mystery_rig(tmp_path, mfile):
    path, doc = mfile
    plan = tmp_path / "plan.toml"
    plan.write_text(SHORT_PLAN)
    out = tmp_path / "runs"
    labrig("sweep", "--sim", "--rig", path, "--plan", plan, "-o", out, check=0)
    sidecars = sorted(out.glob("*.json"))
    assert len(sidecars) == 2
    for sc in sidecars:  # the runs do not give the secret away either
        text = sc.read_text()
        assert not any(n in text for n in HIDDEN_EFFECTS)
    p = labrig("analyse", out, "--json", check=0)
    assert json.loads(p.stdout)["km"] > 0


def _model(tmp_path, name, effects, plant=None):
    truth = _default_doc()["plant"]
    plant = plant or {"R": truth["R_ohm"], "L": truth["L_h"], "J": truth["J_kgm2"],
                      "B": truth["B_nms_per_rad"], "K": truth["K_nm_per_a"]}
    m = {"format": "labrig-model/1", "structure": "dc-servo", "method": "co",
         "effects": list(effects), "params": plant, "effect_params": effects,
         "constants": {"Ka": 5.0}, "rmse_over_noise": {"overall": 1.08, "speed": 1.1,
                                                       "position": 1.05}}
    p = tmp_path / name
    p.write_text(json.dumps(m))
    return p


def test_check_grades_a_correct_model(tmp_path, mfile):
    path, doc = mfile
    truth = {n: {k: v * 1.05 for k, v in ps.items()} for n, ps in doc["effects"].items()}
    plant = {k: doc["plant"][key] for k, key in
             {"R": "R_ohm", "L": "L_h", "J": "J_kgm2", "B": "B_nms_per_rad", "K": "K_nm_per_a"}.items()}
    res = check(path, _model(tmp_path, "good.json", truth, plant))
    assert res["pass"] and res["score"] == 100
    assert set(res["found"]) == set(doc["effects"]) and not res["missed"] and not res["extra"]
    for e in res["effects"].values():
        for p in e["params"].values():
            assert math.isclose(p["error_percent"], 5.0, abs_tol=1e-6)
    assert abs(res["plant"]["km"]["error_percent"]) < 1e-6
    assert res["rmse_over_noise"] == 1.08
    p = labrig("mystery", "check", path, tmp_path / "good.json", "--json", check=0)
    assert json.loads(p.stdout)["score"] == 100


def test_check_grades_a_wrong_model(tmp_path, mfile):
    path, doc = mfile
    names = sorted(doc["effects"])
    first = names[0]
    wrong = {first: {k: v * 1.5 for k, v in doc["effects"][first].items()},  # 50 % off
             "offset": {"u0_v": 0.02}}                                        # not in the rig
    res = check(path, _model(tmp_path, "bad.json", wrong))
    assert not res["pass"] and res["score"] < 50
    assert res["found"] == [first] and res["extra"] == ["offset"]
    assert res["missed"] == names[1:]
    assert res["effects"][first]["status"] == "found" and not res["effects"][first]["pass"]
    assert "+50 %" in res["effects"][first]["verdict"]
    p = labrig("mystery", "check", path, tmp_path / "bad.json", check=0)
    assert "extra" in p.stdout and "score" in p.stdout
    # a student's self-check does not name what is missing
    p = labrig("mystery", "check", path, tmp_path / "bad.json", "--blind", "--json", check=0)
    js = json.loads(p.stdout)
    assert js["missed_count"] == len(names) - 1
    for n in names[1:]:
        assert n not in p.stdout


def test_check_accepts_an_equivalent_effect(tmp_path):
    doc = new_mystery(10)  # coulomb_friction only
    assert list(doc["effects"]) == ["coulomb_friction"]
    path = write_mystery(doc, tmp_path / "c.mystery", seed=10)
    tc = doc["effects"]["coulomb_friction"]["tc_v"]
    m = _model(tmp_path, "user.json", {"my_coulomb": {"tc_v": tc}})
    raw = json.loads(m.read_text())
    raw["effects"] = ["my_effects.py:MyCoulomb"]   # how identify saves a user effect
    m.write_text(json.dumps(raw))
    res = check(path, m)
    assert res["found"] == ["coulomb_friction"] and res["pass"] and not res["extra"]


@pytest.mark.parametrize("damage", ["header", "body", "truncate", "binary", "checksum"])
def test_corrupt_file_is_a_one_line_user_error(tmp_path, mfile, damage):
    path, _ = mfile
    lines = path.read_text().splitlines()
    if damage == "header":
        lines[0] = "labrig-mystery/9"
        path.write_text("\n".join(lines))
    elif damage == "body":
        s = lines[3]
        lines[3] = s[:10] + ("A" if s[10] != "A" else "B") + s[11:]
        path.write_text("\n".join(lines))
    elif damage == "truncate":
        path.write_text("\n".join(lines[:3]))
    elif damage == "binary":
        path.write_bytes(b"\x00\xff\xfe" * 50)
    else:
        lines[1] = "salt " + "00" * 16
        path.write_text("\n".join(lines))
    with pytest.raises(UserError):
        read_mystery(path)
    for args in (("mystery", "reveal", path), ("sweep", "--sim", "--rig", path, "-o", tmp_path / "r")):
        p = labrig(*args, check=2)
        err = p.stderr.strip().splitlines()
        assert len(err) == 1 and str(path) in err[0], p.stderr
    assert not (tmp_path / "r").exists()


def test_missing_files_are_user_errors(tmp_path, mfile):
    path, _ = mfile
    p = labrig("mystery", "check", path, tmp_path / "nope.json", check=2)
    assert "not found" in p.stderr
    p = labrig("mystery", "reveal", tmp_path / "nope.mystery", check=2)
    assert len(p.stderr.strip().splitlines()) == 1
    labrig("mystery", check=2)
    labrig("mystery", "new", "-o", tmp_path / "x.mystery", check=2)  # --seed required


def test_reveal_matches_the_document(mfile):
    path, doc = mfile
    r = reveal(path)
    assert r["seed"] == 3
    assert {n: e["params"] for n, e in r["effects"].items()} == doc["effects"]
    assert r["plant"]["R"]["value"] == doc["plant"]["R_ohm"]
