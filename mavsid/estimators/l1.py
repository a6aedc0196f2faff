"""L1 (lasso) and elastic net through cvxpy (CLARABEL), with bounds and sign constraints.

The problem is posed on the Gram's square root, not on the rows, so that its size is the
number of features whatever the number of samples::

    min_Θ  ‖R Θs − Q‖²_F / n + α (ρ ‖Θs‖₁ + (1 − ρ)/2 ‖Θs‖²_F)   (bias not penalised)

with ``Θs`` the coefficients of the unit-RMS columns, ``RᵀR`` the scaled Gram and
``RᵀQ = ZᵀY`` (scaled), which equals ``‖Y − ZΘ‖²`` up to a constant.

Examples
--------
>>> import numpy as np
>>> from mavsid.estimators.base import Gram
>>> from mavsid.estimators.regressors import Structure
>>> rng = np.random.default_rng(0)
>>> z = rng.standard_normal((500, 3))
>>> y = z @ np.array([[1.0], [0.0], [-2.0]])
>>> st = Structure(("p",), ("p", "q", "r"))
>>> coef = Lasso(alpha=1e-3)._solve(Gram.of(z, y), 1e-3, st)
>>> np.round(coef.ravel(), 2).tolist()
[1.0, 0.0, -2.0]
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from mavsid.errors import ConfigError, SolverError
from mavsid.estimators.base import Estimator, Gram, column_scales, param_names, penalised
from mavsid.estimators.regressors import Structure

__all__ = ["ElasticNet", "Lasso", "gram_sqrt"]


def gram_sqrt(zz: np.ndarray, zy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``R, Q`` with ``RᵀR = zz`` and ``RᵀQ = zy`` (eigen-square-root; works when singular)."""
    lam, vec = np.linalg.eigh(zz)
    lam = np.clip(lam, 0, None)
    tol = lam.max() * 1e-13 if lam.size else 0.0
    keep = lam > tol
    r = np.sqrt(lam[keep])[:, None] * vec[:, keep].T
    q = (vec[:, keep].T @ zy) / np.sqrt(lam[keep])[:, None]
    return r, q


class ElasticNet(Estimator):
    """Elastic net / lasso via cvxpy on the Gram.

    Parameters
    ----------
    alpha : float or "cv"
        Penalty weight (per row, on unit-RMS columns); ``"cv"``: by rollout cross-validation.
    l1_ratio : float
        ρ: 1 is the lasso, 0 ridge.
    bounds : Mapping[str, tuple[float, float]]
        Parameter name (e.g. ``"B_d[p,u_roll]"``) -> (low, high) on the raw coefficient.
    signs : Mapping[str, int]
        Parameter name -> +1 (≥ 0) or −1 (≤ 0).
    zero_tol : float
        A term whose contribution (coefficient × its column's RMS) is below ``zero_tol`` ×
        the output's RMS is set exactly to zero (the interior-point solver's numerical zeros).
    solver : str
        cvxpy solver (CLARABEL by default).
    """

    name = "elasticnet"
    penalised = True

    def __init__(self, structure: Structure | None = None, *, alpha: float | str = "cv",
                 l1_ratio: float = 0.5, bounds: Mapping[str, tuple[float, float]] | None = None,
                 signs: Mapping[str, int] | None = None, zero_tol: float = 1e-4,
                 solver: str = "CLARABEL", n_bootstrap: int = 0, **kwargs: object) -> None:
        super().__init__(structure, alpha=alpha, n_bootstrap=n_bootstrap,
                         **kwargs)  # type: ignore[arg-type]
        self.l1_ratio = l1_ratio
        self.bounds = dict(bounds or {})
        self.signs = dict(signs or {})
        self.zero_tol = zero_tol
        self.solver = solver

    def _constraints(self, structure: Structure) -> tuple[np.ndarray, np.ndarray]:
        names = param_names(structure)
        flat = {n: (j, i) for j, row in enumerate(names) for i, n in enumerate(row)}
        p, m = len(names), len(structure.outputs)
        lo, hi = np.full((p, m), -np.inf), np.full((p, m), np.inf)
        for name, (a, b) in self.bounds.items():
            if name not in flat:
                raise ConfigError(f"bound on unknown parameter {name!r}; known: {sorted(flat)}")
            lo[flat[name]], hi[flat[name]] = max(lo[flat[name]], a), min(hi[flat[name]], b)
        for name, sgn in self.signs.items():
            if name not in flat:
                raise ConfigError(f"sign on unknown parameter {name!r}; known: {sorted(flat)}")
            if sgn > 0:
                lo[flat[name]] = max(lo[flat[name]], 0.0)
            elif sgn < 0:
                hi[flat[name]] = min(hi[flat[name]], 0.0)
        return lo, hi

    def _problem(self, p: int, m: int, pen: np.ndarray, lo_mask: np.ndarray,
                 hi_mask: np.ndarray) -> tuple[Any, dict[str, Any]]:
        """The parametrised cvxpy problem for this shape (built once, then re-solved: cvxpy
        caches the canonicalisation of a DPP problem)."""
        import cvxpy as cp

        key = (p, m, pen.tobytes(), lo_mask.tobytes(), hi_mask.tobytes(), self.l1_ratio)
        cache: dict[Any, tuple[Any, dict[str, Any]]] = self.__dict__.setdefault("_cvx", {})
        if key in cache:
            return cache[key]
        th = cp.Variable((p, m))
        par = {"r": cp.Parameter((p, p)), "q": cp.Parameter((p, m)),
               "alpha": cp.Parameter(nonneg=True), "lo": cp.Parameter((p, m)),
               "hi": cp.Parameter((p, m)), "th": th}
        rho = float(self.l1_ratio)
        weighted = cp.multiply(pen[:, None] * np.ones((1, m)), th)
        obj = cp.sum_squares(par["r"] @ th - par["q"]) + par["alpha"] * (
            rho * cp.sum(cp.abs(weighted)) + 0.5 * (1 - rho) * cp.sum_squares(weighted))
        cons = []
        if lo_mask.any():
            cons.append(cp.multiply(lo_mask.astype(float), th) >= par["lo"])
        if hi_mask.any():
            cons.append(cp.multiply(hi_mask.astype(float), th) <= par["hi"])
        cache[key] = (cp.Problem(cp.Minimize(obj), cons), par)
        return cache[key]

    def _solve(self, g: Gram, alpha: float, structure: Structure) -> np.ndarray:
        import cvxpy as cp

        p, m = g.zy.shape
        s = column_scales(g)
        zz = g.zz / np.outer(s, s) / g.n
        zy = g.zy / s[:, None] / g.n
        r, q = gram_sqrt(zz, zy)
        r_full, q_full = np.zeros((p, p)), np.zeros((p, m))
        r_full[: r.shape[0]], q_full[: q.shape[0]] = r, q
        pen = penalised(structure).astype(float)
        lo, hi = self._constraints(structure)
        lo_s, hi_s = lo * s[:, None], hi * s[:, None]
        lo_mask, hi_mask = np.isfinite(lo_s), np.isfinite(hi_s)
        prob, par = self._problem(p, m, pen, lo_mask, hi_mask)
        par["r"].value, par["q"].value = r_full, q_full
        par["alpha"].value = max(float(alpha), 0.0)
        par["lo"].value = np.where(lo_mask, lo_s, 0.0)
        par["hi"].value = np.where(hi_mask, hi_s, 0.0)
        try:
            prob.solve(solver=self.solver)
        except cp.error.SolverError as exc:
            raise SolverError(f"{self.name}: {self.solver} failed: {exc}") from None
        th = par["th"]
        if th.value is None or prob.status not in ("optimal", "optimal_inaccurate"):
            raise SolverError(f"{self.name}: {self.solver} status {prob.status}")
        val = np.array(th.value)
        ys = np.sqrt(np.clip(np.diag(g.yy), 0, None) / g.n)
        val[np.abs(val) < self.zero_tol * np.where(ys > 0, ys, 1.0)[None, :]] = 0.0
        return val / s[:, None]


class Lasso(ElasticNet):
    """The lasso: :class:`ElasticNet` with ``l1_ratio=1``."""

    name = "l1"

    def __init__(self, structure: Structure | None = None, *, alpha: float | str = "cv",
                 **kwargs: object) -> None:
        kwargs.setdefault("l1_ratio", 1.0)
        super().__init__(structure, alpha=alpha, **kwargs)  # type: ignore[arg-type]
