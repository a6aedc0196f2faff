"""The array API (mavsid.identify, mavsid.regress): against independent computations (numpy,
statsmodels on the same arrays) and against simulated truth (interval coverage)."""

from __future__ import annotations

import functools
import json
import warnings
from dataclasses import replace

import numpy as np
import pytest
from scipy import linalg, optimize, signal

import mavsid
from mavsid import NoExcitationError, identify, regress
from mavsid.data import Segment
from mavsid.errors import ConfigError
from mavsid.estimators import Structure, fit_axis, load_model, select_delay
from mavsid.estimators import output_error as oe
from mavsid.estimators.least_squares import LeastSquares
from mavsid.estimators.regressors import InputFilter, filter_inputs
from mavsid.estimators.select import (
    DelayScan,
    _slow_mse,
    lag_filter,
    search_structure,
    with_lag,
)

# ----------------------------------------------------------------------- lecture examples


def test_two_rows_give_a_and_b_exactly():
    m = identify([1.0, 2.0, 1.8], [1.0, 0.0, 0.0], dt=1.0, n_bootstrap=0)
    assert m.params["A_d[x,x]"] == pytest.approx(0.9, abs=1e-14)
    assert m.params["B_d[x,u]"] == pytest.approx(1.1, abs=1e-14)
    r = regress([[1.0, 1.0], [2.0, 0.0]], [2.0, 1.8], names=["a", "b"])
    assert r.params == pytest.approx({"a": 0.9, "b": 1.1}, abs=1e-14)


def test_zero_input_is_unidentifiable_naming_b_and_the_input():
    with pytest.raises(NoExcitationError, match=r"B_d\[x,u_elev\].*u_elev is zero"):
        identify([1.0, 2.0, 1.8, 1.6], np.zeros(4), dt=1.0, input_names=["u_elev"])
    with pytest.raises(NoExcitationError, match="b unidentifiable: regressor b is zero"):
        regress([[1.0, 0.0], [2.0, 0.0], [3.0, 0.0]], [1.0, 2.0, 3.0], names=["a", "b"])


def test_a_dependent_third_row_leaves_theta_unchanged():
    two = regress([[1.0, 1.0], [2.0, 0.0]], [2.0, 1.8]).coef
    for alpha, beta in ((1.0, 1.0), (2.0, -0.5), (0.3, 0.0)):
        row = alpha * np.array([1.0, 1.0]) + beta * np.array([2.0, 0.0])
        target = alpha * 2.0 + beta * 1.8
        three = regress([[1.0, 1.0], [2.0, 0.0], row], [2.0, 1.8, target]).coef
        np.testing.assert_allclose(three, two, atol=1e-13)


def test_ridge_is_the_textbook_formula():
    rng = np.random.default_rng(0)
    z = rng.standard_normal((3, 50))  # regressors x samples, as the lecture writes Z
    xp = np.array([0.5, -1.0, 2.0]) @ z + 0.1 * rng.standard_normal(50)
    for lam in (0.0, 0.1, 10.0):
        got = regress(z.T, xp, alpha=lam).coef
        want = xp[None, :] @ z.T @ np.linalg.inv(z @ z.T + lam * np.eye(3))
        np.testing.assert_allclose(got, want[0], rtol=1e-12)


def test_pendulum_library_gives_zero_zero_minus_c():
    c, dt = 4.0, 0.005
    t = np.arange(0, 8, dt)
    from scipy.integrate import solve_ivp

    sol = solve_ivp(lambda _, s: [s[1], -c * np.sin(s[0])], (0, t[-1]), [2.0, 0.0], t_eval=t,
                    rtol=1e-11, atol=1e-11)
    m = identify(sol.y.T, dt=dt, kind="continuous", state_names=("theta", "omega"),
                 outputs=("omega",), features=("1", "theta", "sin(theta)"),
                 estimator="stlsq", n_bootstrap=0)
    assert m.coef[0, 0] == 0.0 and m.coef[1, 0] == 0.0
    assert m.coef[2, 0] == pytest.approx(-c, rel=1e-4)
    # without sparsity the small terms stay (derivative errors), nonzero
    ls = identify(sol.y.T, dt=dt, kind="continuous", state_names=("theta", "omega"),
                  outputs=("omega",), features=("1", "theta", "sin(theta)"), n_bootstrap=0)
    assert ls.coef[0, 0] != 0.0
    # regress with thresholding on the same library and the exact acceleration
    lib = np.column_stack([np.ones_like(t), sol.y[0], np.sin(sol.y[0])])
    r = regress(lib, -c * np.sin(sol.y[0]) + 1e-6 * np.cos(7 * t), names=["1", "theta", "sin"],
                select="threshold")
    assert r.params["1"] == 0.0 and r.params["theta"] == 0.0
    assert r.params["sin"] == pytest.approx(-c, rel=1e-6)
    assert "threshold" in r.selection and "left out 1, theta" in r.selection


# ----------------------------------------------------------------------- against numpy


def _plant(n, seed, a=((0.95, 0.05), (-0.1, 0.9)), b=((0.2,), (0.5,)), noise=0.01):
    rng = np.random.default_rng(seed)
    a, b = np.array(a), np.array(b)
    u = np.repeat(rng.standard_normal((n // 5 + 1, b.shape[1])), 5, axis=0)[:n]
    x = np.zeros((n, a.shape[0]))
    for k in range(n - 1):
        x[k + 1] = a @ x[k] + b @ u[k] + noise * rng.standard_normal(a.shape[0])
    return x, u


def test_identify_equals_numpy_lstsq_on_the_same_rows():
    x, u = _plant(800, 1)
    m = identify(x, u, dt=0.01, state_names=("v", "w"), input_names=("d",), n_bootstrap=0)
    z = np.column_stack([x[:-1], u[:-1]])
    want, *_ = np.linalg.lstsq(z, x[1:], rcond=None)
    np.testing.assert_allclose(m.coef, want, rtol=1e-9, atol=1e-12)
    assert m.features == ("v", "w", "d")


def test_records_are_never_joined():
    (x1, u1), (x2, u2) = _plant(300, 2), _plant(400, 3)
    x2 = x2 + 5.0  # a jump between the records: joining them would corrupt one row
    m = identify([x1, x2], [u1, u2], dt=0.01, bias=True, n_bootstrap=0)
    z = np.vstack([np.column_stack([x1[:-1], u1[:-1], np.ones(299)]),
                   np.column_stack([x2[:-1], u2[:-1], np.ones(399)])])
    y = np.vstack([x1[1:], x2[1:]])
    want, *_ = np.linalg.lstsq(z, y, rcond=None)
    np.testing.assert_allclose(m.coef, want, rtol=1e-9, atol=1e-12)
    joined = identify(np.vstack([x1, x2]), np.vstack([u1, u2]), dt=0.01, bias=True,
                      n_bootstrap=0)
    assert not np.allclose(joined.coef, want, rtol=1e-6)
    assert m.provenance["settings"]["rows"] == 299 + 399  # type: ignore[index]


def test_continuous_derivatives_stay_inside_each_record():
    a_c, b_c, dt = -2.0, 3.0, 0.01
    t = np.arange(500) * dt
    recs = []
    for w in (1.3, 2.1):
        u = np.sin(w * t)
        # exact response of x' = a x + b u to a sine from x(0) = 0
        amp = b_c / (a_c**2 + w**2)
        x = amp * (-a_c * np.sin(w * t) - w * np.cos(w * t)) + amp * w * np.exp(a_c * t)
        recs.append((x, u))
    m = identify([r[0] for r in recs], [r[1] for r in recs], dt=dt, kind="continuous",
                 n_bootstrap=0, window=9)
    assert m.params["A[x,x]"] == pytest.approx(a_c, rel=1e-4)
    assert m.params["B[x,u]"] == pytest.approx(b_c, rel=1e-4)
    assert m.provenance["settings"]["rows"] == 2 * (500 - 8)  # type: ignore[index]


def test_the_model_does_what_the_log_path_model_does(tmp_path):
    x, u = _plant(1000, 4, a=((0.97,),), b=((0.3,),))
    m = identify(x, u, dt=0.02, state_names=["airspeed"], input_names=["throttle"],
                 units={"airspeed": "m/s", "throttle": "%"}, bias=True)
    assert m.units["B_d[airspeed,throttle]"] == "m/s/%"
    assert m.units["A[airspeed,airspeed]"] == "1/s"
    assert np.isfinite(m.stderr["B_d[airspeed,throttle]"])
    assert m.sigma is not None and m.sigma[0] == pytest.approx(0.01, rel=0.1)
    path = tmp_path / "m.json"
    m.save(path)
    back = load_model(path)
    assert back.params == pytest.approx(m.params)
    assert back.units == m.units
    json.loads(path.read_text())
    free = m.simulate_inputs(u, x0=x[0])
    assert free.shape == x.shape
    seg = Segment(np.arange(1000) * 0.02, x, u, ("airspeed",), ("throttle",), 0.02, "all",
                  "array")
    np.testing.assert_allclose(m.simulate(seg), free)
    assert np.all(np.isnan(m.predict(seg, 1)[0]))
    ss = m.to_statespace()
    assert ss.A[0, 0] == pytest.approx(m.params["A_d[airspeed,airspeed]"])
    from mavsid.validation import validate

    val = validate(m, [seg])
    assert val is not None


def test_estimator_by_name_or_instance():
    from mavsid.estimators import Ridge

    x, u = _plant(800, 9)
    by_name = identify(x, u, dt=0.01, estimator="ridge", alpha=1e-3, n_bootstrap=0)
    by_instance = identify(x, u, dt=0.01, estimator=Ridge(alpha=1e-3, n_bootstrap=0))
    np.testing.assert_allclose(by_name.coef, by_instance.coef)
    assert by_name.provenance["settings"]["estimator"] == "ridge"  # type: ignore[index]
    with pytest.raises(ConfigError, match="unknown estimator"):
        identify(x, u, dt=0.01, estimator="magic")


def test_delay_search_on_arrays():
    x, u = _plant(3000, 5, a=((0.9,),), b=((0.4,),), noise=1e-4)
    u_late = np.concatenate([np.zeros((4, 1)), u[:-4]])  # the plant sees u 4 samples late
    xs = np.zeros_like(x)
    rng = np.random.default_rng(0)
    for k in range(len(x) - 1):
        xs[k + 1] = 0.9 * xs[k] + 0.4 * u_late[k, 0] + 1e-4 * rng.standard_normal()
    m = identify(xs, u, dt=0.01, delay="search", n_bootstrap=0)
    assert (m.delay, m.delay_frac) == (4, 0.0)
    assert m.params["B_d[x,u]"] == pytest.approx(0.4, rel=1e-3)
    with pytest.raises(ConfigError, match="delay must be"):
        identify(xs, u, dt=0.01, delay="guess")


def test_bad_arrays_are_config_errors():
    with pytest.raises(ConfigError, match="x has 20 samples, u has 19"):
        identify(np.zeros(20), np.zeros(19))
    with pytest.raises(ConfigError, match="unknown variables"):
        identify(np.zeros(20), np.zeros(20), features=("x", "q"))
    with pytest.raises(ConfigError, match="kind must be"):
        identify(np.zeros(20), kind="hybrid")
    with pytest.raises(ConfigError, match="names"):
        regress(np.zeros((5, 2)), np.zeros(5), names=["a"])


# ----------------------------------------------------------------------- regress statistics


def test_regress_matches_statsmodels_ols_and_hac():
    sm = pytest.importorskip("statsmodels.api")
    rng = np.random.default_rng(0)
    n = 400
    x = np.column_stack([np.ones(n), np.cumsum(rng.standard_normal((n, 2)), axis=0) * 0.1])
    y = x @ [0.3, 1.0, -2.0] + signal.lfilter([1], [1, -0.7], rng.standard_normal(n))
    ols = sm.OLS(y, x).fit()
    r = regress(x, y, colored="newey-west", lags=6)
    np.testing.assert_allclose(r.coef, ols.params, rtol=1e-10)
    np.testing.assert_allclose(list(r.stderr.values()), ols.bse, rtol=1e-10)
    np.testing.assert_allclose(list(r.tstat_conventional.values()), ols.tvalues, rtol=1e-8)
    assert r.r2 == pytest.approx(ols.rsquared, rel=1e-12)
    assert r.s2 == pytest.approx(ols.scale, rel=1e-12)
    np.testing.assert_allclose(r.residuals, ols.resid, atol=1e-12)
    hac = sm.OLS(y, x).fit(cov_type="HAC", cov_kwds={"maxlags": 6, "use_correction": False})
    np.testing.assert_allclose(list(r.stderr_colored.values()), hac.bse, rtol=1e-10)
    assert r.colored_method == "Newey-West (Bartlett, 6 lags)"


def test_colored_correction_is_the_double_sum_over_all_lags():
    """(XᵀX)⁻¹[Σᵢ Σⱼ x(i) R̂(i−j) x(j)ᵀ](XᵀX)⁻¹ written out with a Toeplitz matrix; two records
    each summed on its own (no lag crosses a record's end)."""
    rng = np.random.default_rng(1)
    xs = [rng.standard_normal((n, 2)) for n in (120, 90)]
    ys = [x @ [1.0, -1.0] + signal.lfilter([1], [1, -0.8], rng.standard_normal(len(x)))
          for x in xs]
    r = regress(xs, ys)
    xa, ya = np.vstack(xs), np.concatenate(ys)
    theta = np.linalg.solve(xa.T @ xa, xa.T @ ya)
    v = ya - xa @ theta
    vs = [v[:120], v[120:]]
    n = len(v)
    rvv = np.zeros(120)
    for e in vs:
        for k in range(len(e)):
            rvv[k] += e[: len(e) - k] @ e[k:] / n
    meat = sum(x.T @ linalg.toeplitz(rvv[: len(x)]) @ x for x in xs)
    bread = np.linalg.inv(xa.T @ xa)
    np.testing.assert_allclose(r.cov_colored, bread @ meat @ bread, rtol=1e-9)
    assert r.colored_method.startswith("Klein-Morelli")
    np.testing.assert_allclose(r.cov, v @ v / (n - 2) * bread, rtol=1e-10)
    # PSE: mean squared residual plus σ²max p / N
    smax = ((ya - ya.mean()) ** 2).mean()
    assert r.pse == pytest.approx(v @ v / n + smax * 2 / n, rel=1e-12)


def _coverage(rho_v: float, method: str = "all-lags", reps: int = 200, n: int = 1000
              ) -> tuple[np.ndarray, np.ndarray]:
    """Fraction of ``reps`` noisy repetitions whose ±2σ intervals hold the truth: corrected σ,
    conventional σ. Regressors are AR(1) (ρ = 0.9), as smooth flight-test inputs are."""
    rng = np.random.default_rng(7)
    truth = np.array([1.5, -0.7])
    xs = signal.lfilter([np.sqrt(1 - 0.81)], [1, -0.9], rng.standard_normal((reps, 2, n)))
    e = rng.standard_normal((reps, n))
    v = 0.5 * (signal.lfilter([np.sqrt(1 - rho_v**2)], [1, -rho_v], e) if rho_v else e)
    hit_c = np.zeros(2)
    hit_w = np.zeros(2)
    for i in range(reps):
        r = regress(xs[i].T, xs[i].T @ truth + v[i], colored=method)
        hit_c += np.abs(r.coef - truth) <= 2 * np.sqrt(np.diag(r.cov_colored))
        hit_w += np.abs(r.coef - truth) <= 2 * np.sqrt(np.diag(r.cov))
    return hit_c / reps, hit_w / reps


@pytest.mark.slow
def test_two_sigma_coverage_white_noise():
    corrected, conventional = _coverage(0.0)
    assert np.all((corrected >= 0.91) & (corrected <= 0.99)), corrected
    assert np.all((conventional >= 0.91) & (conventional <= 0.99)), conventional


@pytest.mark.slow
def test_two_sigma_coverage_coloured_noise_needs_the_correction():
    corrected, conventional = _coverage(0.8)
    assert np.all((corrected >= 0.90) & (corrected <= 0.99)), corrected
    assert np.all(conventional < 0.7), conventional  # s²(XᵀX)⁻¹ is far too optimistic


def test_stepwise_finds_the_true_regressors():
    rng = np.random.default_rng(3)
    n = 500
    x = rng.standard_normal((n, 5))
    y = 2.0 + 1.5 * x[:, 0] - 0.8 * x[:, 3] + 0.3 * rng.standard_normal(n)
    r = regress(np.column_stack([np.ones(n), x]), y, names=["1", "a", "b", "c", "d", "e"],
                select="stepwise", keep=["1"])
    assert r.selected.tolist() == [True, True, False, False, True, False]
    assert r.selection.startswith("stepwise: partial F to enter >= 4, to stay >= 4")
    assert r.params["a"] == pytest.approx(1.5, abs=0.05)
    full = regress(np.column_stack([np.ones(n), x]), y)
    assert r.pse <= full.pse


# ----------------------------------------------------------------------- output error, CR bound


@pytest.mark.slow
def test_output_error_cramer_rao_bounds_cover_the_truth():
    """x[k+1] = a x[k] + b u[k] measured with white noise: the output-error estimate with its
    Cramér–Rao bound holds the truth within ±2σ in ~95 % of 100 repetitions."""
    a, b, n, reps = 0.95, 0.25, 600, 100
    rng = np.random.default_rng(11)
    hits = np.zeros(2)
    ses, ests = [], []
    for _ in range(reps):
        u = np.repeat(rng.standard_normal(n // 10), 10)
        x = signal.lfilter([0.0, b], [1.0, -a], u)
        y = x + 0.05 * rng.standard_normal(n)
        m = identify(y, u, dt=0.01, refine="oe", n_bootstrap=0)
        est = np.array([m.params["A_d[x,x]"], m.params["B_d[x,u]"]])
        se = np.array([m.stderr["A_d[x,x]"], m.stderr["B_d[x,u]"]])
        hits += np.abs(est - [a, b]) <= 2 * se
        ses.append(se)
        ests.append(est)
    assert m.provenance["refine"]["covariance"] == "cramer-rao"  # type: ignore[index]
    cover = hits / reps
    assert np.all((cover >= 0.88) & (cover <= 1.0)), cover
    # the bound is the spread of the estimates over the repetitions (efficient estimator)
    ratio = np.mean(ses, axis=0) / np.std(ests, axis=0, ddof=1)
    assert np.all((ratio > 0.75) & (ratio < 1.33)), ratio


# ----------------------------------------------------------------------- the log path uses it


def test_fit_axis_is_identify_with_the_axis_names():
    x, u = _plant(1500, 6, a=((0.98,),), b=((0.6,),))
    seg = Segment(np.arange(1500) * 0.0025, x, u, ("p",), ("u_roll",), 0.0025, "roll", "scan")
    via_log = fit_axis([seg], "roll", delay=0, filters=(), lags_s=None, refine=None,
                       n_bootstrap=0)
    via_arrays = identify(x, u, dt=0.0025, state_names=["p"], input_names=["u_roll"],
                          bias=True, n_bootstrap=0)
    np.testing.assert_allclose(via_log.coef, via_arrays.coef, rtol=1e-12)
    assert via_log.params == pytest.approx(via_arrays.params)


def test_fast_delay_scan_equals_refitting_every_candidate():
    rng = np.random.default_rng(2)
    flt = (InputFilter(20.0, 2, "gyro", rate_hz=1000.0), InputFilter(8.0, 1, "lag"))
    segs = []
    for n in (700, 15, 900):  # a record shorter than the longest delay, too
        u = rng.standard_normal((n, 2))
        x = np.cumsum(rng.standard_normal((n, 2)), axis=0) * 0.1
        segs.append(Segment(np.arange(n) * 0.0025, x, u, ("p", "q"), ("u_roll", "u_pitch"),
                            0.0025, "all", "scan"))
    st = Structure(("p", "q"), ("p", "q", "u_roll", "u_pitch", "1"), filters=flt)
    scan = DelayScan(segs, st, 14)
    for dly in (0.0, 1.0, 2.5, 7.125, 13.0, 13.875):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            slow = _slow_mse(segs, st, dly)
        assert scan.mse(dly) == pytest.approx(slow, rel=1e-9)
    best, _ = select_delay(segs, st, [0.0, 1.0, 2.5])
    assert best in (0.0, 1.0, 2.5)
    dlys = [0.0, 1.0, 2.5, 7.125, 13.875]  # scored together: the numbers of one by one
    assert scan.mse_many(dlys) == pytest.approx([scan.mse(d) for d in dlys], rel=1e-12)


def test_every_lag_of_the_search_scores_as_refitting_it():
    """The lags share the rows no lag changes: each (lag, delay) still scores as its own
    refit, records as short as the longest delay (and one sample longer) included; the
    inputs kept per lag are those the whole filter chain gives."""
    rng = np.random.default_rng(4)
    gyro = (InputFilter(20.0, 2, "gyro", rate_hz=1000.0),)
    segs = []
    for n in (900, 12, 13, 14, 700):  # 11 samples of delay at most: 12 regressor rows
        u = rng.standard_normal((n, 2))
        x = np.cumsum(rng.standard_normal((n, 2)), axis=0) * 0.1
        segs.append(Segment(np.arange(n) * 0.0025, x, u, ("p", "q"), ("u_roll", "u_pitch"),
                            0.0025, "all", "scan"))
    st = Structure(("p", "q"), ("p", "q", "u_roll", "u_pitch", "1"), ("u_roll", "u_pitch"),
                   filters=gyro)
    choice = search_structure(segs, st, lags_s=(0.01, 0.02), max_delay_s=0.025)
    assert sorted(choice.inputs) == [0.0, 0.01, 0.02]
    assert sorted(choice.ls_coef) == [0.0, 0.01, 0.02]  # scored from one Gram per lag
    checked = 0
    for key, mse in choice.scan.items():
        lag, dly = (float(v.split("=")[1].rstrip("s")) for v in key.split(","))
        if dly not in (0.0, 3.0, 10.0) and dly % 1 == 0:
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            slow = _slow_mse(segs, replace(st, filters=gyro + lag_filter(lag)), dly)
        assert mse == pytest.approx(slow, rel=1e-9), key
        checked += 1
    assert checked >= 9
    for lag, per_seg in choice.inputs.items():
        for seg, cols in zip(segs, per_seg, strict=True):
            whole = filter_inputs(seg.inputs, seg.dt, gyro + lag_filter(lag))
            np.testing.assert_array_equal(np.column_stack([cols["u_roll"], cols["u_pitch"]]),
                                          whole)


def test_output_error_coef_takes_the_search_inputs():
    """The neighbouring lags' refinement on the search's filtered inputs: the same numbers
    as filtering them again."""
    x, u = _plant(3000, 8, a=((0.985,),), b=((0.4,),), noise=0.01)
    segs = [Segment(np.arange(len(x)) * 0.0025, x, u, ("p",), ("u_roll",), 0.0025, "roll",
                    "sysid"), Segment(np.arange(900) * 0.0025, x[:900], u[:900] * 0.5,
                                      ("p",), ("u_roll",), 0.0025, "roll", "sysid")]
    base = Structure(("p",), ("p", "u_roll", "1"), ("u_roll",),
                     filters=(InputFilter(20.0, 2, "gyro", rate_hz=1000.0),))
    choice = search_structure(segs, base, lags_s=(0.01, 0.02), max_delay_s=0.01)
    for lag, (_, dly) in choice.by_lag.items():
        start = LeastSquares(with_lag(base, lag, dly), n_bootstrap=0).fit(segs).model_
        plain = oe.output_error_coef(start, segs)
        given = oe.output_error_coef(start, segs, filtered=choice.inputs[lag])
        assert plain is not None and given is not None
        np.testing.assert_array_equal(given[0], plain[0])
        assert given[1] == plain[1]


def test_output_error_coef_reaches_the_trust_region_optimum():
    """The search's neighbouring-lag refinement (variable projection on the pole) lands on
    the minimum refine_output_error finds with tight tolerances, at its cost."""
    x, u = _plant(3000, 8, a=((0.985,),), b=((0.4,),), noise=0.01)
    segs = [Segment(np.arange(len(x)) * 0.0025, x, u, ("p",), ("u_roll",), 0.0025, "roll",
                    "sysid")]
    base = Structure(("p",), ("p", "u_roll", "1"), ("u_roll",))
    start = LeastSquares(with_lag(base, 0.01, 2.0), n_bootstrap=0).fit(segs).model_
    got = oe.output_error_coef(start, segs)
    assert got is not None
    tight = functools.partial(optimize.least_squares, ftol=1e-15, xtol=1e-15, gtol=1e-15)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(optimize, "least_squares", tight)
        ref = oe.refine_output_error(start, segs, covariance="plain")
    np.testing.assert_allclose(got[0], ref.coef, rtol=1e-6)
    assert got[1] <= ref.provenance["refine"]["cost"] * (1 + 1e-12)
    # not its kind: two states, or a continuous-time model -> None (callers refine)
    seg2 = [Segment(np.arange(len(x)) * 0.0025, np.hstack([x, 0.5 * x]), u, ("p", "q"),
                    ("u_roll",), 0.0025, "all", "sysid")]
    m2 = mavsid.Model(("p", "q"), ("u_roll",), ("p", "q", "u_roll"),
                      np.array([[0.9, 0.1], [0.0, 0.8], [0.4, 0.2]]), 0.0025)
    assert oe.output_error_coef(m2, seg2) is None
    assert oe.output_error_coef(replace(start, continuous=True), segs) is None


def test_fit_axis_bounds_hold_through_output_error():
    """A bounded fit (what a verdict on damping and control sign needs): the L1 path with
    alpha=0 and bounds, kept by the output-error refinement."""
    x, u = _plant(2000, 8, a=((0.99,),), b=((0.5,),), noise=0.02)
    seg = Segment(np.arange(2000) * 0.0025, x, u, ("p",), ("u_roll",), 0.0025, "roll", "scan")
    free = fit_axis([seg], "roll", delay=0, filters=(), lags_s=None, n_bootstrap=0)
    cap = free.params["B_d[p,u_roll]"] * 0.9
    m = fit_axis([seg], "roll", "l1", alpha=0.0, delay=0, filters=(), lags_s=None,
                 bounds={"B_d[p,u_roll]": (0.0, cap)}, signs={"A_d[p,p]": +1})
    assert m.params["B_d[p,u_roll]"] <= cap * (1 + 1e-9)
    assert m.params["B_d[p,u_roll]"] == pytest.approx(cap, rel=1e-3)  # the bound binds
    assert "refine" in m.provenance


def test_public_names():
    assert mavsid.identify is identify and mavsid.regress is regress
    assert mavsid.Model.__name__ == "Model"
    with pytest.raises(AttributeError):
        _ = mavsid.no_such_name  # type: ignore[attr-defined]


def test_the_array_api_guide_examples_run():
    """The array-API guide's examples are a doctest (its ``pycon`` blocks)."""
    import doctest
    import re
    import textwrap

    from helpers import ROOT

    guide = (ROOT / "docs" / "guide" / "arrays.rst").read_text(encoding="utf-8")
    blocks = [textwrap.dedent(b) for b in
              re.findall(r"\.\. code-block:: pycon\n\n(.*?)(?=\n\S|\Z)", guide, flags=re.S)]
    assert len(blocks) == 3
    parser = doctest.DocTestParser()
    test = parser.get_doctest("\n".join(blocks), {}, "README", "README.md", 0)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
    runner.run(test)
    assert runner.failures == 0 and runner.tries == sum(b.count(">>> ") for b in blocks) > 0


@pytest.mark.parametrize("func", ["identify", "regress", "records", "fit_axis"])
def test_every_parameter_is_documented(func):
    """python-control's meta-test: a parameter missing from the docstring fails."""
    import inspect
    import re

    import mavsid.estimators

    f = getattr(mavsid.estimators, func)
    doc = inspect.getdoc(f) or ""
    section = doc.split("Parameters\n----------\n", 1)[1].split("\n\nReturns", 1)[0]
    entries = set()
    for line in section.splitlines():
        m = re.match(r"^(\*\*)?([\w, *]+?)(\s*:|$)", line)
        if m and not line.startswith(" "):
            entries.update(n.strip().lstrip("*") for n in m.group(2).split(","))
    for name in inspect.signature(f).parameters:
        assert name in entries, f"{func}: parameter {name} not documented"


def test_predictions_from_one_run_equal_stepping_every_start():
    """A stable one-state affine model predicts every horizon from one run of its recursion;
    the same numbers as stepping each start forward (what other models do)."""
    x, u = _plant(600, 9, a=((0.97,),), b=((0.3,),), noise=0.02)
    seg = Segment(np.arange(len(x)) * 0.01, x, u, ("p",), ("u_roll",), 0.01, "roll", "sysid")
    m = mavsid.Model(("p",), ("u_roll",), ("p", "u_roll", "1"),
                     np.array([[0.97], [0.3], [0.01]]), 0.01, delay=2, delay_frac=0.5,
                     filters=(InputFilter(8.0, 1, "lag"),))
    _, var = m._measured(seg)
    phi, f = m._affine(var)
    for h, got in zip((1, 7, 50, 599, 600), m.predict_horizons(seg, [1, 7, 50, 599, 600]),
                      strict=True):
        want = np.full_like(x, np.nan)
        if h < len(x):
            step = x[: len(x) - h].copy()
            for j in range(h):
                step = step @ phi.T + f[j : j + len(x) - h]
            want[h:] = step
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(np.isnan(got), np.isnan(m.predict(seg, h)))


def test_output_error_holds_a_coefficient_its_bounds_fix() -> None:
    """Bounds that meet hold their coefficient there (a zero σ: nothing is estimated of
    it); a bound that binds holds another on its edge; the rest is refined: the free run
    fits better than the equation-error start's."""
    x, u = _plant(3000, 8, a=((0.985,),), b=((0.4,),), noise=0.01)
    seg = Segment(np.arange(len(x)) * 0.0025, x, u, ("p",), ("u_roll",), 0.0025, "roll",
                  "sysid")
    start = LeastSquares(Structure(("p",), ("p", "u_roll", "1"), ("u_roll",)),
                         n_bootstrap=0).fit([seg]).model_
    lo = np.array([[0.98], [-np.inf], [-np.inf]])
    hi = np.array([[0.98], [0.39], [np.inf]])
    got = oe.refine_output_error(start, [seg], covariance="plain", bounds=(lo, hi))
    assert got.coef[0, 0] == 0.98 and got.coef_stderr is not None
    assert got.coef_stderr[0, 0] == 0.0 and got.coef_stderr[2, 0] > 0
    assert got.coef[1, 0] <= 0.39 and got.coef[1, 0] == pytest.approx(0.39, abs=1e-6)
    refine = got.provenance["refine"]
    assert refine["cost"] < refine["cost_start"]  # type: ignore[index]
