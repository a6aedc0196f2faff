"""A model's coefficients by instrumental variables: a check on the feedback's bias.

In closed loop the controller output ``u`` carries the gyro's noise back into the plant's
input, and the measured state ``x`` carries it as well: least squares (and output error)
on ``x[k+1] = a·x[k] + b·u[k−d] + c`` is then biased — on a manual flight with a noisy
gyro, control effectiveness came out 12 % low at 3 σ. A signal the noise does not reach
but the motion follows — the pilot's commanded attitude — makes the estimate consistent:
with instruments ``ζ[k] = (r[k], r[k−m], 1)``, ``r`` the command through the model's input
filters and delay,

    θ = (Σ ζ φᵀ)⁻¹ Σ ζ y

(the *instrumental-variable* estimate, Söderström & Stoica, *System Identification*, ch. 8).
It is used as the frequency response against an injection is: its difference to the fit
joins the fit's covariance (:func:`mavsid.estimators.identification.identify_segments`), so
that a fit the feedback biased reports a σ that covers it.

Examples
--------
An open-loop plant driven by a command through a noisy actuator, its state measured with
noise, fitted by least squares and by the command as instrument:

>>> import numpy as np
>>> from mavsid.data import Segment
>>> rng = np.random.default_rng(0)
>>> n, dt = 4000, 0.01
>>> r = np.repeat(rng.standard_normal(n // 40), 40)
>>> x = np.zeros(n)
>>> u = r + 0.5 * rng.standard_normal(n)
>>> for k in range(n - 1):
...     x[k + 1] = 0.95 * x[k] + 0.2 * u[k]
>>> noisy = x + 0.3 * rng.standard_normal(n)
>>> seg = Segment(np.arange(n) * dt, noisy[:, None], u[:, None], ("q",), ("u_pitch",), dt,
...               "pitch", "scan")
>>> from mavsid.estimators.model import Model
>>> ls = Model(("q",), ("u_pitch",), ("q", "u_pitch", "1"), np.zeros(3), dt)
>>> phi = np.column_stack([noisy[:-1], u[:-1], np.ones(n - 1)])
>>> np.round(np.linalg.lstsq(phi, noisy[1:], rcond=None)[0][:2], 2).tolist()  # biased
[0.93, 0.23]
>>> iv = instrument_estimate(ls, [seg], [r])
>>> np.round(iv.coef[:2, 0], 2).tolist()
[0.95, 0.2]
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from mavsid.data import Segment
from mavsid.estimators.model import Model
from mavsid.estimators.regressors import variables

__all__ = ["MAX_INSTRUMENT_SPREAD", "instrument_estimate"]

#: Largest standard error (jackknife over :data:`_BLOCKS` blocks of rows) of the input's
#: coefficient, relative to it, for the estimate to be made: weaker instruments (a command
#: the motion hardly follows, a short window) give an estimate noisier than the bias it
#: checks (a tenth is then a 2-σ difference), and none is made.
MAX_INSTRUMENT_SPREAD = 0.05
_BLOCKS = 8
#: The instruments' second lag (s): long enough that ``r[k]`` and ``r[k − m]`` are not one
#: signal twice, short against a manoeuvre.
_SECOND_LAG_S = 0.05


def instrument_estimate(model: Model, segments: Sequence[Segment],
                        references: Sequence[np.ndarray | None]) -> Model | None:
    """``model``'s coefficients by instrumental variables, ``references[i]`` (one value per
    sample of ``segments[i]``; None or non-finite values: rows left out) the instrument.

    Only a discrete one-state model whose features are its state, its input and optionally
    a constant (the rate model); None otherwise, with fewer than 50 usable rows, or when
    the estimate of the input's coefficient is not precise to :data:`MAX_INSTRUMENT_SPREAD`
    of itself.
    """
    if (model.continuous or len(model.state_names) != 1 or len(model.input_names) != 1):
        return None
    state, inp = model.state_names[0], model.input_names[0]
    if set(model.features) - {state, inp, "1"} or not {state, inp} <= set(model.features):
        return None
    st = model.structure
    m = max(1, round(_SECOND_LAG_S / model.dt))
    xs, zs, ys = [], [], []
    for seg, ref in zip(segments, references, strict=True):
        if ref is None or len(ref) != len(seg):
            continue
        var = variables(seg, st, names=(state, inp))
        # the command through the input's filters and delay, as the input goes (from its
        # first value: the input's history is not the command's)
        r = variables(replace(seg, inputs=np.asarray(ref, float)[:, None], input_names=(inp,),
                              inputs_before=None), st, names=(inp,))[inp]
        k = np.arange(st.lead + m, len(seg) - st.trail)
        cols = {state: var[state][k], inp: var[inp][k], "1": np.ones(k.size)}
        xs.append(np.column_stack([cols[f] for f in model.features]))
        zs.append(np.column_stack([r[k], r[k - m], np.ones(k.size)]))
        ys.append(var[state][k + 1])
    if not xs:
        return None
    x, z, y = np.concatenate(xs), np.concatenate(zs), np.concatenate(ys)
    ok = np.isfinite(x).all(axis=1) & np.isfinite(z).all(axis=1) & np.isfinite(y)
    x, z, y = x[ok], z[ok], y[ok]
    if "1" not in model.features:
        z = z[:, :2]
    if len(y) < 50:
        return None
    coef = _iv(z, x, y)
    if coef is None:
        return None
    # precise enough to tell a bias of a tenth? its spread over the rows, by deleting one
    # of _BLOCKS contiguous blocks at a time (the jackknife: the rows are not independent)
    edges = np.linspace(0, len(y), _BLOCKS + 1).astype(int)
    part = []
    for a, b in itertools.pairwise(edges):
        keep = np.r_[0:a, b:len(y)]
        got = _iv(z[keep], x[keep], y[keep])
        if got is None:
            return None
        part.append(got)
    spread = np.sqrt((_BLOCKS - 1) * np.var(np.array(part), axis=0))
    j = model.features.index(inp)
    if not spread[j] <= MAX_INSTRUMENT_SPREAD * abs(coef[j]):
        return None
    return replace(model, coef=coef[:, None], covariance=None, coef_stderr=None)


def _iv(z: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray | None:
    """``(zᵀx)⁻¹ zᵀy``, None where singular or not finite."""
    try:
        coef = np.linalg.solve(z.T @ x, z.T @ y)
    except np.linalg.LinAlgError:
        return None
    return coef if np.isfinite(coef).all() else None
