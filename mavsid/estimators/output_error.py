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
from dataclasses import dataclass, replace

import numpy as np

from mavsid import dsp
from mavsid.data import Segment
from mavsid.errors import ConfigError, SolverError
from mavsid.estimators import library
from mavsid.estimators._base import hac_covariance
from mavsid.estimators.model import Model
from mavsid.estimators.regressors import Regression

__all__ = ["box_least_squares", "output_error_coef", "refine_output_error"]


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
        Limit on residual evaluations of the solver (:func:`box_least_squares`; those of its
        finite-difference Jacobians not counted).
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
        sol = box_least_squares(residuals, theta0, lo, hi, x_scale, max_nfev)
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


@dataclass(frozen=True)
class _Solution:
    """What :func:`box_least_squares` found: the point, its residuals, their Jacobian there,
    half their sum of squares and the residual evaluations it took (Jacobians' not
    counted)."""

    x: np.ndarray
    fun: np.ndarray
    jac: np.ndarray
    cost: float
    nfev: int


def _jacobian(fun: Callable[[np.ndarray], np.ndarray], x: np.ndarray, f: np.ndarray,
              lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Forward differences, step ``√ε · max(1, |x|)`` (away from a bound it would cross), as
    ``scipy.optimize.least_squares``' default ``"2-point"`` Jacobian takes them."""
    h = np.sqrt(np.finfo(float).eps) * np.maximum(1.0, np.abs(x)) * np.where(x < 0, -1.0, 1.0)
    h = np.where((x + h > hi) | (x + h < lo), -h, h)
    jac = np.empty((f.size, x.size))
    for j in range(x.size):
        step = x.copy()
        step[j] += h[j]
        jac[:, j] = (fun(step) - f) / (step[j] - x[j])
    return jac


def box_least_squares(fun: Callable[[np.ndarray], np.ndarray], x0: np.ndarray,
                      lo: np.ndarray, hi: np.ndarray, x_scale: np.ndarray, max_nfev: int = 100,
                      ftol: float = 1e-8, xtol: float = 1e-8, gtol: float = 1e-8) -> _Solution:
    """Minimise ``½‖fun(x)‖²`` within the box ``lo <= x <= hi`` from ``x0``: Levenberg–Marquardt
    on the variables scaled by ``x_scale`` (the damping updated by Nielsen's rule): each step
    solved for the variables no bound holds (one at its bound with the gradient pushing out
    stays), from the QR factors of their scaled Jacobian (forward differences,
    :func:`_jacobian`), then projected onto the box. Stops, as
    ``scipy.optimize.least_squares`` does with the same tolerances, when an accepted step
    lowers the cost by less than ``ftol`` of it or moves the scaled point by less than
    ``xtol`` of its norm, when the scaled projected gradient falls below ``gtol``, or after
    ``max_nfev`` residual evaluations. What the refinement (and
    :func:`mavsid.frequency.fit_tf`) used from scipy's solver (0.2 s of imports a fit does
    without); the same optimum to its tolerances (tests compare, with and without bounds).
    Raises ValueError when the residuals at ``x0`` are not finite.

    Examples
    --------
    >>> t = np.linspace(0.0, 1.0, 50)
    >>> sol = box_least_squares(lambda x: x[0] * np.exp(-x[1] * t) - 2.0 * np.exp(-3.0 * t),
    ...                         np.array([1.0, 1.0]), np.full(2, -np.inf), np.full(2, np.inf),
    ...                         np.ones(2))
    >>> [round(float(v), 6) for v in sol.x], sol.cost < 1e-20
    ([2.0, 3.0], True)
    """
    x = np.clip(np.asarray(x0, float), lo, hi)
    f = fun(x)
    if not np.all(np.isfinite(f)):
        raise ValueError("the residuals are not finite at the starting point")
    nfev, cost = 1, 0.5 * float(f @ f)
    jac = _jacobian(fun, x, f, lo, hi)
    mu, nu = -1.0, 2.0
    while nfev < max_nfev:
        js = jac * x_scale  # the Jacobian of the scaled variables z = x / x_scale
        g = js.T @ f
        # the gradient's components a bound does not stop (it stops those pointing out)
        free = ~(((x <= lo) & (g > 0)) | ((x >= hi) & (g < 0)))
        if float(np.max(np.abs(g[free]), initial=0.0)) < gtol:
            break
        q, r = np.linalg.qr(js[:, free])  # (the variables a bound holds stay where they are)
        qtf = q.T @ f
        a = r.T @ r
        if mu < 0:
            mu = 1e-3 * float(np.max(np.diag(a), initial=0.0)) or 1e-3
        accepted, n = False, int(free.sum())
        while nfev < max_nfev:
            lhs = np.vstack([r, np.sqrt(mu) * np.eye(n)])
            dz = np.zeros(x.size)
            dz[free] = np.linalg.lstsq(lhs, np.concatenate([-qtf, np.zeros(n)]), rcond=None)[0]
            x_new = np.clip(x + dz * x_scale, lo, hi)
            dz = (x_new - x) / x_scale  # the step the box allows
            if not np.any(dz):  # (the box stops every variable the step would move)
                break
            predicted = -float(g @ dz + 0.5 * np.sum((js @ dz) ** 2))
            f_new = fun(x_new)
            nfev += 1
            cost_new = 0.5 * float(f_new @ f_new)
            if predicted > 0 and np.isfinite(cost_new) and cost_new < cost:
                rho = (cost - cost_new) / predicted
                mu *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
                nu = 2.0
                accepted = True
                break
            mu *= nu
            nu *= 2.0
            if not np.isfinite(mu) or mu > 1e300:
                break
        if not accepted:
            break
        drop = cost - cost_new
        z_norm = float(np.linalg.norm(x / x_scale))
        x, f, cost = x_new, f_new, cost_new
        jac = _jacobian(fun, x, f, lo, hi)
        if drop < ftol * (cost + drop) or float(np.linalg.norm(dz)) < xtol * (xtol + z_norm):
            break
    return _Solution(x, f, jac, cost, nfev)


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
                r[:k] = dsp.lfilter([1.0], [1.0, -a], ft[:k], axis=-1)
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
                sa = dsp.lfilter([1.0], [1.0, -a], x[:-1])
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
