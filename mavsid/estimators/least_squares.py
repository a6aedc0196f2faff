"""Least squares, ridge and sequentially thresholded least squares, all on the Gram.

Examples
--------
>>> import numpy as np
>>> from mavsid.data import Segment
>>> from mavsid.estimators.regressors import Structure
>>> rng = np.random.default_rng(1)
>>> u = rng.standard_normal(400)
>>> p = np.zeros(400)
>>> for k in range(399):
...     p[k + 1] = 0.9 * p[k] + 0.2 * u[k]
>>> seg = Segment(np.arange(400) * 0.01, p[:, None], u[:, None], ("p",), ("u_roll",), 0.01,
...               "roll", "scan")
>>> est = LeastSquares(Structure(("p",), ("p", "u_roll")), n_bootstrap=0).fit([seg])
>>> np.round(est.coef_.ravel(), 6).tolist()
[0.9, 0.2]
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from mavsid.errors import ConfigError
from mavsid.estimators.base import Estimator, Gram, column_scales, penalised, solve
from mavsid.estimators.regressors import Structure

__all__ = ["STLSQ", "LeastSquares", "Ridge", "thresholded"]


class LeastSquares(Estimator):
    """Ordinary least squares (Cholesky of the unit-RMS-scaled Gram).

    See :class:`~mavsid.estimators.base.Estimator` for the shared parameters.
    """

    name = "ls"

    def _solve(self, g: Gram, alpha: float, structure: Structure) -> np.ndarray:
        return solve(g)


class Ridge(Estimator):
    """Ridge regression: ``min ‖y − Zθ‖² + α n ‖diag(s)θ‖²`` (bias not penalised).

    ``alpha="cv"`` (the default) chooses α by cross-validation across blocks, scored by
    rollout (free run unless ``cv_horizon`` is given).
    """

    name = "ridge"
    penalised = True

    def __init__(self, structure: Structure | None = None, *, alpha: float | str = "cv",
                 **kwargs: object) -> None:
        super().__init__(structure, alpha=alpha, **kwargs)  # type: ignore[arg-type]

    def _solve(self, g: Gram, alpha: float, structure: Structure) -> np.ndarray:
        return solve(g, ridge=alpha, penalize=penalised(structure))


class STLSQ(Estimator):
    """Sequentially thresholded least squares (SINDy) on the Gram.

    Terms whose *standardised* coefficient ``|θⱼ| rms(zⱼ) / rms(y)`` falls below
    ``threshold`` are removed and the rest refitted (ridge ``alpha``), until nothing changes.

    Parameters
    ----------
    threshold : float
        Relative threshold (dimensionless).
    keep : sequence of str
        Features never removed (e.g. the inputs whose effectiveness is wanted).
    max_iter : int
    """

    name = "stlsq"
    penalised = True

    def __init__(self, structure: Structure | None = None, *, threshold: float = 0.05,
                 keep: Sequence[str] = (), max_iter: int = 20, alpha: float | str = 0.0,
                 **kwargs: object) -> None:
        super().__init__(structure, alpha=alpha, **kwargs)  # type: ignore[arg-type]
        self.threshold = threshold
        self.keep = tuple(keep)
        self.max_iter = max_iter

    def _solve(self, g: Gram, alpha: float, structure: Structure) -> np.ndarray:
        unknown = set(self.keep) - set(structure.features)
        if unknown:
            raise ConfigError(f"STLSQ keep= names unknown features {sorted(unknown)}")
        keep = np.array([f in self.keep for f in structure.features])
        return thresholded(g, self.threshold, keep, alpha, penalised(structure),
                           self.max_iter)


def thresholded(g: Gram, threshold: float, keep: np.ndarray | None = None, alpha: float = 0.0,
                penalize: np.ndarray | None = None, max_iter: int = 20,
                standardize: bool = True) -> np.ndarray:
    """Sequentially thresholded least squares on a Gram, output by output.

    A term whose standardised coefficient ``|θⱼ| rms(zⱼ) / rms(y)`` is below ``threshold``
    is removed and the rest refitted, until nothing changes; ``keep`` terms stay. ``alpha``
    is a ridge weight as in :func:`~mavsid.estimators.base.solve` (``standardize`` too).

    Returns
    -------
    numpy.ndarray, shape (p, m)
        Zero exactly where a term was removed.
    """
    p, m = g.zy.shape
    s = column_scales(g)
    ys = np.sqrt(np.clip(np.diag(g.yy), 0, None) / max(g.n, 1))
    ys = np.where(ys > 0, ys, 1.0)
    keep = np.zeros(p, bool) if keep is None else np.asarray(keep, bool)
    out = np.zeros((p, m))
    for i in range(m):
        gi = Gram(g.zz, g.zy[:, i : i + 1], g.yy[i : i + 1, i : i + 1], g.n)
        act = np.ones(p, bool)
        coef = solve(gi, alpha, penalize, act, standardize)
        for _ in range(max_iter):
            new = act & ((np.abs(coef[:, 0]) * s / ys[i] >= threshold) | keep)
            if np.array_equal(new, act):
                break
            act = new
            coef = solve(gi, alpha, penalize, act, standardize)
        out[:, i] = coef[:, 0]
    return out
