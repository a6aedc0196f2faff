"""Output-error refinement: adjust a fitted model so that its *free run* follows the data.

Equation-error estimators (least squares on ``x[k+1]`` from the measured ``x[k]``) weigh every
frequency alike and are biased when the measured state carries sensor noise; the output-error
estimate minimises ``Σ‖y − ŷ_free‖²`` over the training segments, each simulated from its first
sample with the measured inputs only — the same quantity validation reports as fit %. It
starts from the equation-error solution and keeps its structure (terms an L1 or thresholded
fit removed stay removed).

Uncertainty: ``Cov θ = (JᵀJ)⁻¹ S (JᵀJ)⁻¹`` with ``J`` the Jacobian of the free-run residuals and
``S`` the Newey–West long-run covariance of the scores ``Jₜeₜ`` (free-run residuals are strongly
coloured, so ``σ²(JᵀJ)⁻¹`` alone would be far too optimistic).

Examples
--------
>>> import numpy as np
>>> from mavsid.data import Segment
>>> from mavsid.estimators.model import Model
>>> rng = np.random.default_rng(0)
>>> u = np.repeat(rng.standard_normal(100), 10)[:, None] * 0.1
>>> p = np.zeros(1000)
>>> for k in range(999):
...     p[k + 1] = 0.98 * p[k] + 0.5 * u[k, 0]
>>> seg = Segment(np.arange(1000) * 0.01, p[:, None], u, ("p",), ("u_roll",), 0.01, "roll",
...               "scan")
>>> start = Model(("p",), ("u_roll",), ("p", "u_roll"), np.array([[0.97], [0.45]]), 0.01)
>>> refined = refine_output_error(start, [seg])
>>> np.round(refined.coef.ravel(), 6).tolist()
[0.98, 0.5]
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from scipy import optimize

from mavsid.data import Segment
from mavsid.errors import ConfigError, SolverError
from mavsid.estimators._base import hac_covariance
from mavsid.estimators.model import Model
from mavsid.estimators.regressors import Regression

__all__ = ["refine_output_error"]


def _measured(model: Model, seg: Segment) -> np.ndarray:
    return np.column_stack([seg.states[:, seg.state_names.index(s)] for s in model.state_names])


def refine_output_error(model: Model, segments: Sequence[Segment], max_nfev: int = 100,
                        hac: bool = True, covariance: str | None = None,
                        bounds: tuple[np.ndarray, np.ndarray] | None = None) -> Model:
    """Refine ``model``'s non-zero coefficients by minimising the free-run error.

    Parameters
    ----------
    model : Model
        Starting point (e.g. a least-squares fit), also giving the structure.
    segments : sequence of Segment
        Training segments; each is simulated from its own first sample.
    max_nfev : int
        Limit on residual evaluations of the trust-region solver.
    hac : bool
        Newey–West correction of the covariance (when ``covariance`` is not given).
    covariance : {"newey-west", "cramer-rao"}, optional
        ``"cramer-rao"``: the Cramér–Rao bound for white Gaussian output noise,
        ``(Σₜ Jₜᵀ R̂⁻¹ Jₜ)⁻¹`` with ``R̂`` the diagonal of the residual variances per output
        (what the output-error literature reports; too optimistic when the residuals are
        coloured). ``"newey-west"``: the sandwich above. Default: from ``hac``.
    bounds : (low, high) arrays shaped like ``model.coef``, optional
        Bounds kept during the refinement (those of a bounded L1 fit, for instance).

    Returns
    -------
    Model
        With refined ``coef``, ``covariance``, ``coef_stderr``, ``sigma`` and the refinement
        recorded in ``provenance['refine']``.
    """
    segments = list(segments)
    if covariance is None:
        covariance = "newey-west" if hac else "plain"
    if covariance not in ("newey-west", "cramer-rao", "plain"):
        raise ConfigError(f"covariance must be 'newey-west' or 'cramer-rao', got {covariance!r}")
    active = model.coef != 0
    idx = np.flatnonzero(active.ravel())
    ys = [_measured(model, s) for s in segments]
    scale = np.concatenate(ys).std(axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    big = 1e3

    def build(theta: np.ndarray) -> Model:
        coef = np.zeros(model.coef.size)
        coef[idx] = theta
        return replace(model, coef=coef.reshape(model.coef.shape), covariance=None,
                       coef_stderr=None)

    # the inputs are filtered and delayed once: only the coefficients change
    variables = [model._measured(s)[1] for s in segments]

    def residuals(theta: np.ndarray) -> np.ndarray:
        m = build(theta)
        out = []
        with np.errstate(all="ignore"):
            for y, var in zip(ys, variables, strict=True):
                e = (m._free_run(y[0], var, len(y)) - y) / scale
                out.append(np.where(np.isfinite(e), np.clip(e, -big, big), big).ravel())
        return np.concatenate(out)

    theta0 = model.coef.ravel()[idx]
    lo, hi = np.full(len(idx), -np.inf), np.full(len(idx), np.inf)
    if bounds is not None:
        lo = np.asarray(bounds[0], float).reshape(model.coef.shape).ravel()[idx]
        hi = np.asarray(bounds[1], float).reshape(model.coef.shape).ravel()[idx]
        theta0 = np.clip(theta0, lo, hi)
    x_scale = np.where(np.abs(theta0) > 0, np.abs(theta0), 1.0)
    try:
        sol = optimize.least_squares(residuals, theta0, x_scale=x_scale, max_nfev=max_nfev,
                                     method="trf",
                                     bounds=(lo, hi) if bounds is not None else (-np.inf, np.inf))
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise SolverError(f"output-error refinement failed: {exc}") from None
    start_cost = 0.5 * float(np.sum(residuals(theta0) ** 2))
    if not np.all(np.isfinite(sol.x)) or sol.cost > start_cost:
        raise SolverError("output-error refinement diverged (the starting model's free run "
                          "is unstable or the data do not constrain it)")
    refined = build(sol.x)
    # sandwich covariance from the Jacobian of the scaled free-run residuals (the scaling
    # cancels between bread and meat), then split into per-output blocks
    m_out = len(model.state_names)
    jac = np.asarray(sol.jac)
    e = sol.fun
    spans, start = [], 0
    for i, s in enumerate(segments):
        spans.append((start, start + len(s) * m_out, i, 0))
        start += len(s) * m_out
    pseudo = Regression(z=jac, y=(e + jac @ sol.x)[:, None], structure=model.structure,
                        blocks=np.asarray(spans, dtype=int), segments=tuple(segments))
    jtj = jac.T @ jac
    bread = np.linalg.pinv(jtj, hermitian=True)
    if covariance == "newey-west":
        cov_s, sig, lags = hac_covariance(pseudo, sol.x[:, None], bread)
        cov_theta = cov_s[0]
    elif covariance == "cramer-rao":
        # rows of sol.fun are (sample, output) interleaved: output i is row % m_out
        out_of_row = np.arange(len(e)) % m_out
        dof = max(len(e) - len(idx), 1) / m_out
        var = np.array([float(e[out_of_row == i] @ e[out_of_row == i]) / dof
                        for i in range(m_out)])
        w = 1.0 / np.where(var > 0, var, np.inf)[out_of_row]
        cov_theta = np.linalg.pinv(jac.T @ (jac * w[:, None]), hermitian=True)
        lags = 0
    else:
        dof = max(len(e) - len(idx), 1)
        sig = np.array([np.sqrt(float(e @ e) / dof)])
        cov_theta, lags = sig[0] ** 2 * bread, 0
    p, m = model.coef.shape
    cov = np.full((m, p, p), np.nan)
    pos = {int(k): n for n, k in enumerate(idx)}
    for i in range(m):
        cols = [j for j in range(p) if active[j, i]]
        sel = [pos[j * m + i] for j in cols]
        cov[i][np.ix_(cols, cols)] = cov_theta[np.ix_(sel, sel)]
    se = np.sqrt(np.clip(np.stack([np.diag(c) for c in cov], axis=1), 0, None))
    se = np.where(active, se, np.nan)
    resid = np.concatenate([refined._free_run(y[0], var, len(y)) - y
                            for y, var in zip(ys, variables, strict=True)])
    sigma = np.sqrt(np.mean(resid**2, axis=0))
    prov = dict(model.provenance)
    prov["refine"] = {"method": "output-error", "nfev": int(sol.nfev), "hac_lags": int(lags),
                      "covariance": covariance,
                      "cost_start": start_cost, "cost": float(sol.cost)}
    return replace(refined, covariance=cov, coef_stderr=se, sigma=sigma, provenance=prov)
