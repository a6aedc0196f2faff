"""mavsid.numerics (filters, spectra, lti) against the scipy functions they stand in for on
the fit path."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from mavsid.data import demean, detrend_linear
from mavsid.numerics import filters, lti, spectra

RNG = np.random.default_rng(7)
X = RNG.standard_normal(20_000)


@pytest.mark.parametrize(("b", "a", "zi"), [
    ([1.0], [1.0, -0.99], None),
    ([1.0], [1.0, -0.99], [0.3]),
    ([0.2], [1.0, -0.8], [0.1]),
    ([0.5, 0.25], [2.0, -1.0], [0.7]),  # a[0] != 1 and a numerator of two taps
    ([1.0, 2.0, 1.0], [1.0], [0.5, -0.2]),  # FIR with a state
    ([0.1, 0.2], [1.0, -1.5, 0.6], [0.05, 0.02]),  # numerator shorter than the denominator
])
def test_lfilter_matches_scipy(b: list[float], a: list[float], zi: list[float] | None) -> None:
    want = signal.lfilter(b, a, X, zi=zi)
    want = want[0] if zi is not None else want
    got = filters.lfilter(b, a, X, zi=zi)
    assert got == pytest.approx(want, rel=1e-12, abs=1e-12)


def test_lfilter_along_an_axis_with_states_per_column_and_complex_poles() -> None:
    b, a = filters.butter_lowpass(2, 20.0, 1000.0)
    u = RNG.standard_normal((3000, 3))
    zi = filters.lfilter_zi(b, a).reshape(-1, 1) * u[:1]
    want = signal.lfilter(b, a, u, axis=0, zi=zi)[0]
    assert filters.lfilter(b, a, u, axis=0, zi=zi) == pytest.approx(want, rel=1e-12, abs=1e-12)
    rows = RNG.standard_normal((4, 3000))
    want = signal.lfilter([1.0], [1.0, -0.7], rows, axis=-1)
    assert filters.lfilter([1.0], [1.0, -0.7], rows, axis=-1) == pytest.approx(want, abs=1e-12)
    lam = 0.9 * np.exp(0.3j)
    want = signal.lfilter([1.0], [1.0, -lam], X, zi=[lam * 0.5])[0]
    got = filters.lfilter([1.0], [1.0, -lam], X, zi=[lam * 0.5])
    assert np.iscomplexobj(got) and np.max(np.abs(got - want)) < 1e-12


@pytest.mark.parametrize("order", [1, 2, 3, 4])
@pytest.mark.parametrize(("cutoff", "fs"), [(20.0, 1000.0), (80.0, 400.0), (5.0, 50.0)])
def test_butterworth_design_and_steady_state(order: int, cutoff: float, fs: float) -> None:
    b, a = filters.butter_lowpass(order, cutoff, fs)
    wb, wa = signal.butter(order, cutoff, fs=fs)
    assert b == pytest.approx(wb, rel=1e-12) and a == pytest.approx(wa, rel=1e-12, abs=1e-14)
    assert filters.lfilter_zi(b, a) == pytest.approx(signal.lfilter_zi(wb, wa), rel=1e-10)
    with pytest.raises(ValueError):
        filters.butter_lowpass(order, fs / 2, fs)


@pytest.mark.parametrize(("num", "den"), [([0.2, 0.3], [1.0, -0.5]), ([1.0], [1.0, 0.0, 0.0]),
                                          ([0.5, 0.5], [1.0, 0.0, 0.0, 0.0]),
                                          ([0.1, 0.2, 0.1], [2.0, -1.5, 0.6]), ([2.0], [3.0])])
def test_tf2ss_matches_scipy(num: list[float], den: list[float]) -> None:
    for got, want in zip(lti.tf2ss(num, den), signal.tf2ss(num, den), strict=True):
        assert np.shape(got) == np.shape(want)
        assert np.asarray(got) == pytest.approx(np.asarray(want), rel=1e-14, abs=1e-15)


@pytest.mark.slow
@pytest.mark.parametrize("nper", [800, 801, 256, 37])
@pytest.mark.parametrize("detrend", [demean, detrend_linear])
def test_welch_csd_and_per_window_spectra_match_scipy(nper: int, detrend) -> None:  # type: ignore[no-untyped-def]
    y = signal.lfilter([0.3], [1.0, -0.7], X) + 0.1 * RNG.standard_normal(X.size)
    f0, p0 = signal.welch(y, fs=400.0, nperseg=nper, detrend=detrend)
    f1, p1 = spectra.welch(y, 400.0, nper, detrend=detrend)
    assert np.array_equal(f0, f1) and p1 == pytest.approx(p0, rel=1e-12)
    _, c0 = signal.csd(X, y, fs=400.0, nperseg=nper, noverlap=nper // 3, detrend=detrend)
    _, c1 = spectra.csd(X, y, 400.0, nper, nper // 3, detrend=detrend)
    assert np.max(np.abs(c1 - c0) / np.abs(c0)) < 1e-10
    _, _, s0 = signal.spectrogram(y, fs=400.0, nperseg=nper, noverlap=nper // 2, detrend=detrend)
    win = spectra.tukey(nper, 0.25)
    assert win == pytest.approx(signal.get_window(("tukey", 0.25), nper), abs=1e-15)
    seg = spectra.segment_ffts(y, nper, nper // 2, detrend, window=win)
    s1 = spectra.density(seg, seg, 400.0, nper, average=False, window=win).real.T
    assert s1.shape == s0.shape and s1 == pytest.approx(s0, rel=1e-10, abs=1e-12 * s0.max())


def test_detrend_linear_matches_scipy_on_stacked_windows() -> None:
    x = RNG.standard_normal((5, 300)) + np.linspace(-40.0, 90.0, 300)
    assert detrend_linear(x) == pytest.approx(signal.detrend(x, type="linear"), abs=1e-11)
    assert detrend_linear(x[0]) == pytest.approx(signal.detrend(x[0], type="linear"), abs=1e-11)


@pytest.mark.parametrize(("cutoff", "fs"), [(20.0, 400.0), (80.0, 1000.0), (30.0, 8000.0)])
def test_lowpass2p_steps_scipys_filter_from_its_steady_state(cutoff: float, fs: float) -> None:
    """The autopilots' streaming biquad, one vector sample at a time, against
    scipy.signal.lfilter of scipy.signal.butter's low-pass started in the steady state of
    the first sample (lfilter_zi): to 1e-12 of the signal (a second-order section rounds
    the last digit or two); a cut-off of 0 lets the samples through."""
    u = RNG.standard_normal((3000, 3)) + 5.0
    f = filters.Lowpass2p(cutoff, fs, 3)
    got = np.array([f(row) for row in u])
    b, a = signal.butter(2, cutoff, fs=fs)
    want = signal.lfilter(b, a, u, axis=0, zi=signal.lfilter_zi(b, a)[:, None] * u[:1])[0]
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * np.abs(want).max())
    off = filters.Lowpass2p(0.0, fs, 3)
    np.testing.assert_array_equal(np.array([off(row) for row in u[:50]]), u[:50])


def _rounding_scale(b: np.ndarray, a: np.ndarray, u: np.ndarray, want: np.ndarray
                    ) -> np.ndarray:
    """Per column, how far a float64 filter's output can sit from ``want`` by rounding alone:
    ``4 ε Σⱼ max|∂y/∂ln aⱼ|``, the output's change when each denominator coefficient moves by
    one rounding of itself (first order, measured at 1e-9 relative, scipy.signal.lfilter).
    The recursion's own roundings (ε of each ``aⱼ y[k-j]``) travel through ``1/A(z)`` as a
    coefficient's do, so two correct implementations each sit within about ``ε Σⱼ ...``; the
    factor 4 covers both, twice. About 1e-15 of the output for a first-order low-pass at
    0.03 of Nyquist, 1e-9 for the fifth-order one (its poles crowd near z = 1)."""
    h, sens = 1e-9, np.zeros(u.shape[1])
    for j in range(1, a.size):
        moved = a.copy()
        moved[j] *= 1.0 + h
        sens += np.abs(signal.lfilter(b, moved, u, axis=0) - want).max(axis=0) / h
    return 4.0 * np.finfo(float).eps * sens


@pytest.mark.parametrize("order", [1, 2, 3, 5])
def test_the_compiled_recursion_is_scipys_lfilter(order: int) -> None:
    """mavsid._filter, and the path a build without a C compiler takes, against
    scipy.signal.lfilter per column, to the rounding the filter itself amplifies
    (:func:`_rounding_scale`: both compute in float64 in their own order, and the
    BLAS-free C loops of each may be compiled with or without fused multiply-adds); a
    denominator coefficient wrong by 1e-12 of itself is far outside it."""
    if filters._filter is None:
        pytest.skip("built without a C compiler: the scipy path is the only one")
    b, a = signal.butter(order, 0.03)
    u = RNG.standard_normal((4000, 3))
    want = signal.lfilter(b, a, u, axis=0)
    tol = _rounding_scale(b, a, u, want)
    got = filters.lfilter(b, a, u, axis=0)
    compiled, filters._filter = filters._filter, None
    try:
        plain = filters.lfilter(b, a, u, axis=0)
        wrong = a.copy()
        wrong[1] *= 1.0 + 1e-12
        off = filters.lfilter(b, wrong, u, axis=0)
    finally:
        filters._filter = compiled
    for out in (got, plain):
        assert np.all(np.abs(out - want).max(axis=0) <= tol)
    assert np.all(np.abs(off - want).max(axis=0) > 100.0 * tol)
    with pytest.raises(ValueError, match="whole columns"):
        filters._filter.recurse(np.ones(2), np.zeros(7), 3)


def _structured(rng: np.random.Generator, n: int, m: int) -> np.ndarray:
    """[[A, B], [0, 0]] dt: what a continuous model's zero-order hold exponentiates (the
    zero block makes it defective: no eigenvector basis)."""
    big = np.zeros((n + m, n + m))
    big[:n, :n] = rng.standard_normal((n, n)) * 5 - 3 * np.eye(n)
    big[:n, n:] = rng.standard_normal((n, m)) * 100
    return big * 0.0025


def test_expm_and_logm_refuse_what_scipy_would_turn_into_a_nan_model() -> None:
    with pytest.raises(ValueError, match="square"):
        lti.expm(np.ones((2, 3)))
    with pytest.raises(ValueError, match="square"):
        lti.logm(np.ones(3))
    for func in (lti.expm, lti.logm):
        with pytest.raises(ValueError, match="infinities or NaN"):
            func(np.array([[1.0, np.nan], [0.0, 1.0]]))


def test_logm_is_scipys_and_undoes_the_zero_order_hold() -> None:
    """The discrete models mavsid takes to continuous time: real positive poles, the
    [[A_d, B_d], [0, I]] of a zero-order hold, a repeated pole (a Jordan block); the 1×1
    case in closed form. Against scipy.linalg.logm to rounding (its real part, for a
    negative pole), and the continuous matrix each hold came from back."""
    from scipy import linalg

    rng = np.random.default_rng(12)
    cases = [np.array([[v]]) for v in (1e-6, 0.37, 0.999999, 1.0, 3.5)]
    for n in (1, 2, 3, 4):
        q = rng.standard_normal((n, n)) + 2 * np.eye(n)
        cases.append(q @ np.diag(np.exp(rng.uniform(-2, 0.3, n))) @ np.linalg.inv(q))
    held = [_structured(rng, n, 2) for n in (1, 2, 3)]
    for c in held:  # (the input block's zeros held: the identity below B_d)
        cases.append(linalg.expm(c))
    cases.append(np.array([[0.9, 1.0], [0.0, 0.9]]))
    cases.append(np.array([[-0.5]]))
    for a in cases:
        with np.errstate(all="ignore"):
            want = np.real(linalg.logm(a))
        np.testing.assert_allclose(lti.logm(a), want, rtol=1e-12, atol=1e-14)
    for c in held:
        np.testing.assert_allclose(lti.logm(lti.expm(c)), c, rtol=1e-9,
                                   atol=1e-12 * np.abs(c).max())
    assert lti.logm(np.array([[0.9, 1.0], [0.0, 0.9]]))[0, 1] == pytest.approx(1 / 0.9,
                                                                             rel=1e-12)


@pytest.mark.slow
def test_a_fit_without_the_compiled_recursion_is_the_same_fit(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A build without a C compiler filters through scipy: the same model within a
    thousandth of each coefficient's standard error. (The two filters differ in their last
    bits; the output-error solver, stopping when a step lowers the cost by less than 1e-8 of
    it, carries that to about 1e-8 σ here. A sample of delay in the filters' output moves the
    coefficients by up to 4 σ, a denominator coefficient wrong by 1e-6 of itself by 0.006 σ.)"""
    if filters._filter is None:
        pytest.skip("built without a C compiler: the scipy path is the only one")
    from helpers import FIXTURES

    from mavsid import pipeline

    cfg = pipeline.PipelineConfig(axes=("roll",))
    compiled = pipeline.fit([FIXTURES / "sysid_roll.bin"], cfg).axes["roll"].model
    monkeypatch.setattr(filters, "_filter", None)
    plain = pipeline.fit([FIXTURES / "sysid_roll.bin"], cfg).axes["roll"].model
    assert compiled.coef_stderr is not None and np.all(compiled.coef_stderr > 0)
    assert np.all(np.abs(plain.coef - compiled.coef) <= 1e-3 * compiled.coef_stderr)
    assert plain.params.keys() == compiled.params.keys()
    for name, value in compiled.params.items():
        assert plain.params[name] == pytest.approx(value, abs=1e-3 * compiled.stderr[name])


def test_zero_order_hold_against_scipy_and_back() -> None:
    """lti.c2d against scipy.signal.cont2discrete, and lti.d2c giving back the continuous
    system, also with an integrator (a pole of the held system at 1: the block logarithm)."""
    from scipy.signal import cont2discrete

    rng = np.random.default_rng(11)
    for n, m, integrator in ((1, 1, False), (1, 2, True), (3, 2, False), (3, 1, True)):
        a = -np.diag(rng.uniform(1.0, 30.0, n)) + 0.1 * rng.standard_normal((n, n))
        if integrator:
            a[:, 0] = 0.0
        b = rng.standard_normal((n, m))
        phi, gamma = lti.c2d(a, b, 0.01)
        want_phi, want_gamma, *_ = cont2discrete((a, b, np.eye(n), np.zeros((n, m))), 0.01)
        np.testing.assert_allclose(phi, want_phi, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(gamma, want_gamma, rtol=1e-12, atol=1e-14)
        back_a, back_b = lti.d2c(phi, gamma, 0.01)
        np.testing.assert_allclose(back_a, a, rtol=1e-8, atol=1e-8)
        np.testing.assert_allclose(back_b, b, rtol=1e-8, atol=1e-8)
