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

import math

import numpy as np

from labrig.model.plants import VoltagePlant

STRUCTURAL = 1e-6
#: relative singular value under which (R/l, L/l, lJ, lB, K) counts as the exact symmetry
PRACTICAL = 1e-3
#: a quantity (a combination, or a direction of the parameters) whose 95 % interval spans
#: more than this factor is "not seen by these data": no interval is printed for it
SEEN_SPAN = 2.0
COMBINATION_UNITS = {"km": "speed per input V", "tau_m_s": "s", "tau_e_s": "s"}


def _combos(plant, values: dict, constants: dict) -> np.ndarray:
    sp = plant.servo(values, constants)
    every = {"km": sp.km, **_time_constants(sp)}
    return np.array([every[k] for k in plant.combinations])


def time_constants(plant, values: dict, constants: dict) -> dict:
    """``{"tau_m_s", "tau_e_s"}`` of a voltage plant's parameters; {} for a plant whose
    drive imposes the torque (its "electrical" pole is the drive's, not the data's)."""
    if plant.kind != VoltagePlant.kind:
        return {}
    return _time_constants(plant.servo(values, constants))


def _time_constants(sp) -> dict:
    """tau_m (slow) and tau_e (fast) of J L s^2 + (J R + B L) s + (B R + K ke), the poles
    of :attr:`ServoParams.poles`, by the quadratic formula in the form that keeps both
    roots' precision when they are decades apart: np.roots loses digits of the slow one,
    which the finite differences of the intervals would turn into a spread."""
    a2, a1 = sp.J * sp.L, sp.J * sp.R + sp.B * sp.L
    a0 = sp.B * sp.R + sp.K * sp.ke
    disc = a1 * a1 - 4.0 * a2 * a0
    if disc < 0:  # complex pair: one real part
        return {"tau_m_s": 2.0 * a2 / a1, "tau_e_s": 2.0 * a2 / a1}
    big = 0.5 * (a1 + math.sqrt(disc))
    return {"tau_m_s": big / a0, "tau_e_s": a2 / big}


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


def _coefficient_jacobian(plant: dict, free: list[str], plant_class, current: bool):
    """d(coefficients)/d ln(free plant parameters), or None when none is free."""
    names = plant_class.names
    idx = [names.index(n) for n in free if n in names]
    if not idx:
        return None
    p = np.array([plant[n] for n in names])
    coeffs = _coefficients(plant_class, current)
    lp = np.log(p)
    Jm = np.empty((len(coeffs(lp)), len(idx)))
    for c, k in enumerate(idx):
        d = np.zeros(len(names))
        d[k] = 1e-6
        Jm[:, c] = (coeffs(lp + d) - coeffs(lp - d)) / 2e-6
    return Jm


def structural_rank(plant: dict, free: list[str], plant_class=VoltagePlant,
                    current: bool = False) -> int:
    """Rank of d(coefficients)/d ln(free plant parameters): for the voltage plant 3 at
    most from speed and position, 5 with the armature current; 2 for torque/force."""
    Jm = _coefficient_jacobian(plant, free, plant_class, current)
    if Jm is None:
        return 0
    s = np.linalg.svd(Jm, compute_uv=False)
    return int(np.sum(s > 1e-6 * s[0]))


def structural_null(plant: dict, free: list[str], plant_class=VoltagePlant,
                    current: bool = False) -> np.ndarray:
    """The exact symmetries of the model at ``plant``: an orthonormal basis (rows) of the
    directions in ln(free plant parameters) that leave every transfer-function
    coefficient unchanged, e.g. (R/l, L/l, l J, l B, K). Empty (0 rows) when the free
    plant parameters are all identifiable."""
    plant_free = [n for n in free if n in plant_class.names]
    Jm = _coefficient_jacobian(plant, plant_free, plant_class, current)
    if Jm is None:
        return np.empty((0, 0))
    _, s, Vt = np.linalg.svd(Jm, full_matrices=True)
    rank = int(np.sum(s > 1e-6 * s[0]))
    return Vt[rank:]


def _combination_spread(S, G, r0, s2, null, free, plant_names):
    """How far the data let each combination move: ``(sd, shift)`` of ln(combination)
    (rows of ``G``, d ln c / d search coordinate) by the delta method, every direction of
    the fit counted, and the Gauss-Newton step to the local optimum.

    The combinations are unchanged along the model's exact symmetries (``null``: rows in
    ln(free plant parameters)), so those directions are taken out before inverting;
    there the sensitivity ``S`` holds only rounding, which would drown any combination.
    Every other direction counts with its own singular value, however small: a
    combination that moves along a weak direction (tau_e of a pole faster than the
    sampling) gets the wide interval the data allow, one that does not keeps a tight one.
    (A pseudo-inverse with a cut-off would drop the weak directions and hand every
    combination a tight interval.) The step says where the optimum lies when the fit
    stopped short of it (JFO and PSO end near, not at, the optimum): an interval must
    hold it too.
    """
    D = S.shape[1]
    Q = np.eye(D)
    if len(null):
        N = np.zeros((len(null), D))
        N[:, [free.index(n) for n in free if n in plant_names]] = null
        Q = np.linalg.svd(N, full_matrices=True)[2][len(null):].T  # the rest, orthonormal
    U, sv, Wt = np.linalg.svd(S @ Q, full_matrices=False)
    A = Wt @ (G @ Q).T                          # (directions, combinations)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(A == 0, 0.0, A / sv[:, None])  # a direction with no singular value: inf
        sd = np.sqrt(s2 * np.sum(z ** 2, axis=0))
        # the step only along directions the data see: along a free one it runs off to a
        # bound (where a fit may rest with a slope), and the spread above already counts it
        seen = (sv > STRUCTURAL * sv[0]) & (2 * 1.96 * np.sqrt(s2) / sv <= np.log(SEEN_SPAN))
    shift = -(U.T @ r0)[seen] @ z[seen]
    return sd, shift


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
    R = objective.noise_residuals(X)
    S = np.empty((R.shape[1], D))
    free_log = sp.log[sp.free_idx]
    for k in range(D):
        # search coordinates are log10 for log parameters: convert to d/d ln p
        scale = 1.0 / np.log(10.0) if free_log[k] else 1.0
        S[:, k] = (R[2 * k] - R[2 * k + 1]) / (2 * step[k]) * scale
    r0 = objective.noise_residuals(x_search[None, :])[0]
    m = len(r0)
    U, sv, Vt = np.linalg.svd(S, full_matrices=False)
    rel = sv / sv[0] if sv[0] > 0 else sv
    s2 = float(np.sum(r0 ** 2) / max(m - D, 1))
    # a direction is unseen when the data leave it free beyond a factor SEEN_SPAN (95 %):
    # the same measure that decides the combinations below, so no direction is called
    # free while a combination that moves along it gets an interval
    with np.errstate(divide="ignore", invalid="ignore"):
        unseen = (rel < STRUCTURAL) | (2 * 1.96 * np.sqrt(s2) / sv > np.log(SEEN_SPAN))
    keep = ~unseen
    cov = s2 * (Vt[keep].T / sv[keep] ** 2) @ Vt[keep]
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
    small = [k for k in range(D) if unseen[k]]
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
    snull = structural_null(pd, free, plant, current)
    sdl, shift = _combination_spread(S, G, r0, s2, snull, free, plant.names)
    dt = min(r.dt for r in objective.runs)
    comb = {}
    speed = plant.speed_unit()
    units = {**COMBINATION_UNITS, "km": f"{speed} per V"}
    for key, v, sc, dc in zip(plant.combinations, base, sdl, shift):
        # the 95 % interval about the value, stretched to the optimum when the fit
        # stopped short of it; seen when it spans less than a factor SEEN_SPAN (wider says
        # nothing: a pole the data barely touch), and only then printed
        lo, hi = min(dc, 0.0) - 1.96 * sc, max(dc, 0.0) + 1.96 * sc
        ok = bool(np.isfinite(hi - lo) and hi - lo <= np.log(SEEN_SPAN))
        # one rule for every fit: a time constant under half a sample period is not seen,
        # whatever its interval (friction or an offset can lend it a spurious one), unless
        # it is given (L fixed by a locked-rotor test sets the fast pole)
        if key.startswith("tau_") and v < 0.5 * dt and not (key == "tau_e_s" and "L" in sp.fixed):
            ok = False
        comb[key] = {"value": float(v), "unit": units[key], "identifiable": ok,
                     "interval95": [float(v * np.exp(lo)), float(v * np.exp(hi))] if ok else None}
    te = comb.get("tau_e_s")
    if te is not None and not te["identifiable"]:
        k = plant.combinations.index("tau_e_s")
        fix = "sample faster, or fix L and R (locked-rotor test: --fix R=..,L=..)"
        why = (f"it is shorter than half a sample period ({0.5 * dt:.3g} s); {fix}"
               if te["value"] < 0.5 * dt else
               "the fit had not settled along it; polish the fit (--polish)"
               if abs(shift[k]) > 1.96 * sdl[k] else
               f"the fit barely changes when it moves; {fix}")
        warnings.append(f"tau_e = {te['value']:.3g} s (the fast pole) is not seen by these data: "
                        f"{why}")
    params = {}
    for k, n in enumerate(free):
        v = pd[n]
        s = sd[k]
        if free_log[k]:
            iv = [v * np.exp(-1.96 * s), v * np.exp(1.96 * s)]
        else:
            iv = [v - 1.96 * s, v + 1.96 * s]
        # unseen along a weak direction of the data, along an exact symmetry of the model
        # (whatever the finite differences say: stick-slip lends them noise), or as the
        # inductance of a pole the data do not see
        flag = (any(abs(Vt[j, k]) > 0.1 for j in small)
                or (n in plant_free and len(snull)
                    and float(np.linalg.norm(snull[:, plant_free.index(n)])) > 0.1)
                or (n == "L" and te is not None and not te["identifiable"]))
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
