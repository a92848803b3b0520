"""Local least-squares optimisation, the paper's "CO" (docs/physics.md,
'Constrained optimisation (CO)').

``scipy.optimize.least_squares(method="trf")`` with box bounds, multi-started
from `x0` and/or Latin-hypercube points; :func:`polish` refines a global
(JFO/PSO) result the way ``differential_evolution(polish=True)`` does.

Conventions
-----------
* ``fun`` of the result is the **mean square residual** ``sum(r**2) / m``
  (m = number of residuals), so it is comparable between data sets of
  different length; ``cost = 0.5 * sum(r**2)`` is scipy's value.
* The covariance is ``s**2 (J^T J)^+`` with ``s**2 = 2 cost / (m - n)``,
  computed by SVD with the same singular-value cut-off as
  ``scipy.optimize.curve_fit``; it is NaN when ``m <= n``.  For
  rank-deficient J (an unidentifiable combination of parameters) the
  pseudo-inverse hides the unidentifiable direction, so also look at
  ``extra["rank"]`` and ``extra["singular_values"]``.
* ``nfev`` counts residual vectors evaluated: one per ``residuals`` call and
  P per ``jac_batch`` call of P rows.
* With ``jac_batch`` the trust region works on :func:`reduced` rows (n + 1 of them,
  the same Gauss-Newton model as the m residuals): its SVD no longer grows with m.
  ``fun``, ``jac`` and ``cost`` of the result are the full ones.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from labrig.identification.lhs import latin_hypercube
from labrig.identification.result import IdentResult, check_bounds, check_callable, check_int, check_seed
from labrig.core.parallel import each

__all__ = ["local", "polish", "covariance", "batch_jacobian", "reduced"]

_EPS = np.finfo(float).eps


def _least_squares():
    # scipy.optimize costs ~0.4 s to import; JFO and PSO without polishing never need it
    from scipy.optimize import least_squares

    return least_squares


class _Residuals:
    """Count calls, check the shape, and remember the last evaluation.

    The one-entry cache lets us check a start point for finite residuals
    before handing it to ``least_squares`` without paying twice.
    """

    def __init__(self, residuals: Callable, jac_batch: Callable | None) -> None:
        self.residuals = residuals
        self.jac_batch = jac_batch
        self.m: int | None = None
        self.nfev = 0
        self._last: tuple[np.ndarray, np.ndarray] | None = None

    def _check(self, r: np.ndarray, name: str, rows: int | None = None) -> np.ndarray:
        if rows is None and (r.ndim != 1 or r.size == 0):
            raise ValueError(f"{name}: must return a non-empty 1-D array, got shape {r.shape}")
        if self.m is None and rows is None:
            self.m = r.size  # fixed by the first evaluation
            return r
        expect = (self.m,) if rows is None else (rows, self.m)
        if r.shape != expect:
            raise ValueError(f"{name}: returned shape {r.shape}, expected {expect}")
        return r

    def __call__(self, x: np.ndarray) -> np.ndarray:
        if self._last is not None and np.array_equal(x, self._last[0]):
            return self._last[1].copy()
        r = self._check(np.asarray(self.residuals(x), dtype=float), "residuals")
        self.nfev += 1
        self._last = (np.array(x, dtype=float), r)
        return r.copy()

    def batch(self, X: np.ndarray) -> np.ndarray:
        R = np.asarray(self.jac_batch(X), dtype=float)
        if self.m is None and R.ndim == 2:
            self.m = R.shape[1]
        self.nfev += X.shape[0]
        return self._check(R, "jac_batch", rows=X.shape[0])


def batch_jacobian(batch: Callable[[np.ndarray], np.ndarray], x: np.ndarray,
                   lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Forward-difference Jacobian from ONE population-vectorised call.

    Evaluates ``batch`` on the D + 1 rows ``[x, x + h_1 e_1, ..., x + h_D e_D]``
    with ``h_k = sqrt(eps) * max(1, |x_k|)``, stepping backwards where a
    forward step would leave the box.  The base point is part of the same
    call (rather than reusing ``residuals(x)``) so that a batched simulator
    whose numerics depend on the batch (e.g. a shared adaptive step) still
    gives consistent differences.

    Parameters
    ----------
    batch : callable
        ``batch(X) -> R``, X shape (P, D), R shape (P, m).
    x : ndarray, shape (D,)
    lower, upper : ndarray, shape (D,)

    Returns
    -------
    ndarray, shape (m, D)
    """
    x = np.asarray(x, dtype=float)
    n = x.size
    h = np.sqrt(_EPS) * np.maximum(1.0, np.abs(x))
    forward_ok = x + h <= upper
    backward_ok = x - h >= lower
    h = np.where(forward_ok, h, np.where(backward_ok, -h,
                 # box narrower than h: use the larger side
                 np.where(upper - x >= x - lower, upper - x, lower - x)))
    X = np.repeat(x[None, :], n + 1, axis=0)
    X[np.arange(1, n + 1), np.arange(n)] += h
    h = X[np.arange(1, n + 1), np.arange(n)] - x  # the step actually taken
    R = np.asarray(batch(X), dtype=float)
    return (R[1:] - R[0]).T / h


def reduced(J: np.ndarray, f: np.ndarray) -> np.ndarray:
    """An (n+1, n) matrix K with ``K^T K = J^T J`` and ``K^T (|f| e) = J^T f``
    (e the last unit vector): the least-squares problem at this point in n + 1 rows.

    scipy's trust region takes an SVD of the m x n Jacobian and a product with it at
    every step; with m in the tens of thousands that, not the simulation, was most of a
    fit. The Gauss-Newton model it builds, ``|f|^2 + 2 g^T p + p^T J^T J p``, depends on
    J and f only through ``J^T J``, ``g = J^T f`` and ``|f|``, which K and ``|f| e``
    carry exactly; so is the scaling by column norms. The Gram matrix of ``[J f]`` is
    equilibrated, factored by a symmetric eigendecomposition (rank-deficient J is
    fine) and turned by one Householder reflection so its last column is ``|f| e``.
    """
    rows = np.empty((J.shape[1] + 1, J.shape[0]))
    rows[:-1], rows[-1] = J.T, f
    # einsum, not BLAS: a threaded BLAS sums in an order that depends on its thread
    # count, and a fit along a flat valley would end elsewhere on another machine
    A = np.einsum("im,jm->ij", rows, rows)
    d = np.sqrt(np.diag(A))
    d[~(d > 0)] = 1.0
    lam, V = np.linalg.eigh(A / np.outer(d, d))
    M = np.sqrt(np.clip(lam, 0.0, None))[:, None] * V.T * d[None, :]
    c = M[:, -1].copy()
    c[-1] -= np.linalg.norm(c)
    if c @ c > 0:
        M -= np.outer(c, (2.0 / (c @ c)) * (c @ M))
    return M[:, :-1]


def covariance(jac: np.ndarray, cost: float) -> dict[str, Any]:
    """Parameter covariance ``s^2 (J^T J)^+`` and related diagnostics.

    Parameters
    ----------
    jac : ndarray, shape (m, n)
        Residual Jacobian at the optimum.
    cost : float
        ``0.5 * sum(r**2)`` at the optimum.

    Returns
    -------
    dict
        ``cov`` (n, n), ``stderr`` (n,), ``s2``, ``rank``,
        ``singular_values``.  Values are NaN when ``m <= n``.
    """
    J = np.asarray(jac, dtype=float)
    m, n = J.shape
    _, sv, VT = np.linalg.svd(J, full_matrices=False)
    cut = _EPS * max(J.shape) * (sv[0] if sv.size else 0.0)
    keep = sv > cut
    pinv_jtj = (VT[keep].T / sv[keep] ** 2) @ VT[keep]
    s2 = 2.0 * cost / (m - n) if m > n else np.nan
    cov = s2 * pinv_jtj
    return {"cov": cov, "stderr": np.sqrt(np.clip(np.diag(cov), 0.0, None)),
            "s2": s2, "rank": int(keep.sum()), "singular_values": sv}


def local(residuals: Callable[[np.ndarray], np.ndarray], lower: Any, upper: Any, *,
          x0: Any = None, starts: int = 8, seed: int | None = None,
          max_nfev: int | None = None,
          jac_batch: Callable[[np.ndarray], np.ndarray] | None = None,
          options: dict[str, Any] | None = None,
          callback: Callable[[int, float], Any] | None = None,
          threads: bool = False,
          stop: Callable[[list], bool] | None = None,
          prior: tuple[Any, Any] | None = None) -> IdentResult:
    """Bounded multi-start nonlinear least squares (trust-region reflective).

    Parameters
    ----------
    residuals : callable
        ``residuals(x) -> r``, x shape (D,), r a 1-D array of fixed length m.
        Non-finite residuals at a start point skip that start; during the
        search trf shrinks its trust region away from them.
    lower, upper : array_like, shape (D,)
        Finite bounds, ``lower < upper``.
    x0 : array_like, shape (D,), optional
        First start (must lie in the box); the other ``starts - 1`` starts
        are Latin-hypercube points.  Without x0 all starts are LHS points.
    starts : int
        Total number of starts (>= 1).
    seed : int or None
        Seeds the Latin-hypercube sampler; None draws one (reported).
    max_nfev : int, optional
        Per-start evaluation limit passed to ``least_squares``.
    jac_batch : callable, optional
        ``jac_batch(X) -> R``, X shape (P, D), R shape (P, m): the same
        residuals for a population.  When given, the Jacobian is computed by
        :func:`batch_jacobian` in one call of D + 1 rows instead of D
        separate ``residuals`` calls.
    options : dict, optional
        Extra keyword arguments for ``least_squares`` (e.g. ``x_scale``,
        ``ftol``); ``method``, ``bounds``, ``jac`` and ``max_nfev`` are set
        here.
    callback : callable, optional
        ``callback(start, best_fun)`` after each start (1-based).
    threads : bool
        Run the starts side by side on the machine's cores
        (:mod:`labrig.core.parallel`); ``residuals`` and ``jac_batch`` must then be
        safe to call from several threads. The result is the same as one by one.
    stop : callable, optional
        ``stop(history) -> bool`` after each iteration of a start (``least_squares``'
        callback), ``history`` the start's mean square residual at its first point and
        after each iteration so far; True ends that start there (its status is -2). A
        start that is not stopped runs exactly as without it.
    prior : (centre, A), optional
        ``centre`` shape (D,), ``A`` shape (k, D): the k rows ``A @ (x - centre)`` are
        added to the residuals the trust region minimises (a Gaussian prior on k
        combinations of the coordinates). Along a valley of equally good fits it settles
        the answer at the point nearest ``centre`` in A's metric, the same point whatever
        the rounding of the machine's linear algebra (:mod:`labrig.identification.settle`).
        The best start is the one of least cost including these rows; ``fun`` and
        ``cost`` of the result are the data's alone.

    Returns
    -------
    IdentResult
        ``method="co"``; ``fun`` is the mean square residual; ``jac`` and
        ``cost`` at the optimum; ``extra`` has ``cost``, ``jac``, ``cov``,
        ``stderr``, ``s2``, ``rank``, ``singular_values``, ``m``,
        ``active_mask``, ``optimality`` and a per-start summary ``starts``.

    Raises
    ------
    ValueError
        Bad argument; the message starts with the argument's name.
    """
    lo, hi = check_bounds(lower, upper)
    D = lo.size
    check_callable("residuals", residuals)
    check_callable("jac_batch", jac_batch, optional=True)
    check_callable("callback", callback, optional=True)
    starts = check_int("starts", starts, 1)
    if max_nfev is not None:
        max_nfev = check_int("max_nfev", max_nfev, 1)
    options = dict(options or {})
    clash = {"method", "bounds", "jac", "max_nfev", "x0", "fun"} & options.keys()
    if clash:
        raise ValueError(f"options: may not set {sorted(clash)}")
    seed = check_seed(seed)
    rng = np.random.default_rng(seed)
    centre, A = _check_prior(prior, D)

    points = []
    if x0 is not None:
        try:
            x0 = np.asarray(x0, dtype=float)
        except (TypeError, ValueError):
            raise ValueError("x0: not numeric") from None
        if x0.shape != (D,):
            raise ValueError(f"x0: shape {x0.shape} does not match bounds shape {(D,)}")
        if not np.all((x0 >= lo) & (x0 <= hi)):
            raise ValueError("x0: lies outside [lower, upper]")
        points.append(x0)
    points.extend(latin_hypercube(starts - len(points), lo, hi, rng))

    def one(start: np.ndarray):
        """One start, with its own counters: (result or None, summary, evaluations)."""
        wrapped = _Residuals(residuals, jac_batch)
        full_jac: dict[bytes, np.ndarray] = {}   # the last Jacobian, for the result

        def jac(x: np.ndarray) -> np.ndarray:
            J = batch_jacobian(wrapped.batch, x, lo, hi)
            full_jac.clear()
            full_jac[x.tobytes()] = J
            return J

        def fun(x: np.ndarray) -> np.ndarray:   # the reduced problem: only |r| matters
            r = wrapped(x)
            out = np.zeros(D + 1)
            p = A @ (x - centre)
            out[-1] = np.sqrt(np.einsum("i,i", r, r) + np.einsum("i,i", p, p)) \
                if np.all(np.isfinite(r)) else np.inf
            return out

        def jac_reduced(x: np.ndarray) -> np.ndarray:
            J, r = jac(x), wrapped(x)
            if prior is not None:   # the prior's rows A (x - centre), their Jacobian A
                J, r = np.vstack([J, A]), np.concatenate([r, A @ (x - centre)])
            return reduced(J, r)

        def with_prior(x: np.ndarray) -> np.ndarray:
            return np.concatenate([wrapped(x), A @ (x - centre)])

        r0 = wrapped(start)
        if not np.all(np.isfinite(r0)):
            return None, {"x0": start, "x": start, "fun": np.inf, "nfev": wrapped.nfev,
                          "status": None, "message": "residuals not finite at start"}, \
                wrapped.nfev
        opts = options
        if stop is not None:
            seen = [float(np.einsum("i,i", r0, r0)) / r0.size]

            def halt(intermediate_result):
                seen.append(2.0 * float(intermediate_result.cost) / r0.size)
                if stop(list(seen)):
                    raise StopIteration
            opts = {**options, "callback": halt}
        if jac_batch is not None:
            res = _least_squares()(fun, start, jac=jac_reduced, bounds=(lo, hi),
                                   method="trf", max_nfev=max_nfev, **opts)
            # the full residuals and Jacobian at the optimum, as without the reduction
            res.fun = wrapped(res.x)
            res.jac = full_jac.get(res.x.tobytes())
            if res.jac is None:
                res.jac = jac(res.x)
        else:
            res = _least_squares()(with_prior if prior is not None else wrapped, start,
                                   jac="2-point", bounds=(lo, hi), method="trf",
                                   max_nfev=max_nfev, **opts)
            res.fun = wrapped(res.x)
        # the data's own cost beside the one minimised (with the prior's rows)
        res.data_cost = float(res.cost) if prior is None else \
            0.5 * float(np.einsum("i,i", res.fun, res.fun))
        return res, {"x0": start, "x": res.x, "fun": 2.0 * res.data_cost / res.fun.size,
                     "nfev": wrapped.nfev, "status": int(res.status),
                     "message": res.message}, wrapped.nfev

    if threads:
        outcomes = each(one, points)
    else:
        outcomes = [one(p) for p in points]
    best = None
    history: list[float] = []
    summary: list[dict[str, Any]] = []
    nfev = 0
    for k, (res, summ, n) in enumerate(outcomes, 1):   # in the starts' order, as one by one
        summary.append(summ)
        nfev += n
        if res is not None and (best is None or res.cost < best.cost):
            best = res
        history.append(float(2.0 * best.data_cost / best.fun.size) if best is not None else np.inf)
        if callback is not None:
            callback(k, history[-1])

    if best is None:
        return IdentResult(x=np.asarray(points[0], dtype=float).copy(), fun=np.inf,
                           nfev=nfev, nit=len(points), history=history, seed=seed,
                           message="residuals not finite at any start point",
                           method="co", success=False, extra={"starts": summary})

    m = best.fun.size
    stats = covariance(best.jac, best.data_cost)
    extra = {"cost": float(best.data_cost), "jac": best.jac, **stats, "m": m,
             "active_mask": best.active_mask, "optimality": float(best.optimality),
             "starts": summary}
    return IdentResult(
        x=best.x.copy(), fun=float(2.0 * best.data_cost / m), nfev=nfev,
        nit=len(points), history=history, seed=seed,
        message=f"best of {len(points)} starts: {best.message}", method="co",
        success=bool(best.success and np.isfinite(best.cost)), jac=best.jac,
        cost=float(best.data_cost), extra=extra)


def _check_prior(prior, D: int) -> tuple[np.ndarray, np.ndarray]:
    """(centre (D,), A (k, D)); no prior: no rows."""
    if prior is None:
        return np.zeros(D), np.zeros((0, D))
    try:
        centre, A = (np.asarray(a, dtype=float) for a in prior)
    except (TypeError, ValueError):
        raise ValueError("prior: must be a pair (centre, A) of numeric arrays") from None
    if centre.shape != (D,) or A.ndim != 2 or A.shape[1] != D:
        raise ValueError(f"prior: centre must have shape {(D,)} and A shape (k, {D})")
    if not (np.all(np.isfinite(centre)) and np.all(np.isfinite(A))):
        raise ValueError("prior: centre and A must be finite")
    return centre, A


def polish(result: IdentResult, residuals: Callable[[np.ndarray], np.ndarray],
           lower: Any, upper: Any,
           jac_batch: Callable[[np.ndarray], np.ndarray] | None = None, *,
           max_nfev: int | None = None,
           options: dict[str, Any] | None = None,
           prior: tuple[Any, Any] | None = None) -> IdentResult:
    """Refine a global result with one :func:`local` run from ``result.x``.

    Parameters
    ----------
    result : IdentResult
        Output of :func:`jellyfish` or :func:`pso` (same search space).
    residuals, lower, upper, jac_batch, max_nfev, options, prior
        As for :func:`local`.

    Returns
    -------
    IdentResult
        ``method = result.method + "+co"``; ``x``, ``fun`` (mean square
        residual), ``jac``, ``cost`` and covariance from the local run;
        ``nfev`` summed; ``nit``/``history``/``seed`` from the global run;
        ``extra["global"]`` keeps the global run's summary (its ``fun`` is
        in the units of the global objective).  If the residuals are not
        finite at ``result.x`` the global result is returned unchanged apart
        from the message and ``extra["polish"]``.
    """
    lo, hi = check_bounds(lower, upper)
    x0 = np.clip(np.asarray(result.x, dtype=float), lo, hi)
    loc = local(residuals, lo, hi, x0=x0, starts=1, seed=result.seed,
                max_nfev=max_nfev, jac_batch=jac_batch, options=options, prior=prior)
    glob = {"method": result.method, "x": result.x, "fun": result.fun,
            "nfev": result.nfev, "nit": result.nit, "message": result.message,
            "extra": result.extra}
    if not np.isfinite(loc.fun):
        return IdentResult(
            x=result.x.copy(), fun=result.fun, nfev=result.nfev + loc.nfev,
            nit=result.nit, history=list(result.history), seed=result.seed,
            message=f"{result.message}; polish failed: {loc.message}",
            method=result.method, success=result.success,
            extra={**result.extra, "polish": loc.to_dict()})
    return IdentResult(
        x=loc.x, fun=loc.fun, nfev=result.nfev + loc.nfev, nit=result.nit,
        history=list(result.history), seed=result.seed,
        message=f"{result.message}; polished: {loc.message}",
        method=f"{result.method}+co", success=bool(result.success and loc.success),
        jac=loc.jac, cost=loc.cost, extra={**loc.extra, "global": glob})
