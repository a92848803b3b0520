"""Tests for labrig.identification optimisers (JFO, PSO, CO); seeded and fast."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.optimize import curve_fit

from labrig.identification.jellyfish import JellyfishSolver, jellyfish, logistic_init, wrap_bounds
from labrig.identification.local import batch_jacobian, covariance, local, polish, reduced
from labrig.identification.pso import PSOSolver, apply_boundary, constriction, pso
from labrig.identification.result import IdentResult


# ---------------------------------------------------------------- problems

def sphere(X):
    return np.sum((X - 0.3) ** 2, axis=1)


def rosenbrock(X):
    return np.sum(100.0 * (X[:, 1:] - X[:, :-1] ** 2) ** 2 + (1.0 - X[:, :-1]) ** 2, axis=1)


SHIFT = np.array([1.5, -2.0, 0.5, 3.0])
WEIGHTS = np.array([1.0, 10.0, 100.0, 1000.0])


def ellipsoid(X):
    return np.sum(WEIGHTS * (X - SHIFT) ** 2, axis=1)


BOX5 = (-5.0 * np.ones(4), 5.0 * np.ones(4))


# ---------------------------------------------------------------- PSO basics

def test_constriction_value():
    assert abs(constriction(2.05, 2.05) - 0.7298437881) < 1e-9
    # phi must exceed 4
    with pytest.raises(ValueError, match="c1"):
        constriction(2.0, 2.0)


@pytest.mark.parametrize("name,fun,box,xstar,tol", [
    ("sphere", sphere, BOX5, np.full(4, 0.3), 1e-4),
    ("rosenbrock", rosenbrock, (-2.0 * np.ones(2), 2.0 * np.ones(2)), np.ones(2), 1e-3),
    ("ellipsoid", ellipsoid, BOX5, SHIFT, 1e-4),
])
def test_pso_finds_minimum(name, fun, box, xstar, tol):
    res = pso(fun, *box, pop=40, iters=250, seed=3)
    assert res.method == "pso" and res.success
    np.testing.assert_allclose(res.x, xstar, atol=tol)
    assert res.nfev == 40 * 251
    assert len(res.history) == res.nit == 250
    assert all(b <= a for a, b in zip(res.history, res.history[1:]))


@pytest.mark.parametrize("boundary", ["absorb", "reflect", "random", "wrap"])
def test_pso_boundaries_keep_swarm_inside(boundary):
    lo, hi = np.array([0.0, -1.0]), np.array([1.0, 2.0])
    seen = []

    def fun(X):
        seen.append(X.copy())
        # minimum outside the box pushes particles against the upper bounds
        return np.sum((X - np.array([3.0, 5.0])) ** 2, axis=1)

    res = pso(fun, lo, hi, pop=20, iters=30, seed=0, boundary=boundary)
    allx = np.vstack(seen)
    assert np.all(allx >= lo) and np.all(allx <= hi)
    assert all(s.shape == (20, 2) for s in seen)  # one vectorised call per iteration
    if boundary == "absorb":  # absorbing walls let particles sit on the corner
        np.testing.assert_allclose(res.x, hi, atol=1e-12)
    else:
        np.testing.assert_allclose(res.x, hi, atol=0.05)


def test_absorb_clips_and_zeroes_velocity():
    lo, hi = np.zeros(3), np.ones(3)
    X = np.array([[1.5, 0.5, -0.2]])
    V = np.array([[0.7, 0.3, -0.4]])
    Xn, Vn = apply_boundary(X, V, lo, hi, "absorb", np.random.default_rng(0))
    np.testing.assert_array_equal(Xn, [[1.0, 0.5, 0.0]])
    np.testing.assert_array_equal(Vn, [[0.0, 0.3, 0.0]])


def test_other_boundaries():
    lo, hi = np.zeros(2), np.ones(2)
    X = np.array([[1.25, -0.25]])
    V = np.array([[0.5, -0.5]])
    rng = np.random.default_rng(0)
    Xr, Vr = apply_boundary(X, V, lo, hi, "reflect", rng)
    np.testing.assert_allclose(Xr, [[0.75, 0.25]])
    np.testing.assert_allclose(Vr, [[-0.5, 0.5]])
    Xw, Vw = apply_boundary(X, V, lo, hi, "wrap", rng)
    np.testing.assert_allclose(Xw, [[0.25, 0.75]])
    np.testing.assert_array_equal(Vw, V)
    Xq, _ = apply_boundary(X, V, lo, hi, "random", rng)
    assert np.all((Xq >= lo) & (Xq <= hi))
    inside = np.array([[0.2, 0.9]])
    for mode in ("absorb", "reflect", "random", "wrap"):
        Xi, Vi = apply_boundary(inside, V, lo, hi, mode, rng)
        np.testing.assert_array_equal(Xi, inside)
        np.testing.assert_array_equal(Vi, V)


def test_pso_velocity_clamp_and_strict_personal_best():
    lo, hi = np.array([0.0, 0.0]), np.array([1.0, 10.0])
    # constant objective: no strict improvement ever, so personal bests
    # and the global best stay at the initial swarm
    s = PSOSolver(lambda X: np.zeros(len(X)), lo, hi, pop=10, iters=20, seed=1)
    P0, g0 = s.P.copy(), s.x_best.copy()
    for _ in range(20):
        s.step()
        assert np.all(np.abs(s.V) <= hi - lo + 1e-15)
    np.testing.assert_array_equal(s.P, P0)
    np.testing.assert_array_equal(s.x_best, g0)
    np.testing.assert_array_equal(g0, P0[0])
    assert s.done
    with pytest.raises(RuntimeError):
        s.step()


# ---------------------------------------------------------------- JFO

@pytest.mark.parametrize("batch", [True, False])
@pytest.mark.parametrize("name,fun,box,xstar,tol,iters", [
    ("sphere", sphere, BOX5, np.full(4, 0.3), 1e-4, 200),
    ("rosenbrock", rosenbrock, (-2.0 * np.ones(2), 2.0 * np.ones(2)), np.ones(2), 2e-3, 300),
    ("ellipsoid", ellipsoid, BOX5, SHIFT, 1e-3, 300),
])
def test_jellyfish_finds_minimum(batch, name, fun, box, xstar, tol, iters):
    res = jellyfish(fun, *box, pop=30, iters=iters, seed=7, batch=batch)
    assert res.method == "jfo" and res.success
    np.testing.assert_allclose(res.x, xstar, atol=tol)
    assert res.nfev == 30 * (iters + 1)
    assert all(b <= a for a, b in zip(res.history, res.history[1:]))


def test_jellyfish_call_pattern():
    calls = {True: [], False: []}
    for batch in (True, False):
        jellyfish(lambda X, b=batch: (calls[b].append(len(X)), sphere(X))[1],
                  *BOX5, pop=8, iters=5, seed=0, batch=batch)
    assert calls[True] == [8] * 6          # init + one call per iteration
    assert calls[False] == [8] + [1] * 40  # init + one row per jellyfish


@pytest.mark.parametrize("batch", [True, False])
def test_jellyfish_solver_greedy_and_best(batch):
    s = JellyfishSolver(rosenbrock, *BOX5, pop=10, iters=8, seed=4, batch=batch)
    f_prev = s.f.copy()
    while not s.done:
        s.step()
        assert np.all(s.f <= f_prev)              # greedy: nobody gets worse
        assert s.f_best == s.f.min()              # the best is in the population
        np.testing.assert_array_equal(rosenbrock(s.x_best[None]), [s.f_best])
        f_prev = s.f.copy()
    assert s.result().nit == 8


def _reference_js(fun, lo, hi, pop, iters, seed, rule="paper", beta=3.0,
                  gamma=0.1, c0=0.5):
    """Literal transcription of docs/physics.md, 'Jellyfish Search' (sequential), same
    draw order."""
    rng = np.random.default_rng(seed)
    D = lo.size
    u = np.empty((pop, D))
    u[0] = rng.random(D)
    for k in range(1, pop):
        u[k] = 4.0 * u[k - 1] * (1 - u[k - 1])
    X = lo + u * (hi - lo)
    f = fun(X)
    b = int(np.argmin(f))
    xb, fb = X[b].copy(), f[b]
    for t in range(1, iters + 1):
        mu = X.mean(axis=0)
        for i in range(pop):
            c = (1 - t / iters) * (2 * rng.random() - 1)
            if abs(c) >= c0:
                xn = X[i] + rng.random(D) * (xb - beta * rng.random() * mu)
            elif rng.random() > 1 - (abs(c) if rule == "paper" else c):
                xn = X[i] + gamma * rng.random() * (hi - lo)
            else:
                j = int(rng.integers(pop - 1))
                j = j + 1 if j >= i else j
                d = X[j] - X[i] if f[j] < f[i] else X[i] - X[j]
                xn = X[i] + rng.random(D) * d
            for _ in range(1000):  # the spec's "repeat until inside"
                xn = np.where(xn > hi, lo + (xn - hi), xn)
                xn = np.where(xn < lo, hi + (xn - lo), xn)
                if np.all((xn >= lo) & (xn <= hi)):
                    break
            fn = fun(xn[None])[0]
            if fn < f[i]:
                X[i], f[i] = xn, fn
                if fn < fb:
                    xb, fb = xn.copy(), fn
    return xb, fb


@pytest.mark.parametrize("rule", ["paper", "reference"])
def test_jellyfish_sequential_matches_spec(rule):
    lo, hi = np.array([-1.0, 0.0, 2.0]), np.array([1.0, 3.0, 2.5])

    def fun(X):
        return np.sum((X - [0.2, 2.9, 2.1]) ** 2, axis=1)

    res = jellyfish(fun, lo, hi, pop=12, iters=15, seed=11, rule=rule, batch=False)
    xb, fb = _reference_js(fun, lo, hi, 12, 15, 11, rule=rule)
    np.testing.assert_allclose(res.x, xb, rtol=0, atol=1e-12)
    assert res.fun == pytest.approx(fb, abs=1e-14)


def _expected_branch_totals(pop, iters, c0):
    t = np.arange(1, iters + 1)
    s = 1.0 - t / iters
    with np.errstate(divide="ignore"):
        p_ocean = np.where(s > 0, np.clip(1.0 - c0 / np.where(s > 0, s, 1), 0, None), 0.0)
    # P(passive, paper) = E[|c| 1{|c| < c0}], |c| ~ U(0, s)
    p_pass = np.where(s <= c0, s / 2.0, c0 ** 2 / (2.0 * np.where(s > 0, s, 1)))
    return p_ocean, p_pass


@pytest.mark.parametrize("batch", [True, False])
def test_ocean_current_probability(batch):
    pop, iters, c0 = 200, 40, 0.3
    counts = {}
    for rule in ("paper", "reference"):
        res = jellyfish(lambda X: np.zeros(len(X)), -np.ones(2), np.ones(2), pop=pop,
                        iters=iters, seed=5, c0=c0, rule=rule, batch=batch)
        counts[rule] = res.extra["branch_counts"]
        assert counts[rule].shape == (iters, 3)
        assert np.all(counts[rule].sum(axis=1) == pop)
    p_ocean, p_pass = _expected_branch_totals(pop, iters, c0)

    def z(observed, p):
        return (observed - pop * p.sum()) / np.sqrt(pop * np.sum(p * (1 - p)))

    for rule in counts:
        assert abs(z(counts[rule][:, 0].sum(), p_ocean)) < 4
        # the early phase alone (strongly ocean-dominated) also matches
        assert abs(z(counts[rule][:10, 0].sum(), p_ocean[:10])) < 4
    # the ocean current is never taken once 1 - t/T <= c0
    assert counts["paper"][p_ocean == 0, 0].sum() == 0
    assert abs(z(counts["paper"][:, 1].sum(), p_pass)) < 4
    # reference rule: signed c halves the passive probability
    assert abs(z(counts["reference"][:, 1].sum(), p_pass / 2)) < 4


def test_logistic_init_and_wrap():
    lo, hi = np.array([-3.0, 10.0, 0.0]), np.array([-1.0, 20.0, 1e-3])
    X = logistic_init(500, lo, hi, np.random.default_rng(2))
    assert np.all((X >= lo) & (X <= hi))
    u = (X - lo) / (hi - lo)
    np.testing.assert_allclose(u[1:], 4 * u[:-1] * (1 - u[:-1]), atol=1e-9)
    # wrap: shifts by whole box widths, as the repeated rule would
    lo2, hi2 = np.zeros(2), np.array([1.0, 2.0])
    Y = wrap_bounds(np.array([[1.25, -0.5], [3.5, 5.0], [0.4, 2.0], [-7.75, 0.0]]), lo2, hi2)
    np.testing.assert_allclose(Y, [[0.25, 1.5], [0.5, 1.0], [0.4, 2.0], [0.25, 0.0]])
    big = wrap_bounds(np.random.default_rng(0).normal(scale=1e6, size=(1000, 2)), lo2, hi2)
    assert np.all((big >= lo2) & (big <= hi2))


def test_jellyfish_points_inside_bounds_with_big_moves():
    lo, hi = np.array([0.0, 5.0]), np.array([0.1, 5.5])
    seen = []

    def fun(X):
        seen.append(X.copy())
        return np.sum(X, axis=1)

    jellyfish(fun, lo, hi, pop=15, iters=20, seed=0, beta=30.0, gamma=3.0)
    allx = np.vstack(seen)
    assert np.all((allx >= lo) & (allx <= hi))


# ---------------------------------------------------------------- common

@pytest.mark.parametrize("opt", [jellyfish, pso])
def test_reproducible_and_callback(opt):
    seen = []
    a = opt(rosenbrock, *BOX5, pop=10, iters=15, seed=42,
            callback=lambda it, f: seen.append((it, f)))
    b = opt(rosenbrock, *BOX5, pop=10, iters=15, seed=42)
    c = opt(rosenbrock, *BOX5, pop=10, iters=15, seed=43)
    np.testing.assert_array_equal(a.x, b.x)
    assert a.history == b.history and a.seed == 42
    assert not np.array_equal(a.x, c.x)
    assert [i for i, _ in seen] == list(range(1, 16))
    assert [f for _, f in seen] == a.history
    # seed=None draws a seed that reproduces the run
    d = opt(rosenbrock, *BOX5, pop=10, iters=5, seed=None)
    e = opt(rosenbrock, *BOX5, pop=10, iters=5, seed=d.seed)
    np.testing.assert_array_equal(d.x, e.x)
    # raising StopIteration stops the run; return values are ignored
    # (tqdm.update() returns True)

    def stop_at_3(it, f):
        if it >= 3:
            raise StopIteration
        return True

    s = opt(sphere, *BOX5, pop=10, iters=50, seed=1, callback=stop_at_3)
    assert s.nit == 3 and "callback" in s.message and s.nfev == 40


@pytest.mark.parametrize("opt", [jellyfish, pso])
def test_nan_and_inf_candidates_never_win(opt):
    def fun(X):
        f = sphere(X)
        f[X[:, 0] > 0] = np.nan   # "failed simulations" in half the box
        f[X[:, 1] > 4] = np.inf
        return f

    res = opt(fun, *BOX5, pop=20, iters=60, seed=0)
    assert np.isfinite(res.fun) and res.x[0] <= 0 and res.x[1] <= 4
    json.dumps(res.to_dict())


def test_all_failed_candidates():
    res = pso(lambda X: np.full(len(X), np.nan), *BOX5, pop=4, iters=2, seed=0)
    assert not res.success and res.fun == np.inf
    assert res.to_dict()["fun"] is None


BAD = [
    (dict(lower=[0, 1], upper=[1, 0]), "lower"),
    (dict(lower=[0, 0], upper=[1, 1, 1]), "upper"),
    (dict(lower=[[0, 0]], upper=[[1, 1]]), "lower"),
    (dict(lower=[0, -np.inf], upper=[1, 1]), "lower"),
    (dict(pop=1), "pop"),
    (dict(iters=0), "iters"),
    (dict(pop=2.5), "pop"),
    (dict(seed=-1), "seed"),
    (dict(seed="x"), "seed"),
    (dict(callback=3), "callback"),
]


@pytest.mark.parametrize("opt", [jellyfish, pso])
@pytest.mark.parametrize("kwargs,name", BAD)
def test_bad_arguments_common(opt, kwargs, name):
    kw = dict(lower=[0, 0], upper=[1, 1], pop=4, iters=2, seed=0)
    kw.update(kwargs)
    lower, upper = kw.pop("lower"), kw.pop("upper")
    with pytest.raises(ValueError, match=f"^{name}"):
        opt(sphere, lower, upper, **kw)


@pytest.mark.parametrize("opt,kwargs,name", [
    (jellyfish, dict(rule="matlab"), "rule"),
    (jellyfish, dict(c0=1.5), "c0"),
    (jellyfish, dict(eta=0.0), "eta"),
    (jellyfish, dict(beta=float("nan")), "beta"),
    (pso, dict(boundary="bounce"), "boundary"),
    (pso, dict(c1=1.0, c2=1.0), "c1"),
])
def test_bad_arguments_specific(opt, kwargs, name):
    with pytest.raises(ValueError, match=f"^{name}"):
        opt(sphere, [0, 0], [1, 1], pop=4, iters=2, seed=0, **kwargs)


def test_local_bad_residual_shape():
    with pytest.raises(ValueError, match="^residuals"):
        local(lambda p: 1.0, LO, HI, starts=1, seed=0)
    with pytest.raises(ValueError, match="^jac_batch"):
        local(residuals, LO, HI, starts=1, seed=0, jac_batch=lambda P: P)


def test_bad_objective_shape():
    with pytest.raises(ValueError, match="^fun"):
        pso(lambda X: np.zeros((len(X), 2)), [0, 0], [1, 1], pop=4, iters=2, seed=0)


# ---------------------------------------------------------------- local (CO)

T = np.linspace(0.0, 4.0, 60)
TRUE = np.array([2.0, 0.7, 0.5])
NOISE = 0.02
Y = TRUE[0] * np.exp(-TRUE[1] * T) + TRUE[2] + NOISE * np.random.default_rng(9).normal(size=T.size)
LO, HI = np.array([0.1, 0.01, -2.0]), np.array([10.0, 5.0, 2.0])


def model(t, a, k, c):
    return a * np.exp(-k * t) + c


def residuals(p):
    return model(T, *p) - Y


def residuals_batch(P):
    return P[:, :1] * np.exp(-P[:, 1:2] * T) + P[:, 2:3] - Y


def test_local_recovers_exponential_and_covariance():
    res = local(residuals, LO, HI, starts=4, seed=0)
    assert res.method == "co" and res.success and res.nit == 4
    popt, pcov = curve_fit(model, T, Y, p0=[1, 1, 0])
    np.testing.assert_allclose(res.x, popt, rtol=1e-6)
    assert res.fun == pytest.approx(np.mean(residuals(res.x) ** 2), rel=1e-12)
    assert res.cost == pytest.approx(0.5 * np.sum(residuals(res.x) ** 2), rel=1e-12)
    assert res.fun == pytest.approx(NOISE ** 2, rel=0.4)
    cov = res.extra["cov"]
    np.testing.assert_allclose(cov, pcov, rtol=1e-3)
    np.testing.assert_allclose(cov, cov.T)
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    assert np.all(np.abs(res.x - TRUE) < 4 * res.extra["stderr"])
    assert res.extra["rank"] == 3 and res.jac.shape == (60, 3)
    json.dumps(res.to_dict())


def test_local_jac_batch_same_optimum():
    calls = []

    def rb(P):
        calls.append(len(P))
        return residuals_batch(P)

    a = local(residuals, LO, HI, starts=3, seed=1)
    b = local(residuals, LO, HI, starts=3, seed=1, jac_batch=rb)
    np.testing.assert_allclose(b.x, a.x, rtol=1e-7)
    np.testing.assert_allclose(b.extra["cov"], a.extra["cov"], rtol=1e-4)
    assert calls and set(calls) == {4}  # D + 1 rows per Jacobian
    assert b.nfev > sum(calls)           # residual calls are counted too


def test_batch_jacobian_respects_bounds():
    x = np.array([10.0, 0.01, 0.3])      # at the upper / lower bounds
    seen = []

    def rb(P):
        seen.append(P.copy())
        return residuals_batch(P)

    J = batch_jacobian(rb, x, LO, HI)
    assert np.all((seen[0] >= LO) & (seen[0] <= HI))
    analytic = np.column_stack([np.exp(-x[1] * T), -x[0] * T * np.exp(-x[1] * T), np.ones_like(T)])
    np.testing.assert_allclose(J, analytic, rtol=1e-5, atol=1e-5)


def test_local_x0_and_failed_starts():
    def r_nan(p):  # undefined in part of the box
        return residuals(p) if p[0] < 5 else np.full(T.size, np.nan)

    res = local(r_nan, LO, HI, x0=[1.0, 1.0, 0.0], starts=6, seed=3)
    np.testing.assert_allclose(res.extra["starts"][0]["x0"], [1.0, 1.0, 0.0])
    assert res.success and res.x[0] < 5
    np.testing.assert_allclose(res.x, TRUE, atol=0.1)
    bad = local(lambda p: np.full(3, np.nan), LO, HI, starts=2, seed=0)
    assert not bad.success and bad.fun == np.inf


@pytest.mark.parametrize("kwargs,name", [
    (dict(x0=[1.0, 1.0]), "x0"),
    (dict(x0=[100.0, 1.0, 0.0]), "x0"),
    (dict(starts=0), "starts"),
    (dict(max_nfev=0), "max_nfev"),
    (dict(jac_batch="no"), "jac_batch"),
    (dict(options={"method": "lm"}), "options"),
    (dict(lower=HI, upper=LO), "lower"),
])
def test_local_bad_arguments(kwargs, name):
    lower, upper = kwargs.pop("lower", LO), kwargs.pop("upper", HI)
    with pytest.raises(ValueError, match=f"^{name}"):
        local(residuals, lower, upper, seed=0, **kwargs)


@pytest.mark.parametrize("opt,tag", [(jellyfish, "jfo+co"), (pso, "pso+co")])
def test_polish(opt, tag):
    def obj(P):
        return np.sqrt(np.mean(residuals_batch(P) ** 2, axis=1))  # RMSE

    g = opt(obj, LO, HI, pop=15, iters=10, seed=0)
    p = polish(g, residuals, LO, HI, jac_batch=residuals_batch)
    assert p.method == tag and p.nfev > g.nfev and p.history == g.history
    popt, _ = curve_fit(model, T, Y, p0=[1, 1, 0])
    np.testing.assert_allclose(p.x, popt, rtol=1e-6)
    assert p.fun <= g.fun ** 2 + 1e-15
    assert p.extra["global"]["fun"] == g.fun
    json.dumps(p.to_dict())


def test_covariance_degenerate():
    J = np.array([[1.0, 2.0], [2.0, 4.0], [3.0, 6.0]])  # rank 1
    out = covariance(J, cost=0.5)
    assert out["rank"] == 1 and np.all(np.isfinite(out["cov"]))
    assert np.isnan(covariance(np.eye(2), 0.1)["s2"])


def test_result_to_dict():
    r = IdentResult(x=np.array([1.0, np.nan]), fun=np.inf, nfev=3, nit=1,
                    extra={"a": np.arange(2), "b": np.float32(1.5)})
    d = r.to_dict()
    assert d["x"] == [1.0, None] and d["fun"] is None and d["extra"]["a"] == [0, 1]
    json.dumps(d)


@pytest.mark.parametrize("rank", [3, 2])
def test_reduced_problem_carries_the_gauss_newton_model(rank):
    """The n + 1 rows the trust region sees: the same J^T J, J^T f and |f| as the m rows,
    also when a parameter has no effect at all (a column of zeros)."""
    rng = np.random.default_rng(3)
    J = rng.normal(size=(5000, 3)) * [1e3, 1.0, 1e-3]
    if rank == 2:
        J[:, 2] = 0.0
    f = rng.normal(size=5000)
    K = reduced(J, f)
    e = np.zeros(4)
    e[-1] = np.linalg.norm(f)
    assert K.shape == (4, 3)
    np.testing.assert_allclose(K.T @ K, J.T @ J, rtol=1e-9, atol=1e-9 * np.abs(J.T @ J).max())
    np.testing.assert_allclose(K.T @ e, J.T @ f, rtol=1e-9, atol=1e-9 * np.abs(J.T @ f).max())


def test_reduced_fit_matches_the_full_one():
    """local() with a batch Jacobian (the reduced problem) lands where scipy lands on all
    residuals, to the optimiser's tolerance, and reports the full residuals and Jacobian."""
    from scipy.optimize import least_squares

    a = local(residuals, LO, HI, x0=np.array([1.0, 1.0, 0.0]), starts=1, seed=0,
              jac_batch=residuals_batch)
    b = least_squares(residuals, [1.0, 1.0, 0.0], bounds=(LO, HI), method="trf")
    np.testing.assert_allclose(a.x, b.x, rtol=1e-6)
    assert a.jac.shape == (T.size, 3) and a.cost == pytest.approx(b.cost, rel=1e-9)
