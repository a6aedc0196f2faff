"""The one regression core every estimator shares.

Rows of all segments are reduced block by block to Gram matrices ``[Z Y]ᵀ[Z Y]``; every
solver (least squares, ridge, L1, thresholded LS) works on the summed Gram, so that solving
costs the same for 10⁴ or 10⁶ rows. The blocks (contiguous row ranges inside one segment) are
what cross-validation holds out and what the bootstrap resamples.

Uncertainty: ``Cov θ = G⁻¹ S G⁻¹`` with ``S`` the Newey–West (Bartlett-kernel, HAC) long-run
covariance of the scores ``zₜeₜ``, summed only within segments, which corrects ``σ²G⁻¹`` for
coloured residuals; plus a bootstrap over blocks. The reported standard error is the larger
of the two.

Identifiability: before solving, a column that does not vary, or a set of nearly collinear
columns, raises :class:`~mavsid.errors.NoExcitationError` naming the parameters and the cause.

Examples
--------
>>> import numpy as np
>>> z = np.column_stack([np.arange(5.0), np.ones(5)])
>>> g = Gram.of(z, 2 * z[:, :1] + 1)
>>> g.n, np.round(solve(g), 6).ravel().tolist()
(5, [2.0, 1.0])
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from mavsid.data import Segment
from mavsid.errors import (
    ConfigError,
    DataQualityWarning,
    NoExcitationError,
    SolverError,
    finite_number,
    whole_number,
)
from mavsid.estimators import library
from mavsid.estimators.model import Model, provenance
from mavsid.estimators.regressors import Regression, Structure, stack
from mavsid.numerics.stats import bartlett_meat

__all__ = [
    "Estimator",
    "Gram",
    "block_grams",
    "check_identifiable",
    "collinear",
    "column_scales",
    "hac_covariance",
    "param_names",
    "penalised",
    "rollout_fit",
    "solve",
]


@dataclass(frozen=True)
class Gram:
    """Sufficient statistics of a least-squares problem: ``ZᵀZ``, ``ZᵀY``, ``YᵀY``, rows."""

    zz: np.ndarray
    zy: np.ndarray
    yy: np.ndarray
    n: int

    @classmethod
    def of(cls, z: np.ndarray, y: np.ndarray) -> Gram:
        """Gram of the rows ``z`` (n, p) and targets ``y`` (n, m)."""
        y = y.reshape(len(y), -1)
        return cls(z.T @ z, z.T @ y, y.T @ y, int(z.shape[0]))

    def __add__(self, other: Gram) -> Gram:
        return Gram(self.zz + other.zz, self.zy + other.zy, self.yy + other.yy,
                    self.n + other.n)

    def __sub__(self, other: Gram) -> Gram:
        return Gram(self.zz - other.zz, self.zy - other.zy, self.yy - other.yy,
                    self.n - other.n)

    def scaled(self, w: float) -> Gram:
        """The Gram of the rows repeated ``w`` times (bootstrap weights)."""
        return Gram(self.zz * w, self.zy * w, self.yy * w, round(self.n * w))

    def sse(self, coef: np.ndarray) -> np.ndarray:
        """Residual sum of squares per output (from the Gram alone)."""
        return np.diag(self.yy) - 2 * np.sum(coef * self.zy, axis=0) + np.sum(
            coef * (self.zz @ coef), axis=0)


def block_grams(reg: Regression) -> list[Gram]:
    """One Gram per block of rows."""
    return [Gram.of(reg.z[a:b], reg.y[a:b]) for a, b, _, _ in reg.blocks]


def param_names(structure: Structure) -> list[list[str]]:
    """``names[j][i]``: the parameter name of feature ``j`` for output ``i``."""
    m = Model.of(structure, np.zeros((len(structure.features), len(structure.outputs))), 1.0)
    return [[m._name(o, f)[0] for o in structure.outputs] for f in structure.features]


def column_scales(g: Gram) -> np.ndarray:
    """Column RMS (1 for an all-zero column)."""
    s = np.sqrt(np.clip(np.diag(g.zz), 0, None) / max(g.n, 1))
    return np.where(s > 0, s, 1.0)


def penalised(structure: Structure) -> np.ndarray:
    """Which features a penalty acts on: every one but the bias (bool, per feature)."""
    return np.array([f != library.BIAS for f in structure.features])


def collinear(corr: np.ndarray, max_condition: float) -> tuple[float, list[int]]:
    """The condition number of a correlation matrix and, when it exceeds ``max_condition``,
    the columns that are collinear (the large weights of its smallest eigenvector; else
    none).

    Examples
    --------
    >>> cond, cols = collinear(np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
    ...                        1e10)
    >>> cond > 1e10, cols
    (True, [0, 1])
    """
    lam, vec = np.linalg.eigh(corr)
    cond = float(lam[-1] / max(lam[0], 1e-300))
    if not cond > max_condition:
        return cond, []
    w = np.abs(vec[:, 0])
    return cond, [int(j) for j in np.flatnonzero(w > 0.2 * w.max())]


def check_identifiable(reg: Regression, g: Gram, max_condition: float = 1e10) -> None:
    """Raise ``NoExcitationError`` when the rows cannot identify every parameter.

    Causes named: too few rows; a feature that is zero or constant (when a bias is present)
    over the selected segments; features that are (nearly) collinear — the smallest
    eigenvalue of the correlation-scaled Gram ``< λmax / max_condition``.
    """
    st = reg.structure
    names = param_names(st)
    p = len(st.features)

    def label(js: Sequence[int]) -> str:
        return ", ".join(n for j in js for n in names[j])

    if g.n < p:
        raise NoExcitationError(
            f"{label(range(p))} unidentifiable: only {g.n} rows for {p} parameters per output"
        )
    has_bias = library.BIAS in st.features
    zz = g.zz / g.n
    mean = g.zz[st.features.index(library.BIAS)] / g.n if has_bias else np.zeros(p)
    for j, f in enumerate(st.features):
        if f == library.BIAS:
            continue
        col = reg.z[:, j]
        rms = np.sqrt(max(zz[j, j], 0.0))
        spread = float(np.ptp(col)) if has_bias else rms
        if spread <= 1e-12 * max(rms, 1e-300) or rms == 0.0:
            what = "is zero" if rms == 0.0 else "does not vary"
            raise NoExcitationError(
                f"{label([j])} unidentifiable: {f} {what} in the selected segments"
            )
    s = np.sqrt(np.diag(zz))
    corr = zz / np.outer(s, s)
    if has_bias:  # condition of the centred problem: correlation among the varying columns
        k = st.features.index(library.BIAS)
        keep = [j for j in range(p) if j != k]
        cov = zz - np.outer(mean, mean)
        sc = np.sqrt(np.diag(cov)[keep])
        corr = cov[np.ix_(keep, keep)] / np.outer(sc, sc)
    else:
        keep = list(range(p))
    if len(keep) < 2:
        return
    cond, cols = collinear(corr, max_condition)
    if cols:
        js = [keep[i] for i in cols]
        feats = " and ".join(st.features[j] for j in js)
        raise NoExcitationError(
            f"{label(js)} unidentifiable: {feats} are collinear in the selected segments "
            f"(condition number {cond:.1e} > {max_condition:.0e})"
        )


def solve(g: Gram, ridge: float = 0.0, penalize: np.ndarray | None = None,
          active: np.ndarray | None = None, standardize: bool = True) -> np.ndarray:
    """Least squares (ridge when ``ridge > 0``) from the Gram.

    Columns are scaled to unit RMS first; the penalty ``ridge · n · ‖diag(s) θ‖²`` acts on
    the scaled coefficients of the ``penalize`` columns (default: all). Columns outside
    ``active`` are fixed at zero. Solved by Cholesky of the scaled Gram. With
    ``standardize=False`` the penalty is the textbook ``ridge · n · ‖θ‖²`` on the raw
    coefficients (``θ = (ZᵀZ + λI)⁻¹ZᵀY`` for ``λ = ridge · n``).

    Returns
    -------
    numpy.ndarray, shape (p, m)
    """
    p = g.zz.shape[0]
    act = np.ones(p, bool) if active is None else np.asarray(active, bool)
    coef = np.zeros((p, g.zy.shape[1]))
    if not act.any():
        return coef
    s = column_scales(g)[act] if standardize else np.ones(int(act.sum()))
    a = g.zz[np.ix_(act, act)] / np.outer(s, s)
    b = g.zy[act] / s[:, None]
    if ridge > 0:
        pen = np.ones(p, bool) if penalize is None else np.asarray(penalize, bool)
        a = a + ridge * g.n * np.diag(pen[act].astype(float))
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):  # (as scipy.linalg refused)
        raise ValueError("array must not contain infs or NaNs")
    try:  # (Cholesky, then the two triangular systems; least squares if not definite)
        low = np.linalg.cholesky(a)
        sol = np.linalg.solve(low.T, np.linalg.solve(low, b))
    except np.linalg.LinAlgError:
        sol, *_ = np.linalg.lstsq(a, b, rcond=None)
    coef[act] = sol / s[:, None]
    return coef


def hac_covariance(reg: Regression, coef: np.ndarray, bread: np.ndarray | list[np.ndarray],
                   active: np.ndarray | None = None, lags: int | None = None
                   ) -> tuple[np.ndarray, np.ndarray, int]:
    """Newey–West covariance of the coefficients, per output.

    Parameters
    ----------
    reg : Regression
    coef : numpy.ndarray, shape (p, m)
    bread : numpy.ndarray (p, p) or list of them per output
        The inverse (penalised) Gram on the active columns (``G⁻¹`` for least squares).
    active : numpy.ndarray of bool, shape (p, m), optional
    lags : int, optional
        Bartlett lags; default chosen from the data (at least Newey–West's
        ``4 (n/100)^{2/9}``, more while the scores stay correlated, at most a tenth of the
        shortest segment's rows).

    Returns
    -------
    cov : numpy.ndarray, shape (m, p, p)
    sigma : numpy.ndarray, shape (m,)
        Residual standard deviation.
    lags : int
    """
    z, y = reg.z, reg.y
    p, m = coef.shape
    act = np.ones((p, m), bool) if active is None else np.asarray(active, bool)
    resid = y - z @ coef
    seg_rows: dict[int, list[int]] = {}
    for a, b, si, _ in reg.blocks:
        r = seg_rows.setdefault(int(si), [int(a), int(b)])
        r[0], r[1] = min(r[0], int(a)), max(r[1], int(b))
    spans = sorted((v[0], v[1]) for v in seg_rows.values())
    shortest = min(b - a for a, b in spans)
    cov = np.full((m, p, p), np.nan)
    sigma = np.empty(m)
    used = 0
    for i in range(m):
        cols = np.flatnonzero(act[:, i])
        k = len(cols)
        e = resid[:, i]
        dof = max(reg.n - k, 1)
        sigma[i] = np.sqrt(float(e @ e) / dof)
        if k == 0:
            continue
        scores = z[:, cols] * e[:, None]
        L = lags
        if L is None:
            L = _auto_lags(scores, spans, shortest)
        used = max(used, L)
        meat = np.zeros((k, k))
        for a, b in spans:
            meat += bartlett_meat(scores[a:b], L)
        meat *= reg.n / dof
        br = bread[i] if isinstance(bread, list) else bread
        br = br if br.shape[0] == k else br[np.ix_(cols, cols)]
        cov[i][np.ix_(cols, cols)] = br @ meat @ br
    return cov, sigma, used


def _auto_lags(scores: np.ndarray, spans: Sequence[tuple[int, int]], shortest: int) -> int:
    """Bartlett bandwidth: the lag where the normalised score autocorrelation has decayed."""
    n = scores.shape[0]
    base = int(np.ceil(4 * (n / 100.0) ** (2.0 / 9.0)))
    cap = max(1, min(shortest // 10, 4000))
    sd = scores.std(axis=0)
    u = (scores / np.where(sd > 0, sd, 1.0)).sum(axis=1)
    a, b = max(spans, key=lambda s: s[1] - s[0])
    u = u[a:b] - u[a:b].mean()
    nfft = 1 << int(np.ceil(np.log2(2 * len(u))))
    f = np.fft.rfft(u, nfft)
    acf = np.fft.irfft(f * np.conj(f), nfft)[: len(u)]
    acf = acf / acf[0] if acf[0] > 0 else acf
    band = 2.0 / np.sqrt(len(u))
    inside = np.flatnonzero(np.abs(acf[1:]) < band)
    first = int(inside[0]) + 1 if inside.size else cap
    return int(min(cap, max(base, 2 * first)))


def _subsegment(reg: Regression, block: np.ndarray) -> Segment:
    """The samples a block's rows use, as a Segment (for rollout scoring)."""
    a, b, si, start = (int(v) for v in block)
    seg = reg.segments[si]
    lo = max(0, start - reg.structure.lead)
    hi = min(len(seg), start + (b - a) + reg.structure.trail)
    return seg.cut(lo, hi, meta=dict(seg.meta))


def rollout_fit(model: Model, segment: Segment, horizon: int | None = None) -> float:
    """Fit % (mean over outputs) of a free run (``horizon=None``) or k-step prediction.

    ``100 (1 − ‖y − ŷ‖ / ‖y − ȳ‖)``, the same measure :mod:`mavsid.validation` reports.
    """
    if horizon is None:
        yh = model.simulate(segment)
    else:
        yh = model.predict(segment, horizon=horizon)
    y = np.column_stack([segment.states[:, segment.state_names.index(s)]
                         for s in model.state_names])
    ok = np.all(np.isfinite(yh), axis=1)
    if ok.sum() < 2:
        return -np.inf
    err = np.linalg.norm(y[ok] - yh[ok], axis=0)
    den = np.linalg.norm(y[ok] - y[ok].mean(axis=0), axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        fit = 100.0 * (1.0 - err / den)
    fit = np.where(np.isfinite(fit), fit, -1e6)
    return float(np.mean(fit))


class Estimator:
    """Base of the estimators (scikit-learn conventions: ``__init__`` stores, ``fit``
    learns attributes ending in ``_`` and returns ``self``).

    Parameters
    ----------
    structure : Structure, optional
        Default structure for :meth:`fit`.
    alpha : float or "cv"
        Regularisation weight (relative, per row, on unit-RMS columns); ``"cv"``: chosen from
        ``alphas`` by cross-validation across blocks scored by rollout.
    alphas : sequence of float
        Candidates for ``alpha="cv"``.
    cv_horizon : int, optional
        Rollout horizon (samples) of the CV score; None: free run.
    n_bootstrap : int
        Bootstrap replicates over blocks (0: none).
    hac : bool
        Newey–West correction of the covariance (else ``σ²G⁻¹``).
    min_blocks : int
        Segments are cut into at least this many blocks for CV and bootstrap.
    max_condition : float
        Condition number above which the fit is refused as unidentifiable.
    random_state : int
        Seed of the bootstrap.
    """

    name = "base"
    penalised = False

    def __init__(self, structure: Structure | None = None, *, alpha: float | str = 0.0,
                 alphas: Sequence[float] = tuple(10.0 ** np.arange(-9.0, 0.0)),
                 cv_horizon: int | None = None, n_bootstrap: int = 100, hac: bool = True,
                 min_blocks: int = 10, max_condition: float = 1e10,
                 random_state: int = 0) -> None:
        if isinstance(alpha, str):
            if alpha != "cv":
                raise ConfigError(f"alpha must be a number or 'cv', got {alpha!r}")
        elif not (finite_number(alpha) and alpha >= 0):
            raise ConfigError(f"alpha must be a finite number >= 0 or 'cv', got {alpha!r}")
        if not (whole_number(n_bootstrap) and n_bootstrap >= 0):
            raise ConfigError(f"n_bootstrap must be a whole number >= 0, got {n_bootstrap!r}")
        self.structure = structure
        self.alpha = alpha
        self.alphas = alphas
        self.cv_horizon = cv_horizon
        self.n_bootstrap = n_bootstrap
        self.hac = hac
        self.min_blocks = min_blocks
        self.max_condition = max_condition
        self.random_state = random_state

    # -- the one hook a solver overrides
    def _solve(self, g: Gram, alpha: float, structure: Structure) -> np.ndarray:
        """Coefficients (p, m) from the Gram; zero where a term is removed."""
        raise NotImplementedError

    def _bread(self, g: Gram, coef: np.ndarray, alpha: float, structure: Structure
               ) -> list[np.ndarray]:
        """Per output, the inverse (penalised) Gram on the active columns."""
        out = []
        for i in range(coef.shape[1]):
            act = coef[:, i] != 0
            if not act.any():
                out.append(np.zeros((0, 0)))
                continue
            a = g.zz[np.ix_(act, act)]
            if alpha > 0 and self.penalised:
                s = column_scales(g)[act]
                pen = penalised(structure)[act]
                a = a + alpha * g.n * np.diag(s**2 * pen)
            out.append(np.linalg.pinv(a, hermitian=True))
        return out

    def _settings(self) -> dict[str, Any]:
        return {k: v for k, v in vars(self).items()
                if not k.endswith("_") and not k.startswith("_") and k != "structure"}

    def fit(self, segments: Sequence[Segment], structure: Structure | None = None
            ) -> Estimator:
        """Fit on the stacked rows of ``segments``; returns ``self``.

        Learned attributes: ``coef_`` (p, m), ``stderr_`` (p, m), ``stderr_hac_``,
        ``stderr_bootstrap_``, ``sigma_`` (m,), ``alpha_``, ``cv_scores_``, ``hac_lags_``,
        ``n_rows_``, ``model_`` (:class:`~mavsid.estimators.model.Model`).
        """
        st = structure or self.structure
        if st is None:
            raise ConfigError(f"{type(self).__name__}.fit needs a structure")
        segments = list(segments)
        reg = stack(segments, st, min_blocks=self.min_blocks)
        grams = block_grams(reg)
        g = sum(grams[1:], grams[0])
        check_identifiable(reg, g, self.max_condition)
        self.cv_scores_: dict[float, float] = {}
        if isinstance(self.alpha, str):  # ("cv": checked when made)
            alpha = self._cross_validate(reg, grams, g)
        else:
            alpha = float(self.alpha)
        self.alpha_ = alpha
        coef = self._solve(g, alpha, st)
        if not np.all(np.isfinite(coef)):
            raise SolverError(f"{self.name}: solver returned non-finite coefficients")
        bread = self._bread(g, coef, alpha, st)
        active = coef != 0
        if self.hac:
            cov, sigma, lags = hac_covariance(reg, coef, bread, active)
        else:
            resid = reg.y - reg.z @ coef
            dof = np.maximum(reg.n - active.sum(axis=0), 1)
            sigma = np.sqrt((resid**2).sum(axis=0) / dof)
            cov = np.full((coef.shape[1], coef.shape[0], coef.shape[0]), np.nan)
            for i in range(coef.shape[1]):
                cols = np.flatnonzero(active[:, i])
                cov[i][np.ix_(cols, cols)] = sigma[i] ** 2 * bread[i]
            lags = 0
        se_hac = np.sqrt(np.clip(np.stack([np.diag(c) for c in cov], axis=1), 0, None))
        se_boot = self._bootstrap(grams, alpha, st, coef.shape)
        se = se_hac if se_boot is None else np.fmax(se_hac, se_boot)
        se = np.where(active, se, np.nan)
        self.coef_ = coef
        self.stderr_hac_ = se_hac
        self.stderr_bootstrap_ = se_boot
        self.stderr_ = se
        self.sigma_ = sigma
        self.hac_lags_ = lags
        self.n_rows_ = reg.n
        self.model_ = Model.of(
            st, coef, float(segments[0].dt), covariance=cov, coef_stderr=se, sigma=sigma,
            provenance=provenance(
                segments, estimator=self.name, alpha_selected=alpha, rows=reg.n,
                blocks=len(reg.blocks), hac_lags=lags, derivative=st.derivative
                if st.continuous else None, hyperparameters=self._settings()),
        )
        return self

    def _bootstrap(self, grams: list[Gram], alpha: float, st: Structure,
                   shape: tuple[int, ...]) -> np.ndarray | None:
        k = len(grams)
        if self.n_bootstrap <= 0 or k < 5:
            return None
        rng = np.random.default_rng(self.random_state)
        reps = []
        for _ in range(self.n_bootstrap):
            w = rng.multinomial(k, np.full(k, 1.0 / k))
            gs = [grams[i].scaled(float(w[i])) for i in np.flatnonzero(w)]
            gb = sum(gs[1:], gs[0])
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    reps.append(self._solve(gb, alpha, st))
            except (SolverError, np.linalg.LinAlgError, NoExcitationError):
                continue
        if len(reps) < max(5, self.n_bootstrap // 2):
            warnings.warn(f"{self.name}: bootstrap failed on most replicates; standard errors "
                          "from the covariance only", DataQualityWarning, stacklevel=3)
            return None
        arr = np.asarray(reps)
        return np.asarray(arr.std(axis=0, ddof=1))

    def _cross_validate(self, reg: Regression, grams: list[Gram], g: Gram) -> float:
        """Choose alpha by leave-one-block-out rollout fit %, averaged over blocks."""
        st = reg.structure
        if len(grams) < 2:
            raise NoExcitationError("cross-validation needs at least two blocks of data")
        subs = [_subsegment(reg, b) for b in reg.blocks]
        best, best_score = float(self.alphas[0]), -np.inf
        for alpha in self.alphas:
            scores = []
            for i, gi in enumerate(grams):
                try:
                    coef = self._solve(g - gi, float(alpha), st)
                except (SolverError, np.linalg.LinAlgError):
                    scores.append(-np.inf)
                    continue
                m = Model.of(st, coef, subs[i].dt)
                with np.errstate(all="ignore"):
                    scores.append(rollout_fit(m, subs[i], self.cv_horizon))
            score = float(np.mean(scores))
            self.cv_scores_[float(alpha)] = score
            if score > best_score:
                best, best_score = float(alpha), score
        return best

    # conveniences: the fitted model's interface
    def simulate(self, segment: Segment) -> np.ndarray:
        """Free run of the fitted model (see :meth:`Model.simulate`)."""
        return self.model_.simulate(segment)

    def predict(self, segment: Segment, horizon: int = 1) -> np.ndarray:
        """k-step prediction of the fitted model (see :meth:`Model.predict`)."""
        return self.model_.predict(segment, horizon)

    def score(self, segment: Segment, horizon: int | None = None) -> float:
        """Fit % of a free run (or ``horizon``-step prediction) on ``segment``."""
        return rollout_fit(self.model_, segment, horizon)
