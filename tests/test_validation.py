"""Validation by rollout, against a known first-order plant and hand-computed measures."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from toy_plants import DiagonalPlant, chirp, run_plant

from mavsid.data import SysidRun
from mavsid.errors import ConfigError, NoExcitationError
from mavsid.validation import fit_percent, residual_test, rmse, validate

DT = 0.0025
PLANT = DiagonalPlant(a=(0.98,), b=(0.6,), c=(0.001,), dt=DT, delay=2)


def _noise_input(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    # piecewise-constant random steps: broadband but not white
    return np.repeat(rng.uniform(-0.1, 0.1, n // 20 + 1), 20)[:n]


def test_fit_percent_by_hand() -> None:
    y = np.array([1.0, 3.0, 2.0, 6.0])  # mean 3, deviations -2 0 -1 3 -> 14
    yhat = np.array([1.0, 2.0, 2.0, 5.0])  # errors 0 1 0 1 -> 2
    assert float(fit_percent(y, yhat)) == pytest.approx(100 * (1 - np.sqrt(2 / 14)))
    two = fit_percent(np.c_[y, y], np.c_[yhat, y])
    assert two.shape == (2,) and two[1] == 100.0
    # NaN predictions are left out, and the mean is of the rows kept
    assert float(fit_percent(np.r_[y, 50.0], np.r_[yhat, np.nan])) == pytest.approx(
        100 * (1 - np.sqrt(2 / 14))
    )
    assert np.isnan(fit_percent(np.ones(4), np.zeros(4)))
    assert float(rmse(y, yhat)) == pytest.approx(np.sqrt(0.5))


def test_true_model_on_noiseless_data_is_perfect() -> None:
    segs = [run_plant(PLANT, _noise_input(4000, s), seed=s, t0=10.0 * s) for s in range(2)]
    v = validate(PLANT, segs, horizons_s=(0.01, 0.5, 2.0))
    assert v.horizons.tolist() == [1, 4, 200, 800]
    assert np.allclose(v.fit_vs_horizon, 100.0, atol=1e-6)
    assert np.allclose(v.fit_free_run, 100.0, atol=1e-6)
    assert v.rmse_free_run[0] < 1e-9
    assert v.fit_summary("p") == pytest.approx(
        {"one_step": 100.0, "0.5s": 100.0, "free_run": 100.0}, abs=1e-6
    )
    assert [s.start_s for s in v.segments] == [0.0, 10.0]


def test_pooled_fit_matches_hand_formula() -> None:
    wrong = dataclasses.replace(PLANT, a=(0.97,))
    segs = [run_plant(PLANT, _noise_input(3000, s), seed=s, noise=1e-3) for s in (3, 4)]
    v = validate(wrong, segs, horizons_s=())
    err = norm = 0.0
    for seg in segs:
        y = seg.states[:, 0]
        # the wrong model's free run, written out independently of the plant class
        yh = np.empty_like(y)
        yh[0] = y[0]
        u = seg.inputs[:, 0]
        for k in range(len(y) - 1):
            yh[k + 1] = 0.97 * yh[k] + (0.6 * u[k - 2] if k >= 2 else 0.0) + 0.001
        err += np.sum((y - yh) ** 2)
        norm += np.sum((y - y.mean()) ** 2)
    assert v.fit_free_run[0] == pytest.approx(100 * (1 - np.sqrt(err / norm)), rel=1e-9)
    # errors compound: the wrong model's free run is worse than its one-step prediction
    assert v.fit_free_run[0] < v.fit_one_step[0] - 10


def test_fit_falls_with_horizon_for_a_wrong_model() -> None:
    wrong = dataclasses.replace(PLANT, b=(0.5,))
    seg = run_plant(PLANT, _noise_input(8000, 1), noise=2e-3)
    v = validate(wrong, [seg])
    fits = v.fit_vs_horizon[:, 0]
    assert v.horizons.tolist() == [1, 4, 8, 20, 40, 80, 200, 400, 800]
    # the plant forgets its past in ~50 samples: fit falls until then, then levels off
    assert np.all(np.diff(fits[:6]) < 0)
    assert np.allclose(fits[6:], v.fit_free_run[0], atol=0.5)
    assert v.fit_free_run[0] < fits[0] - 10


def test_residuals_white_for_true_model_not_for_wrong() -> None:
    segs = [run_plant(PLANT, _noise_input(6000, s), noise=2e-3, seed=s) for s in (5, 6)]
    good = validate(PLANT, segs, max_lag=30).residuals
    assert good.n == 12000 - 2 * 3  # the delay and one step of history are unpredictable
    assert good.autocorr[0, 0] == pytest.approx(1.0)
    assert good.band == pytest.approx(2.5758 / np.sqrt(good.n), rel=1e-3)
    assert good.autocorr_outside[0] <= 0.1
    assert good.crosscorr_outside[0, 0] <= 0.1
    bad = validate(dataclasses.replace(PLANT, a=(0.95,), b=(0.3,)), segs, max_lag=30).residuals
    assert bad.autocorr_outside[0] > 0.5
    assert bad.crosscorr_outside[0, 0] > 0.5


def test_residual_correlation_never_pairs_segments() -> None:
    # two segments of constant, opposite residuals: pooled lag-1 autocorrelation is 1
    # within each; pairing across the boundary would lower it
    e = [np.r_[np.ones(50), -np.ones(50)][:, None], np.r_[-np.ones(50), np.ones(50)][:, None]]
    u = [np.arange(100.0)[:, None]] * 2
    t = residual_test(e, u, max_lag=1)
    assert t.autocorr[1, 0] == pytest.approx((98 - 2) / 100 * 1.0 - 0.0, abs=0.02)


def test_eigenvalues_and_stability() -> None:
    seg = run_plant(PLANT, _noise_input(1000, 0))
    v = validate(PLANT, [seg], horizons_s=())
    assert v.eigenvalues is not None and np.allclose(v.eigenvalues, [0.98])
    assert v.stable is True
    unstable = dataclasses.replace(PLANT, a=(1.01,))
    assert validate(unstable, [seg], horizons_s=()).stable is False
    hidden = dataclasses.replace(PLANT, expose_a=False)
    v2 = validate(hidden, [seg], horizons_s=())
    assert v2.eigenvalues is None and v2.stable is None


def test_chirp_frequency_response_matches_true_plant() -> None:
    n = round(60 / DT)
    run = SysidRun(0.0, (n - 1) * DT, "SIDS", f_start_hz=0.5, f_stop_hz=20.0)
    seg = run_plant(PLANT, chirp(n, DT), source="sysid", sysid=run)
    v = validate(PLANT, [seg], horizons_s=())
    (fr,) = v.frequency
    assert (fr.input_name, fr.output_name, fr.band_hz) == ("u_roll", "p", (0.5, 20.0))
    band = (fr.freq_hz >= 1.0) & (fr.freq_hz <= 15.0)
    truth = PLANT.response(fr.freq_hz[band])
    assert np.all(fr.coherence[band] > 0.95)
    assert np.allclose(fr.measured[band], truth, rtol=0.03)
    assert np.allclose(fr.model[band], truth, rtol=0.03)
    # a model with 20 % more gain shows it in its response, measured stays the truth
    fr_big = validate(dataclasses.replace(PLANT, b=(0.72,)), [seg], horizons_s=()).frequency[0]
    ratio = np.abs(fr_big.model[band]) / np.abs(truth)
    assert np.allclose(ratio, 1.2, rtol=0.03)
    assert np.allclose(fr_big.measured[band], truth, rtol=0.03)


def test_no_frequency_response_without_chirp() -> None:
    seg = run_plant(PLANT, _noise_input(2000, 0))
    assert validate(PLANT, [seg], horizons_s=()).frequency == ()


def test_bad_input_raises_typed_errors() -> None:
    seg = run_plant(PLANT, _noise_input(500, 0))
    with pytest.raises(NoExcitationError):
        validate(PLANT, [])
    other = dataclasses.replace(PLANT, state_names=("q",))
    with pytest.raises(ConfigError, match="no state q"):
        validate(other, [seg])
    with pytest.raises(ConfigError, match="dt"):
        validate(dataclasses.replace(PLANT, dt=0.01), [seg])


@settings(max_examples=80, deadline=None)
@given(
    y=arrays(np.float64, st.integers(3, 60), elements=st.floats(-1e3, 1e3)),
    noise=st.floats(0.0, 10.0),
    scale=st.floats(0.01, 100.0) | st.floats(-100.0, -0.01),
    shift=st.floats(-1e3, 1e3),
)
def test_fit_percent_invariants(y: np.ndarray, noise: float, scale: float, shift: float) -> None:
    yhat = y + noise * np.cos(np.arange(len(y)))
    f = float(fit_percent(y, yhat))
    if np.ptp(y) < 1e-6:
        return
    assert f <= 100.0 + 1e-9
    # units do not matter: the same affine change of y and yhat leaves fit % unchanged
    assert float(fit_percent(scale * y + shift, scale * yhat + shift)) == pytest.approx(
        f, abs=1e-6 * max(1.0, abs(f))
    )


def test_ljung_box_matches_statsmodels() -> None:
    sm = pytest.importorskip("statsmodels.stats.diagnostic")
    rng = np.random.default_rng(4)
    e = rng.standard_normal(3000)
    coloured = np.convolve(e, [1.0, 0.6, 0.3], mode="same")
    for x in (e, coloured):
        t = residual_test([x[:, None]], [rng.standard_normal((x.size, 1))], max_lag=30)
        q, p = t.ljung_box(20)
        ref = sm.acorr_ljungbox(x, lags=[20])
        assert q[0] == pytest.approx(float(ref["lb_stat"].iloc[0]), rel=1e-9)
        assert p[0] == pytest.approx(float(ref["lb_pvalue"].iloc[0]), rel=1e-6, abs=1e-300)
    white = residual_test([e[:, None]], [e[:, None]]).ljung_box(20)[1][0]
    assert white > 0.01
    assert residual_test([coloured[:, None]], [e[:, None]]).ljung_box(20)[1][0] < 1e-10


def test_each_held_out_window_runs_with_its_own_trim() -> None:
    """A rate plant near an integrator, whose trim (the constant term) moved between the
    training and the held-out window: with the training trim its free run drifts away; each
    window's own trim (one number, estimated like its initial state) recovers the true
    dynamics' fit, and the shift found is the trim's true change."""
    from mavsid.data import Segment
    from mavsid.estimators.model import Model
    from mavsid.validation import segment_trim

    dt = 0.01
    feats = ("r", "u_yaw", "1")
    trained = Model(("r",), ("u_yaw",), feats, np.array([[0.992], [0.09], [-1e-4]]), dt=dt)
    held = dataclasses.replace(trained, coef=np.array([[0.992], [0.09], [2.5e-4]]))
    u = chirp(3000, dt, 0.5, 15.0)[:, None]
    y = held.simulate_inputs(u, x0=np.array([0.01]))
    seg = Segment(np.arange(3000) * dt, y, u, ("r",), ("u_yaw",), dt, "yaw", "sysid")
    v = validate(trained, [seg], horizons_s=(0.5,))
    assert v.fit_free_run_own_trim is not None and v.fit_free_run_own_trim[0] < 0
    assert v.fit_free_run[0] == pytest.approx(100.0, abs=1e-6)
    assert np.allclose(v.fit_vs_horizon, 100.0, atol=1e-6)  # every horizon with the trim
    assert v.segments[0].trim_shift == pytest.approx([3.5e-4], rel=1e-9)
    assert v.segments[0].fit_free_run_own_trim[0] == pytest.approx(v.fit_free_run_own_trim[0])
    # the trim cannot make wrong dynamics (damping 2 1/s for 0.8; effectiveness 22 % low)
    # good, whatever the trim they start from
    from mavsid.verdict import GOOD_FREE_RUN_PCT

    for a, b in ((0.98, 0.09), (0.992, 0.07)):
        for c in (-1e-4, 2.5e-4):
            wrong = dataclasses.replace(trained, coef=np.array([[a], [b], [c]]))
            assert validate(wrong, [seg], horizons_s=()).fit_free_run[0] < GOOD_FREE_RUN_PCT
    # a model without a constant term is run as it is
    plain = Model(("r",), ("u_yaw",), feats[:2], np.array([[0.992], [0.09]]), dt=dt)
    same, shift = segment_trim(plain, seg)
    assert same is plain and shift.tolist() == [0.0]
    vp = validate(plain, [seg], horizons_s=())
    assert vp.fit_free_run_own_trim is not None
    assert vp.fit_free_run[0] == vp.fit_free_run_own_trim[0]


def test_the_residual_band_is_the_normal_quantile() -> None:
    from scipy import stats

    e = np.random.default_rng(2).standard_normal((400, 1))
    for confidence in (0.9, 0.95, 0.99):
        got = residual_test([e], [e], confidence=confidence).band
        assert got == pytest.approx(stats.norm.ppf(0.5 + confidence / 2) / np.sqrt(400),
                                    rel=1e-14)
