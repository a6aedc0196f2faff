"""The loop analysis (margins, bandwidths, step figures, margins of measured responses)
against python-control and scipy."""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest
from loop_plants import AXES_INDEX, true_plant
from loop_reference import analyse_loop, controller_tf

from mavsid.loop.analysis import (
    analyse_plant,
    closed_figures,
    controller_polys,
    frd_margins_at,
    grid_margins,
    loop_figures,
    margin_db,
    margin_grid,
    margins_of,
)
from mavsid.loop.controllers import controller_from_params, scaled
from mavsid.loop.plant import ss2tf
from mavsid.synthetic.plant import PlantParams


@pytest.mark.parametrize(("params", "lag", "tau"), [
    ({}, 0, 0.0), ({}, 2, 0.3),
    ({"MC_ROLLRATE_P": 0.15, "MC_ROLLRATE_D": 0.003, "IMU_GYRO_RATEMAX": 400.0}, 1, 0.5)])
def test_loop_figures_are_analyse_loops(params: dict[str, float], lag: int, tau: float
                                        ) -> None:
    """The σ draws' numpy figures equal python-control's to rounding: margins, crossover,
    disturbance bandwidth and phase delay to 1e-7, the step's rise and overshoot to 1e-6.
    Bandwidth and peak equal python-control's point-by-point evaluation of the closed loop
    to 1e-8, :func:`analyse_loop`'s to 1e-3 only: that evaluates the 11th-order closed
    loop through one polynomial ratio (:func:`frequency_response`), off by 1e-4 here and
    0.5 % on the SITL flight's yaw (the numpy figures multiply the parts' responses)."""
    import control

    ctrl = controller_from_params(params, "roll")
    tp = true_plant(PlantParams(), 0, 1.0 / ctrl.loop_hz)
    ss = control.ss(tp.a, tp.b.reshape(-1, 1), tp.c.reshape(1, -1), 0.0, tp.dt)
    want = analyse_loop(ss, ctrl, lag, meas_delay=tau).figures()
    got = loop_figures(tp, ctrl, lag, meas_delay=tau)
    assert set(got) == set(want)
    for k in ("gain_margin_db", "phase_margin_deg", "crossover_hz",
              "disturbance_bandwidth_hz", "phase_delay_s"):
        assert got[k] == pytest.approx(want[k], rel=1e-7), k
    # the closed loop evaluated point by point by python-control (a solve per frequency)
    dt = tp.dt
    cfb, ct = controller_tf(ctrl, dt)
    ct = ct * control.tf([1.0], [1.0] + [0.0] * lag, dt)
    cfb = cfb * control.tf([1.0 - tau, tau], [1.0, 0.0], dt)
    closed = control.feedback(ss, control.ss(cfb)) * control.ss(ct)
    f = np.geomspace(0.1, 0.45 / dt, 400)
    t_resp = np.ravel(closed(np.exp(2j * np.pi * f * dt)))
    mag, _, bw, _, _ = closed_figures(f, t_resp, np.ones(f.size))
    assert got["bandwidth_hz"] == pytest.approx(bw, rel=1e-8)
    assert got["peak_db"] == pytest.approx(float(np.max(mag)), rel=1e-8, abs=1e-9)
    for k in ("bandwidth_hz", "peak_db"):
        assert got[k] == pytest.approx(want[k], rel=1e-3, abs=1e-4), k
    assert got["rise_time_s"] == pytest.approx(want["rise_time_s"], abs=1e-9)
    assert got["overshoot_percent"] == pytest.approx(want["overshoot_percent"], abs=1e-6)


_CONTROLLERS = [
    ({}, "roll"), ({}, "yaw"),
    ({"ATC_RAT_RLL_FF": 0.1, "ATC_RAT_RLL_FLTE": 10.0, "ATC_RAT_RLL_FLTD": 0.0}, "roll"),
    ({"MC_ROLLRATE_P": 0.15, "MC_ROLLRATE_D": 0.003, "MC_ROLLRATE_FF": 0.05,
      "IMU_GYRO_RATEMAX": 400.0, "IMU_DGYRO_CUTOFF": 30.0}, "roll"),
    ({"MC_ROLLRATE_P": 0.15, "IMU_DGYRO_CUTOFF": 0.0}, "roll")]


@pytest.mark.parametrize(("params", "axis"), _CONTROLLERS)
def test_controller_polys_are_python_controls(params: dict[str, float], axis: str) -> None:
    # the controller over one denominator is python-control's sums and products of its
    # parts: the same responses over the band the analysis reads (from 0.001 of the loop
    # rate, where the margins' grid starts, to Nyquist; nearer z = 1 the integrator's pole
    # costs both evaluations digits)
    ctrl = controller_from_params(params, axis)
    for dt in (1.0 / ctrl.loop_hz, 0.001):
        z = np.exp(2j * np.pi * np.geomspace(1e-3 / dt, 0.5 / dt, 300) * dt)
        for tf, (num, den) in zip(controller_tf(ctrl, dt), controller_polys(ctrl, dt),
                                  strict=True):
            np.testing.assert_allclose(np.polyval(num, z) / np.polyval(den, z), np.ravel(tf(z)),
                                       rtol=1e-9)


@pytest.mark.parametrize(("params", "axis"), _CONTROLLERS)
def test_controller_polys_are_the_stepped_controllers(params: dict[str, float], axis: str
                                                      ) -> None:
    """The transfer functions are the controllers stepped (:class:`RatePID`,
    :class:`PX4RatePID` from rest, inputs small enough for no limit to act): a random
    target and measured rate through ``scipy.signal.lfilter`` of ``C_t`` and ``C_fb``. PX4's
    integrator adds ``K·I·err·dt`` after the output it is part of (one step later than
    ``I·dt/(1 − z⁻¹)``), so its integrator is left out of this comparison."""
    from scipy.signal import lfilter

    ctrl = controller_from_params(params, axis)
    if ctrl.autopilot == "px4":
        ctrl = replace(ctrl, gains=replace(ctrl.gains, i=0.0))
    dt = 1.0 / ctrl.loop_hz
    rng = np.random.default_rng(8)
    n = 400
    target, rate = (np.r_[0.0, 1e-3 * rng.standard_normal(n - 1)] for _ in range(2))
    pid = ctrl.new_pid(dt)
    stepped = np.array([pid.update(a, b) for a, b in zip(target, rate, strict=True)])
    (bf, af), (bt, at) = controller_polys(ctrl, dt)

    def through(num: np.ndarray, den: np.ndarray, x: np.ndarray) -> np.ndarray:
        m = max(num.size, den.size)  # (descending powers of z, aligned at the highest)
        return lfilter(np.pad(num, (m - num.size, 0)), np.pad(den, (m - den.size, 0)), x)

    want = through(bt, at, target) - through(bf, af, rate)
    np.testing.assert_allclose(stepped, want, rtol=0, atol=1e-12 * np.max(np.abs(want)))


def test_numpy_ss2tf_is_scipys() -> None:
    from scipy import signal

    rng = np.random.default_rng(3)
    for n in (1, 3, 8):
        a, b, c = rng.normal(size=(n, n)) * 0.3, rng.normal(size=n), rng.normal(size=n)
        num, den = signal.ss2tf(a, b.reshape(-1, 1), c.reshape(1, -1), np.zeros((1, 1)))
        got = ss2tf(a, b, c)
        np.testing.assert_allclose(got[0], np.atleast_2d(num)[0], rtol=1e-13, atol=1e-15)
        np.testing.assert_allclose(got[1], den, rtol=1e-13, atol=1e-15)


@pytest.mark.slow
@pytest.mark.parametrize(("params", "axis", "plant", "lag", "tau"), [
    ({}, "roll", PlantParams(), 0, 0.0),
    ({}, "roll", PlantParams(), 1, 0.2),
    ({}, "yaw", PlantParams(), 2, 0.5),
    ({"ATC_RAT_RLL_FF": 0.1, "ATC_RAT_RLL_FLTE": 10.0}, "roll",
     PlantParams(), 1, 0.0),
    ({"MC_ROLLRATE_P": 0.15, "MC_ROLLRATE_D": 0.003, "IMU_GYRO_RATEMAX": 400.0}, "roll",
     PlantParams(), 1, 0.5)])
def test_analyse_plant_is_python_controls(params: dict[str, float], axis: str,
                                          plant: PlantParams, lag: int, tau: float) -> None:
    """The numpy loop analysis the report uses against python-control: margins, crossover,
    step figures against :func:`analyse_loop`; the closed loop's figures, the responses
    (closed loop, loop, mixer loop) and the mixer margins against python-control evaluating
    each part point by point (one solve per frequency): ``analyse_loop`` evaluates the closed
    and the mixer loop through one polynomial ratio each, off by 13 % in bandwidth on the yaw
    case here and by up to 99 % in the mixer loop's response on the SITL flight."""
    import control

    ctrl = controller_from_params(params, axis)
    dt = 1.0 / ctrl.loop_hz
    tp = true_plant(plant, AXES_INDEX[axis], dt)
    ss = control.ss(tp.a, tp.b.reshape(-1, 1), tp.c.reshape(1, -1), 0.0, dt)
    want = analyse_loop(ss, ctrl, lag, meas_delay=tau)
    got = analyse_plant(tp, ctrl, lag, meas_delay=tau)
    for k in ("gain_margin_db", "phase_margin_deg", "crossover_hz"):
        assert getattr(got, k) == pytest.approx(getattr(want, k), rel=1e-7), k
    assert got.rise_time_s == pytest.approx(want.rise_time_s, abs=1e-9)
    # (the numpy step runs in blocks through A³² of companion-form filters: its last digits
    # follow the BLAS kernel, 4e-7 of the figure between OpenBLAS's SSE and AVX2 ones)
    assert got.overshoot_percent == pytest.approx(want.overshoot_percent, rel=1e-5, abs=1e-6)
    assert got.figures() == loop_figures(tp, ctrl, lag, meas_delay=tau)
    cfb, ct = controller_tf(ctrl, dt)
    if lag:
        ct = ct * control.tf([1.0], [1.0] + [0.0] * lag, dt)
    if tau:
        cfb = cfb * control.tf([1.0 - tau, tau], [1.0, 0.0], dt)

    def parts(f: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        z = np.exp(2j * np.pi * f * dt)
        pz, cz, tz = (np.ravel(s(z)) for s in (ss, control.ss(cfb), control.ss(ct)))
        mixer = (cz + tz * ctrl.angle_p * dt * z / (z - 1.0)) * pz
        return pz * cz, pz * tz / (1.0 + pz * cz), mixer, z

    lz, tz, mz, _ = parts(got.freq_hz)
    _mag, _ph, bw, dbw, delay = closed_figures(got.freq_hz, tz, 1.0 / (1.0 + lz))
    assert got.bandwidth_hz == pytest.approx(bw, rel=1e-8)
    assert got.disturbance_bandwidth_hz == pytest.approx(dbw, rel=1e-8)
    assert got.phase_delay_s == pytest.approx(delay, rel=1e-8)
    assert got.peak_db == pytest.approx(float(np.max(_mag)), rel=1e-8, abs=1e-9)
    np.testing.assert_allclose(got.loop_response, lz, rtol=1e-8)
    np.testing.assert_allclose(got.closed_response, tz, rtol=1e-8)
    np.testing.assert_allclose(got.mixer_loop_response, mz, rtol=1e-8)
    fm = margin_grid(dt)
    gm, pm, wc = margins_of(fm, parts(fm)[2])
    assert got.mixer_margins["gain_db"] == pytest.approx(margin_db(gm), rel=1e-7)
    assert got.mixer_margins["phase_deg"] == pytest.approx(pm, rel=1e-7)
    assert got.mixer_margins["crossover_hz"] == pytest.approx(wc / (2 * np.pi), rel=1e-7)
    # and python-control's own margins of the (point-by-point) loop, to its interpolation
    ref = control.stability_margins(control.frd(parts(fm)[0], 2 * np.pi * fm))
    assert got.phase_margin_deg == pytest.approx(ref[1], abs=0.05)
    assert got.crossover_hz == pytest.approx(ref[4] / (2 * np.pi), rel=1e-3)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_frd_margins_are_python_controls(seed: int) -> None:
    """The FRD margins without python-control are ``control.stability_margins`` of
    ``control.frd`` (the same spline through the points, the same root finding): a loop
    measured with noise on an uneven grid, several crossings."""
    import control

    rng = np.random.default_rng(seed)
    ctrl = controller_from_params({}, "roll")
    dt = 1.0 / ctrl.loop_hz
    tp = true_plant(PlantParams(), 0, dt)
    f = np.sort(rng.uniform(0.5, 60.0, 150))
    z = np.exp(2j * np.pi * f * dt)
    (bf, af), _ = controller_polys(ctrl, dt)
    bp, ap = ss2tf(tp.a, tp.b, tp.c)
    h = np.polyval(bp, z) / np.polyval(ap, z) * np.polyval(bf, z) / np.polyval(af, z)
    h = h * (1.0 + 0.05 * rng.normal(size=f.size)) * (1.5 + seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        gm, pm, _sm, _wg, wc, _ws = control.stability_margins(control.frd(h, 2 * np.pi * f))
    got = frd_margins_at(h, 2 * np.pi * f)
    assert got[0] == pytest.approx(gm, rel=1e-12)
    assert got[1] == pytest.approx(pm, rel=1e-12)
    assert got[2] == pytest.approx(wc, rel=1e-12)


@pytest.mark.parametrize(("params", "k", "lag", "tau"), [
    ({}, 1.0, 0, 0.0), ({}, 3.0, 0, 0.0), ({}, 0.5, 2, 0.3),
    ({"MC_ROLLRATE_P": 0.15, "MC_ROLLRATE_D": 0.003, "IMU_GYRO_RATEMAX": 400.0}, 2.0, 1, 0.5)])
def test_grid_margins_are_python_controls_stability_margins(params: dict[str, float], k: float,
                                                            lag: int, tau: float) -> None:
    """Every margin read off the loop's response on the grid (what the limits are checked
    with) is one ``control.stability_margins(loop, returnall=True)`` gives for the loop built
    from python-control's parts: the phase margins to 0.01 deg, the gain margins (crossings
    above the grid's lowest frequency) to 1e-3, the stability margins to 1e-5."""
    import control

    from mavsid.loop.controllers import measurement_filter

    ctrl = scaled(controller_from_params(params, "roll"), k)
    dt = 1.0 / ctrl.loop_hz
    tp = true_plant(PlantParams(), 0, dt)
    cfb, _ = controller_tf(ctrl, dt)
    m, num, den = measurement_filter(tau)
    if m:
        cfb = cfb * control.tf(num, den, dt)
    ss = control.ss(tp.a, tp.b.reshape(-1, 1), tp.c.reshape(1, -1), 0.0, dt)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (python-control's fall-back to its FRD method)
        gms, pms, sms, wpc, wgc, _ = control.stability_margins(control.ss(cfb) * ss,
                                                               returnall=True)
    f = np.geomspace(0.01, 0.499 / dt, 3000)
    z = np.exp(2j * np.pi * f * dt)
    (bf, af), _ = controller_polys(ctrl, dt)
    bp, ap = ss2tf(tp.a, tp.b, tp.c)
    lz = (np.polyval(bp, z) / np.polyval(ap, z) * np.polyval(np.polymul(bf, num), z)
          / np.polyval(np.polymul(af, den), z))
    got = grid_margins(f, lz)
    assert got[1].size == pms.size >= 1
    np.testing.assert_allclose(np.sort(got[1]), np.sort(pms), atol=0.01)
    np.testing.assert_allclose(np.sort(got[4]), np.sort(wgc), rtol=1e-4)
    inside = wpc > 2 * np.pi * f[0]
    assert got[0].size == np.count_nonzero(inside) >= 1
    np.testing.assert_allclose(np.sort(got[0]), np.sort(gms[inside]), rtol=1e-3)
    assert float(np.min(got[2])) == pytest.approx(float(np.min(sms)), rel=1e-5)
