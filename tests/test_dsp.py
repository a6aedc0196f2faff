"""mavsid.dsp against the scipy.signal functions it stands in for on the fit path."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from mavsid import dsp
from mavsid.data import demean, detrend_linear

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
    got = dsp.lfilter(b, a, X, zi=zi)
    assert got == pytest.approx(want, rel=1e-12, abs=1e-12)


def test_lfilter_along_an_axis_with_states_per_column_and_complex_poles() -> None:
    b, a = dsp.butter_lowpass(2, 20.0, 1000.0)
    u = RNG.standard_normal((3000, 3))
    zi = dsp.lfilter_zi(b, a).reshape(-1, 1) * u[:1]
    want = signal.lfilter(b, a, u, axis=0, zi=zi)[0]
    assert dsp.lfilter(b, a, u, axis=0, zi=zi) == pytest.approx(want, rel=1e-12, abs=1e-12)
    rows = RNG.standard_normal((4, 3000))
    want = signal.lfilter([1.0], [1.0, -0.7], rows, axis=-1)
    assert dsp.lfilter([1.0], [1.0, -0.7], rows, axis=-1) == pytest.approx(want, abs=1e-12)
    lam = 0.9 * np.exp(0.3j)
    want = signal.lfilter([1.0], [1.0, -lam], X, zi=[lam * 0.5])[0]
    got = dsp.lfilter([1.0], [1.0, -lam], X, zi=[lam * 0.5])
    assert np.iscomplexobj(got) and np.max(np.abs(got - want)) < 1e-12


@pytest.mark.parametrize("order", [1, 2, 3, 4])
@pytest.mark.parametrize(("cutoff", "fs"), [(20.0, 1000.0), (80.0, 400.0), (5.0, 50.0)])
def test_butterworth_design_and_steady_state(order: int, cutoff: float, fs: float) -> None:
    b, a = dsp.butter_lowpass(order, cutoff, fs)
    wb, wa = signal.butter(order, cutoff, fs=fs)
    assert b == pytest.approx(wb, rel=1e-12) and a == pytest.approx(wa, rel=1e-12, abs=1e-14)
    assert dsp.lfilter_zi(b, a) == pytest.approx(signal.lfilter_zi(wb, wa), rel=1e-10)
    with pytest.raises(ValueError):
        dsp.butter_lowpass(order, fs / 2, fs)


@pytest.mark.parametrize(("num", "den"), [([0.2, 0.3], [1.0, -0.5]), ([1.0], [1.0, 0.0, 0.0]),
                                          ([0.5, 0.5], [1.0, 0.0, 0.0, 0.0]),
                                          ([0.1, 0.2, 0.1], [2.0, -1.5, 0.6]), ([2.0], [3.0])])
def test_tf2ss_matches_scipy(num: list[float], den: list[float]) -> None:
    for got, want in zip(dsp.tf2ss(num, den), signal.tf2ss(num, den), strict=True):
        assert np.shape(got) == np.shape(want)
        assert np.asarray(got) == pytest.approx(np.asarray(want), rel=1e-14, abs=1e-15)


@pytest.mark.parametrize("nper", [800, 801, 256, 37])
@pytest.mark.parametrize("detrend", [demean, detrend_linear])
def test_welch_csd_and_per_window_spectra_match_scipy(nper: int, detrend) -> None:  # type: ignore[no-untyped-def]
    y = signal.lfilter([0.3], [1.0, -0.7], X) + 0.1 * RNG.standard_normal(X.size)
    f0, p0 = signal.welch(y, fs=400.0, nperseg=nper, detrend=detrend)
    f1, p1 = dsp.welch(y, 400.0, nper, detrend=detrend)
    assert np.array_equal(f0, f1) and p1 == pytest.approx(p0, rel=1e-12)
    _, c0 = signal.csd(X, y, fs=400.0, nperseg=nper, noverlap=nper // 3, detrend=detrend)
    _, c1 = dsp.csd(X, y, 400.0, nper, nper // 3, detrend=detrend)
    assert np.max(np.abs(c1 - c0) / np.abs(c0)) < 1e-10
    _, _, s0 = signal.spectrogram(y, fs=400.0, nperseg=nper, noverlap=nper // 2, detrend=detrend)
    win = dsp.tukey(nper, 0.25)
    assert win == pytest.approx(signal.get_window(("tukey", 0.25), nper), abs=1e-15)
    seg = dsp.segment_ffts(y, nper, nper // 2, detrend, window=win)
    s1 = dsp.density(seg, seg, 400.0, nper, average=False, window=win).real.T
    assert s1.shape == s0.shape and s1 == pytest.approx(s0, rel=1e-10, abs=1e-12 * s0.max())


def test_detrend_linear_matches_scipy_on_stacked_windows() -> None:
    x = RNG.standard_normal((5, 300)) + np.linspace(-40.0, 90.0, 300)
    assert detrend_linear(x) == pytest.approx(signal.detrend(x, type="linear"), abs=1e-11)
    assert detrend_linear(x[0]) == pytest.approx(signal.detrend(x[0], type="linear"), abs=1e-11)
