"""Settling what the data leave unpinned: the same fit on every machine.

Speed and position alone fix a DC servo's gain Km and time constant tau_m, not R, L, J,
B and K one by one (docs/physics.md, 'Identifiability'): a family of parameter
sets fits exactly as well, and a least-squares fit stops along it wherever the machine's
rounding leaves it (the same command ended at R 4.50, 4.01 or 3.54 ohm with only the
BLAS's kernel changed). :func:`settle` ends every local fit by a stated rule instead:

* the directions of the plant's parameters (log10) that the data leave free are found at
  the fit: unseen by the identifiability report's rule (a 95 % interval wider than a
  factor 2) even were the fit at the noise floor, and a move to the settling point along
  them raises the misfit by less than the noise's 95 % band (:func:`unpinned`);
* the fit is run again from where it ended with a Gaussian prior along those directions
  only, :data:`WEIGHT` per decade, centred on the plant's settling point
  (:meth:`labrig.model.plants.Plant.settling_point`: the geometric middle of each
  parameter's bounds; an inductance where the fit put it);
* the answer is the member of the family nearest that point. The prior has no component
  along a direction the data resolve, so the gain, the time constants and every effect's
  size stay the data's, and the settled fit is one the data cannot tell from the best.
"""
from __future__ import annotations

import numpy as np

from labrig.identification.local import local
from labrig.identification.result import IdentResult

__all__ = ["settle", "unpinned", "UNSEEN_DECADES", "CHI2", "WEIGHT"]

#: a direction is unseen when its 95 % half-width is wider than this, in decades (a
#: factor 2 either way: the identifiability report's rule, docs/physics.md)
UNSEEN_DECADES = float(np.log10(2.0) / 2.0)
#: and it is settled when the move to the settling point along it would raise the
#: misfit by less than the noise's 95 % band: chi-square of one degree of freedom
CHI2 = 3.84
#: the prior's weight along a settled direction, per decade of the parameters, in the
#: residuals' units (each divided by its noise and by the root of their number); far
#: above the data's along such a direction and their finite-difference noise (a tenth of
#: it left the README's fit 5 % apart on two BLAS kernels)
WEIGHT = 10.0


def unpinned(jac: np.ndarray, columns: np.ndarray, toward: np.ndarray, s2: float) -> np.ndarray:
    """The directions of ``columns`` that the data leave free and that may be settled.

    A direction (a right singular vector of ``jac[:, columns]``, singular value s) is
    unseen when ``1.96 sqrt(s2) / s`` exceeds :data:`UNSEEN_DECADES`, and is settled when
    moving ``toward`` along it changes the misfit by at most :data:`CHI2` times ``s2``.

    Parameters
    ----------
    jac : ndarray, shape (m, D)
        The residuals' Jacobian at the fit (search coordinates, log10 for the plant).
    columns : ndarray of int
        The coordinates considered (the plant's).
    toward : ndarray, shape (D,)
        The settling point minus the fit.
    s2 : float
        A residual's variance at the noise floor.

    Returns
    -------
    ndarray, shape (k, D)
        Orthonormal rows, zero outside ``columns``; k may be 0.
    """
    J = np.asarray(jac, float)
    out = np.zeros((0, J.shape[1]))
    if columns.size == 0 or not np.all(np.isfinite(J)) or not s2 > 0:
        return out
    # (never the m x m left factor: m is tens of thousands of residuals)
    _, sv, vt = np.linalg.svd(J[:, columns], full_matrices=J.shape[0] < columns.size)
    sv = np.concatenate([sv, np.zeros(columns.size - sv.size)])
    move = vt @ np.asarray(toward, float)[columns]
    unseen = 1.96 * np.sqrt(s2) > UNSEEN_DECADES * sv
    flat = unseen & ((sv * move) ** 2 <= CHI2 * s2)
    out = np.zeros((int(flat.sum()), J.shape[1]))
    out[:, columns] = vt[flat]
    return out


def settle(result: IdentResult, objective, lower: np.ndarray, upper: np.ndarray) -> IdentResult:
    """End a local fit at the settled member of its family of equal fits.

    Parameters
    ----------
    result : IdentResult
        A local fit (CO, or JFO/PSO polished) with its Jacobian.
    objective : labrig.identification.objective.Objective
    lower, upper : ndarray
        The search bounds.

    Returns
    -------
    IdentResult
        ``result`` when the data pin every plant direction (or the fit has no Jacobian);
        else the settled fit: ``x``, ``fun``, ``jac``, covariance from the run with the
        prior, the evaluations summed, ``history`` and ``nit`` kept, and
        ``extra["settled"]`` with the number of directions settled and the point.
    """
    if result.jac is None or result.cost is None or not np.isfinite(result.fun):
        return result
    space = objective.space
    free = space.free
    log = dict(zip(space.names, space.log))
    cols = np.array([j for j, n in enumerate(free) if n in space.plant.names and log[n]], int)
    lo, hi = np.asarray(lower, float), np.asarray(upper, float)
    centre = np.array(result.x, float)
    fitted = space.as_dict(space.to_physical(np.asarray(result.x, float)[None, :])[0])
    point = space.plant.settling_point({n: (space.lower[space.names.index(n)],
                                            space.upper[space.names.index(n)]) for n in free
                                        if n in space.plant.names}, fitted)
    for j in cols:
        centre[j] = np.log10(point[free[j]])
    # measured against the sensors' noise, not the fit's misfit: a model that lacks an
    # effect has a misfit far above the floor, and judged by it would let a direction go
    # that the data resolve once the effect is in (each residual is divided by its noise
    # floor and by the root of their number, so at the floor each has variance 1/m)
    s2 = 1.0 / objective.m
    dirs = unpinned(result.jac, cols, centre - np.asarray(result.x, float), s2)
    if not len(dirs):
        return result
    x0 = np.clip(np.asarray(result.x, float), lo, hi)
    loc = local(objective.solver_residuals, lo, hi, x0=x0, starts=1, seed=result.seed,
                jac_batch=objective.solver_residuals_batch, prior=(centre, WEIGHT * dirs))
    if not np.isfinite(loc.fun):
        return result
    return IdentResult(
        x=loc.x, fun=loc.fun, nfev=result.nfev + loc.nfev, nit=result.nit,
        history=list(result.history), seed=result.seed,
        message=f"{result.message}; settled along {len(dirs)} unpinned direction(s)",
        method=result.method, success=bool(result.success and loc.success),
        jac=loc.jac, cost=loc.cost,
        extra={**loc.extra, "settled": {"directions": int(len(dirs)),
                                        "point": {free[j]: float(point[free[j]]) for j in cols}},
               "unsettled": {"x": np.asarray(result.x).tolist(), "fun": float(result.fun)}})
