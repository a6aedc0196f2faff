"""The identified plant of one axis as a discrete linear system (:class:`LinearPlant`): the
model's input filters and delay included, re-discretised at the controller's step.

The gyro low-pass (``INS_GYRO_FILTER``, ``IMU_GYRO_CUTOFF``) and any notch sit between the
rotating body and what the controller reads; the logged rate (``RATE.R``,
``vehicle_angular_velocity``) is already filtered, so a plant identified from it to the
logged rate includes them: the twin feeds the plant model's output straight to the PID.

Examples
--------
>>> p = LinearPlant(np.array([[0.9]]), np.array([0.5]), np.array([1.0]), 0.01)
>>> bool(np.isclose(plant_response(p, np.array([0.0]))[0], 5.0))
True
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from mavsid.errors import ConfigError
from mavsid.loop.controllers import AXIS_RATE
from mavsid.numerics.lti import c2d

if TYPE_CHECKING:
    from mavsid.estimators.model import Model

#: A single-input single-output transfer function ``(num, den)``, descending powers of z.
Poly = tuple[np.ndarray, np.ndarray]

__all__ = [
    "LinearPlant",
    "Poly",
    "as_plant",
    "plant_from_model",
    "plant_response",
    "plant_statespace",
    "ss2tf",
]

@dataclass(frozen=True)
class LinearPlant:
    """A discrete single-output plant ``x⁺ = A x + B (u + u_offset) + E w``, ``y = C x``.

    ``u`` is the axis's controller output (mixer input, normalised); ``w`` the model's other
    inputs, taken as measured; ``u_offset`` the model's bias expressed as an input offset.
    """

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    dt: float
    e: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    u_offset: float = 0.0
    other_inputs: tuple[str, ...] = ()

    def initial_state(self, y0: float, u0: float, w0: np.ndarray | None = None) -> np.ndarray:
        """A state in equilibrium with the input ``u0`` (and ``w0``) as far as the plant
        allows, moved (least norm) so that its output is ``y0``."""
        n = self.a.shape[0]
        forcing = self.b * (u0 + self.u_offset)
        if w0 is not None and self.e.size:
            forcing = forcing + self.e @ w0
        try:
            x = np.linalg.solve(np.eye(n) - self.a, forcing)
            if not np.all(np.isfinite(x)) or np.linalg.cond(np.eye(n) - self.a) > 1e8:
                raise np.linalg.LinAlgError
        except np.linalg.LinAlgError:
            x = np.zeros(n)
        cc = self.c.reshape(1, n)
        return x + (np.linalg.pinv(cc) @ np.array([y0 - float((cc @ x)[0])])).ravel()


def _at_step(model: Model, dt: float) -> Model:
    """The linear model at step ``dt``, delay kept in seconds: a discrete one re-discretised
    (:meth:`mavsid.estimators.model.Model.resampled`: zero-order hold inverted, then applied
    at ``dt``), a continuous one discretised (zero-order hold)."""
    if not model.continuous:
        if math.isclose(model.dt, dt, rel_tol=1e-9):
            return model
        return model.resampled(dt)
    states, exo, other = model._split
    if other:
        raise ConfigError("the closed-loop twin needs a linear model (no library terms)")
    a = model.A
    n = a.shape[0]
    b = model.coef[exo].T if exo else np.zeros((n, 0))
    phi, gamma = c2d(a, b, dt)
    coef = np.zeros_like(model.coef)
    for j in states:
        coef[j] = phi[:, model.state_names.index(model.features[j])]
    for k, j in enumerate(exo):
        coef[j] = gamma[:, k]
    steps = model.delay_s / dt
    whole = math.floor(steps + 1e-9)
    frac = steps - whole if steps - whole > 1e-9 else 0.0
    return replace(model, coef=coef, dt=dt, continuous=False, delay=whole, delay_frac=frac,
                   covariance=None, coef_stderr=None)


def plant_from_model(model: Any, axis: str, dt: float | None = None) -> LinearPlant:
    """The identified plant of ``axis`` as a :class:`LinearPlant` at step ``dt`` (default
    the model's own): input filters and delay included, the bias as an input offset.

    ``model`` is a :class:`mavsid.estimators.Model` (linear features).

    Raises
    ------
    ConfigError
        The model is not linear, does not predict the axis's rate from its input, or cannot
        be re-discretised at ``dt``.
    """
    from mavsid.estimators import library

    rate, u_name = AXIS_RATE[axis], f"u_{axis}"
    if not all(hasattr(model, a) for a in ("features", "coef", "statespace_matrices",
                                           "_split")):
        raise ConfigError(f"the {axis} model is not a mavsid estimators.Model: no loop model")
    if rate not in model.state_names or u_name not in model.input_names:
        raise ConfigError(f"the {axis} model does not map {u_name} to {rate}")
    if not library.is_linear(model.features):
        raise ConfigError("the closed-loop twin needs a linear model (no library terms)")
    m = _at_step(model, model.dt if dt is None else dt)
    a, bmat, cmat, dmat, ins, _ = m.statespace_matrices()  # numpy: no python-control here
    row = m.state_names.index(rate)
    c = np.asarray(cmat, dtype=float)[row]
    if np.any(np.abs(np.asarray(dmat, dtype=float)[row]) > 0):
        raise ConfigError("the model's output reacts to its input within the same step")
    j = ins.index(u_name)
    others = tuple(k for k in ins if k != u_name)
    e = bmat[:, [ins.index(k) for k in others]] if others else np.zeros((a.shape[0], 0))
    # bias c[rate] as the input offset that produces it: B_plant * u0 = c
    offset = 0.0
    if library.BIAS in m.features:
        fb, fu = m.features.index(library.BIAS), m.features.index(u_name)
        bu = float(m.coef[fu, row])
        if bu != 0:
            offset = float(m.coef[fb, row]) / bu
    return LinearPlant(a, bmat[:, j].copy(), c, m.dt, e, offset, others)


def plant_statespace(model: Any, axis: str, dt: float) -> Any:
    """The axis's plant (controller output -> rate) as a discrete python-control system at
    step ``dt`` (filters and delay included; bias and other inputs left out)."""
    import control

    pl = plant_from_model(model, axis, dt)
    return control.ss(pl.a, pl.b.reshape(-1, 1), pl.c.reshape(1, -1), 0.0, dt)


def as_plant(plant: Any) -> LinearPlant:
    """A :class:`LinearPlant` as it is, or one of a discrete python-control state space
    (no feedthrough)."""
    if isinstance(plant, LinearPlant):
        return plant
    d = np.asarray(plant.D, dtype=float)
    if d.size and np.any(d != 0):
        raise ConfigError("the plant must have no feedthrough (D = 0)")
    return LinearPlant(np.atleast_2d(np.asarray(plant.A, dtype=float)),
                       np.asarray(plant.B, dtype=float).ravel(),
                       np.asarray(plant.C, dtype=float).ravel(), float(plant.dt))


def ss2tf(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: float = 0.0) -> Poly:
    """``scipy.signal.ss2tf`` of a single-input single-output state space (its formula:
    ``den = poly(A)``, ``num = poly(A − B·C) + (D − 1)·den``)."""
    a = np.atleast_2d(np.asarray(a, dtype=float))
    b, c = np.asarray(b, dtype=float).reshape(-1, 1), np.asarray(c, dtype=float).reshape(1, -1)
    den = np.poly(a)
    return np.poly(a - b @ c) + (float(d) - 1.0) * den, den


def plant_response(plant: LinearPlant, freq_hz: np.ndarray) -> np.ndarray:
    """``C (zI − A)⁻¹ B`` of a :class:`LinearPlant` at ``freq_hz``.

    Examples
    --------
    >>> p = LinearPlant(np.array([[0.9]]), np.array([0.5]), np.array([1.0]), 0.01)
    >>> h = plant_response(p, np.array([0.0]))
    >>> bool(np.isclose(h[0], 0.5 / (1 - 0.9)))
    True
    """
    z = np.exp(2j * np.pi * np.asarray(freq_hz, dtype=float) * plant.dt)
    num, den = ss2tf(plant.a, plant.b, plant.c)
    return np.polyval(num, z) / np.polyval(den, z)
