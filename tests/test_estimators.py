"""Estimators against plants whose truth the test itself defines (numpy-simulated), and against
independent numpy/scipy/cvxpy computations of the same problems."""

from __future__ import annotations

import json
import re
import warnings

import numpy as np
import pytest
from scipy import signal

from mavsid.data import Segment
from mavsid.errors import ConfigError, LogFormatError, NoExcitationError
from mavsid.estimators import (
    STLSQ,
    InputFilter,
    Lasso,
    LeastSquares,
    Ridge,
    Structure,
    filters_from_params,
    fit_axis,
    library,
    load_model,
    stack,
)

DT = 0.0025
STATES = ("p", "q", "r")
INPUTS = ("u_roll", "u_pitch", "u_yaw")


def excitation(n: int, m: int, rng: np.random.Generator, smooth: int = 8) -> np.ndarray:
    """Band-limited random inputs (held random steps, lightly smoothed)."""
    steps = np.repeat(rng.standard_normal((n // smooth + 1, m)), smooth, axis=0)[:n]
    return 0.05 * signal.lfilter([0.5], [1.0, -0.5], steps, axis=0)


def plant(a: np.ndarray, b: np.ndarray, c: np.ndarray, delay: int, n: int, seed: int,
          noise: float = 0.0, frac: float = 0.0, filt: InputFilter | None = None,
          u: np.ndarray | None = None, ar_noise: float = 0.0) -> Segment:
    """x[k+1] = A x[k] + B v[k] + c + w[k], v = filtered input delayed by delay + frac samples
    (written out sample by sample, independently of the package)."""
    rng = np.random.default_rng(seed)
    nx, nu = b.shape
    if u is None:
        u = excitation(n, nu, rng)
    v = u.copy()
    if filt is not None:
        bf, af = signal.butter(filt.order, filt.cutoff_hz, fs=1 / DT)
        v = signal.lfilter(bf, af, v, axis=0, zi=signal.lfilter_zi(bf, af)[:, None] * v[:1])[0]
    x = np.zeros((n, nx))
    w = noise * rng.standard_normal((n, nx))
    if ar_noise:
        w = signal.lfilter([1.0], [1.0, -ar_noise], w, axis=0)
    for k in range(n - 1):
        i0 = max(k - delay, 0)
        i1 = max(k - delay - 1, 0)
        vk = (1 - frac) * v[i0] + frac * v[i1]
        x[k + 1] = a @ x[k] + b @ vk + c + w[k]
    names = STATES[:nx]
    return Segment(np.arange(n) * DT, x, u, names, INPUTS[:nu], DT, "all", "scan",
                   params={"INS_GYRO_FILTER": filt.cutoff_hz} if filt else {})


A2 = np.array([[0.995, 0.002], [-0.003, 0.993]])
B2 = np.array([[0.75, 0.02], [0.0, 0.70]])
C2 = np.array([0.001, -0.002])
LIN2 = Structure(("p", "q"), ("p", "q", "u_roll", "u_pitch", "1"), delay=3)


def truth_coef() -> np.ndarray:
    return np.vstack([A2.T, B2.T, C2[None, :]])


# ----------------------------------------------------------------------- recovery


def test_noise_free_recovers_coupled_plant_within_1_percent():
    segs = [plant(A2, B2, C2, 3, 3000, s) for s in (1, 2)]
    m = LeastSquares(LIN2, n_bootstrap=0).fit(segs).model_
    for j, f in enumerate(LIN2.features):
        for i, o in enumerate(LIN2.outputs):
            true = truth_coef()[j, i]
            got = m.coef[j, i]
            assert got == pytest.approx(true, rel=0.01, abs=1e-6), (f, o)
    name = "B_d[p,u_roll]"
    assert m.params[name] == pytest.approx(0.75, rel=1e-6)
    assert m.units[name] == "rad/s"


@pytest.mark.slow
@pytest.mark.parametrize("est", ["ls", "ridge"])
def test_truth_inside_three_sigma_in_95_percent_of_50_seeds(est):
    hits = total = 0
    a = np.array([[0.99]])
    b = np.array([[0.6]])
    c = np.array([0.002])
    for seed in range(50):
        segs = [plant(a, b, c, 2, 1200, 100 * seed + i, noise=0.01) for i in range(3)]
        kw = {"alpha": 1e-9} if est == "ridge" else {}
        model = fit_axis(segs, "roll", est, delay=2, filters=(), n_bootstrap=30,
                         random_state=seed, refine=None, **kw)
        for name, true in (("A_d[p,p]", 0.99), ("B_d[p,u_roll]", 0.6), ("c_d[p]", 0.002)):
            total += 1
            hits += abs(model.params[name] - true) <= 3 * model.stderr[name]
    assert hits / total >= 0.95, f"{hits}/{total}"


@pytest.mark.slow
def test_output_error_truth_inside_three_sigma_with_sensor_noise():
    """Sensor (output) noise: equation-error LS is biased (the noisy p[k] is a regressor),
    the output-error refinement recovers the plant with calibrated error bars."""
    hits = total = ls_hits = 0
    a_c, b_c = -3.0, 200.0
    ad = np.exp(a_c * DT)
    bd = b_c * (ad - 1) / a_c
    for seed in range(50):
        rng = np.random.default_rng(seed)
        segs = []
        for _ in range(2):
            clean = plant(np.array([[ad]]), np.array([[bd]]), np.zeros(1), 0, 1500,
                          int(rng.integers(1 << 30)))
            noisy = clean.states + 0.02 * rng.standard_normal(clean.states.shape)
            segs.append(Segment(clean.time_s, noisy, clean.inputs, ("p",), ("u_roll",), DT,
                                "roll", "scan"))
        # the structure known (no lag searched): the statistical σ alone are compared
        m = fit_axis(segs, "roll", delay=0, filters=(), bias=False, n_bootstrap=0,
                     lags_s=None)
        ls = fit_axis(segs, "roll", delay=0, filters=(), bias=False, n_bootstrap=0,
                      refine=None, lags_s=None)
        for name, true in (("A_d[p,p]", ad), ("B_d[p,u_roll]", bd)):
            total += 1
            hits += abs(m.params[name] - true) <= 3 * m.stderr[name]
            ls_hits += abs(ls.params[name] - true) <= 3 * ls.stderr[name]
    assert hits / total >= 0.95, f"{hits}/{total}"
    assert ls_hits / total < 0.75, f"{ls_hits}/{total}"  # biased: far from 99.7 %


def test_hac_covers_truth_under_coloured_noise_where_plain_sigma_does_not():
    """Static regression y = B u + c with AR(0.95) noise: σ²(ZᵀZ)⁻¹ is far too small, the
    Newey–West correction restores the coverage."""
    hac_hits = plain_hits = 0
    for seed in range(50):
        rng = np.random.default_rng(seed)
        n = 2000
        u = excitation(n, 1, rng, smooth=40)
        e = signal.lfilter([1.0], [1.0, -0.95], 0.01 * rng.standard_normal(n))
        y = 0.5 * u[:, 0] + e
        seg = Segment(np.arange(n) * DT, y[:, None], u, ("p",), ("u_roll",), DT, "roll", "scan")
        st = Structure(("p",), ("u_roll", "1"), continuous=False)
        # target: p[k+1]; regress p[k+1] on u[k] -> build with y shifted so truth is 0.5
        seg = Segment(seg.time_s, np.r_[0.0, y[:-1]][:, None], u, ("p",), ("u_roll",), DT,
                      "roll", "scan")
        for hac in (True, False):
            m = LeastSquares(st, hac=hac, n_bootstrap=0).fit([seg]).model_
            ok = abs(m.params["B_d[p,u_roll]"] - 0.5) <= 3 * m.stderr["B_d[p,u_roll]"]
            if hac:
                hac_hits += ok
            else:
                plain_hits += ok
    assert hac_hits >= 47
    assert plain_hits < 40


def test_delay_found_exactly_with_the_known_filter():
    filt = InputFilter(20.0, 2, "INS_GYRO_FILTER")
    a, b, c = np.array([[0.995]]), np.array([[0.77]]), np.array([0.0])
    seg = plant(a, b, c, 5, 6000, 7, noise=1e-4, filt=filt)
    m = fit_axis([seg], "roll", delay_step=1.0, n_bootstrap=0, filters=(filt,))
    assert m.delay == 5 and m.delay_frac == 0.0
    assert m.filters == (filt,)
    assert m.params["B_d[p,u_roll]"] == pytest.approx(0.77, rel=0.01)
    # the same data without the filter in the model: the lag is absorbed, the gain is wrong
    m0 = fit_axis([seg], "roll", delay_step=1.0, filters=(), n_bootstrap=0, lags_s=None,
                  refine=None)
    assert abs(m0.params["B_d[p,u_roll]"] / 0.77 - 1) > 0.05


def test_fractional_delay_found():
    a, b, c = np.array([[0.99]]), np.array([[0.5]]), np.array([0.0])
    seg = plant(a, b, c, 2, 5000, 8, noise=1e-5, frac=0.5)
    m = fit_axis([seg], "roll", filters=(), delay_step=0.25, n_bootstrap=0)
    assert (m.delay, m.delay_frac) == (2, 0.5)


def test_continuous_time_savgol_and_tv_recover_the_plant():
    """ẋ = a x + b u(t) with a smooth multisine u: the exact (analytic) response is sampled."""
    a_c, b_c = -3.0, 250.0
    rng = np.random.default_rng(4)
    n = 4000
    t = np.arange(n) * DT
    freqs = np.linspace(0.3, 8.0, 12)
    amps = 0.01 * rng.uniform(0.5, 1.0, freqs.size)
    phases = rng.uniform(0, 2 * np.pi, freqs.size)
    w = 2 * np.pi * freqs
    phasor = amps * np.exp(1j * phases)
    u = np.real(np.exp(1j * np.outer(t, w)) @ phasor)
    gain = b_c / (1j * w - a_c)
    forced = np.real(np.exp(1j * np.outer(t, w)) @ (gain * phasor))
    x = forced - forced[0] * np.exp(a_c * t)  # x(0) = 0
    seg = Segment(t, x[:, None], u[:, None], ("p",), ("u_roll",), DT, "roll", "scan")
    for method in ("savgol", "tv"):
        st = Structure(("p",), ("p", "u_roll"), continuous=True, derivative=method,
                       window=9, tv_weight=1e-8)
        m = LeastSquares(st, n_bootstrap=0).fit([seg]).model_
        assert m.params["A[p,p]"] == pytest.approx(a_c, rel=0.01), method
        assert m.params["B[p,u_roll]"] == pytest.approx(b_c, rel=0.01), method
        assert m.units["B[p,u_roll]"] == "rad/s^2"


def test_continuous_equivalent_of_discrete_fit_is_the_physical_plant():
    a_c, b_c = -2.0, 300.0
    ad = np.exp(a_c * DT)
    bd = b_c * (ad - 1) / a_c
    seg = plant(np.array([[ad]]), np.array([[bd]]), np.array([0.0]), 0, 4000, 3, noise=1e-4)
    m = fit_axis([seg], "roll", delay=0, filters=(), n_bootstrap=20)
    assert m.params["B[p,u_roll]"] == pytest.approx(b_c, rel=0.01)
    assert m.params["A[p,p]"] == pytest.approx(a_c, abs=0.2)
    assert m.units["B[p,u_roll]"] == "rad/s^2" and m.units["A[p,p]"] == "1/s"
    assert 0 < m.stderr["B[p,u_roll]"] < 5


# ----------------------------------------------------------------------- sparsity


def _library_case(seed: int = 11) -> tuple[list[Segment], Structure]:
    rng = np.random.default_rng(seed)
    n = 4000
    u = excitation(n, 1, rng)
    roll = np.cumsum(rng.standard_normal(n)) * 0.002
    p = np.zeros(n)
    for k in range(n - 1):
        p[k + 1] = 0.95 * p[k] + 0.5 * u[k, 0] + 1.5 * p[k] * u[k, 0] \
            + 1e-4 * rng.standard_normal()
    seg = Segment(np.arange(n) * DT, np.column_stack([p, roll]), u, ("p", "roll"),
                  ("u_roll",), DT, "roll", "scan")
    feats = library.library(library.polynomial(("p", "u_roll"), 3),
                            library.trigonometric(("roll",)))
    return [seg], Structure(("p",), feats)


def test_l1_zeroes_irrelevant_library_terms():
    segs, st = _library_case()
    m = Lasso(st, alpha=1e-5).fit(segs).model_
    relevant = {"p", "u_roll", "p*u_roll", "1"}  # the bias is never penalised
    coef = dict(zip(st.features, m.coef[:, 0], strict=True))
    zeros = {f for f, v in coef.items() if v == 0.0}
    assert zeros - {"1"} == set(st.features) - relevant
    assert coef["u_roll"] == pytest.approx(0.5, rel=0.01)
    assert coef["p"] == pytest.approx(0.95, rel=0.01)
    assert coef["p*u_roll"] == pytest.approx(1.5, rel=0.01)


def test_stlsq_keeps_exactly_the_true_terms():
    segs, st = _library_case()
    m = STLSQ(st, threshold=0.02, n_bootstrap=0).fit(segs).model_
    kept = {f for f, v in zip(st.features, m.coef[:, 0], strict=True) if v != 0}
    assert kept == {"p", "u_roll", "p*u_roll"}
    assert np.isnan(m.stderr["W_d[p,p^2]"])


def test_l1_bounds_and_signs_are_enforced():
    segs, st = _library_case()
    m = Lasso(st, alpha=1e-6, bounds={"B_d[p,u_roll]": (0.0, 0.4)},
              signs={"W_d[p,p*u_roll]": -1}).fit(segs).model_
    assert m.params["B_d[p,u_roll]"] <= 0.4 + 1e-7
    assert m.params["W_d[p,p*u_roll]"] <= 1e-9
    with pytest.raises(ConfigError, match="unknown parameter"):
        Lasso(st, alpha=1e-6, bounds={"B[nope]": (0, 1)}).fit(segs)


# ----------------------------------------------------------------------- stacking, references


def _rows_by_hand(seg: Segment, delay: int) -> tuple[np.ndarray, np.ndarray]:
    x, u = seg.states, seg.inputs
    zs, ys = [], []
    for k in range(delay, len(seg) - 1):
        zs.append(np.r_[x[k], u[k - delay], 1.0])
        ys.append(x[k + 1])
    return np.array(zs), np.array(ys)


def test_stacking_two_segments_equals_the_merged_regressions_by_hand():
    s1 = plant(A2, B2, C2, 3, 700, 21, noise=1e-3)
    s2 = plant(A2, B2, C2, 3, 900, 22, noise=1e-3)
    z1, y1 = _rows_by_hand(s1, 3)
    z2, y2 = _rows_by_hand(s2, 3)
    ref, *_ = np.linalg.lstsq(np.vstack([z1, z2]), np.vstack([y1, y2]), rcond=None)
    got = LeastSquares(LIN2, n_bootstrap=0).fit([s1, s2]).coef_
    np.testing.assert_allclose(got, ref, rtol=1e-8, atol=1e-10)
    reg = stack([s1, s2], LIN2)
    assert reg.n == len(z1) + len(z2)
    # naive concatenation pairs s1's last sample with s2's first: a different answer
    cat = Segment(np.arange(1600) * DT, np.vstack([s1.states, s2.states]),
                  np.vstack([s1.inputs, s2.inputs]), s1.state_names, s1.input_names, DT,
                  "all", "scan")
    naive = LeastSquares(LIN2, n_bootstrap=0).fit([cat]).coef_
    assert not np.allclose(naive, ref, rtol=1e-6, atol=1e-9)


def test_ls_and_ridge_equal_scipy_normal_equations():
    segs = [plant(A2, B2, C2, 3, 1500, s, noise=1e-3) for s in (31, 32)]
    z = np.vstack([_rows_by_hand(s, 3)[0] for s in segs])
    y = np.vstack([_rows_by_hand(s, 3)[1] for s in segs])
    from scipy import linalg

    ls = LeastSquares(LIN2, n_bootstrap=0).fit(segs)
    np.testing.assert_allclose(ls.coef_, linalg.lstsq(z, y)[0], rtol=1e-7, atol=1e-10)
    alpha = 1e-3
    s = np.sqrt((z**2).mean(axis=0))
    pen = np.array([1, 1, 1, 1, 0.0])
    ref = linalg.solve(z.T @ z + alpha * len(z) * np.diag(s**2 * pen), z.T @ y)
    rg = Ridge(LIN2, alpha=alpha, n_bootstrap=0).fit(segs)
    np.testing.assert_allclose(rg.coef_, ref, rtol=1e-7, atol=1e-10)
    # covariance without HAC: sigma^2 (Z^T Z)^-1 per output
    plain = LeastSquares(LIN2, n_bootstrap=0, hac=False).fit(segs)
    e = y - z @ plain.coef_
    sig2 = (e**2).sum(axis=0) / (len(z) - z.shape[1])
    np.testing.assert_allclose(plain.model_.covariance[0], sig2[0] * np.linalg.inv(z.T @ z),
                               rtol=1e-6)


def test_lasso_equals_cvxpy_on_the_raw_rows():
    import cvxpy as cp

    segs, st = _library_case(12)
    reg = stack(segs, st)
    z, y = reg.z, reg.y[:, 0]
    alpha = 1e-5
    s = np.sqrt((z**2).mean(axis=0))
    pen = np.array([f != "1" for f in st.features], float)
    th = cp.Variable(z.shape[1])
    obj = cp.sum_squares(z @ th - y) / len(z) + alpha * cp.norm1(cp.multiply(pen * s, th))
    cp.Problem(cp.Minimize(obj)).solve(solver="CLARABEL")
    got = Lasso(st, alpha=alpha, zero_tol=0.0).fit(segs).coef_[:, 0]
    # compared on unit-RMS columns: the solvers' tolerances are relative to those
    np.testing.assert_allclose(got * s, th.value * s, atol=1e-5 * np.abs(th.value * s).max())


def test_ridge_cv_chooses_alpha_by_rollout():
    segs = [plant(A2, B2, C2, 3, 2000, s, noise=1e-3) for s in (41, 42)]
    est = Ridge(LIN2, alphas=(1e-9, 1e-1, 10.0), n_bootstrap=0).fit(segs)
    assert est.alpha_ == 1e-9
    assert set(est.cv_scores_) == {1e-9, 1e-1, 10.0}
    assert est.cv_scores_[1e-9] > est.cv_scores_[10.0]


# ----------------------------------------------------------------------- identifiability


def test_constant_input_raises_naming_the_parameter_and_cause():
    seg = plant(np.array([[0.99]]), np.array([[0.5]]), np.array([0.0]), 0, 500, 1,
                u=np.full((500, 1), 0.1), noise=1e-3)
    with pytest.raises(NoExcitationError,
                       match=r"B_d\[p,u_roll\] unidentifiable: u_roll does not vary in the "
                             r"selected segments"):
        fit_axis([seg], "roll", delay=0, filters=())


def test_collinear_inputs_raise_naming_both():
    rng = np.random.default_rng(2)
    u1 = excitation(800, 1, rng)
    seg = plant(np.eye(1) * 0.99, np.array([[0.5, 0.1]]), np.array([0.0]), 0, 800, 1,
                u=np.hstack([u1, 2 * u1]), noise=1e-3)
    st = Structure(("p",), ("p", "u_roll", "u_pitch", "1"))
    with pytest.raises(NoExcitationError, match=r"u_roll and u_pitch are collinear"):
        LeastSquares(st).fit([seg])


def test_too_short_and_empty_inputs_are_typed_errors():
    seg = plant(np.eye(1) * 0.9, np.ones((1, 1)), np.zeros(1), 0, 3, 0)
    with pytest.raises(NoExcitationError):
        LeastSquares(Structure(("p",), ("p", "u_roll", "1"))).fit([seg])
    with pytest.raises(NoExcitationError):
        fit_axis([], "roll")
    with pytest.raises(ConfigError):
        fit_axis([seg], "sideways")
    with pytest.raises(ConfigError):
        fit_axis([seg], "roll", estimator="magic")


# ----------------------------------------------------------------------- model object


def test_simulate_and_predict_match_an_independent_loop():
    seg = plant(A2, B2, C2, 3, 600, 51, noise=1e-3)
    m = LeastSquares(LIN2, n_bootstrap=0).fit([seg]).model_
    a = m.coef[:2].T
    b = m.coef[2:4].T
    c = m.coef[4]
    x = np.zeros((600, 2))
    x[0] = seg.states[0]
    for k in range(599):
        x[k + 1] = a @ x[k] + b @ seg.inputs[max(k - 3, 0), :2] + c
    np.testing.assert_allclose(m.simulate(seg), x, rtol=1e-9, atol=1e-12)
    one = m.predict(seg, 1)
    assert np.isnan(one[0]).all()
    k = 100
    ref = a @ seg.states[k - 1] + b @ seg.inputs[k - 1 - 3, :2] + c
    np.testing.assert_allclose(one[k], ref, rtol=1e-9)
    h = 25
    many = m.predict(seg, h)
    xx = seg.states[k - h].copy()
    for j in range(k - h, k):
        xx = a @ xx + b @ seg.inputs[max(j - 3, 0), :2] + c
    np.testing.assert_allclose(many[k], xx, rtol=1e-9)


def test_nonlinear_model_rollout_matches_an_independent_loop():
    segs, st = _library_case(13)
    m = STLSQ(st, threshold=0.02, n_bootstrap=0).fit(segs).model_
    seg = segs[0]
    co = dict(zip(st.features, m.coef[:, 0], strict=True))
    x = np.empty(300)
    x[0] = seg.states[0, 0]
    for k in range(299):
        uk = seg.inputs[k, 0]
        x[k + 1] = co["p"] * x[k] + co["u_roll"] * uk + co["p*u_roll"] * x[k] * uk
    short = Segment(seg.time_s[:300], seg.states[:300], seg.inputs[:300], seg.state_names,
                    seg.input_names, DT, "roll", "scan")
    np.testing.assert_allclose(m.simulate(short)[:, 0], x, rtol=1e-9, atol=1e-12)


def test_json_round_trip(tmp_path):
    filt = InputFilter(20.0, 2, "INS_GYRO_FILTER")
    seg = plant(np.array([[0.995]]), np.array([[0.77]]), np.array([0.0]), 2, 2000, 3,
                noise=1e-4, filt=filt)
    m = fit_axis([seg], "roll", n_bootstrap=20)  # filter from INS_GYRO_FILTER, at 1 kHz
    path = tmp_path / "m.json"
    m.save(path)
    back = load_model(path)
    assert back.params == m.params
    assert back.units == m.units
    np.testing.assert_allclose(back.simulate(seg), m.simulate(seg))
    assert json.loads(path.read_text())["provenance"]["settings"]["estimator"] == "ls"
    for k, v in m.stderr.items():
        assert back.stderr[k] == pytest.approx(v, nan_ok=True)
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(LogFormatError, match=r"bad\.json"):
        load_model(bad)
    bad.write_text(json.dumps({"format": "other"}))
    with pytest.raises(LogFormatError):
        load_model(bad)


@pytest.mark.parametrize(("change", "said"), [
    ({"dt": 0.0}, "dt 0.0 s is not a sample step"),  # was a ZeroDivisionError
    ({"dt": float("nan")}, "dt nan s is not a sample step"),  # a ValueError traceback
    ({"delay": 10**9}, "delay 1000000000 samples"),  # took the machine's memory
    ({"delay": -3}, "is not an input delay"),
    ({"delay_frac": 7.5}, "delay_frac 7.5 is not a fraction"),
    ({"filters": [{"cutoff_hz": 20.0, "order": 10**6, "rate_hz": 1000.0}]},
     "order 1000000"),  # ran for minutes
    ({"filters": [{"cutoff_hz": 900.0, "order": 2, "rate_hz": 1000.0}]},
     "cutoff below half the rate"),
    ({"coef": "nan"}, "coef holds a value that is not a finite"),
    ({"coef": [[0.9, 1.0]]}, "coef has shape"),
    ({"coef_stderr": [[float("inf")], [0.1]]}, "coef_stderr holds an infinite"),
    ({"version": 99}, "model format version 99"),
])
def test_a_stored_model_that_no_fit_gives_is_refused(tmp_path, change, said):
    """A model file is input: each value no fit writes is one typed error naming the file
    and the value."""
    seg = plant(np.array([[0.995]]), np.array([[0.77]]), np.array([0.0]), 2, 800, 3)
    d = fit_axis([seg], "roll", n_bootstrap=0, features=("p", "u_roll")).to_dict()
    path = tmp_path / "m.json"
    if change.get("coef") == "nan":
        change = {"coef": [[float("nan")] * len(row) for row in d["coef"]]}
    path.write_text(json.dumps({**d, **change}))
    with pytest.raises(LogFormatError, match=re.escape(said)) as err:
        load_model(path)
    assert str(path) in str(err.value)


@pytest.mark.parametrize(("name", "value"), [("INS_GYRO_FILTER", -20.0),
                                           ("INS_GYRO_FILTER", float("nan")),
                                           ("IMU_GYRO_CUTOFF", float("inf"))])
def test_a_damaged_gyro_filter_parameter_is_said(name, value):
    """A gyro filter that is no frequency was left out of the model silently (the fitted
    delay took its lag): now a warning names it."""
    from mavsid.errors import DataQualityWarning

    with pytest.warns(DataQualityWarning, match=f"{name} = {value:g} is no filter frequency"):
        assert filters_from_params({name: value}, DT) == ()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        filters_from_params({"INS_GYRO_FILTER": 0.0}, DT)  # 0: no filter, as ArduPilot's


def test_gyro_filter_from_params_runs_at_the_gyro_rate():
    flt = filters_from_params({"INS_GYRO_FILTER": 20.0, "INS_GYRO_RATE": 1}, DT)
    assert flt == (InputFilter(20.0, 2, "INS_GYRO_FILTER", rate_hz=2000.0),)
    assert flt[0].substeps(DT) == 5
    rng = np.random.default_rng(0)
    u = rng.standard_normal(300)
    b, a = signal.butter(2, 20.0, fs=2000.0)
    fast = signal.lfilter(b, a, np.repeat(u, 5), zi=signal.lfilter_zi(b, a) * u[0])[0]
    np.testing.assert_allclose(flt[0].apply(u, DT), fast[4::5], rtol=1e-12, atol=1e-15)
    assert filters_from_params({"IMU_GYRO_CUTOFF": 40.0, "IMU_GYRO_RATEMAX": 800.0}, DT)[0] \
        == InputFilter(40.0, 2, "IMU_GYRO_CUTOFF", rate_hz=800.0)
    assert filters_from_params({"INS_GYRO_FILTER": 0.0}, DT) == ()


def test_to_statespace_reproduces_simulate():
    control = pytest.importorskip("control")
    filt = InputFilter(20.0, 2, "INS_GYRO_FILTER", rate_hz=1200.0)
    seg = plant(np.array([[0.995]]), np.array([[0.77]]), np.array([0.0]), 2, 1500, 9,
                noise=1e-4, filt=filt)
    m = fit_axis([seg], "roll", bias=False, delay=2.5, n_bootstrap=0)
    sys = m.to_statespace()
    assert sys.dt == DT
    u = seg.inputs[:, 0] - seg.inputs[0, 0]
    shifted = Segment(seg.time_s, np.zeros((len(seg), 1)), u[:, None], ("p",), ("u_roll",),
                      DT, "roll", "scan")
    resp = control.forced_response(sys, U=u)
    np.testing.assert_allclose(np.ravel(resp.outputs), m.simulate(shifted)[:, 0],
                               atol=1e-9 * np.abs(resp.outputs).max())


@pytest.mark.slow
def test_coupled_pqr_model_with_all_inputs():
    a = np.array([[0.995, 0.002, 0.0], [-0.003, 0.993, 0.001], [0.0, 0.0, 0.998]])
    b = np.array([[0.75, 0.02, 0.0], [0.0, 0.70, 0.01], [0.0, 0.0, 0.04]])
    c = np.array([0.001, -0.002, 0.0005])
    segs = [plant(a, b, c, 2, 3000, s, noise=1e-5) for s in (61, 62)]
    m = fit_axis(segs, "all", filters=(), delay_step=1, lags_s=None, n_bootstrap=0)
    assert m.state_names == ("p", "q", "r") and m.input_names == INPUTS
    assert m.delay == 2
    np.testing.assert_allclose(m.A, a, atol=2e-4)
    for i, x in enumerate(("p", "q", "r")):
        for j, u in enumerate(INPUTS):
            assert m.params[f"B_d[{x},{u}]"] == pytest.approx(b[i, j], abs=2e-3)
    assert m.simulate(segs[0]).shape == (3000, 3)
    assert m.to_statespace().ninputs == 3


def test_property_noiseless_plants_are_recovered_and_one_step_equals_predict():
    hypothesis = pytest.importorskip("hypothesis")
    st = hypothesis.strategies

    @hypothesis.settings(max_examples=25, deadline=None)
    @hypothesis.given(pole=st.floats(0.5, 0.999), gain=st.floats(-2.0, 2.0).filter(
        lambda g: abs(g) > 0.01), bias=st.floats(-0.01, 0.01), delay=st.integers(0, 6),
        seed=st.integers(0, 1000))
    def check(pole, gain, bias, delay, seed):
        seg = plant(np.array([[pole]]), np.array([[gain]]), np.array([bias]), delay, 400, seed)
        st_ = Structure(("p",), ("p", "u_roll", "1"), delay=delay)
        m = LeastSquares(st_, n_bootstrap=0).fit([seg]).model_
        np.testing.assert_allclose(m.coef[:, 0], [pole, gain, bias], rtol=1e-6, atol=1e-9)
        one = m.predict(seg, 1)[1:, 0]
        x, u = seg.states[:, 0], seg.inputs[:, 0]
        held = np.r_[np.full(delay, u[0]), u][: len(u)]
        ref = m.coef[0, 0] * x[:-1] + m.coef[1, 0] * held[:-1] + m.coef[2, 0]
        np.testing.assert_allclose(one, ref, rtol=1e-9, atol=1e-12)

    check()


def test_rows_with_nan_are_left_out_with_a_warning():
    from mavsid.errors import DataQualityWarning

    seg = plant(A2, B2, C2, 3, 1500, 71, noise=1e-4)
    states = seg.states.copy()
    states[700, 0] = np.nan
    bad = Segment(seg.time_s, states, seg.inputs, seg.state_names, seg.input_names, DT, "all",
                  "scan")
    with pytest.warns(DataQualityWarning, match="2 of 1496 rows"):
        m = LeastSquares(LIN2, n_bootstrap=0).fit([bad]).model_
    np.testing.assert_allclose(m.coef, truth_coef(), atol=2e-3)


@pytest.mark.parametrize("params", [
    {"IMU_GYRO_CUTOFF": 30.0, "IMU_GYRO_RATEMAX": float("inf")},
    {"IMU_GYRO_CUTOFF": 30.0, "IMU_GYRO_RATEMAX": 1e9},
    {"INS_GYRO_FILTER": 20.0, "INS_GYRO_RATE": float("nan")},
    {"INS_GYRO_FILTER": 20.0, "INS_GYRO_RATE": 1e6},
    {"INS_GYRO_FILTER": float("inf")},
])
def test_damaged_gyro_filter_parameters_do_not_crash_or_oversample(params) -> None:  # type: ignore[no-untyped-def]
    """A non-finite or absurd gyro rate raised OverflowError (or asked for millions of
    filter sub-steps per sample); the filter now runs at its nominal rate or not at all."""
    from mavsid.estimators.regressors import filters_from_params

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (an infinite cut-off is said: see above)
        got = filters_from_params(params, dt=0.0025)
    for f in got:
        assert f.substeps(0.0025) <= 20


def test_the_gram_solve_refuses_non_finite_sums_and_matches_lstsq() -> None:
    """The Gram solve (numpy's Cholesky now, scipy's before): the least-squares solution,
    and a ValueError for a Gram holding NaN or inf (as scipy.linalg refused it: the callers
    turn that into a refusal, never a model of NaN)."""
    from mavsid.estimators.base import Gram, solve

    rng = np.random.default_rng(4)
    z = rng.standard_normal((500, 4))
    y = z @ np.array([[0.5], [-1.0], [2.0], [0.1]]) + 0.01 * rng.standard_normal((500, 1))
    want = np.linalg.lstsq(z, y, rcond=None)[0]
    np.testing.assert_allclose(solve(Gram.of(z, y)), want, rtol=1e-10)
    z[3, 1] = np.nan
    with pytest.raises(ValueError, match="infs or NaNs"):
        solve(Gram.of(z, y))
