"""Equation-error regression of a measured quantity on regressors: :func:`regress`.

The statistics of the flight-test literature (Klein & Morelli, *Aircraft System
Identification*, ch. 5): conventional standard errors ``s²(XᵀX)⁻¹``, the coloured-residual
correction, t-statistics, R², the predicted squared error (PSE) and stepwise or thresholded
structure selection, in a :class:`RegressionResult`.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mavsid.errors import ConfigError, NoExcitationError
from mavsid.estimators.arrays import as_records, column_names
from mavsid.estimators.base import Gram, collinear, solve
from mavsid.estimators.least_squares import thresholded
from mavsid.numerics.stats import bartlett_meat
from mavsid.threads import one_blas_thread

__all__ = ["RegressionResult", "regress"]



@dataclass(frozen=True)
class RegressionResult:
    """Equation-error regression ``y = Xθ + v`` and its statistics.

    Attributes
    ----------
    names : tuple of str
        Regressor names (all candidates, in the order given).
    coef : numpy.ndarray, shape (p,)
        Estimates (0 for a regressor left out by structure selection).
    selected : numpy.ndarray of bool, shape (p,)
        Regressors in the model.
    cov, cov_colored : numpy.ndarray, shape (p, p)
        Conventional ``s²(XᵀX)⁻¹`` and coloured-residual corrected covariance (NaN rows and
        columns for regressors left out).
    colored_method : str
        Which correction ``cov_colored`` is.
    s2 : float
        Fit-error variance ``vᵀv / (N − p)``.
    r2 : float
        Coefficient of determination ``1 − vᵀv / Σ(y − ȳ)²``.
    pse : float
        Predicted squared error ``vᵀv/N + σ²_max p/N``, ``σ²_max = Σ(y − ȳ)²/N``.
    residuals : numpy.ndarray, shape (N,)
        ``y − Xθ`` (records concatenated).
    n : int
        Rows.
    alpha : float
        Ridge weight λ of ``min ‖y − Xθ‖² + λ‖θ‖²`` (0: least squares).
    selection : str
        The structure-selection criterion used and what it did ("none" when all kept).
    """

    names: tuple[str, ...]
    coef: np.ndarray
    selected: np.ndarray
    cov: np.ndarray = field(repr=False)
    cov_colored: np.ndarray = field(repr=False)
    colored_method: str
    s2: float
    r2: float
    pse: float
    residuals: np.ndarray = field(repr=False)
    n: int
    alpha: float = 0.0
    selection: str = "none"

    @property
    def params(self) -> dict[str, float]:
        """Name -> estimate."""
        return {k: float(v) for k, v in zip(self.names, self.coef, strict=True)}

    def _diag(self, cov: np.ndarray) -> dict[str, float]:
        se = np.sqrt(np.clip(np.diag(cov), 0, None))
        return {k: float(v) for k, v in zip(self.names, se, strict=True)}

    @property
    def stderr(self) -> dict[str, float]:
        """Name -> conventional standard error ``sqrt(s² (XᵀX)⁻¹)ⱼⱼ``."""
        return self._diag(self.cov)

    @property
    def stderr_colored(self) -> dict[str, float]:
        """Name -> coloured-residual corrected standard error (see ``colored_method``)."""
        return self._diag(self.cov_colored)

    def _t(self, se: dict[str, float]) -> dict[str, float]:
        with np.errstate(divide="ignore", invalid="ignore"):
            return {k: float(np.float64(v) / se[k]) if s else float("nan")
                    for (k, v), s in zip(self.params.items(), self.selected, strict=True)}

    @property
    def tstat(self) -> dict[str, float]:
        """Name -> ``θⱼ / stderr_colored[j]`` (NaN for regressors left out)."""
        return self._t(self.stderr_colored)

    @property
    def tstat_conventional(self) -> dict[str, float]:
        """Name -> ``θⱼ / stderr[j]``."""
        return self._t(self.stderr)

    def predict(self, X: Any) -> np.ndarray:
        """``X θ`` for new regressor rows."""
        return np.asarray(np.asarray(X, dtype=float).reshape(-1, len(self.names)) @ self.coef)

    def summary(self) -> str:
        """A table: estimate, conventional and corrected standard error, t, per regressor."""
        lines = [f"{'':>12} {'estimate':>12} {'stderr':>11} {'stderr_col':>11} {'t':>8}"]
        se, sc, t = self.stderr, self.stderr_colored, self.tstat
        for k, v in self.params.items():
            lines.append(f"{k:>12} {v:12.6g} {se[k]:11.4g} {sc[k]:11.4g} {t[k]:8.2f}")
        lines.append(f"N={self.n} s2={self.s2:.4g} R2={self.r2:.4f} PSE={self.pse:.4g}; "
                     f"corrected: {self.colored_method}; selection: {self.selection}")
        return "\n".join(lines)


def _autocorrelation(v: Sequence[np.ndarray], n: int) -> np.ndarray:
    """``R̂(k) = (1/N) Σᵢ v(i) v(i+k)``, pooled over records (lags within a record only)."""
    longest = max(len(e) for e in v)
    r = np.zeros(longest)
    for e in v:
        m = len(e)
        nfft = 1 << int(np.ceil(np.log2(max(2 * m, 2))))
        f = np.fft.rfft(e, nfft)
        r[:m] += np.fft.irfft(f * np.conj(f), nfft)[:m]
    return r / n


def _toeplitz_times(r: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``T x`` with ``T[i, j] = r[|i − j|]`` (all lags of the record), by FFT."""
    m = len(x)
    two = np.concatenate([r[m - 1 : 0 : -1], r[:m]])  # lags −(m−1) … m−1
    nfft = 1 << int(np.ceil(np.log2(3 * m)))
    conv = np.fft.irfft(np.fft.rfft(two, nfft)[:, None] * np.fft.rfft(x, nfft, axis=0), nfft,
                        axis=0)
    return np.asarray(conv[m - 1 : 2 * m - 1])


@one_blas_thread
def regress(
    X: Any,
    y: Any,
    names: Sequence[str] | None = None,
    *,
    alpha: float = 0.0,
    select: str | None = None,
    threshold: float = 0.05,
    f_in: float = 4.0,
    f_out: float = 4.0,
    keep: Sequence[str] = (),
    colored: str = "all-lags",
    lags: int | None = None,
) -> RegressionResult:
    """Equation-error least squares ``y = Xθ + v`` with textbook statistics.

    Parameters
    ----------
    X : array_like (N, p), or a list of records
        Regressors (include a column of ones for a bias).
    y : array_like (N,), or a list of records
        Measured quantity.
    names : sequence of str, optional
        Regressor names (default ``x1 … xp``).
    alpha : float
        Ridge weight λ: ``θ = (XᵀX + λI)⁻¹Xᵀy`` (every regressor penalised).
    select : {None, "stepwise", "threshold"}
        ``"stepwise"``: Klein & Morelli's stepwise regression — the candidate with the
        largest partial F enters while it is ≥ ``f_in``, a regressor leaves when its partial F
        drops below ``f_out`` (the partial F tests use least squares, then the selected
        model is fitted with ``alpha``). ``"threshold"``: sequentially thresholded (ridge)
        least squares, a regressor leaves while its standardised coefficient
        ``|θⱼ| rms(xⱼ) / rms(y)`` is below ``threshold``. ``keep`` names stay in either way.
    threshold : float
        ``select="threshold"``: the relative threshold (dimensionless).
    f_in, f_out : float
        ``select="stepwise"``: partial F to enter, to stay.
    keep : sequence of str
        Regressors never left out by selection (e.g. the bias).
    colored : {"all-lags", "newey-west"}
        Correction of the covariance for coloured residuals: ``"all-lags"`` is Klein &
        Morelli's ``(XᵀX)⁻¹[Σᵢ Σⱼ x(i) R̂ᵥᵥ(i−j) x(j)ᵀ](XᵀX)⁻¹`` with the residual
        autocorrelation ``R̂ᵥᵥ(k) = (1/N) Σᵢ v(i) v(i+k)`` over every lag (pooled over records;
        biased low for a bias column, whose residuals sum to zero); ``"newey-west"`` is the
        Bartlett-weighted sandwich. Sums never cross a record's end.
    lags : int, optional
        ``"all-lags"``: truncate the sum at this lag. ``"newey-west"``: Bartlett lags
        (default ``⌈4 (N/100)^{2/9}⌉``).

    Returns
    -------
    RegressionResult

    Raises
    ------
    NoExcitationError
        A regressor is zero or regressors are collinear (named), or fewer rows than
        regressors.

    Examples
    --------
    The lecture's two rows, and a third row that is their sum (a linear combination, so
    Θ is unchanged):

    >>> r = regress([[1.0, 1.0], [2.0, 0.0]], [2.0, 1.8], names=["a", "b"])
    >>> {k: round(v, 12) for k, v in r.params.items()}
    {'a': 0.9, 'b': 1.1}
    >>> r3 = regress([[1.0, 1.0], [2.0, 0.0], [3.0, 1.0]], [2.0, 1.8, 3.8], names=["a", "b"])
    >>> {k: round(v, 12) for k, v in r3.params.items()}
    {'a': 0.9, 'b': 1.1}

    An input column of zeros:

    >>> regress([[1.0, 0.0], [2.0, 0.0], [1.5, 0.0]], [2.0, 1.8, 1.5], names=["a", "b"])
    Traceback (most recent call last):
    ...
    mavsid.errors.NoExcitationError: b unidentifiable: regressor b is zero

    Ridge is ``Θ = X₊Zᵀ(ZZᵀ + λI)⁻¹`` (rows of ``Z`` regressors, columns samples):

    >>> import numpy as np
    >>> Z = np.array([[1.0, 2.0, 1.8, 0.5], [1.0, 0.0, 0.0, 1.0]])
    >>> Xp = np.array([[2.0, 1.8, 1.6, 1.4]])
    >>> lam = 0.5
    >>> ridge = regress(Z.T, Xp[0], names=["a", "b"], alpha=lam).coef
    >>> textbook = Xp @ Z.T @ np.linalg.inv(Z @ Z.T + lam * np.eye(2))
    >>> ridge.round(10).tolist(), textbook.round(10).tolist()
    ([0.8825710754, 0.8304573548], [[0.8825710754, 0.8304573548]])
    """
    xs = as_records(X, "X")
    ys = as_records(y, "y")
    if len(xs) != len(ys):
        raise ConfigError(f"X has {len(xs)} records, y has {len(ys)}")
    p = xs[0].shape[1]
    for i, (a, b) in enumerate(zip(xs, ys, strict=True)):
        if a.shape[1] != p or b.shape[1] != 1 or len(a) != len(b):
            raise ConfigError(f"record {i}: X {a.shape} and y {b.shape} do not match "
                              f"(N, {p}) and (N,)")
    nm = column_names(names, p, "x", "names")
    if select not in (None, "stepwise", "threshold"):
        raise ConfigError(f"select must be None, 'stepwise' or 'threshold', got {select!r}")
    if colored not in ("all-lags", "newey-west"):
        raise ConfigError(f"colored must be 'all-lags' or 'newey-west', got {colored!r}")
    if not 0 <= alpha < math.inf:
        raise ConfigError(f"alpha must be a finite number >= 0, got {alpha}")
    unknown = set(keep) - set(nm)
    if unknown:
        raise ConfigError(f"keep names unknown regressors {sorted(unknown)}")
    xa, ya = np.concatenate(xs), np.concatenate(ys)
    ok = np.isfinite(xa).all(axis=1) & np.isfinite(ya[:, 0])
    if not ok.all():
        raise ConfigError(f"{int((~ok).sum())} rows with non-finite values; remove them first")
    n = len(xa)
    g = Gram.of(xa, ya)
    _check_columns(g, nm)
    keep_mask = np.array([k in keep for k in nm])
    lam_rows = alpha / n
    if select == "threshold":
        act = thresholded(g, threshold, keep_mask, lam_rows, standardize=False)[:, 0] != 0
        how = f"threshold: |θⱼ| rms(xⱼ)/rms(y) >= {threshold:g}"
    elif select == "stepwise":
        act, how = _stepwise(g, f_in, f_out, keep_mask, nm)
    else:
        act, how = np.ones(p, bool), "none"
    dropped = [k for k, a in zip(nm, act, strict=True) if not a]
    if dropped:
        how += f"; left out {', '.join(dropped)}"
    coef = solve(g, lam_rows, None, act, standardize=False)[:, 0]
    v = ya[:, 0] - xa @ coef
    k = int(act.sum())
    dof = n - k
    sse = float(v @ v)
    s2 = sse / dof if dof > 0 else float("nan")
    xx = g.zz[np.ix_(act, act)]
    bread = np.linalg.inv(xx + alpha * np.eye(k))
    cov_a = s2 * bread @ xx @ bread
    xsel = [a[:, act] for a in xs]
    edges = np.cumsum([0] + [len(a) for a in xs])
    vs = [v[a:b] for a, b in itertools.pairwise(edges)]
    if colored == "all-lags":
        r = _autocorrelation(vs, n)
        if lags is not None:
            r[int(lags) + 1 :] = 0.0
        meat = sum(xr.T @ _toeplitz_times(r[: len(xr)], xr) for xr in xsel)
        method = ("Klein-Morelli: residual autocorrelation over all lags" if lags is None
                  else f"Klein-Morelli: residual autocorrelation up to lag {int(lags)}")
    else:
        nl = int(np.ceil(4 * (n / 100.0) ** (2.0 / 9.0))) if lags is None else int(lags)
        meat = sum(bartlett_meat(xr * e[:, None], nl) for xr, e in zip(xsel, vs, strict=True))
        method = f"Newey-West (Bartlett, {nl} lags)"
    cov_c = bread @ np.asarray(meat) @ bread
    cov = np.full((p, p), np.nan)
    cov_col = np.full((p, p), np.nan)
    cov[np.ix_(act, act)] = cov_a
    cov_col[np.ix_(act, act)] = cov_c
    sst = float(((ya[:, 0] - ya[:, 0].mean()) ** 2).sum())
    r2 = 1.0 - sse / sst if sst > 0 else float("nan")
    pse = sse / n + (sst / n) * k / n
    return RegressionResult(nm, coef, act, cov, cov_col, method, s2, r2, pse, v, n,
                            float(alpha), how)


def _check_columns(g: Gram, names: Sequence[str]) -> None:
    """Zero regressors, too few rows, collinear regressors -> NoExcitationError."""
    p = len(names)
    if g.n < p:
        raise NoExcitationError(f"{', '.join(names)} unidentifiable: only {g.n} rows for "
                                f"{p} regressors")
    d = np.diag(g.zz)
    for j in map(int, np.flatnonzero(d <= 0)):
        raise NoExcitationError(f"{names[j]} unidentifiable: regressor {names[j]} is zero")
    s = np.sqrt(d)
    _, js = collinear(g.zz / np.outer(s, s), 1e12)
    if js:
        raise NoExcitationError(f"{', '.join(names[j] for j in js)} unidentifiable: "
                                f"regressors {' and '.join(names[j] for j in js)} are collinear")


def _stepwise(g: Gram, f_in: float, f_out: float, keep: np.ndarray, names: Sequence[str]
              ) -> tuple[np.ndarray, str]:
    """Forward-backward stepwise regression by partial F (Klein & Morelli §5.4.1)."""
    p = g.zz.shape[0]

    def sse(act: np.ndarray) -> float:
        if not act.any():
            return float(g.yy[0, 0])
        return float(g.sse(solve(g, 0.0, None, act, standardize=False))[0])

    act = keep.copy()
    steps = []
    for _ in range(4 * p):
        changed = False
        base = sse(act)
        k = int(act.sum())
        out = [j for j in range(p) if not act[j]]
        if out and g.n - k - 1 > 0:
            trial = []
            for j in out:
                a2 = act.copy()
                a2[j] = True
                s_new = sse(a2)
                s2 = s_new / (g.n - k - 1)
                trial.append(((base - s_new) / s2 if s2 > 0 else np.inf, j))
            f, j = max(trial)
            if f >= f_in:
                act[j] = True
                steps.append(f"+{names[j]} (F={f:.3g})")
                changed = True
        base = sse(act)
        k = int(act.sum())
        s2 = base / (g.n - k) if g.n > k else np.inf
        removable = [j for j in range(p) if act[j] and not keep[j]]
        if removable and s2 > 0:
            trial = []
            for j in removable:
                a2 = act.copy()
                a2[j] = False
                trial.append(((sse(a2) - base) / s2, j))
            f, j = min(trial)
            if f < f_out:
                act[j] = False
                steps.append(f"-{names[j]} (F={f:.3g})")
                changed = True
        if not changed:
            break
    how = (f"stepwise: partial F to enter >= {f_in:g}, to stay >= {f_out:g}"
           + (f" ({', '.join(steps)})" if steps else ""))
    return act, how
