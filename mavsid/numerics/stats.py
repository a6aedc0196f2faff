"""Statistics on numpy without scipy.stats: the chi-square tail of a residual whiteness test
and the Newey-West (Bartlett-weighted) sum of a covariance's "meat".

Each is checked against an outside reference: :func:`chi2_sf` against
``scipy.special.chdtrc``, :func:`bartlett_meat` against the explicit lag sum
(tests/test_stats.py).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["bartlett_meat", "chi2_sf"]


def bartlett_meat(scores: np.ndarray, lags: int) -> np.ndarray:
    """``Σ_{|l|≤L} (1 − |l|/(L+1)) Σₜ sₜ sₜ₊ₗᵀ`` (Newey–West) in O(n·k²) whatever ``L``
    (``L`` is capped at ``n − 1``).

    The Bartlett weights are the autocorrelation of a boxcar of length ``L + 1``, so the sum
    equals ``Σ bbᵀ / (L+1)`` over the full moving sums ``b`` of the scores.

    Examples
    --------
    >>> s = np.array([[1.0], [2.0], [3.0]])
    >>> float(bartlett_meat(s, 1)[0, 0])   # 1+4+9 + 2 * 0.5 * (1*2 + 2*3)
    22.0
    """
    n, k = scores.shape
    w = min(int(lags), max(n - 1, 0)) + 1
    padded = np.zeros((n + 2 * w - 1, k))
    padded[w - 1 : w - 1 + n] = scores
    c = np.vstack([np.zeros((1, k)), np.cumsum(padded, axis=0)])
    b = c[w:] - c[:-w]  # moving sums of length w: n + w - 1 of them
    return np.asarray(b.T @ b / w)


def chi2_sf(q: np.ndarray, dof: int) -> np.ndarray:
    """``scipy.stats.chi2.sf(q, dof)`` for a whole number of degrees of freedom, in closed
    form: with ``x = q / 2``, ``exp(-x) Σₖ xᵏ / k!`` (``k < dof / 2``) for an even ``dof``;
    ``erfc(√x) + exp(-x) Σₖ x^(k-½) / Γ(k+½)`` (``1 ≤ k ≤ (dof - 1) / 2``) for an odd one;
    the terms summed as logarithms (no overflow for a large ``q``). NaN stays NaN.

    Examples
    --------
    >>> [round(float(v), 6) for v in chi2_sf(np.array([3.84145882, 0.0, 1e4]), 1)]
    [0.05, 1.0, 0.0]
    >>> round(float(chi2_sf(np.array([31.41043284]), 20)[0]), 6)
    0.05
    """
    if dof < 1:
        raise ValueError(f"chi2_sf: {dof} degrees of freedom")
    x = np.asarray(q, float) / 2.0
    out = np.full(x.shape, np.nan)
    ok = np.isfinite(x) & (x >= 0)
    out[np.isposinf(x)] = 0.0
    xs = x[ok]
    with np.errstate(divide="ignore"):
        logx = np.log(xs)
    if dof % 2 == 0:
        ks = np.arange(dof // 2, dtype=float)
        first = np.zeros(xs.shape)
    else:
        ks = np.arange(1, (dof - 1) // 2 + 1, dtype=float) - 0.5
        first = np.array([math.erfc(math.sqrt(v)) for v in xs.tolist()])
    lgam = np.array([math.lgamma(k + 1.0) for k in ks.tolist()])
    with np.errstate(invalid="ignore"):  # (0 * log 0: the k = 0 term is exp(-x))
        terms = np.exp(-xs[:, None] + np.where(ks > 0, ks * logx[:, None], 0.0) - lgam)
    out[ok] = np.minimum(first + terms.sum(axis=1), 1.0)
    return out
