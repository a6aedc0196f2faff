"""The array API refuses what the data cannot support (an aliased gyro, an effectiveness of
the wrong sign) and still identifies an ordinary noisy rate: plants simulated here with
scipy.signal, vibration at the motors' frequency aliased by the logging."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy import signal

import mavsid
from mavsid.errors import ImplausibleModelError, MavsidError
from mavsid.estimators.plausibility import lag1_autocorrelation

# b e^{-τs} / ((s + a)(T s + 1)): a rate plant with drag, motor lag and delay
B, A, LAG, DELAY = 500.0, 2.0, 0.013, 0.019
SIM_FS, STEP = 1000.0, 10  # simulated at 1 kHz, logged at 100 Hz (every 10th sample)
LOG_DT = STEP / SIM_FS


def logged_chirp(seed: int, vibration: float, noise: float) -> tuple[np.ndarray, np.ndarray]:
    """The plant's input and its gyro logged at 100 Hz: the rate, motor vibration at 162 and
    171 Hz that the logging folds to 38 and 29 Hz (no anti-alias filter before it), and
    white measurement noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 20.0, 1 / SIM_FS)
    u = 0.05 * signal.chirp(t, 1.0, t[-1], 30.0, method="logarithmic")
    d = round(DELAY * SIM_FS)
    late = np.concatenate([np.zeros(d), u[:-d]])
    _, rate, _ = signal.lsim(([B], np.polymul([1.0, A], [LAG, 1.0])), late, t)
    vib = vibration * (np.sin(2 * np.pi * 162 * t + rng.uniform(0, 6))
                       + 0.7 * np.sin(2 * np.pi * 171 * t + rng.uniform(0, 6)))
    gyro = (rate + vib)[::STEP] + noise * rng.standard_normal(t.size // STEP)
    return u[::STEP], gyro


def test_aliased_gyro_is_refused_with_the_reason() -> None:
    u, gyro = logged_chirp(0, vibration=2.0, noise=0.3)
    assert lag1_autocorrelation([gyro]) < 0
    # what the regression returns on it unchecked: a negative effectiveness
    unchecked = mavsid.identify(gyro, u, dt=LOG_DT, n_bootstrap=0, expect_positive=False)
    assert unchecked.params["B_d[x,u]"] < 0
    with pytest.raises(ImplausibleModelError, match=r"lag-1 autocorrelation -0\.\d+ < 0.*alias"):
        mavsid.identify(gyro, u, dt=LOG_DT, n_bootstrap=0)
    with pytest.raises(ImplausibleModelError):  # also with the delay and lag searched
        mavsid.identify(gyro, u, dt=LOG_DT, n_bootstrap=0, delay="search",
                        lags_s=[0.0, 0.01, 0.02])


def test_a_negative_effectiveness_is_refused_even_when_the_output_is_smooth_enough() -> None:
    """Less vibration: the gyro's lag-1 autocorrelation stays above 0, the fit still comes
    out reversed, and says so."""
    u, gyro = logged_chirp(1, vibration=1.0, noise=0.0)
    assert lag1_autocorrelation([gyro]) > 0
    with pytest.raises(ImplausibleModelError, match=r"B_d\[x,u\] = -[\d.]+ is not positive"):
        mavsid.identify(gyro, u, dt=LOG_DT, n_bootstrap=0)


def test_the_frequency_domain_sibling_fits_where_the_aliased_gyro_is_coherent() -> None:
    u, gyro = logged_chirp(0, vibration=2.0, noise=0.3)
    fit = mavsid.identify_frequency(u, gyro, LOG_DT, excited_hz=(1.0, 30.0))
    assert fit.gain > 0


def test_ordinary_measurement_noise_still_identifies() -> None:
    """White gyro noise of 0.1 rad/s, no vibration: not refused, and the continuous-time
    effectiveness and drag pole come out near the simulated plant's."""
    u, gyro = logged_chirp(2, vibration=0.0, noise=0.1)
    assert lag1_autocorrelation([gyro]) > 0.9
    m = mavsid.identify(gyro, u, dt=LOG_DT, n_bootstrap=0, delay="search",
                        lags_s=[0.0, 0.005, 0.01, 0.013, 0.015, 0.02], refine="oe")
    assert abs(m.params["B[x,u]"] / B - 1) < 0.1, m.params
    assert abs(m.delay_s - DELAY) < 0.006, m.delay_s


def test_a_discrete_process_that_alternates_is_fitted_when_declared() -> None:
    rng = np.random.default_rng(3)
    u = rng.standard_normal(400)
    x = signal.lfilter([0.0, 0.5], [1.0, 0.6], u)  # x⁺ = −0.6 x + 0.5 u
    with pytest.raises(ImplausibleModelError):
        mavsid.identify(x, u, dt=1.0, n_bootstrap=0)
    m = mavsid.identify(x, u, dt=1.0, n_bootstrap=0, expect_positive=False)
    assert m.params["A_d[x,x]"] == pytest.approx(-0.6, abs=1e-9)


def sidd_gyro_and_mixer(name: str) -> tuple[np.ndarray, np.ndarray, float]:
    """A real SYSTEMID run's SIDD.Gx (rad/s) and RATE.ROut on the SIDD samples."""
    from test_frequency_real import real_log

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        raw = mavsid.read_log(real_log(name), messages=["SIDD", "RATE"])
    sidd, rate = raw.messages["SIDD"], raw.messages["RATE"]
    t = sidd.time_s
    u = np.interp(t, rate.time_s, np.asarray(rate.columns["ROut"], float))
    return np.radians(np.asarray(sidd.columns["Gx"], float)), u, float(np.median(np.diff(t)))


@pytest.mark.slow
def test_real_runs_aliased_gyro_refused_and_the_chirp_kept() -> None:
    """00000062 (a run that injected nothing): SIDD.Gx is vibration, lag-1 autocorrelation
    below 0 — refused; 00000071 (the 20° roll chirp): SIDD.Gx is the rate — identified with a
    positive effectiveness."""
    g, u, dt = sidd_gyro_and_mixer("00000062.BIN")
    assert lag1_autocorrelation([g]) < 0
    with pytest.raises(ImplausibleModelError, match="lag-1 autocorrelation"):
        mavsid.identify(g, u, dt=dt, n_bootstrap=0)
    g, u, dt = sidd_gyro_and_mixer("00000071.BIN")
    try:
        m = mavsid.identify(g, u, dt=dt, n_bootstrap=0)
    except MavsidError as exc:  # pragma: no cover - the failure's text is the message
        pytest.fail(f"the real chirp was refused: {exc}")
    assert m.params["B_d[x,u]"] > 0
