"""The rate plant's transfer function fitted to a measured frequency response (CIFER's cost),
on plants simulated here with scipy.signal whose B, lag and delay are known."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

import mavsid
from mavsid.errors import NoExcitationError
from mavsid.frequency import frf
from mavsid.frequency_fit import cifer_cost, fit_plant

B, LAG, DELAY = 500.0, 0.013, 0.019  # rad/s² per unit, s, s (a Pixhawk 6C quad's roll)
SIM_DT, LOG_DT = 0.001, 0.01


def closed_loop_chirp(seed: int, *, gyro_noise: float = 0.02, torque_noise: float = 2.0,
                      kp: float = 0.04, seconds: float = 25.0, f_hz: tuple[float, float] = (
                          1.0, 30.0)) -> dict[str, np.ndarray]:
    """A rate loop (P on a noisy gyro) flown at 1 kHz with a chirp injected at the mixer and
    a random torque disturbance, logged at 100 Hz: the mixer input ``u``, the rate ``y``
    (noisy gyro) and the injection ``r``. The plant ``B e^{-τs} / (s (T s + 1))`` is
    discretised exactly for a held input (``scipy.signal.cont2discrete``, ZOH): the hold adds
    half a simulation step to the delay, which :data:`true_delay` counts."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, SIM_DT)
    r = 0.05 * signal.chirp(t, f_hz[0], seconds, f_hz[1], method="logarithmic")
    a = np.array([[0.0, B], [0.0, -1.0 / LAG]])
    bm = np.array([[0.0], [1.0 / LAG]])
    ad, bd, *_ = signal.cont2discrete((a, bm, np.eye(2), np.zeros((2, 1))), SIM_DT, "zoh")
    d = round(DELAY / SIM_DT)
    x = np.zeros(2)
    u = np.zeros(t.size)
    y = np.zeros(t.size)
    # the disturbance: white torque through a 2-Hz low-pass (wind, prop wash)
    dist = signal.lfilter(*signal.butter(1, 2.0, fs=1 / SIM_DT),
                          rng.standard_normal(t.size)) * torque_noise
    for k in range(t.size):
        y[k] = x[0]
        meas = x[0] + gyro_noise * rng.standard_normal()
        u[k] = r[k] - kp * meas
        x = ad @ x + bd[:, 0] * (u[k - d] if k >= d else 0.0) + np.array([dist[k] * SIM_DT, 0])
    step = round(LOG_DT / SIM_DT)
    gyro = y + gyro_noise * rng.standard_normal(t.size)
    return {"u": u[::step], "y": gyro[::step], "r": r[::step]}


#: the delay the simulated plant has: its own plus half a step of the simulation's hold
true_delay = DELAY + SIM_DT / 2


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2])
def test_closed_loop_plant_recovered_within_sigma(seed: int) -> None:
    """Against the injection the feedback does not bias the plant: B, lag and delay each
    within 3 σ of the truth, with σ small enough to mean something."""
    run = closed_loop_chirp(seed)
    measured = frf([run["u"]], [run["y"]], LOG_DT, reference=[run["r"]], f_min_hz=1.0,
                   f_max_hz=30.0)
    fit = fit_plant(measured, excited_hz=(1.0, 30.0))
    assert fit.structure == "integrator", fit.reason
    sd = fit.stderr
    assert abs(fit.gain - B) <= 3 * sd["gain"] and sd["gain"] < 0.05 * B, (fit.gain, sd)
    assert abs(fit.lag_s - LAG) <= 3 * sd["lag_s"] and sd["lag_s"] < 0.003, (fit.lag_s, sd)
    assert abs(fit.delay_s - true_delay) <= 3 * sd["delay_s"] and sd["delay_s"] < 0.003, (
        fit.delay_s, sd)
    assert fit.cost < 100 and fit.band_hz[0] <= 1.5 and fit.band_hz[1] >= 10


def test_the_composites_bias_is_in_the_sigma() -> None:
    """A noise-free chirp: what stays between the fit and the truth is the composite's own
    bias (leakage where the sweep is fast), which the residuals hide where the parameters
    absorb it. The random σ alone left the delay 3.4 σ and the lag 2.6 σ from the truth;
    with the bias (:data:`~mavsid.frequency.FRF_STRUCTURE_FLOOR`, correlated over an
    octave) each is within 1.1 σ, and σ still means something."""
    run = closed_loop_chirp(1, kp=0.0, torque_noise=0.0, gyro_noise=0.0)
    measured = frf([run["u"]], [run["y"]], LOG_DT, reference=[run["r"]], f_min_hz=1.0,
                   f_max_hz=30.0)
    fit = fit_plant(measured, excited_hz=(1.0, 30.0))
    sd = fit.stderr
    assert abs(fit.delay_s - true_delay) > 3 * sd["delay_s_random"]
    for name, value, truth in (("gain", fit.gain, B), ("lag_s", fit.lag_s, LAG),
                               ("delay_s", fit.delay_s, true_delay)):
        assert abs(value - truth) <= 2.5 * sd[name], (name, value, truth, sd)
        assert sd[name] >= sd[f"{name}_random"]
    assert sd["gain"] < 0.03 * B and sd["lag_s"] < 0.002 and sd["delay_s"] < 0.002, sd


def test_cost_is_ciFERs_definition_against_a_plain_computation() -> None:
    """J = 20/n Σ W_γ [ΔdB² + 0.01745 Δdeg²], W_γ = [1.58 (1 − e^{−γ²})]², written out."""
    rng = np.random.default_rng(3)
    f = np.geomspace(1, 15, 30)
    model = 1 / (2j * np.pi * f)
    meas = model * 10 ** (rng.normal(0, 1, 30) / 20) * np.exp(1j * np.radians(rng.normal(0, 5, 30)))
    coh = rng.uniform(0.6, 1.0, 30)
    ddb = 20 * np.log10(np.abs(meas)) - 20 * np.log10(np.abs(model))
    ddeg = np.degrees(np.angle(meas)) - np.degrees(np.angle(model))
    ddeg = (ddeg + 180) % 360 - 180
    plain = 20 / 30 * np.sum((1.58 * (1 - np.exp(-coh))) ** 2 * (ddb**2 + 0.01745 * ddeg**2))
    assert cifer_cost(meas, model, coh) == pytest.approx(plain, rel=1e-12)


def aliased_gyro(seed: int, vibration: float) -> dict[str, np.ndarray]:
    """The open-loop plant driven by a chirp, its rate read by a gyro that carries motor
    vibration aliased by the 100-Hz logging (an alternating component: lag-1
    autocorrelation below zero, as SIDD.Gx often is)."""
    run = closed_loop_chirp(seed, kp=0.0, torque_noise=0.0, gyro_noise=0.0, seconds=20.0)
    rng = np.random.default_rng(seed + 100)
    n = run["y"].size
    k = np.arange(n)
    vib = vibration * ((-1.0) ** k * (1 + 0.3 * rng.standard_normal(n))
                       + 0.5 * np.sin(2 * np.pi * 0.43 * k + rng.uniform(0, 6)))
    y = run["y"] + vib
    return {"u": run["u"], "y": y}


def lag1(x: np.ndarray) -> float:
    x = np.diff(x)  # (the rate itself is dominated by the slow sweep)
    x = x - x.mean()
    return float(np.dot(x[1:], x[:-1]) / np.dot(x, x))


def test_aliased_gyro_fits_where_coherence_holds() -> None:
    """A gyro full of aliased vibration: the frequency-domain fit keeps to the coherent band
    and recovers the plant, never a negative effectiveness."""
    run = aliased_gyro(4, vibration=3.0)
    assert lag1(run["y"]) < 0
    fit = mavsid.identify_frequency(run["u"], run["y"], LOG_DT, excited_hz=(1.0, 30.0))
    assert fit.gain > 0
    assert abs(fit.gain / B - 1) < 0.1, fit
    assert abs(fit.delay_s - true_delay) < 0.003 and abs(fit.lag_s - LAG) < 0.004, fit
    assert fit.band_hz[1] < 30.0  # (the vibration's alias took the top of the sweep)


def test_aliased_gyro_refused_with_the_reason_when_nothing_is_coherent() -> None:
    run = aliased_gyro(5, vibration=300.0)
    with pytest.raises(NoExcitationError, match="coheren"):
        mavsid.identify_frequency(run["u"], run["y"], LOG_DT, excited_hz=(1.0, 30.0))


FIXTURES = __import__("pathlib").Path(__file__).resolve().parents[1] / "fixtures"


@pytest.mark.slow
def test_validate_on_another_flight_in_the_frequency_domain(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A model fitted on one simulated chirp, validated on another flight's chirp (another
    seed, noisier): the model's response against the one measured there against its
    injection, and the simulator's truth (roll damping 4 1/s, effectiveness 180)."""
    from mavsid import pipeline

    cfg = pipeline.PipelineConfig(axes=("roll",))
    fitted = pipeline.fit([FIXTURES / "sysid_roll.bin"], cfg)
    models = {"roll": fitted.axes["roll"].model}
    other = pipeline.validate_logs(models, [FIXTURES / "noisy_sysid.bin"], cfg)
    fr = other.axes["roll"].to_dict()["frequency_response"]
    check = fr["model_check"]
    assert check["rms_db"] < 1.5 and check["rms_deg"] < 10, check
    # the other flight's own transfer function: its truth within 3 % (the composite's bias)
    assert fr["structure"] == "first_order" and abs(fr["B"] / 180 - 1) < 0.03, fr["B"]
    assert other.verdicts["roll"].numbers["frequency_rms_db"] == pytest.approx(check["rms_db"])
