"""The fitted model: named parameters with units and standard errors, rollouts, JSON.

A :class:`Model` is ``x[k+1] = Θᵀ φ(x[k], u[k-d])`` (discrete) or ``ẋ = Θᵀ φ(x, u(t-d·dt))``
(continuous) for the modelled states ``state_names``, with the features ``φ`` named as in
:mod:`mavsid.estimators.library` and the inputs passed through the model's known input
filters first. Variables a feature uses that are neither modelled states nor inputs (say
``roll`` in a model of ``p``) are taken from the measured segment.

Parameter names: ``A[p,p]`` (state), ``B[p,u_roll]`` (input), ``c[p]`` (bias), ``W[p,term]``
(library term) for continuous time; discrete-time coefficients carry ``_d`` (``A_d[p,p]``...).
A linear discrete model also reports the equivalent continuous-time ``A``, ``B``, ``c`` (zero-
order hold inverted), with standard errors by the delta method: ``B[p,u_roll]`` is the control
effectiveness in rad/s² per unit of controller output, whichever form was fitted.

Examples
--------
>>> import numpy as np
>>> from mavsid.data import Segment
>>> m = Model(("p",), ("u_roll",), ("p", "u_roll", "1"), np.array([[0.99], [0.5], [0.0]]),
...           dt=0.01)
>>> sorted(m.params)[:3], m.units["B[p,u_roll]"]
(['A[p,p]', 'A_d[p,p]', 'B[p,u_roll]'], 'rad/s^2')
>>> round(m.params["B[p,u_roll]"], 2)   # 0.5 rad/s per sample -> about 50 rad/s^2
50.25
>>> seg = Segment(np.arange(4) * 0.01, np.zeros((4, 1)), np.ones((4, 1)), ("p",), ("u_roll",),
...               0.01, "roll", "scan")
>>> m.simulate(seg).ravel().round(3).tolist()   # 0.99 * 0.995 + 0.5 = 1.48505
[0.0, 0.5, 0.995, 1.485]
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import math
import os
import threading
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import Future
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from mavsid.data import Segment
from mavsid.errors import ConfigError, LogFormatError, whole_number
from mavsid.estimators import library
from mavsid.estimators.regressors import InputFilter, Structure, variables
from mavsid.numerics.filters import lfilter
from mavsid.numerics.lti import c2d, d2c, tf2ss

__all__ = ["UNITS", "Model", "load_model"]

#: Units of the canonical variables.
UNITS: dict[str, str] = {
    "p": "rad/s", "q": "rad/s", "r": "rad/s",
    "roll": "rad", "pitch": "rad", "yaw": "rad",
    "u_roll": "1", "u_pitch": "1", "u_yaw": "1", "u_thrust": "1",
}

_FORMAT = "mavsid-model"
_VERSION = 1  # of the stored form (:meth:`Model.to_dict`)


def _unit(var: str, units: Mapping[str, str] | None = None) -> str:
    if units and var in units:
        return str(units[var])
    return UNITS.get(var, "?")


def _rate_unit(unit: str) -> str:
    """Unit of the time derivative of a quantity in ``unit``."""
    if unit == "rad/s":
        return "rad/s^2"
    if unit == "rad":
        return "rad/s"
    if unit in ("?", "1"):
        return f"{unit}/s" if unit == "?" else "1/s"
    return f"({unit})/s" if "/" in unit or "*" in unit else f"{unit}/s"


def _feature_unit(feature: str, units: Mapping[str, str] | None = None) -> str:
    facs = library.parse(feature)
    parts = []
    for f in facs:
        u = "1" if f.func else _unit(f.var, units)
        if u != "1":
            parts.append(u if f.power == 1 else f"({u})^{f.power}")
    return "*".join(parts) or "1"


def _ratio(num: str, den: str) -> str:
    if den == "1":
        return num
    if num == den:
        return "1"
    if num == _rate_unit(den):  # (rad/s^2)/(rad/s), (m/s)/s over m/s ...
        return "1/s"
    return f"{num}/({den})" if "*" in den or "/" in den else f"{num}/{den}"


#: each file's sha256 (None: not a file), by its path and version (:func:`_version`),
#: hashed once per process in a thread
_HASHES: dict[tuple[Any, ...], Future[str | None]] = {}
_HASHES_LOCK = threading.Lock()


def _version(path: str) -> tuple[Any, ...]:
    """What tells one version of a file from another: its path, inode, size and time of
    last modification (just the path when it cannot be looked at)."""
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return (path,)
    return path, st.st_ino, st.st_size, st.st_mtime_ns


def _hash_file(path: str) -> str | None:
    if not path or not Path(path).is_file():
        return None
    with open(path, "rb") as fh:
        return hashlib.file_digest(fh, "sha256").hexdigest()


def _hashes(paths: Iterable[str]) -> list[Future[str | None]]:
    """Each file's hash to come (:func:`hash_soon`), the versions not asked for before
    hashed one after another in a thread (hashlib lets other threads run)."""
    out: list[Future[str | None]] = []
    jobs: list[tuple[str, Future[str | None]]] = []
    with _HASHES_LOCK:
        for path in paths:
            key = _version(path)
            got = _HASHES.get(key)
            if got is None:
                got = _HASHES[key] = Future()
                jobs.append((path, got))
            out.append(got)
    if jobs:
        def run() -> None:
            for path, job in jobs:
                try:
                    job.set_result(_hash_file(path))
                except BaseException as exc:  # (raised where the hash is asked for)
                    job.set_exception(exc)

        threading.Thread(target=run, name="mavsid-sha256", daemon=True).start()
    return out


def hash_soon(paths: Iterable[str]) -> None:
    """Start hashing the files ``paths``, for :func:`provenance` and :func:`file_sha256`
    (a 100-MB log's ~0.1 s then overlaps the fit)."""
    _hashes(paths)


def file_sha256(path: str) -> str | None:
    """sha256 of the file ``path``, hashed once per process and version of the file (its
    inode, size and modification time: a log written again is hashed again); None when
    ``path`` is not a file. OSError when it cannot be read."""
    return _hashes([path])[0].result()


def provenance(segments: Sequence[Segment], **settings: object) -> dict[str, object]:
    """Where a fit came from: logs (with sha256), segment windows, settings, time, version."""
    from mavsid import __version__

    logs = sorted({s.log for s in segments if s.log})
    return {
        "logs": [{"path": p, "sha256": file_sha256(p)} for p in logs],
        "segments": [
            {"log": s.log, "start_s": s.start_s, "stop_s": s.stop_s, "axis": s.axis,
             "source": s.source}
            for s in segments
        ],
        "settings": settings,
        "created_utc": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "mavsid_version": __version__,
    }


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, Mapping):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        return float(obj) if math.isfinite(float(obj)) else None
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, InputFilter):
        return obj.to_dict()
    return obj


def _none_to_nan(obj: Any) -> Any:
    if isinstance(obj, list):
        return [_none_to_nan(v) for v in obj]
    return np.nan if obj is None else obj


_SS = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def _series(first: _SS, then: _SS) -> _SS:
    """``then`` driven by the output of ``first`` (states of ``first`` first)."""
    a1, b1, c1, d1 = first
    a2, b2, c2, d2 = then
    n1, n2 = a1.shape[0], a2.shape[0]
    a = np.block([[a1, np.zeros((n1, n2))], [b2 @ c1, a2]])
    b = np.vstack([b1, b2 @ d1])
    c = np.hstack([d2 @ c1, c2])
    return a, b, c, d2 @ d1


def _block_diagonal(one: _SS, n: int) -> _SS:
    """``n`` independent copies of a single-input single-output system, side by side."""
    if n == 1:
        return one
    a, b, c, d = (np.kron(np.eye(n), x) for x in one)
    return a, b, c, d


#: what a stored model's sample step, input delay and input filters may be (a file is
#: input: a step of 0 divided by zero, a delay of 10⁹ samples took the machine's memory, a
#: filter of order 10⁶ ran for minutes)
STORED_DT_S = (1e-5, 1.0)
STORED_MAX_DELAY_S = 2.0
STORED_MAX_FILTER_ORDER = 8


def _check_stored(dt: float, delay: int, delay_frac: float, filters: Sequence[InputFilter],
                  coef: np.ndarray, n_features: int, n_states: int,
                  spread: Mapping[str, np.ndarray | None]) -> None:
    """Raise :class:`LogFormatError` naming what a stored model holds that no fit gives
    (``spread``: its covariance, standard errors and noise, NaN where unknown).

    Examples
    --------
    >>> _check_stored(0.0025, 2, 0.0, (), np.zeros((2, 1)), 2, 1, {})
    >>> _check_stored(0.0, 2, 0.0, (), np.zeros((2, 1)), 2, 1, {})
    Traceback (most recent call last):
    mavsid.errors.LogFormatError: dt 0.0 s is not a sample step (1e-05 to 1 s)
    """
    lo, hi = STORED_DT_S
    if not lo <= dt <= hi:
        raise LogFormatError(f"dt {dt!r} s is not a sample step ({lo:g} to {hi:g} s)")
    if not 0 <= delay * dt <= STORED_MAX_DELAY_S:
        raise LogFormatError(f"delay {delay} samples ({delay * dt:.3g} s) is not an input delay "
                             f"(0 to {STORED_MAX_DELAY_S:g} s)")
    if not 0 <= delay_frac < 1:
        raise LogFormatError(f"delay_frac {delay_frac!r} is not a fraction of a sample [0, 1)")
    for f in filters:
        if not (1 <= f.order <= STORED_MAX_FILTER_ORDER and 0 < f.cutoff_hz < math.inf
                and 0 <= f.rate_hz < math.inf
                and (f.rate_hz == 0 or f.cutoff_hz < f.rate_hz / 2)):
            raise LogFormatError(f"input filter {f.source or '?'}: order {f.order}, cutoff "
                                 f"{f.cutoff_hz:g} Hz, rate {f.rate_hz:g} Hz is not a filter "
                                 f"(order 1 to {STORED_MAX_FILTER_ORDER}, positive finite "
                                 "frequencies, the cutoff below half the rate)")
    if coef.shape != (n_features, n_states):
        raise LogFormatError(f"coef has shape {coef.shape}, not {n_features} features × "
                             f"{n_states} states")
    if not np.isfinite(coef).all():
        raise LogFormatError("coef holds a value that is not a finite number")
    for key, values in spread.items():  # (NaN: not known, as to_dict writes None)
        if values is not None and (np.isinf(values).any() or (
                key != "covariance" and (values < 0).any())):
            raise LogFormatError(f"{key} holds an infinite or negative value")


@dataclass(frozen=True)
class Model:
    """A fitted attitude-dynamics model.

    Parameters
    ----------
    state_names : tuple of str
        Modelled states (what ``simulate`` and ``predict`` return, in this order).
    input_names : tuple of str
        Inputs (filtered by ``filters``, delayed by ``delay`` samples).
    features : tuple of str
        Regressors, see :mod:`mavsid.estimators.library`.
    coef : numpy.ndarray, shape (len(features), len(state_names))
        Θ.
    dt : float
        Sample time (s) the model was fitted at.
    delay : int
        Input delay (samples).
    delay_frac : float
        Further fraction of a sample of input delay (see ``Structure``).
    continuous : bool
        ``ẋ = Θᵀφ`` instead of ``x[k+1] = Θᵀφ``.
    filters : tuple of InputFilter
        Known filters applied to the inputs (e.g. the gyro low-pass).
    covariance : numpy.ndarray, shape (len(state_names), p, p), optional
        Covariance of each output's coefficient column.
    coef_stderr : numpy.ndarray, shape like ``coef``, optional
        Reported standard errors (NaN: not estimated, e.g. a term an L1 fit removed).
    sigma : numpy.ndarray, shape (len(state_names),), optional
        Residual standard deviation per output.
    provenance : Mapping
        Logs (sha256), segments, estimator and its settings.
    var_units : Mapping[str, str]
        Units of the variables (states, inputs) beyond the canonical ones of ``UNITS``
        (``"?"`` where neither says); parameter units are derived from them.
    """

    state_names: tuple[str, ...]
    input_names: tuple[str, ...]
    features: tuple[str, ...]
    coef: np.ndarray
    dt: float
    delay: int = 0
    continuous: bool = False
    filters: tuple[InputFilter, ...] = ()
    delay_frac: float = 0.0
    covariance: np.ndarray | None = field(default=None, repr=False)
    coef_stderr: np.ndarray | None = field(default=None, repr=False)
    sigma: np.ndarray | None = field(default=None, repr=False)
    provenance: Mapping[str, object] = field(default_factory=dict, repr=False)
    var_units: Mapping[str, str] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        coef = np.asarray(self.coef, dtype=float).reshape(len(self.features),
                                                         len(self.state_names))
        object.__setattr__(self, "coef", coef)
        object.__setattr__(self, "state_names", tuple(self.state_names))
        object.__setattr__(self, "input_names", tuple(self.input_names))
        object.__setattr__(self, "features", tuple(self.features))
        object.__setattr__(self, "filters", tuple(self.filters))
        for f in self.features:
            library.parse(f)

    # ----------------------------------------------------------------- structure

    @classmethod
    def of(cls, structure: Structure, coef: np.ndarray, dt: float, **fields: Any) -> Model:
        """The model of ``structure`` (its names, delay, filters, time base) with ``coef``;
        ``fields``: the others (``covariance``, ``provenance``...).

        Examples
        --------
        >>> st = Structure(("p",), ("p", "u_roll"), delay=2)
        >>> m = Model.of(st, np.array([[0.9], [0.5]]), 0.01)
        >>> m.input_names, m.delay, m.structure == st
        (('u_roll',), 2, True)
        """
        return cls(structure.outputs, structure.inputs, structure.features, coef, dt,
                   delay=structure.delay, continuous=structure.continuous,
                   filters=structure.filters, delay_frac=structure.delay_frac, **fields)

    @property
    def structure(self) -> Structure:
        """The regression structure this model evaluates."""
        return Structure(outputs=self.state_names, features=self.features,
                         inputs=self.input_names, delay=self.delay,
                         delay_frac=self.delay_frac, continuous=self.continuous,
                         filters=self.filters)

    @cached_property
    def _split(self) -> tuple[list[int], list[int], list[int]]:
        """Feature indices: exactly a modelled state / free of modelled states / other."""
        states, exo, other = [], [], []
        for j, f in enumerate(self.features):
            facs = library.parse(f)
            if len(facs) == 1 and facs[0].var in self.state_names and facs[0].power == 1 \
                    and not facs[0].func:
                states.append(j)
            elif all(fac.var not in self.state_names for fac in facs):
                exo.append(j)
            else:
                other.append(j)
        return states, exo, other

    @property
    def delay_s(self) -> float:
        """Total input delay in seconds (whole samples plus the fraction)."""
        return (self.delay + self.delay_frac) * self.dt

    @property
    def is_affine(self) -> bool:
        """True when the modelled states enter linearly (inputs may enter through any term)."""
        return not self._split[2]

    @property
    def A(self) -> np.ndarray:
        """State matrix of the modelled states (discrete ``A_d`` or continuous ``A``)."""
        n = len(self.state_names)
        a = np.zeros((n, n))
        for j in self._split[0]:
            a[:, self.state_names.index(self.features[j])] = self.coef[j]
        return a

    def eigenvalues(self) -> np.ndarray:
        """Eigenvalues of :attr:`A` (linear part; discrete or continuous per ``continuous``)."""
        return np.asarray(np.linalg.eigvals(self.A))

    # ----------------------------------------------------------------- parameters

    def _name(self, out: str, feature: str) -> tuple[str, str]:
        """Parameter name and unit of coefficient (feature -> d out)."""
        sfx = "" if self.continuous else "_d"
        facs = library.parse(feature)
        vu = self.var_units
        yunit = _unit(out, vu) if not self.continuous else _rate_unit(_unit(out, vu))
        funit = _feature_unit(feature, vu)
        if not facs:
            return f"c{sfx}[{out}]", yunit
        kind = "W"
        if len(facs) == 1 and facs[0].power == 1 and not facs[0].func:
            kind = "B" if facs[0].var in self.input_names else "A"
        unit = _ratio(yunit, funit)
        if not self.continuous and kind == "A" and _unit(out, vu) == _unit(feature, vu):
            unit = "1"
        return f"{kind}{sfx}[{out},{feature}]", unit

    @cached_property
    def _table(self) -> tuple[dict[str, float], dict[str, float], dict[str, str]]:
        params: dict[str, float] = {}
        stderr: dict[str, float] = {}
        units: dict[str, str] = {}
        se = self.coef_stderr if self.coef_stderr is not None else np.full_like(
            self.coef, np.nan)
        for i, out in enumerate(self.state_names):
            for j, f in enumerate(self.features):
                name, unit = self._name(out, f)
                params[name] = float(self.coef[j, i])
                stderr[name] = float(se[j, i])
                units[name] = unit
        derived = self._continuous_equivalent()
        if derived is not None:
            for name, (val, err, unit) in derived.items():
                params[name], stderr[name], units[name] = val, err, unit
        return params, stderr, units

    @property
    def params(self) -> dict[str, float]:
        """Parameter name -> value (see the module docstring for names)."""
        return dict(self._table[0])

    @property
    def stderr(self) -> dict[str, float]:
        """Parameter name -> standard error (NaN where not estimated)."""
        return dict(self._table[1])

    @property
    def units(self) -> dict[str, str]:
        """Parameter name -> unit."""
        return dict(self._table[2])

    def _continuous_equivalent(self) -> dict[str, tuple[float, float, str]] | None:
        """Continuous-time A, B, c of a linear discrete model (ZOH inverted), delta-method σ."""
        if self.continuous or not library.is_linear(self.features):
            return None
        states, exo, _ = self._split
        if not states:
            return None

        def convert(coef: np.ndarray) -> np.ndarray | None:
            n = len(self.state_names)
            ad = np.zeros((n, n))
            for j in states:
                ad[:, self.state_names.index(self.features[j])] = coef[j]
            bd = coef[exo].T  # (n, len(exo))
            ev = np.linalg.eigvals(ad)
            if np.any(np.abs(ev.imag) > 1e-12) or np.any(ev.real <= 0):
                return None
            ac, bc = d2c(ad, bd, self.dt)
            return np.concatenate([ac.T.ravel(), bc.T.ravel()])

        base = convert(self.coef)
        if base is None:
            return None
        # delta method over every coefficient, per-output covariance (outputs independent)
        cov = self._reported_covariance()
        var = np.zeros_like(base)
        if cov is not None:
            for i in range(len(self.state_names)):
                jac = np.zeros((base.size, len(self.features)))
                for j in range(len(self.features)):
                    h = 1e-6 * max(1.0, abs(self.coef[j, i]))
                    pert = self.coef.copy()
                    pert[j, i] += h
                    up = convert(pert)
                    pert[j, i] -= 2 * h
                    dn = convert(pert)
                    if up is None or dn is None:
                        jac[:, j] = np.nan
                    else:
                        jac[:, j] = (up - dn) / (2 * h)
                var += np.einsum("ij,jk,ik->i", jac, np.nan_to_num(cov[i]), jac)
            var = np.where(np.isfinite(var), var, np.nan)
        err = np.sqrt(var) if cov is not None else np.full_like(base, np.nan)
        out: dict[str, tuple[float, float, str]] = {}
        flip = replace(self, continuous=True, covariance=None, coef_stderr=None)
        k = 0
        for j in states:  # ac.T.ravel(): column = feature state, row = output
            for out_name in self.state_names:
                name, unit = flip._name(out_name, self.features[j])
                out[name] = (float(base[k]), float(err[k]), unit)
                k += 1
        for j in exo:
            for out_name in self.state_names:
                name, unit = flip._name(out_name, self.features[j])
                out[name] = (float(base[k]), float(err[k]), unit)
                k += 1
        return out

    def _reported_covariance(self) -> np.ndarray | None:
        """Covariance whose diagonal is the reported standard error squared."""
        if self.covariance is None:
            return None
        cov = np.array(self.covariance, dtype=float)
        if self.coef_stderr is None:
            return cov
        out = np.empty_like(cov)
        for i in range(cov.shape[0]):
            d = np.sqrt(np.clip(np.diag(cov[i]), 0, None))
            with np.errstate(divide="ignore", invalid="ignore"):
                corr = cov[i] / np.outer(d, d)
            corr = np.where(np.isfinite(corr), corr, 0.0)
            np.fill_diagonal(corr, 1.0)
            s = np.nan_to_num(self.coef_stderr[:, i])
            out[i] = corr * np.outer(s, s)
        return out

    def resampled(self, dt: float) -> Model:
        """The same dynamics at another sample time ``dt`` (s), for data logged at another rate.

        A linear discrete model ``x[k+1] = A_d x[k] + B_d u[k-d] + c_d`` is taken back to
        continuous time (zero-order hold inverted, as the reported ``A``, ``B``, ``c`` are) and
        discretised again at ``dt``; the delay is kept in seconds (whole plus fractional
        samples of the new step) and the input filters, defined in Hz, are unchanged. A
        continuous-time model only changes its step. Standard errors are not carried over
        (they belong to the fitted coefficients); ``provenance['resampled_from_dt']`` records
        the original step.

        Raises
        ------
        ConfigError
            A nonlinear library model, or a discrete model with no continuous equivalent
            (an eigenvalue of ``A_d`` on or left of the imaginary axis's image, <= 0).

        Examples
        --------
        >>> m = Model(("p",), ("u_roll",), ("p", "u_roll", "1"),
        ...           np.array([[0.99], [0.5], [0.0]]), dt=0.01, delay=2)
        >>> slow = m.resampled(0.04)
        >>> round(slow.params["A_d[p,p]"], 6), round(0.99 ** 4, 6)
        (0.960596, 0.960596)
        >>> round(slow.params["B[p,u_roll]"], 3) == round(m.params["B[p,u_roll]"], 3)
        True
        >>> slow.delay, slow.delay_frac
        (0, 0.5)
        """
        dt = float(dt)
        if not dt > 0:
            raise ConfigError(f"sample time must be > 0 s, got {dt:g}")
        total = (self.delay + self.delay_frac) * self.dt / dt
        whole = int(np.floor(total + 1e-9))
        frac = round(total - whole, 9) % 1.0
        prov = {**dict(self.provenance), "resampled_from_dt": self.dt}
        if self.continuous:
            return replace(self, dt=dt, delay=whole, delay_frac=frac, covariance=None,
                           coef_stderr=None, provenance=prov)
        if not library.is_linear(self.features):
            raise ConfigError("a nonlinear library model cannot be re-discretised; refit it at "
                              f"{1 / dt:.3g} Hz")
        states, exo, _ = self._split
        n, q = len(self.state_names), len(exo)
        ad = np.zeros((n, n))
        for j in states:
            ad[:, self.state_names.index(self.features[j])] = self.coef[j]
        ev = np.linalg.eigvals(ad)
        if np.any(np.abs(ev.imag) > 1e-12) or np.any(ev.real <= 0):
            raise ConfigError(f"the {1 / self.dt:.3g} Hz model has no continuous-time "
                              f"equivalent (eigenvalues {np.round(ev, 4).tolist()}); refit it at "
                              f"{1 / dt:.3g} Hz")
        phi, gamma = c2d(*d2c(ad, self.coef[exo].T.reshape(n, q), self.dt), dt)
        coef = np.zeros_like(self.coef)
        for j in states:
            coef[j] = phi[:, self.state_names.index(self.features[j])]
        coef[exo] = gamma.T
        return replace(self, coef=coef, dt=dt, delay=whole, delay_frac=frac, covariance=None,
                       coef_stderr=None, sigma=None, provenance=prov)

    # ----------------------------------------------------------------- rollouts

    def _check_segment(self, segment: Segment) -> None:
        if not np.isclose(segment.dt, self.dt, rtol=1e-3):
            raise ConfigError(f"segment dt {segment.dt:g} s differs from the model dt {self.dt:g}"
                              " s; resample the data or refit")

    def _measured(self, segment: Segment, filtered: Mapping[str, np.ndarray] | None = None
                  ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Measured modelled states (n, m) and every feature variable (inputs filtered and
        delayed, other variables as measured; ``filtered``: the inputs already through the
        model's filters, see :func:`~mavsid.estimators.regressors.variables`)."""
        self._check_segment(segment)
        var = variables(segment, self.structure,
                        library.variables_of(self.features) + self.state_names, filtered)
        x = np.column_stack([var[s] for s in self.state_names])
        return x, var

    def _affine(self, var: Mapping[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """Discrete-time transition ``Φ`` (m, m) and forcing ``f`` (n, m): x⁺ = Φx + f."""
        _, exo, _ = self._split
        n = len(next(iter(var.values())))
        feats = [self.features[j] for j in exo]
        forcing = (library.evaluate(feats, var) @ self.coef[exo] if exo
                   else np.zeros((n, len(self.state_names))))
        a = self.A
        if not self.continuous:
            return a, forcing
        phi, gamma = c2d(a, np.eye(len(self.state_names)), self.dt)
        return phi, forcing @ gamma.T

    def _stepper(self, var: Mapping[str, np.ndarray]) -> Callable[[np.ndarray, np.ndarray],
                                                                  np.ndarray]:
        """Generic one-step map ``(x (k, m), rows (k,)) -> x⁺`` for non-affine models."""
        names = library.variables_of(self.features)

        def rhs(x: np.ndarray, idx: np.ndarray) -> np.ndarray:
            v = {k: (x[:, self.state_names.index(k)] if k in self.state_names else var[k][idx])
                 for k in names}
            return library.evaluate(self.features, v) @ self.coef

        def step(x: np.ndarray, idx: np.ndarray) -> np.ndarray:
            if not self.continuous:
                return rhs(x, idx)
            h = self.dt
            k1 = rhs(x, idx)
            k2 = rhs(x + 0.5 * h * k1, idx)
            k3 = rhs(x + 0.5 * h * k2, idx)
            k4 = rhs(x + h * k3, idx)
            return x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)

        return step

    def simulate(self, segment: Segment, x0: np.ndarray | None = None) -> np.ndarray:
        """Free run: from the segment's first measured state (or ``x0``), measured inputs only,
        the model's own predictions fed back.

        Returns
        -------
        numpy.ndarray, shape (len(segment), len(state_names))
        """
        xm, var = self._measured(segment)
        return self._free_run(xm[0] if x0 is None else x0, var, len(xm))

    def _free_run(self, x0: np.ndarray, var: Mapping[str, np.ndarray], n: int) -> np.ndarray:
        """Free run of ``n`` samples from ``x0`` given every feature variable (inputs already
        filtered and delayed: see :meth:`_measured`)."""
        m = len(self.state_names)
        out = np.empty((n, m))
        out[0] = np.asarray(x0, dtype=float).reshape(m)
        if n == 1:
            return out
        if self.is_affine:
            phi, f = self._affine(var)
            if m == 1:
                out[1:, 0] = lfilter([1.0], [1.0, -phi[0, 0]], f[:-1, 0],
                                     zi=[phi[0, 0] * out[0, 0]])
                return out
            lam, vec = np.linalg.eig(phi)
            if np.linalg.cond(vec) < 1e8:  # modal form: one first-order recursion per mode
                vinv = np.linalg.inv(vec)
                g = f[:-1] @ vinv.T
                z0 = vinv @ out[0]
                modes = np.column_stack([
                    lfilter([1.0], [1.0, -lam[i]], g[:, i], zi=[lam[i] * z0[i]])
                    for i in range(m)])
                out[1:] = np.real(modes @ vec.T)
                return out
            x = out[0]
            for k in range(n - 1):
                x = phi @ x + f[k]
                out[k + 1] = x
            return out
        step = self._stepper(var)
        x2 = out[:1].copy()
        with np.errstate(over="ignore", invalid="ignore"):
            for k in range(n - 1):
                x2 = step(x2, np.array([k]))
                out[k + 1] = x2[0]
        return out

    def simulate_inputs(self, inputs: np.ndarray, x0: np.ndarray | None = None,
                        exogenous: Mapping[str, np.ndarray] | None = None) -> np.ndarray:
        """Free run from arrays: ``inputs`` (n, len(input_names)) in the model's input order,
        initial state ``x0`` (default zeros), other measured variables the features use in
        ``exogenous``.

        Examples
        --------
        >>> m = Model(("p",), ("u_roll",), ("p", "u_roll"), np.array([[0.5], [1.0]]), dt=0.01)
        >>> m.simulate_inputs(np.ones((4, 1))).ravel().tolist()
        [0.0, 1.0, 1.5, 1.75]
        """
        u = np.asarray(inputs, dtype=float).reshape(len(inputs), len(self.input_names))
        n = len(u)
        extra = dict(exogenous or {})
        x = np.zeros((n, len(self.state_names)))
        names = self.state_names + tuple(extra)
        states = np.column_stack([x] + [np.asarray(extra[k], float) for k in extra])
        seg = Segment(np.arange(n) * self.dt, states, u, names, self.input_names, self.dt,
                      "all", "scan")
        x0 = np.zeros(len(self.state_names)) if x0 is None else x0
        return self.simulate(seg, x0=x0)

    def predict(self, segment: Segment, horizon: int = 1) -> np.ndarray:
        """``horizon``-step-ahead prediction: row ``i`` is the prediction of sample ``i`` made
        from the measured state at ``i - horizon`` and the measured inputs; NaN for the first
        ``horizon`` rows.
        """
        return self.predict_horizons(segment, (horizon,))[0]

    def predict_horizons(self, segment: Segment, horizons: Sequence[int]) -> list[np.ndarray]:
        """:meth:`predict` at each of ``horizons`` (samples), the inputs filtered once.

        A stable one-state affine model predicts every horizon from one run ``z`` of its
        recursion from zero: ``x̂[i + h] = z[i + h] + aʰ (x[i] − z[i])`` (the forcing's sum
        over the horizon is ``z[i + h] − aʰ z[i]``), one pass per horizon instead of ``h``;
        other models step every start forward ``h`` times.
        """
        hs = [int(h) for h in horizons]
        if hs and min(hs) < 1:
            raise ConfigError(f"horizon must be >= 1 sample, got {min(hs)}")
        xm, var = self._measured(segment)
        n, m = xm.shape
        outs = [np.full((n, m), np.nan) for _ in hs]
        if not any(h < n for h in hs):
            return outs
        phi = f = z = None
        if self.is_affine:
            phi, f = self._affine(var)
            a = float(phi[0, 0]) if m == 1 else np.inf
            if abs(a) < 1.0 and np.isfinite(f).all():
                z = np.zeros(n)
                z[1:] = lfilter([1.0], [1.0, -a], f[:-1, 0])
        for h, out in zip(hs, outs, strict=True):
            if h >= n:
                continue
            with np.errstate(over="ignore", invalid="ignore"):
                if z is not None and phi is not None:
                    a = float(phi[0, 0])
                    out[h:, 0] = z[h:] + a**h * (xm[: n - h, 0] - z[: n - h])
                    continue
                starts = np.arange(n - h)
                x = xm[starts].copy()
                if phi is not None and f is not None:
                    for j in range(h):
                        x = x @ phi.T + f[starts + j]
                else:
                    step = self._stepper(var)
                    for j in range(h):
                        x = step(x, starts + j)
            out[h:] = x
        return outs

    # ----------------------------------------------------------------- export

    def statespace_matrices(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                           list[str], float]:
        """``(A, B, C, D, input_names, dt)`` of the linear part with the input filters in
        series and (discrete time) the input delay as extra states; numpy only (what
        :meth:`to_statespace` hands to python-control). ``dt`` is 0 for continuous time.

        Examples
        --------
        >>> m = Model(("p",), ("u_roll",), ("p", "u_roll"), np.array([[0.9], [0.5]]),
        ...           dt=0.01, delay=2)
        >>> a, b, c, d, ins, dt = m.statespace_matrices()
        >>> a.shape, ins, dt
        ((3, 3), ['u_roll'], 0.01)
        """
        if not library.is_linear(self.features):
            raise ConfigError("to_statespace needs a linear model; this one has library terms")
        _, exo, _ = self._split
        ins = [j for j in exo if self.features[j] != library.BIAS]
        m = len(self.state_names)
        plant = (self.A, self.coef[ins].T if ins else np.zeros((m, 0)), np.eye(m),
                 np.zeros((m, len(ins))))
        in_names = [self.features[j] for j in ins]
        dt = 0.0 if self.continuous else float(self.dt)
        nin = len(in_names)
        chain = None
        for flt in self.filters:
            if self.continuous:
                from scipy import signal

                num, den = signal.butter(flt.order, 2 * np.pi * flt.cutoff_hz, analog=True)
                one = tuple(np.atleast_2d(x) for x in tf2ss(num, den))
            else:
                one = tuple(np.atleast_2d(x) for x in flt.statespace(self.dt))
            block = _block_diagonal(one, nin)  # type: ignore[arg-type]
            chain = block if chain is None else _series(chain, block)
        if not self.continuous and (self.delay > 0 or self.delay_frac > 0) and nin:
            f = self.delay_frac
            num_d = [1.0 - f, f] if f > 0 else [1.0]
            den_d = [1.0] + [0.0] * (self.delay + (1 if f > 0 else 0))
            one = tuple(np.atleast_2d(x) for x in tf2ss(num_d, den_d))
            block = _block_diagonal(one, nin)  # type: ignore[arg-type]
            chain = block if chain is None else _series(chain, block)
        a, b, c, d = plant if chain is None else _series(chain, plant)
        return a, b, c, d, in_names, dt

    def to_statespace(self) -> Any:
        """A python-control ``StateSpace`` of :meth:`statespace_matrices` (labelled inputs
        and outputs).

        The bias ``c`` is left out (it is an operating-point offset). Continuous-time models
        do not include the delay (``control.pade`` approximates it). Raises ``ConfigError``
        for a model with nonlinear library terms and ``ImportError`` when python-control is
        not installed.
        """
        import control

        a, b, c, d, in_names, dt = self.statespace_matrices()
        return control.ss(a, b, c, d, dt if dt else 0, inputs=in_names,
                          outputs=list(self.state_names))

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe dictionary (non-finite numbers become ``null``)."""
        return _jsonable({
            "format": _FORMAT,
            "version": _VERSION,
            "state_names": self.state_names,
            "input_names": self.input_names,
            "features": self.features,
            "coef": self.coef,
            "dt": self.dt,
            "delay": self.delay,
            "delay_frac": self.delay_frac,
            "delay_s": (self.delay + self.delay_frac) * self.dt,
            "continuous": self.continuous,
            "filters": [f.to_dict() for f in self.filters],
            "covariance": self.covariance,
            "coef_stderr": self.coef_stderr,
            "sigma": self.sigma,
            "params": self.params,
            "stderr": self.stderr,
            "units": self.units,
            "provenance": self.provenance,
            "var_units": dict(self.var_units),
        })

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Model:
        """Rebuild a model written by :meth:`to_dict`."""
        if d.get("format") != _FORMAT:
            raise LogFormatError(f"not a mavsid model (format {d.get('format')!r})")
        version = d.get("version", _VERSION)
        if not whole_number(version) or version > _VERSION:
            raise LogFormatError(f"model format version {version!r}: this mavsid reads "
                                 f"version {_VERSION} and older (a newer mavsid wrote it?)")

        def arr(key: str) -> np.ndarray | None:
            v = d.get(key)
            if v is None:
                return None
            return np.array(_none_to_nan(v), dtype=float)

        try:
            dt, delay = float(d["dt"]), int(d["delay"])
            filters = tuple(InputFilter(float(f["cutoff_hz"]), int(f["order"]),
                                        str(f.get("source", "")),
                                        float(f.get("rate_hz", 0.0) or 0.0))
                            for f in d["filters"])
            coef = np.asarray(d["coef"], dtype=float)
            delay_frac = float(d.get("delay_frac", 0.0))
            spread = {k: arr(k) for k in ("covariance", "coef_stderr", "sigma")}
            _check_stored(dt, delay, delay_frac, filters, coef, len(d["features"]),
                          len(d["state_names"]), spread)
            return cls(
                state_names=tuple(d["state_names"]), input_names=tuple(d["input_names"]),
                features=tuple(d["features"]), coef=coef, dt=dt, delay=delay,
                continuous=bool(d["continuous"]), delay_frac=delay_frac, filters=filters,
                covariance=spread["covariance"], coef_stderr=spread["coef_stderr"],
                sigma=spread["sigma"], provenance=d.get("provenance") or {},
                var_units={str(k): str(v) for k, v in (d.get("var_units") or {}).items()},
            )
        except LogFormatError:
            raise
        except (KeyError, TypeError, ValueError, OverflowError) as exc:
            raise LogFormatError(f"model dictionary is incomplete or malformed: {exc}") from None

    def save(self, path: str | Path) -> None:
        """Write the model as JSON."""
        Path(path).write_text(json.dumps(self.to_dict(), indent=1))


def load_model(path: str | Path) -> Model:
    """Read a model saved by :meth:`Model.save`.

    Raises
    ------
    LogFormatError
        The file is not valid JSON or not a mavsid model.
    """
    try:
        d = json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise LogFormatError(f"cannot read model: {exc}", path=path) from None
    if not isinstance(d, dict):
        raise LogFormatError("not a mavsid model (JSON is not an object)", path=path)
    try:
        return Model.from_dict(d)
    except LogFormatError as exc:
        raise LogFormatError(exc.reason, path=path) from None
