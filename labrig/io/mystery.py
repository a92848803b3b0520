"""Mystery rigs: simulated rigs with hidden physics, for the missing-physics lab.

``new_mystery(seed)`` draws a rig: the default MS150 rig with its plant parameters
perturbed (each of R, L, J, B, K by up to +-20 %) and one or two hidden effects from
the catalogue (deadband, coulomb_friction, saturation, backlash, delay) at sizes a
student can detect with the default sweep. ``write_mystery`` stores it in a file that a
student cannot read by opening it; ``labrig sweep --sim --rig FILE`` uses it like any rig
file (``labrig.io.config.load_rig`` decodes the ``.mystery`` suffix).
``reveal`` shows the truth to the instructor and ``check`` grades a student's
model.json against it.

The file format lives in ``labrig.io.mysteryfile`` (obfuscation, not security).
"""
from __future__ import annotations

import copy
import tomllib
from pathlib import Path

import numpy as np

from labrig.io.config import packaged_config, rig_from_dict, rig_to_doc, load_rig
from labrig.core.errors import UserError
from labrig.core.fileio import atomic_write
from labrig.model.plants import plant_class
from labrig.io.mysteryfile import SUFFIX, decode, encode
from labrig.model.effects import CATALOGUE, catalogue_name, get_effect
from labrig.model import drive_units
from labrig.model.model import read_model_file


#: effects a mystery rig may hide, with the range (uniform) of their parameter, chosen
#: so that the default sweep shows them clearly above the noise
HIDDEN_EFFECTS = {
    "deadband": ("d_v", 0.2, 0.4),
    "coulomb_friction": ("tc_v", 0.15, 0.35),
    # the rail as a share of the largest drive the default plan asks for (Ka x 2.5 V)
    "saturation": ("vmax_v", 0.56, 0.72),
    "backlash": ("a_rad", 0.03, 0.05),
    "delay": ("td_s", 0.008, 0.015),
}
#: backlash on a linear axis, in m (a screw's play)
LINEAR_BACKLASH_M = (2e-4, 5e-4)
#: relative perturbation of each plant parameter (uniform in +-PLANT_SPREAD)
PLANT_SPREAD = 0.20
#: ... but Km and tau_m, which a student measures first, stay within +-this of the default
COMBINATION_SPREAD = 0.25
#: parameter error (relative) within which an identified effect passes
PASS_TOLERANCE = 0.20


# -- drawing a rig ------------------------------------------------------------------

def _default_doc() -> dict:
    path = packaged_config("rig_default.toml")
    return tomllib.loads(path.read_text(encoding="utf-8"))


def _plant(doc: dict):
    return plant_class((doc.get("rig") or {}).get("drive") or "voltage")


def _servo(plant: dict, doc: dict, **constants):
    cls = _plant(doc)
    return cls.servo({n: plant[key] for n, key in cls.toml_keys.items()},
                     {"Ka": doc["amplifier"]["gain"], **constants})


def _derived(plant: dict, doc: dict) -> dict:
    """Km, tau_m (and tau_e for the voltage plant) of a plant section; the key
    ``km_rad_s_per_v`` keeps its name on a linear axis, where it is m/s per V."""
    sp = _servo(plant, doc)
    out = {"km_rad_s_per_v": sp.km, "tau_m_s": sp.tau_m, "tau_m_first_order_s": sp.tau_m_approx}
    if _plant(doc).kind == "voltage":
        out["tau_e_s"] = sp.tau_e
    return out


def _base_doc(base_rig) -> dict:
    """The full document of the rig a mystery is drawn around (every key filled in)."""
    if base_rig is None:
        return _default_doc()

    return rig_to_doc(load_rig(base_rig))


def _plausible(doc: dict, base: dict) -> bool:
    """The default plan stays inside the amplifier rail and the sensors' ranges, and the
    closed position loop of the default plan (Kp 2.0, Kv 0.15) is well damped."""
    p = doc["plant"]
    amp, sens, br = doc["amplifier"], doc["sensors"], doc["bridge"]
    d = _derived(p, doc)
    if amp["gain"] * br["output_limit_v"] > amp["output_limit_v"]:
        return False
    # the identifiable combinations stay near the base rig's (the MS150: Km 97 rad/s/V,
    # tau_m 0.16 s)
    d0 = _derived(base["plant"], base)
    for k in ("km_rad_s_per_v", "tau_m_s"):
        if abs(d[k] / d0[k] - 1.0) > COMBINATION_SPREAD:
            return False
    adc_hi = min(abs(v) for v in br["adc_range_v"])
    top_speed = d["km_rad_s_per_v"] * br["output_limit_v"]
    if sens.get("tacho_v_per_rad_s", 0.0) * top_speed > 0.9 * adc_hi:
        return False
    if not sens.get("encoder_counts_per_unit"):
        # open loop +-2.5 V square, 0.25 Hz: the output shaft travels about w * 2 s / N
        travel = top_speed * 2.0 / doc["rig"]["gear_ratio"]
        lo, hi = br["adc_range_v"]
        pos_hi = sens["pos_offset_v"] + sens["pos_v_per_rad"] * travel
        if not (0.9 * lo < sens["pos_offset_v"] and pos_hi < 0.9 * hi):
            return False
    digital = sens.get("encoder_counts_per_unit") or not sens.get("tacho_v_per_rad_s")
    sp = _servo(p, doc, N=doc["rig"]["gear_ratio"],
                Kt=1.0 / doc["rig"]["gear_ratio"] if digital else sens["tacho_v_per_rad_s"],
                Kpot=1.0 if digital else sens["pos_v_per_rad"])
    eig = np.linalg.eigvals(sp.A_closed(2.0, 0.15))
    if np.any(eig.real >= 0):
        return False
    # damping of the slowest complex pair (if any) at least 0.4
    for z in eig:
        if abs(z.imag) > 1e-9 and -z.real / abs(z) < 0.4:
            return False
    return True


def _sig(x: float, digits: int = 3) -> float:
    return float(f"{x:.{digits}g}")


def new_mystery(seed: int, base_rig: Path | str | None = None) -> dict:
    """A mystery rig document (the dict a rig TOML parses to), drawn from ``seed``.

    Same seed, same rig. ``base_rig`` is the rig file it is drawn around (default the
    MS150; any plant and axis: a torque-driven motor, a linear axis). The hidden truth
    is in ``doc["effects"]`` and ``doc["plant"]``; ``doc["rig"]["name"]`` says only
    "mystery rig <seed>".
    """
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise UserError(f"`seed` must be a whole number >= 0, got {seed!r}")
    rng = np.random.default_rng([seed, 0x6D797374])  # "myst"
    base = _base_doc(base_rig)
    doc = copy.deepcopy(base)
    keys = _plant(base).toml_keys
    for _ in range(1000):
        for key in keys.values():
            f = 1.0 + rng.uniform(-PLANT_SPREAD, PLANT_SPREAD)
            doc["plant"][key] = _sig(base["plant"][key] * f, 4)
        if _plausible(doc, base):
            break
    else:  # the base rig itself is drawn around: keep its plant
        doc["plant"] = dict(base["plant"])
    n = 1 + int(rng.integers(0, 2))
    names = sorted(rng.choice(sorted(HIDDEN_EFFECTS), size=n, replace=False).tolist())
    effects = {}
    drive_max = doc["amplifier"]["gain"] * doc["bridge"]["output_limit_v"]
    for name in names:
        pname, lo, hi = HIDDEN_EFFECTS[name]
        if name == "saturation":
            lo, hi = lo * drive_max, hi * drive_max
        if name == "backlash" and doc["rig"].get("axis") == "linear":
            lo, hi = LINEAR_BACKLASH_M
        effects[name] = {pname: _sig(rng.uniform(lo, hi))}
    doc["effects"] = effects
    doc["rig"]["name"] = f"mystery rig {seed}"
    doc["noise"]["seed"] = int(rng.integers(1, 2 ** 31))
    return doc


# -- the file -------------------------------------------------------------------------

def write_mystery(doc: dict, path: Path | str, seed: int | None = None,
                  overwrite: bool = False) -> Path:
    """Write a mystery rig file (obfuscated, not encrypted: see the module docstring).

    ``seed`` is recorded for ``reveal``. An existing file is only replaced with
    ``overwrite=True``. The write is atomic (temp file + rename).
    """
    path = Path(path)
    if path.suffix != SUFFIX:
        raise UserError(f"{path}: a mystery rig file must end in '{SUFFIX}' "
                        f"(e.g. {path.with_suffix(SUFFIX).name}) so that `rig` recognises it")
    if path.exists() and not overwrite:
        raise UserError(f"{path}: already exists; add `overwrite` to replace it")
    rig_from_dict(doc, str(path))  # never write a rig that cannot be loaded
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, encode({"rig": doc, "seed": seed}))
    return path


def load_mystery(path: Path | str) -> dict:
    """Decode a mystery file -> ``{"rig": doc, "seed": N | None}``.

    The checksum only shows the file is intact, not that its author meant well: the rig
    inside is validated like any rig file, then completed with the defaults so reveal
    and check can read every key.
    """
    m = decode(path)
    return {"rig": rig_to_doc(rig_from_dict(m["rig"], str(path))), "seed": m["seed"]}


def read_mystery(path: Path | str) -> dict:
    """The rig document of a mystery file, as ``labrig.io.config.load_rig`` expects it."""
    return load_mystery(path)["rig"]


# -- reveal ---------------------------------------------------------------------------

def reveal(path: Path | str) -> dict:
    """The hidden truth of a mystery file, with the default rig for comparison."""
    m = load_mystery(path)
    doc = m["rig"]
    rig_from_dict(doc, str(path))
    cls = _plant(doc)
    # the MS150 is the reference of a voltage plant; a mystery drawn around another rig
    # file has none here (that file is its reference)
    base = _default_doc() if cls.kind == "voltage" else None
    plant = {k: {"value": doc["plant"][key], "unit": cls.units[k],
                 "default": base["plant"][key] if base else None,
                 "change_percent": 100.0 * (doc["plant"][key] / base["plant"][key] - 1.0)
                 if base else None}
             for k, key in cls.toml_keys.items()}
    effects = {}
    for name, ps in doc.get("effects", {}).items():
        e = get_effect(name)
        effects[name] = {"params": ps, "summary": e.summary, "signature": e.signature,
                         "experiment": e.experiment,
                         "units": {p.name: p.unit for p in e.params}}
    return {"file": str(path), "seed": m.get("seed"), "name": doc["rig"].get("name"),
            "drive": cls.kind, "axis": cls.axis, "plant": plant, "derived": _derived(doc["plant"], doc),
            "derived_default": _derived(base["plant"], base) if base else None,
            "effects": effects,
            "noise": doc.get("noise", {})}


def format_reveal(r: dict) -> str:
    d, d0 = r["derived"], r["derived_default"]
    speed = "m/s" if r.get("axis") == "linear" else "rad/s"
    out = [f"{r['file']}: {r['name']} (seed {r['seed']}; a {r.get('drive', 'voltage')}-driven "
           f"{r.get('axis', 'rotary')} axis)", "", "plant (truth; default rig in brackets):"]
    if d0 is None:
        out[-1] = "plant (truth):"
        d0 = {k: None for k in d}
    for k, v in r["plant"].items():
        ref = "" if v["default"] is None else \
            f" ({v['default']:.4g}, {v['change_percent']:+.1f} %)"
        out.append(f"  {k:<3}{v['value']:>12.4g} {v['unit']:<10}{ref}")

    def dflt(x, spec, scale=1.0, pad=2):
        return "" if x is None else " " * pad + f"(default {scale * x:{spec}})"
    kspec = ".2f" if speed == "rad/s" else ".4g"
    out += ["", "what a fit should find (identifiable combinations):",
            f"  Km     {d['km_rad_s_per_v']:8{kspec}} {speed} per V"
            + dflt(d0["km_rad_s_per_v"], kspec),
            f"  tau_m  {1e3 * d['tau_m_s']:8.1f} ms" + dflt(d0["tau_m_s"], ".1f", 1e3, 11)]
    if "tau_e_s" in d:
        out.append(f"  tau_e  {1e3 * d['tau_e_s']:8.2f} ms"
                   + dflt(d0["tau_e_s"], ".2f", 1e3, 11))
    out += ["", "hidden effects:"]
    if not r["effects"]:
        out.append("  none")
    for name, e in r["effects"].items():
        ps = ", ".join(f"{k} = {v:g} {e['units'][k]}" for k, v in e["params"].items())
        out += [f"  {name}: {ps}", f"      {e['summary']}",
                f"      shows as: {e['signature']}", f"      confirm with: {e['experiment']}"]
    return "\n".join(out)


# -- check ----------------------------------------------------------------------------

def _model_effects(model: dict) -> dict:
    """name -> params of a model file's effects (user effects by their class name)."""
    # a hand-written model may spell a catalogue effect in any case
    eps = {catalogue_name(k): v for k, v in (model.get("effect_params") or {}).items()}
    out = {}
    for spec in model.get("effects") or []:
        name = catalogue_name(str(spec))
        if name in eps:
            out[name] = eps[name]
            continue
        # a user effect "file.py:Class": its params are stored under the effect's name
        cands = [k for k in eps if k not in out and k not in
                 {catalogue_name(str(e)) for e in model.get("effects") or []}]
        out[name] = eps[cands[0]] if cands else {}
    # a torque or force drive's file names its levels in N m or N: back to input volts
    effects = [get_effect(n) for n in out if n in CATALOGUE]
    out = drive_units.from_drive(effects, out, model.get("structure") or "voltage",
                                 model.get("constants") or {})
    return {k: {p: v for p, v in (ps or {}).items() if isinstance(v, (int, float))}
            for k, ps in out.items()}


def _km_tau(cls, params: dict, ka: float):
    sp = cls.servo(params, {"Ka": ka})
    return sp.km, sp.tau_m_approx


def check(path: Path | str, model_path: Path | str, tolerance: float = PASS_TOLERANCE) -> dict:
    """Grade a model file against a mystery rig's hidden truth.

    An effect is *found* when the model has it by name, or has another effect with the
    same parameter (e.g. ``stiction`` or a user-written Coulomb friction for
    ``coulomb_friction``: both have ``tc_v``). Found effects pass when every parameter
    is within ``tolerance`` (relative) of the truth. Score: per hidden effect 1 point
    for finding it and 1 for its parameters; minus 0.5 for every extra effect; as a
    percentage of the maximum.
    """
    truth = load_mystery(path)["rig"]
    model_path = Path(model_path)
    # validated, never loaded: grading reads the effects' names and numbers only, so a
    # student's user effect (FILE.py:Class) is matched by its parameters, not run
    model = read_model_file(model_path)
    hidden = truth.get("effects", {})  # catalogue names, as load_rig spells them
    have = _model_effects(model)
    used: set[str] = set()
    effects = {}
    for name, tparams in hidden.items():
        match = name if name in have else next(
            (m for m, ps in have.items() if m not in used and set(tparams) <= set(ps)), None)
        if match is None:
            effects[name] = {"status": "missed", "as": None, "params": {}, "pass": False,
                             "verdict": f"{name}: missed — the model has no {name} "
                                        f"({', '.join(f'{k} = {v:g}' for k, v in tparams.items())})"}
            continue
        used.add(match)
        perr = {}
        for k, tv in tparams.items():
            mv = have[match].get(k)
            err = None if mv is None else 100.0 * (mv - tv) / tv
            perr[k] = {"truth": tv, "model": mv, "error_percent": err,
                       "pass": err is not None and abs(err) <= 100 * tolerance}
        ok = all(p["pass"] for p in perr.values())
        alias = "" if match == name else f" (as {match})"
        detail = ", ".join(f"{k} {p['model']:.3g} vs {p['truth']:.3g} ({p['error_percent']:+.0f} %)"
                           if p["model"] is not None else f"{k} missing" for k, p in perr.items())
        effects[name] = {"status": "found", "as": match, "params": perr, "pass": ok,
                         "verdict": f"{name}: found{alias}, {detail}: "
                                    f"{'pass' if ok else f'size off by more than {100 * tolerance:.0f} %'}"}
    extra = {m: ps for m, ps in have.items() if m not in used}
    extra_verdicts = [f"{m}: extra — not in the rig ({', '.join(f'{k} = {v:.3g}' for k, v in ps.items()) or 'no params'}); "
                      "it costs parameters without explaining anything real" for m, ps in extra.items()]
    pts = sum((e["status"] == "found") + e["pass"] for e in effects.values()) - 0.5 * len(extra)
    maxpts = 2 * len(hidden)
    score = 100.0 if maxpts == 0 and not extra else max(0.0, 100.0 * pts / max(maxpts, 1))
    # the identifiable plant combinations, for information
    ka = (model.get("constants") or {}).get("Ka", truth["amplifier"]["gain"])
    plant = {}
    try:
        cls = _plant(truth)
        km, tau = _km_tau(cls, {k: float(model["params"][k]) for k in cls.names}, float(ka))
        d = _derived(truth["plant"], truth)
        plant = {"km": {"truth": d["km_rad_s_per_v"], "model": km,
                        "error_percent": 100 * (km / d["km_rad_s_per_v"] - 1)},
                 "tau_m_s": {"truth": d["tau_m_first_order_s"], "model": tau,
                             "error_percent": 100 * (tau / d["tau_m_first_order_s"] - 1)}}
    except (KeyError, TypeError, ValueError, ZeroDivisionError):
        pass
    rmse = model.get("rmse_over_noise")
    overall = rmse.get("overall") if isinstance(rmse, dict) else rmse
    all_pass = all(e["pass"] for e in effects.values()) and not extra
    n_found = sum(e["status"] == "found" for e in effects.values())
    verdict = (f"{n_found} of {len(hidden)} hidden effect(s) found, "
               f"{sum(e['pass'] for e in effects.values())} sized within {100 * tolerance:.0f} %, "
               f"{len(extra)} extra; score {score:.0f}/100"
               + (" — complete" if all_pass else ""))
    return {"file": str(path), "model": str(model_path), "score": round(score, 1),
            "pass": all_pass, "found": [n for n, e in effects.items() if e["status"] == "found"],
            "missed": [n for n, e in effects.items() if e["status"] == "missed"],
            "extra": sorted(extra), "effects": effects, "extra_verdicts": extra_verdicts,
            "plant": plant, "rmse_over_noise": overall,
            "rmse_over_noise_channels": rmse if isinstance(rmse, dict) else None,
            "tolerance_percent": 100 * tolerance, "verdict": verdict}


def blind(result: dict) -> dict:
    """A check result with the hidden truth taken out (for a student's self-check):
    counts and the student's own effects only, never the names of missed effects."""
    return {"file": result["file"], "model": result["model"],
            "score": result["score"], "pass": result["pass"],
            "found": result["found"], "missed_count": len(result["missed"]),
            "extra": result["extra"],
            "effects": {n: {"pass": e["pass"]} for n, e in result["effects"].items()
                        if e["status"] == "found"},
            "rmse_over_noise": result["rmse_over_noise"],
            "verdict": result["verdict"]}


def format_check(res: dict, blind_mode: bool = False) -> str:
    out = [f"model {res['model']} against {res['file']}:"] if "model" in res else []
    if blind_mode:
        for n, e in res["effects"].items():
            out.append(f"  {n}: found, size {'within' if e['pass'] else 'NOT within'} "
                       "tolerance")
        if res["missed_count"]:
            out.append(f"  {res['missed_count']} hidden effect(s) still missing")
        for m in res["extra"]:
            out.append(f"  {m}: not in the rig")
    else:
        for e in res["effects"].values():
            out.append("  " + e["verdict"])
        out += ["  " + v for v in res["extra_verdicts"]]
        for k, p in res["plant"].items():
            label = "Km (rad/s per V)" if k == "km" else "tau_m (s)"
            out.append(f"  plant {label}: model {p['model']:.4g} vs truth {p['truth']:.4g} "
                       f"({p['error_percent']:+.1f} %)")
    r = res.get("rmse_over_noise")
    if r is not None:
        out.append(f"  rmse/noise of the model: {r:.2f} (1.0 is the noise floor)")
    out.append(res["verdict"])
    return "\n".join(out)
