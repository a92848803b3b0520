"""Identifiability (docs/physics.md, 'Identifiability'): what the data can and cannot pin down.

From u to w or theta the voltage-driven servo has five parameters but only three
transfer-function coefficients (b0 = Ka K/(J L), a1 = R/L + B/J, a0 = (B R + K^2)/(J L)):
a two-dimensional family of (R, L, J, B, K) gives identical responses, e.g.
(R/l, L/l, l J, l B, K). A measured armature current adds two more (Ka/L and
Ka B/(J L)) and fixes all five. A torque- or force-driven axis has two parameters and
two coefficients (kd/J, B/J): both are identifiable. So labrig reports the identifiable
combinations first (Km, tau_m, and tau_e for the voltage plant) with intervals, then
the raw parameters with warnings.
"""
from __future__ import annotations

import numpy as np

from ..model.plants import VoltagePlant

STRUCTURAL = 1e-6
PRACTICAL = 1e-3
COMBINATION_UNITS = {"km": "speed per input V", "tau_m_s": "s", "tau_e_s": "s"}


def _combos(plant, values: dict, constants: dict) -> np.ndarray:
    sp = plant.servo(values, constants)
    every = {"km": sp.km, "tau_m_s": sp.tau_m, "tau_e_s": sp.tau_e}
    return np.array([every[k] for k in plant.combinations])


def _coefficients(plant, current: bool):
    """The transfer-function coefficients the data fix, as a function of ln(parameters)."""
    if plant is not VoltagePlant:
        return lambda lp: np.array([-lp[0], lp[1] - lp[0]])   # kd/J, B/J

    def coeffs(lp):
        R, L, J, B, K = np.exp(lp)
        out = [K / (J * L), R / L + B / J, (B * R + K * K) / (J * L)]
        if current:  # I/U = Ka (J s + B) / (J L s^2 + ...)
            out += [1.0 / L, B / (J * L)]
        return np.log(out)
    return coeffs


def structural_rank(plant: dict, free: list[str], plant_class=VoltagePlant,
                    current: bool = False) -> int:
    """Rank of d(coefficients)/d ln(free plant parameters): for the voltage plant 3 at
    most from speed and position, 5 with the armature current; 2 for torque/force."""
    names = plant_class.names
    idx = [names.index(n) for n in free if n in names]
    if not idx:
        return 0
    p = np.array([plant[n] for n in names])
    coeffs = _coefficients(plant_class, current)
    lp = np.log(p)
    Jm = np.empty((len(coeffs(lp)), len(idx)))
    for c, k in enumerate(idx):
        d = np.zeros(len(names))
        d[k] = 1e-6
        Jm[:, c] = (coeffs(lp + d) - coeffs(lp - d)) / 2e-6
    s = np.linalg.svd(Jm, compute_uv=False)
    return int(np.sum(s > 1e-6 * s[0]))


def readable_direction(v: np.ndarray, names: list[str]) -> str:
    """A null direction in log space as a scaling family, e.g.
    ``(R, L, J, B, K) -> (R l^-1, L l^-1, J l^+1, B l^+1, K)``."""
    v = v / v[np.argmax(np.abs(v))]
    parts = []
    for n, c in zip(names, v):
        parts.append(n if abs(c) < 0.05 else f"{n}*l^{c:+.2f}".replace(".00", ""))
    return f"({', '.join(names)}) -> ({', '.join(parts)}) for any l > 0 leaves the fit unchanged"


def analyse_identifiability(objective, x_search: np.ndarray, Ka: float) -> dict:
    """Sensitivity SVD, correlations and intervals at the optimum.

    Parameters
    ----------
    objective : Objective
    x_search : array
        The optimum in search coordinates.
    Ka : float
        Amplifier gain (known constant) for the combinations.
    """
    sp = objective.space
    free = sp.free
    phys = sp.to_physical(x_search[None, :])[0]
    pd = sp.as_dict(phys)
    # sensitivity of the normalised residuals to ln(parameter) for log ones
    D = len(free)
    lo, hi = sp.search_bounds()
    # log10 steps of 0.005 (1.2 %): small enough for O(h^2) truncation, large enough
    # to step over the tiny discontinuities of the stick-slip resolution
    step = np.where(sp.log[sp.free_idx], 0.005, 1e-3 * (hi - lo))
    X = np.repeat(x_search[None, :], 2 * D, axis=0)
    for k in range(D):
        X[2 * k, k] += step[k]
        X[2 * k + 1, k] -= step[k]
    R = objective.residuals_batch(X)
    S = np.empty((R.shape[1], D))
    free_log = sp.log[sp.free_idx]
    for k in range(D):
        # search coordinates are log10 for log parameters: convert to d/d ln p
        scale = 1.0 / np.log(10.0) if free_log[k] else 1.0
        S[:, k] = (R[2 * k] - R[2 * k + 1]) / (2 * step[k]) * scale
    r0 = objective.residuals_batch(x_search[None, :])[0]
    m = len(r0)
    U, sv, Vt = np.linalg.svd(S, full_matrices=False)
    rel = sv / sv[0] if sv[0] > 0 else sv
    s2 = float(np.sum(r0 ** 2) / max(m - D, 1))
    cov = s2 * np.linalg.pinv(S.T @ S, rcond=PRACTICAL ** 2)
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    with np.errstate(all="ignore"):
        corr = cov / np.outer(sd, sd)
    corr = np.where(np.isfinite(corr), corr, 0.0)

    warnings, null = [], []
    symmetry = None
    if all(n in free for n in ("R", "L", "J", "B")):
        # the exact symmetry (docs/physics.md, 'Identifiability'): (R/l, L/l, lJ, lB, K)
        v = np.zeros(D)
        for n, c in (("R", -1), ("L", -1), ("J", 1), ("B", 1)):
            v[free.index(n)] = c
        v /= np.linalg.norm(v)
        ratio = float(np.linalg.norm(S @ v) / sv[0]) if sv[0] > 0 else 0.0
        if ratio < PRACTICAL:
            symmetry = {"relative_singular_value": ratio, "kind": "structurally",
                        "direction": "(R, L, J, B, K) -> (R/l, L/l, l*J, l*B, K) for any l > 0 "
                                     "leaves the fit unchanged (exact symmetry of the model)"}
            null.append(symmetry)
    plant = sp.plant
    current = bool(getattr(objective, "use_i", False))
    plant_free = [n for n in free if n in plant.names]
    rank = structural_rank(pd, plant_free, plant, current)
    structural_nullity = len(plant_free) - rank
    small = [k for k, r in enumerate(rel) if r < PRACTICAL]
    for j, k in enumerate(small):
        kind = "structurally" if rel[k] < STRUCTURAL or j >= len(small) - structural_nullity \
            else "practically"
        null.append({"relative_singular_value": float(rel[k]), "kind": kind,
                     "direction": readable_direction(Vt[k], free)})
    if rank < len(plant_free):
        how = ("fix R and L (locked-rotor test: --fix R=..,L=..), or fix K (back-EMF test) "
               "and R." if current else
               "measure the armature current too, or fix R and L (locked-rotor test: "
               "--fix R=..,L=..), or fix K (back-EMF test) and R.")
        warnings.append(
            f"structurally unidentifiable: the data fix only {rank} combinations of the "
            f"{len(plant_free)} free plant parameters ({', '.join(plant_free)}); "
            f"{', '.join(plant.names)} below are one member of a family of equally good fits. "
            f"To pin them down: {how}")
    # directions beyond what the structure explains are worth a word each
    extra = [k for k in small if rel[k] >= STRUCTURAL][: max(0, len(small) - structural_nullity)]
    for k in extra:
        warnings.append(f"practically unidentifiable direction (sigma/sigma1 = {rel[k]:.1e}): "
                        f"{readable_direction(Vt[k], free)}")
    if any(n == "L" for n in plant_free) and pd["L"] / pd["R"] < 0.5 * objective.runs[0].dt:
        warnings.append("tau_e = L/R is shorter than half a sample period: the electrical pole "
                        "is barely visible at this sample rate (sample faster or fix L)")
    pairs = []
    for a in range(D):
        for b in range(a + 1, D):
            if abs(corr[a, b]) > 0.95:
                pairs.append({"a": free[a], "b": free[b], "rho": float(corr[a, b])})

    # identifiable combinations, with intervals by the delta method in log space
    consts = {"Ka": Ka}
    base = _combos(plant, pd, consts)
    G = np.zeros((len(base), D))
    for k, n in enumerate(free):
        if n not in plant.names:
            continue
        h = 1e-6
        q = dict(pd)
        q[n] = pd[n] * np.exp(h)
        G[:, k] = (np.log(_combos(plant, q, consts)) - np.log(base)) / h
        if not free_log[k]:
            G[:, k] /= pd[n]
    var = np.einsum("ij,jk,ik->i", G, cov, G)
    sdl = np.sqrt(np.clip(var, 0, None))
    nullspace = Vt[rel < PRACTICAL]
    comb = {}
    speed = plant.speed_unit()
    units = {**COMBINATION_UNITS, "km": f"{speed} per V"}
    for key, v, s, g in zip(plant.combinations, base, sdl, G):
        unit = units[key]
        # a combination that moves along an unidentifiable direction has no interval
        # (the pseudo-inverse would silently drop that direction and claim precision)
        leak = float(np.max(np.abs(nullspace @ g)) / max(np.linalg.norm(g), 1e-300)) if len(nullspace) else 0.0
        ok = leak < 0.01
        comb[key] = {"value": float(v), "unit": unit, "identifiable": ok,
                     "interval95": [float(v * np.exp(-1.96 * s)), float(v * np.exp(1.96 * s))]
                     if ok else None}
    params = {}
    for k, n in enumerate(free):
        v = pd[n]
        s = sd[k]
        if free_log[k]:
            iv = [v * np.exp(-1.96 * s), v * np.exp(1.96 * s)]
        else:
            iv = [v - 1.96 * s, v + 1.96 * s]
        flag = any(abs(Vt[j, k]) > 0.1 for j, r in enumerate(rel) if r < PRACTICAL)
        params[n] = {"value": float(v), "interval95": None if flag else [float(iv[0]), float(iv[1])],
                     "identifiable": not flag}
    for n, v in sp.fixed.items():
        params[n] = {"value": float(v), "fixed": True, "identifiable": True}
    return {**comb, "current_measured": current,
            "structural_rank": rank, "free_plant_parameters": len(plant_free),
            "all_identifiable": not null and rank == len(plant_free),
            "symmetry": symmetry,
            "relative_singular_values": [float(r) for r in rel],
            "null_directions": null, "correlated_pairs": pairs, "parameters": params,
            "warnings": warnings}
