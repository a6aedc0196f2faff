"""Regression rows from segments: what a model structure needs, stacked over many segments.

A :class:`Structure` says which outputs are modelled, from which features (states, inputs,
bias, library terms), with which input delay and input filters, in discrete time
(``x[k+1] = Θᵀ φ(x[k], u[k-d])``) or continuous time (``ẋ(t) = Θᵀ φ(x(t), u(t-d·dt))``, the
derivative estimated by Savitzky–Golay or total-variation regularisation).

Known linear filters that sit between the plant and the measurement (the gyro low-pass
``INS_GYRO_FILTER`` of ArduPilot, for instance) are modelled by filtering the *inputs*
with the same filter: for a linear plant ``F(z) P(z) u = P(z) F(z) u``, so the fitted
parameters stay those of the physical plant instead of absorbing the filter's lag.

Rows never straddle two segments: each segment contributes the rows whose every sample lies
inside it, and its rows are further cut into *blocks* (contiguous row ranges) which are the
unit of cross-validation and of the block bootstrap.

Examples
--------
>>> import numpy as np
>>> from mavsid.data import Segment
>>> t = np.arange(6) * 0.01
>>> seg = Segment(t, np.arange(6.0)[:, None], np.ones((6, 1)), ("p",), ("u_roll",), 0.01,
...               "roll", "scan")
>>> s = Structure(outputs=("p",), features=("p", "u_roll", "1"), delay=1)
>>> z, y = rows(seg, s)
>>> z.tolist()[:2], y.ravel().tolist()
([[1.0, 1.0, 1.0], [2.0, 1.0, 1.0]], [2.0, 3.0, 4.0, 5.0])
"""

from __future__ import annotations

import functools
import itertools
import math
import warnings
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from mavsid.data import Segment
from mavsid.errors import ConfigError, DataQualityWarning, NoExcitationError
from mavsid.estimators import library
from mavsid.numerics.filters import butter_lowpass, lfilter, lfilter_zi
from mavsid.numerics.lti import tf2ss

__all__ = [
    "InputFilter",
    "Regression",
    "Structure",
    "derivative",
    "filter_inputs",
    "filtered_inputs",
    "filters_from_params",
    "input_history",
    "rows",
    "segment_column",
    "stack",
    "variables",
]


@dataclass(frozen=True)
class InputFilter:
    """A known linear filter applied to the inputs before regression.

    Parameters
    ----------
    cutoff_hz : float
        Cut-off frequency (Hz).
    order : int
        Butterworth order (2 = ArduPilot's ``LowPassFilter2p`` biquad; 1 = first order).
    source : str
        Where it came from, e.g. ``"INS_GYRO_FILTER"``.
    rate_hz : float
        Rate the filter runs at (ArduPilot filters every gyro sample, typically 1 kHz or
        more, and the loop reads the latest output). 0: the data's own rate. When it is
        ``r ≥ 2`` times the data rate, the (held) input is filtered at ``r/dt`` and the last
        sub-sample of each step is kept.

    Examples
    --------
    >>> import numpy as np
    >>> f = InputFilter(20.0)
    >>> y = f.apply(np.ones(5), dt=0.0025)   # starts in steady state: a constant passes
    >>> bool(np.allclose(y, 1.0))
    True
    >>> InputFilter(20.0, rate_hz=1000.0).substeps(0.0025)
    2
    """

    cutoff_hz: float
    order: int = 2
    source: str = ""
    rate_hz: float = 0.0

    def substeps(self, dt: float) -> int:
        """Filter steps per data step."""
        return max(1, round(self.rate_hz * dt)) if self.rate_hz > 0 else 1

    def coefficients(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Discrete (bilinear, pre-warped) Butterworth ``(b, a)`` at the filter's own step
        (``dt`` divided by :meth:`substeps`)."""
        fs = self.substeps(dt) / dt
        if not 0 < self.cutoff_hz < 0.5 * fs:
            raise ConfigError(
                f"input filter {self.source or 'cut-off'} {self.cutoff_hz:g} Hz outside "
                f"(0, {0.5 * fs:g}) Hz at {fs:g} Hz"
            )
        b, a, _ = _design(self.order, float(self.cutoff_hz), float(fs))
        return b.copy(), a.copy()

    def statespace(self, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The filter as a discrete state space at the data step ``dt`` (input held over the
        step, output read at its last sub-step), exactly what :meth:`apply` computes."""
        b, a = self.coefficients(dt)
        af, bf, cf, df = tf2ss(b, a)
        r = self.substeps(dt)
        eye = np.eye(af.shape[0])
        powers = [np.linalg.matrix_power(af, i) for i in range(r)]
        big_a = powers[-1] @ af
        big_b = sum((powers[i] for i in range(r)), np.zeros_like(af)) @ bf
        c = cf @ powers[-1]
        d = cf @ sum((powers[i] for i in range(r - 1)), np.zeros_like(eye)) @ bf + df
        return big_a, big_b, c, d

    def apply(self, u: np.ndarray, dt: float) -> np.ndarray:
        """Filter along axis 0, starting in steady state at the first sample."""
        self.coefficients(dt)  # validates the cut-off against the rate
        r = self.substeps(dt)
        b, a, zi = _design(self.order, float(self.cutoff_hz), r / dt)
        u = np.asarray(u, dtype=float)
        fast = np.repeat(u, r, axis=0) if r > 1 else u
        zi = zi.reshape((-1,) + (1,) * (u.ndim - 1)) * u[:1]
        out = lfilter(b, a, fast, axis=0, zi=zi)
        return np.asarray(out[r - 1 :: r] if r > 1 else out)

    def to_dict(self) -> dict[str, object]:
        return {"cutoff_hz": self.cutoff_hz, "order": self.order, "source": self.source,
                "rate_hz": self.rate_hz}


@functools.lru_cache(maxsize=256)
def _design(order: int, cutoff_hz: float, fs: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Butterworth ``(b, a)`` and the steady-state initial condition, designed once per
    (order, cut-off, rate): the structure search and every rollout reuse them."""
    b, a = butter_lowpass(order, cutoff_hz, fs)
    zi = np.asarray(lfilter_zi(b, a), float)
    for arr in (b, a, zi):
        arr.flags.writeable = False
    return b, a, zi


def filters_from_params(params: Mapping[str, float], dt: float) -> tuple[InputFilter, ...]:
    """The known measurement filters that a log's parameters declare.

    ArduPilot: ``INS_GYRO_FILTER`` (Hz), the second-order low-pass on every gyro sample that
    the logged rates (RATE.R/P/Y, SIDD.G*) have passed through, running at the gyro rate
    ``INS_GYRO_RATE`` (0..3 = 1, 2, 4, 8 kHz; 1 kHz when absent). PX4: ``IMU_GYRO_CUTOFF``
    at ``IMU_GYRO_RATEMAX``. 0 or absent: no filter. A cut-off at or above the Nyquist
    frequency cannot be represented and is left out.

    Examples
    --------
    >>> filters_from_params({"INS_GYRO_FILTER": 20.0}, dt=0.0025)
    (InputFilter(cutoff_hz=20.0, order=2, source='INS_GYRO_FILTER', rate_hz=1000.0),)
    >>> filters_from_params({}, dt=0.0025)
    ()
    """
    out = []
    for name in ("INS_GYRO_FILTER", "IMU_GYRO_CUTOFF"):
        fc = float(params.get(name, 0.0) or 0.0)
        if not 0.0 <= fc < math.inf:
            warnings.warn(f"{name} = {fc:g} is no filter frequency (a damaged parameter?): "
                          "the logged rates are modelled as unfiltered", DataQualityWarning,
                          stacklevel=2)
        elif fc > 0.0:
            flt = InputFilter(fc, 2, name, rate_hz=max(_gyro_rate_hz(params, name), 1.0 / dt))
            if fc < 0.5 * flt.substeps(dt) / dt:
                out.append(flt)
    return tuple(out)


def _gyro_rate_hz(params: Mapping[str, float], filter_name: str) -> float:
    """The rate the gyro filter ``filter_name`` runs at by the log's parameters; 0 when
    unknown or damaged (the caller takes the log's rate). ArduPilot's ``INS_GYRO_RATE``
    0-3 is 1, 2, 4, 8 kHz (1 kHz otherwise); PX4's ``IMU_GYRO_RATEMAX`` up to 8 kHz.

    >>> _gyro_rate_hz({"INS_GYRO_RATE": 2}, "INS_GYRO_FILTER"), _gyro_rate_hz({}, "IMU_GYRO_CUTOFF")
    (4000.0, 0.0)
    """
    if filter_name == "INS_GYRO_FILTER":
        k = params.get("INS_GYRO_RATE", 0)
        return 1000.0 * 2 ** (int(k) if isinstance(k, (int, float)) and 0 <= k <= 3 else 0)
    rate = float(params.get("IMU_GYRO_RATEMAX", 0.0) or 0.0)
    return rate if 0.0 < rate <= _MAX_GYRO_RATE_HZ else 0.0  # (beyond any IMU's: damaged)


#: Fastest gyro sampling a parameter can state (PX4's IMU_GYRO_RATEMAX reaches 8 kHz)
_MAX_GYRO_RATE_HZ = 8000.0


@dataclass(frozen=True)
class Structure:
    """What to regress on what.

    Parameters
    ----------
    outputs : tuple of str
        The modelled states (their next value, or their derivative).
    features : tuple of str
        Regressors (see :mod:`mavsid.estimators.library`): states, inputs, ``"1"``, terms.
    inputs : tuple of str
        Which variables are inputs (filtered and delayed); default: every feature variable
        whose name starts with ``u_``.
    delay : int
        Input delay in samples.
    delay_frac : float
        Further fraction of a sample (0 <= f < 1): the input enters as
        ``(1 − f) u[k−d] + f u[k−d−1]``, which is exact for held (zero-order-hold) inputs
        acting on a plant that integrates them over the sample.
    continuous : bool
        Continuous time (derivatives) instead of discrete time (next sample).
    filters : tuple of InputFilter
        Applied to the inputs in order.
    derivative : str
        ``"savgol"`` or ``"tv"`` (continuous time only).
    window : int
        Savitzky–Golay window (odd, samples); also rows trimmed at each end.
    tv_weight : float
        Regularisation of the TV derivative (relative; see :func:`derivative`).
    """

    outputs: tuple[str, ...]
    features: tuple[str, ...]
    inputs: tuple[str, ...] = ()
    delay: int = 0
    delay_frac: float = 0.0
    continuous: bool = False
    filters: tuple[InputFilter, ...] = ()
    derivative: str = "savgol"
    window: int = 9
    tv_weight: float = 1e-3

    def __post_init__(self) -> None:
        if self.delay < 0:
            raise ConfigError(f"delay must be >= 0 samples, got {self.delay}")
        if not 0.0 <= self.delay_frac < 1.0:
            raise ConfigError(f"delay_frac must be in [0, 1), got {self.delay_frac}")
        if not self.outputs or not self.features:
            raise ConfigError("a structure needs at least one output and one feature")
        for f in self.features:
            library.parse(f)
        if not self.inputs:
            ins = tuple(v for v in library.variables_of(self.features) if v.startswith("u_"))
            object.__setattr__(self, "inputs", ins)
        if self.derivative not in ("savgol", "tv"):
            raise ConfigError(f"derivative must be 'savgol' or 'tv', got {self.derivative!r}")

    @property
    def lead(self) -> int:
        """Samples lost at the start of every segment (delay, derivative window)."""
        d = self.delay + (1 if self.delay_frac > 0 else 0)
        return max(d, self.window // 2 if self.continuous else 0)

    @property
    def trail(self) -> int:
        """Samples lost at the end of every segment."""
        return self.window // 2 if self.continuous else 1


@dataclass(frozen=True)
class Regression:
    """Stacked rows of several segments.

    Attributes
    ----------
    z : numpy.ndarray, shape (n, p)
        Regressors, one column per feature.
    y : numpy.ndarray, shape (n, m)
        Targets (next state or derivative), one column per output.
    structure : Structure
    blocks : numpy.ndarray, shape (k, 4)
        ``[row_start, row_stop, segment_index, sample_start]`` of each block; the rows of a
        block are the samples ``sample_start ... sample_start + rows`` of that segment.
    segments : tuple of Segment
    """

    z: np.ndarray
    y: np.ndarray
    structure: Structure
    blocks: np.ndarray
    segments: tuple[Segment, ...] = field(repr=False)

    @property
    def n(self) -> int:
        return int(self.z.shape[0])


def segment_column(segment: Segment, name: str) -> tuple[np.ndarray, bool]:
    """A segment column by name and whether it is an input."""
    if name in segment.input_names:
        return segment.inputs[:, segment.input_names.index(name)], True
    if name in segment.state_names:
        return segment.states[:, segment.state_names.index(name)], False
    raise ConfigError(
        f"segment has no column {name!r} (states {segment.state_names}, "
        f"inputs {segment.input_names})"
    )


def filter_inputs(u: np.ndarray, dt: float, filters: Iterable[InputFilter]) -> np.ndarray:
    """Apply the filters in order along axis 0."""
    for f in filters:
        u = f.apply(u, dt)
    return u


def _shift(u: np.ndarray, d: int, frac: float = 0.0) -> np.ndarray:
    """``u`` delayed by ``d + frac`` samples (held at the first value before it starts)."""
    if d >= len(u):
        return np.repeat(u[:1], len(u), axis=0)
    out = np.concatenate([np.repeat(u[:1], d, axis=0), u[: len(u) - d]], axis=0) if d else u
    if frac > 0:
        out = (1.0 - frac) * out + frac * _shift(u, d + 1)
    return out


def filtered_inputs(segment: Segment, names: Sequence[str],
                    filters: Iterable[InputFilter]) -> np.ndarray:
    """The inputs ``names`` of ``segment`` through ``filters``, from its input history on:
    ``(k + n, len(names))``, the ``k`` rows of ``segment.inputs_before`` first (the filters
    start in steady state at the history's first input, or the segment's without one).

    Examples
    --------
    >>> import dataclasses
    >>> from mavsid.data import Segment
    >>> u = np.r_[np.zeros(50), np.ones(5)][:, None]
    >>> seg = Segment(np.arange(55) * 0.01, u, u, ("p",), ("u_roll",), 0.01, "roll", "scan")
    >>> lag = (InputFilter(5.0, order=1),)
    >>> block = seg.cut(50, 55)  # the step's first 5 samples, 50 before them
    >>> warm = filtered_inputs(block, ["u_roll"], lag)
    >>> cold = filtered_inputs(dataclasses.replace(block, inputs_before=None), ["u_roll"], lag)
    >>> warm.shape, round(float(warm[50, 0]), 2), round(float(cold[0, 0]), 6)  # (or already 1)
    ((55, 1), 0.14, 1.0)
    """
    cols = [segment_column(segment, v)[0] for v in names]
    u = np.column_stack(cols).astype(float) if cols else np.empty((len(segment), 0))
    before = input_history(segment, names)
    if before is not None:
        u = np.concatenate([before, u], axis=0)
    return filter_inputs(u, segment.dt, filters)


def input_history(segment: Segment, names: Sequence[str]) -> np.ndarray | None:
    """The rows of ``segment.inputs_before`` for the inputs ``names`` (None without a
    history or when a name is not among the segment's inputs)."""
    before = segment.inputs_before
    if before is None or not len(before) or not set(names) <= set(segment.input_names):
        return None
    return np.asarray(before, float)[:, [segment.input_names.index(v) for v in names]]


def variables(
    segment: Segment, structure: Structure, names: Sequence[str] | None = None,
    filtered: Mapping[str, np.ndarray] | None = None,
) -> dict[str, np.ndarray]:
    """Every variable the structure needs, full segment length: inputs filtered and delayed
    from the segment's input history on (:func:`filtered_inputs`; without one, held at
    their first filtered value before the delay has elapsed), states as measured.
    ``filtered``: the inputs already through ``structure.filters`` (input name -> column,
    from the history's first row, as :func:`filtered_inputs` gives them), as the structure
    search keeps them; they are then only delayed."""
    names = tuple(names) if names is not None else library.variables_of(structure.features)
    out: dict[str, np.ndarray] = {}
    ins = [v for v in names if v in structure.inputs]
    if ins and filtered is not None and all(v in filtered for v in ins):
        u = np.column_stack([filtered[v] for v in ins]).astype(float)
    elif ins:
        u = filtered_inputs(segment, ins, structure.filters)
    if ins:
        u = _shift(u, structure.delay, structure.delay_frac)[len(u) - len(segment):]
        out.update({v: u[:, i] for i, v in enumerate(ins)})
    for v in names:
        if v not in out:
            out[v] = np.asarray(segment_column(segment, v)[0], dtype=float)
    return out


def derivative(x: np.ndarray, dt: float, method: str = "savgol", window: int = 9,
               tv_weight: float = 1e-3, iterations: int = 20) -> np.ndarray:
    """Time derivative along axis 0.

    ``"savgol"``: Savitzky–Golay (cubic, ``window`` samples). ``"tv"``: the signal is first
    smoothed by ℓ1 trend filtering, ``min ½‖x̂ − x‖² + λ‖D²x̂‖₁`` (piecewise-linear x̂, hence a
    piecewise-constant derivative: the total-variation-regularised derivative), solved by
    iteratively reweighted banded least squares, then differenced centrally. The weight is
    relative: ``λ = tv_weight · ‖x − x̄‖² / ‖D²x‖₁``, which makes both terms comparable at
    ``tv_weight = 1``.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(200) * 0.01
    >>> d = derivative(np.sin(t), 0.01)
    >>> bool(np.allclose(d[10:-10], np.cos(t[10:-10]), atol=1e-6))
    True
    >>> d = derivative(np.sin(t), 0.01, method="tv", tv_weight=1e-6)
    >>> bool(np.allclose(d[10:-10], np.cos(t[10:-10]), atol=1e-2))
    True
    """
    x = np.asarray(x, dtype=float)
    if method == "savgol":
        w = max(5, window | 1)
        if x.shape[0] < w:
            raise NoExcitationError(f"segment of {x.shape[0]} samples shorter than the "
                                    f"derivative window {w}")
        from scipy import signal

        return np.asarray(signal.savgol_filter(x, w, 3, deriv=1, delta=dt, axis=0))
    if method != "tv":
        raise ConfigError(f"derivative method must be 'savgol' or 'tv', got {method!r}")
    from scipy import sparse
    from scipy.sparse import linalg as splinalg

    two_d = x.reshape(x.shape[0], -1)
    out = np.empty_like(two_d)
    n = two_d.shape[0]
    d2 = sparse.diags([1.0, -2.0, 1.0], [0, 1, 2], shape=(n - 2, n), format="csc")
    eye = sparse.identity(n, format="csc")
    for j in range(two_d.shape[1]):
        col = two_d[:, j]
        rough = float(np.abs(np.diff(col, 2)).sum()) or 1.0
        lam = tv_weight * float(((col - col.mean()) ** 2).sum()) / rough
        scale = rough / n
        xh = col.copy()
        for _ in range(iterations):
            w = 1.0 / np.maximum(np.abs(d2 @ xh), 1e-6 * scale)
            xh = splinalg.spsolve((eye + lam * d2.T @ sparse.diags(w) @ d2).tocsc(), col)
        out[:, j] = np.gradient(xh, dt)
    return out.reshape(x.shape)


def rows(segment: Segment, structure: Structure) -> tuple[np.ndarray, np.ndarray]:
    """Regressors and targets of one segment.

    Discrete: rows ``k = delay ... n-2`` with target ``x[k+1]``. Continuous: rows inside the
    derivative window with target ``ẋ[k]``. No row uses a held (pre-delay) input.
    """
    n = len(segment)
    lead, trail = structure.lead, structure.trail
    if n - lead - trail < 1:
        return np.empty((0, len(structure.features))), np.empty((0, len(structure.outputs)))
    var = variables(segment, structure)
    z = library.evaluate(structure.features, var)[lead : n - trail]
    x = np.column_stack([segment_column(segment, o)[0] for o in structure.outputs]).astype(float)
    if structure.continuous:
        y = derivative(x, segment.dt, structure.derivative, structure.window,
                       structure.tv_weight)[lead : n - trail]
    else:
        y = x[lead + 1 : n]
    ok = np.isfinite(z).all(axis=1) & np.isfinite(y).all(axis=1)
    if not ok.all():
        warnings.warn(f"{segment.log or 'segment'} {segment.start_s:.3f}-{segment.stop_s:.3f} s: "
                      f"{int((~ok).sum())} of {len(ok)} rows with non-finite values left out",
                      DataQualityWarning, stacklevel=2)
        z, y = z[ok], y[ok]
    return z, y


def stack(
    segments: Sequence[Segment], structure: Structure, min_blocks: int = 10,
    block_rows: int | None = None
) -> Regression:
    """Rows of every segment, stacked; each segment cut into blocks.

    Parameters
    ----------
    segments : sequence of Segment
        All must share ``dt`` (relative tolerance 1e-6).
    structure : Structure
    min_blocks : int
        When ``block_rows`` is not given, segments are cut so that there are at least this
        many blocks in all (a segment is never cut below 50 rows).
    block_rows : int, optional
        Rows per block.
    """
    segments = tuple(segments)
    if not segments:
        raise NoExcitationError("no segments to fit")
    dt = segments[0].dt
    for s in segments:
        if not np.isclose(s.dt, dt, rtol=1e-6):
            raise ConfigError(f"segments differ in dt ({s.dt:g} s vs {dt:g} s); resample first")
    zs, ys, blocks = [], [], []
    parts = [rows(s, structure) for s in segments]
    total = sum(len(z) for z, _ in parts)
    if block_rows is None:
        block_rows = max(50, total // max(min_blocks, 1))
    start = 0
    for i, (z, y) in enumerate(parts):
        m = len(z)
        if m == 0:
            continue
        k = max(1, m // block_rows)
        edges = np.linspace(0, m, k + 1).astype(int)
        for a, b in itertools.pairwise(edges):
            blocks.append((start + a, start + b, i, structure.lead + a))
        zs.append(z)
        ys.append(y)
        start += m
    if not zs:
        raise NoExcitationError(
            f"segments too short for the structure (each loses {structure.lead + structure.trail}"
            " samples to delay and derivative window)"
        )
    return Regression(
        z=np.concatenate(zs), y=np.concatenate(ys), structure=structure,
        blocks=np.asarray(blocks, dtype=int), segments=segments,
    )
