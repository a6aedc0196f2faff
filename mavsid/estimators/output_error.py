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

from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace

import numpy as np

from mavsid.data import Segment
from mavsid.errors import ConfigError, SolverError
from mavsid.estimators import library
from mavsid.estimators.base import hac_covariance
from mavsid.estimators.model import Model
from mavsid.estimators.regressors import Regression
from mavsid.numerics.filters import lfilter

__all__ = ["output_error_coef", "refine_output_error"]


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
        Limit on residual evaluations of the solver (``scipy.optimize.least_squares``;
        those of its finite-difference Jacobians not counted).
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
    x, e, jac, nfev, cost = _solve(residuals, theta0, lo, hi, max_nfev)
    start_cost = 0.5 * float(np.sum(residuals(theta0) ** 2))
    if not np.all(np.isfinite(x)) or cost > start_cost:
        raise SolverError("output-error refinement diverged (the starting model's free run "
                          "is unstable or the data do not constrain it)")
    refined = build(x)
    # sandwich covariance from the Jacobian of the scaled free-run residuals (the scaling
    # cancels between bread and meat), then split into per-output blocks
    m_out = len(model.state_names)
    spans, start = [], 0
    for i, s in enumerate(segments):
        spans.append((start, start + len(s) * m_out, i, 0))
        start += len(s) * m_out
    pseudo = Regression(z=jac, y=(e + jac @ x)[:, None], structure=model.structure,
                        blocks=np.asarray(spans, dtype=int), segments=tuple(segments))
    jtj = jac.T @ jac
    bread = np.linalg.pinv(jtj, hermitian=True)
    if covariance == "newey-west":
        cov_s, sig, lags = hac_covariance(pseudo, x[:, None], bread)
        cov_theta = cov_s[0]
    elif covariance == "cramer-rao":
        # rows of e are (sample, output) interleaved: output i is row % m_out
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
    prov["refine"] = {"method": "output-error", "nfev": nfev, "hac_lags": int(lags),
                      "covariance": covariance, "cost_start": start_cost, "cost": cost}
    return replace(refined, covariance=cov, coef_stderr=se, sigma=sigma, provenance=prov)


def _solve(residuals: Callable[[np.ndarray], np.ndarray], theta0: np.ndarray,
           lo: np.ndarray, hi: np.ndarray, max_nfev: int
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, float]:
    """``scipy.optimize.least_squares`` (trust-region reflective, forward-difference
    Jacobian, each coefficient scaled by its start) of ``residuals`` from ``theta0`` within
    ``lo <= θ <= hi``; a coefficient whose bounds meet stays there (its Jacobian column
    zero). Returns the point, its residuals and Jacobian, the residual evaluations (the
    Jacobians' not counted) and half the sum of squares; SolverError when the solver
    refuses the start (residuals not finite)."""
    from scipy import optimize

    theta0 = np.clip(theta0, lo, hi)
    free = lo < hi
    if not free.any():
        e = residuals(theta0)
        return theta0, e, np.zeros((e.size, theta0.size)), 1, 0.5 * float(e @ e)

    def full(z: np.ndarray) -> np.ndarray:
        theta = theta0.copy()
        theta[free] = z
        return theta

    z0 = theta0[free]
    try:
        sol = optimize.least_squares(lambda z: residuals(full(z)), z0, method="trf",
                                     bounds=(lo[free], hi[free]), max_nfev=max_nfev,
                                     x_scale=np.where(np.abs(z0) > 0, np.abs(z0), 1.0))
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise SolverError(f"output-error refinement failed: {exc}") from None
    jac = np.zeros((sol.fun.size, theta0.size))
    jac[:, free] = sol.jac
    return full(sol.x), sol.fun, jac, int(sol.nfev), float(sol.cost)


def output_error_coef(model: Model, segments: Sequence[Segment], max_nfev: int = 100,
                      tol: float = 1e-10,
                      filtered: Sequence[Mapping[str, np.ndarray]] | None = None
                      ) -> tuple[np.ndarray, float] | None:
    """The output-error optimum of a one-state affine discrete model, coefficients only.

    The free run ``x[k+1] = a x[k] + Σⱼ θⱼ φⱼ[k]`` (``φ`` the terms free of the state, ``x[0]``
    the first measured sample) is linear in ``θ`` for a given ``a``: ``x = Σⱼ θⱼ Sⱼ(a) + aᵏ x[0]``
    with ``Sⱼ`` the response of the pole ``a`` to ``φⱼ`` (one ``scipy.signal.lfilter`` per
    term). So ``θ`` is solved exactly for each ``a`` (a small Gram), and ``a`` by Newton
    steps on the cost with ``θ`` eliminated (variable projection: its gradient is the plain
    partial derivative, ``Σ e ∂x/∂a`` with ``∂x/∂a`` the pole's response to ``x`` itself; its
    curvature the Gauss–Newton one of ``∂x/∂a`` projected off the ``Sⱼ``). It minimises the
    cost of :func:`refine_output_error` (the same scaled residuals) to the cost's resolution
    (``tol``, relative), in a few passes over the data, where the trust-region solver there
    stops at its default tolerances (about 1e-6 relative) after finite-difference Jacobians
    and an SVD per step. What the structure search needs of the neighbouring lags'
    refinements (their coefficients and cost); covariances stay with
    :func:`refine_output_error`.

    ``filtered`` (per segment, input name -> column): the inputs already through the model's
    filters (the structure search's, :attr:`~mavsid.estimators.select.StructureChoice.inputs`),
    then only delayed here.

    Returns
    -------
    (coef, cost) or None
        The coefficients (shaped like ``model.coef``, zeros kept) and ``½‖e/scale‖²``; None
        when the model is not of that kind, the terms are collinear or the run is not finite
        (callers then use :func:`refine_output_error`).
    """
    if model.continuous or len(model.state_names) != 1 or not model.is_affine:
        return None
    states, exo, _ = model._split
    coef = np.asarray(model.coef, float)
    act = coef[:, 0] != 0
    ia = [j for j in states if act[j]]
    je = [j for j in exo if act[j]]
    if len(ia) > 1 or not je:
        return None
    feats = [model.features[j] for j in je]
    every, ys, fts = [], [], []
    for i, s in enumerate(segments):
        x, var = model._measured(s, None if filtered is None else filtered[i])
        every.append(x[:, 0])
        if len(x) >= 2:  # (a one-sample run is its start: no residual)
            ys.append(x[:, 0])
            # the terms, and an impulse of x[0] (whose response is the start's free decay)
            ft = np.zeros((len(je) + 1, len(x) - 1))
            ft[:-1] = library.evaluate(feats, var)[:-1].T
            ft[-1, 0] = x[0, 0]
            fts.append(ft)
    if not ys:
        return None
    scale = float(np.concatenate(every).std())
    scale = scale if scale > 0 else 1.0
    k = len(je)

    def at(a: float) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray], float,
                              np.ndarray] | None:
        """θ solved for the pole ``a``: (θ, responses per segment, runs, cost, their Gram)."""
        gram = np.zeros((k + 1, k + 1))
        resp = []
        with np.errstate(all="ignore"):
            for y, ft in zip(ys, fts, strict=True):
                r = np.empty(ft.shape)
                r[:k] = lfilter([1.0], [1.0, -a], ft[:k], axis=-1)
                # the start's free decay a^i x[0] (the recursion's own products, in order),
                # then the target less it
                decay = np.full(ft.shape[1], a)
                decay[0] = ft[k, 0]
                np.cumprod(decay, out=r[k])
                r[k] *= a
                np.subtract(y[1:], r[k], out=r[k])
                gram += r @ r.T
                resp.append(r)
            if not np.isfinite(gram).all():
                return None
            try:
                th = np.linalg.solve(gram[:k, :k], gram[:k, k])
            except np.linalg.LinAlgError:
                return None
            xs, cost = [], 0.0
            for y, r in zip(ys, resp, strict=True):
                x = np.empty(len(y))
                x[0] = y[0]
                x[1:] = th @ r[:k]
                e = np.subtract(y[1:], r[k])
                x[1:] += e
                e = np.subtract(x, y)
                e /= scale
                e *= e
                # (an elementwise sum: a long BLAS dot is threaded, slow on a busy machine)
                cost += 0.5 * float(np.sum(e))
                xs.append(x)
        if not (np.isfinite(th).all() and np.isfinite(cost)):
            return None
        return th, resp, xs, cost, gram

    if not ia:  # no pole: θ is linear least squares
        got = at(0.0)
        if got is None:
            return None
        out = np.zeros_like(coef)
        out[je, 0] = got[0]
        return out, got[3]
    a = float(coef[ia[0], 0])
    got = at(a)
    nfev = 1
    if got is None:
        return None
    th, resp, xs, cost, gram = got
    converged = False
    last: tuple[float, float] | None = None  # (a, gradient) of the previous step
    while nfev < max_nfev and not converged:
        # gradient and projected Gauss-Newton curvature of the cost in a (θ optimal)
        grad, sa_sa = 0.0, 0.0
        sa_s = np.zeros(k)
        with np.errstate(all="ignore"):
            for y, r, x in zip(ys, resp, xs, strict=True):
                sa = lfilter([1.0], [1.0, -a], x[:-1])
                grad += float(np.sum(sa * (x[1:] - y[1:])))
                sa_sa += float(np.sum(sa * sa))
                sa_s += r[:k] @ sa
        try:
            curv = sa_sa - float(sa_s @ np.linalg.solve(gram[:k, :k], sa_s))
        except np.linalg.LinAlgError:
            return None
        grad /= scale**2
        curv /= scale**2
        if not (np.isfinite(grad) and np.isfinite(curv)) or curv <= 0:
            return None
        if last is not None and a != last[0]:
            # the secant through the last two gradients holds the residual's own curvature,
            # which Gauss-Newton leaves out (linear convergence): superlinear with it
            secant = (grad - last[1]) / (a - last[0])
            if 0.1 * curv < secant < 10.0 * curv:
                curv = secant
        last = (a, grad)
        step = -grad / curv
        # converged when the step's predicted decrease is below what the cost resolves
        # (its last digits); the step is still taken when it does not raise the cost
        converged = 0.5 * grad * grad / curv <= tol * cost
        while True:
            got = at(a + step)
            nfev += 1
            if got is not None and got[3] <= cost:
                a += step
                th, resp, xs, cost, gram = got
                break
            if converged:
                break
            step *= 0.5
            if nfev >= max_nfev:
                return None
    if not converged:
        return None
    out = np.zeros_like(coef)
    out[ia[0], 0] = a
    out[je, 0] = th
    return out, cost
