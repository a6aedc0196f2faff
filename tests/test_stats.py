"""The chi-square tail and the Newey-West sum (mavsid.numerics.stats) against references."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal, special

from mavsid.numerics.stats import bartlett_meat, chi2_sf


@pytest.mark.parametrize("dof", [1, 2, 3, 7, 20, 41, 60])
def test_chi2_sf_is_scipys(dof: int) -> None:
    """The Ljung–Box p value's χ² tail (closed form, no scipy on the fit path) against
    scipy.special.chdtrc, from the body to the far tail."""
    q = np.concatenate([[0.0, 1e-9], np.linspace(0.01, 6 * dof + 40, 400), [1e3, 1e4]])
    got, want = chi2_sf(q, dof), special.chdtrc(dof, q)
    np.testing.assert_allclose(got, want, rtol=1e-11, atol=1e-300)
    assert np.isnan(chi2_sf(np.array([np.nan]), dof)[0])


def test_newey_west_meat_equals_the_explicit_lag_sum() -> None:
    rng = np.random.default_rng(5)
    s = signal.lfilter([1.0], [1.0, -0.8], rng.standard_normal((700, 4)), axis=0)
    for lags in (0, 1, 13, 200):
        ref = s.T @ s
        for lag in range(1, lags + 1):
            g = s[lag:].T @ s[:-lag]
            ref += (1 - lag / (lags + 1)) * (g + g.T)
        np.testing.assert_allclose(bartlett_meat(s, lags), ref, rtol=1e-10, atol=1e-9)
