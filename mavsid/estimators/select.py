"""Structure from data: which input lag and which delay, chosen by the one-step residual.

The search is what :func:`~mavsid.estimators.identification.identify` (``delay="search"``)
and the log path's :func:`~mavsid.estimators.axis_fit.fit_axis` run before fitting:

* a first-order input lag (motor and ESC response, in no log parameter) and the input delay
  ``d`` (whole samples, then fractions of a sample around the best) are chosen together;
* each candidate is scored by the mean squared one-step residual of a least-squares fit;
* parsimony: the simplest (lag, delay) within ``structure_tol`` of the best wins;
* on noisy data (see :data:`ONE_STEP_NOISE`)
  :func:`~mavsid.estimators.identification.identify_segments` then re-chooses the lag by the
  output-error cost of each lag's best delay (:attr:`StructureChoice.by_lag`).

Cost: the candidates share their rows. For a linear discrete-time structure the inputs are
filtered once per lag (the Butterworth designs are cached), every delayed copy of them is
one column of a single Gram matrix, and a candidate's Gram (including a fractional delay,
``(1 − f) u[k−d] + f u[k−d−1]``, which is linear in two delayed copies) is a small projection
of it plus the few rows at the record's start that only shorter delays use. Scores are
therefore exact (the same rows and sums as refitting each candidate), and the search costs
one pass over the data per lag: the regressors no lag changes (states, bias, outputs) and
their Gram are formed once for every lag, a lag adds its inputs' cross-products with them
(one correlation per regressor) and its lagged input products; a lag's candidate delays are
projected and solved together (:meth:`DelayScan.mse_many`). Each lag's filtered inputs are
kept (:attr:`StructureChoice.inputs`) for the neighbouring lags' refinements. Other
structures (continuous time, nonlinear libraries) are scored candidate by candidate. The
least-squares coefficients of each lag's best delay come from the same Gram
(:attr:`StructureChoice.ls_coef`): what the neighbouring lags' output-error refinements start
from (:func:`~mavsid.estimators.output_error.output_error_coef`).

The default search ranges are the module constants below (``DEFAULT_*``).

Examples
--------
>>> import numpy as np
>>> from mavsid.data import Segment
>>> from mavsid.estimators.regressors import Structure
>>> rng = np.random.default_rng(3)
>>> u = rng.standard_normal(2000) * 0.05
>>> p = np.zeros(2000)
>>> for k in range(1999):  # the input before the record is taken as its first value
...     p[k + 1] = 0.98 * p[k] + 0.4 * u[max(k - 3, 0)]
>>> seg = Segment(np.arange(2000) * 0.0025, p[:, None], u[:, None], ("p",), ("u_roll",),
...               0.0025, "roll", "sysid")
>>> best, scan = select_delay([seg], Structure(("p",), ("p", "u_roll", "1")), range(6))
>>> best, bool(scan[3.0] < 1e-12 * scan[2.0])  # exact at 3 (to rounding)
(3.0, True)
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from mavsid.axes import AXES as ATTITUDE_AXES
from mavsid.axes import INPUT_OF, RATE_OF, RATES
from mavsid.data import Segment
from mavsid.errors import ConfigError, NoExcitationError
from mavsid.estimators import library
from mavsid.estimators.base import Estimator, Gram, block_grams, check_identifiable, solve
from mavsid.estimators.l1 import ElasticNet, Lasso
from mavsid.estimators.least_squares import STLSQ, LeastSquares, Ridge
from mavsid.estimators.regressors import (
    InputFilter,
    Structure,
    filter_inputs,
    filtered_inputs,
    segment_column,
    stack,
)

__all__ = [
    "AXES",
    "DEFAULT_DELAY_STEP",
    "DEFAULT_LAGS_S",
    "DEFAULT_MAX_DELAY_S",
    "DEFAULT_STRUCTURE_TOL",
    "ESTIMATORS",
    "LAG_OE_TOL",
    "LAG_PRUNE",
    "LAG_SOURCE",
    "LONG_LAGS_S",
    "ONE_STEP_NOISE",
    "DelayScan",
    "StructureChoice",
    "is_lag_filter",
    "lag_filter",
    "make_estimator",
    "search_structure",
    "select_delay",
    "with_lag",
]

#: Axis -> (modelled states, inputs).
AXES: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    **{a: ((RATE_OF[a],), (INPUT_OF[a],)) for a in ATTITUDE_AXES},
    "all": (RATES, tuple(INPUT_OF.values())),
}

#: Default candidates for a first-order input (motor) lag, s.
DEFAULT_LAGS_S: tuple[float, ...] = (0.0, 0.005, 0.01, 0.015, 0.02, 0.03, 0.04, 0.06)
#: Longer lags searched too when the longest default one scores best by more than the
#: parsimony margin (a heavy-lift frame's large propellers: motor time constants of 80-150 ms)
LONG_LAGS_S: tuple[float, ...] = (0.08, 0.1, 0.13, 0.17)

#: Noisy data (best one-step residual RMS over ``ONE_STEP_NOISE`` of the output's RMS about
#: its mean, i.e. a one-step fit under 99 %; clean simulated and SITL chirps reach 0.2-0.8 %,
#: simulated gyros with 1-3 deg/s of noise 1.2-9 %) with coefficients refined by output
#: error: the lag is chosen by
#: the free-run (output-error) cost instead, among the lags whose one-step score lies within
#: ``LAG_PRUNE`` of the best, the shortest whose output-error cost lies within ``LAG_OE_TOL``
#: of the lowest. Gyro noise fed back through the controller swamps the one-step score's
#: sensitivity to the motor lag (a 15 ms lag then scores within 0.2 % of none); the free run
#: still sees it, though its cost is flat near its minimum and drifts to longer lags under
#: noise, hence the parsimony margin. On clean data the one-step score is the sharper one
#: (a chirp's training block holds its low frequencies only), so it decides there. The
#: bound lies between the two populations measured: clean logs at most 0.8 %, any fed-back
#: gyro noise from 1 deg/s up at least 1.2 %. At 2 % (the bound before) 1-3 deg/s at
#: 1.2-1.7 % left the lag to one step, which picked 0-5 ms against true 15-30 ms (on a
#: clean chirp's training block a lag 5 ms off the truth scores only 1-1.4 % worse in mean
#: square, a signature such noise in the regressors outweighs): B -9 % at 8 σ, free run
#: 40-67 % where the true plant reaches 87-93 % (``bench_variety.py`` seeds 101, 202).
ONE_STEP_NOISE = 0.01
LAG_PRUNE = 0.25
LAG_OE_TOL = 0.03

#: Longest input delay searched by default, s.
DEFAULT_MAX_DELAY_S: float = 0.025

#: Resolution of the fractional delay search around the best whole sample, samples.
DEFAULT_DELAY_STEP: float = 0.125

#: Parsimony: the simplest candidate within this fraction of the best one-step residual wins.
DEFAULT_STRUCTURE_TOL: float = 0.005

#: Estimator name -> class.
ESTIMATORS: dict[str, type[Estimator]] = {
    "ls": LeastSquares,
    "ridge": Ridge,
    "l1": Lasso,
    "lasso": Lasso,
    "elasticnet": ElasticNet,
    "stlsq": STLSQ,
}


def make_estimator(name: str, structure: Structure | None = None, **kwargs: object
                   ) -> Estimator:
    """An estimator by name (``ls``, ``ridge``, ``l1``, ``elasticnet``, ``stlsq``)."""
    try:
        cls = ESTIMATORS[name]
    except KeyError:
        raise ConfigError(f"unknown estimator {name!r}; choose from {sorted(ESTIMATORS)}") \
            from None
    try:
        return cls(structure, **kwargs)  # type: ignore[arg-type]
    except TypeError as exc:
        raise ConfigError(f"estimator {name!r}: {exc}") from None


#: the ``source`` of the input-lag filter
LAG_SOURCE = "input lag"


def lag_filter(lag_s: float) -> tuple[InputFilter, ...]:
    """A first-order input lag (motor/ESC response) as a filter; none for 0.

    Examples
    --------
    >>> lag_filter(0.0), round(lag_filter(0.02)[0].cutoff_hz, 3)
    ((), 7.958)
    """
    if lag_s <= 0:
        return ()
    return (InputFilter(1.0 / (2 * np.pi * lag_s), 1, f"{LAG_SOURCE} {lag_s * 1e3:g} ms"),)


def is_lag_filter(source: object) -> bool:
    """Whether a filter's ``source`` names the input lag :func:`lag_filter` makes (shown as
    the lag, not among the known filters).

    Examples
    --------
    >>> is_lag_filter(lag_filter(0.02)[0].source), is_lag_filter("INS_GYRO_FILTER")
    (True, False)
    """
    return str(source or "").startswith(LAG_SOURCE)


def _split_delay(dly: float) -> tuple[int, float]:
    d = int(np.floor(dly + 1e-9))
    return d, round(float(dly) - d, 9) % 1.0


def _shift_needed(dly: float) -> int:
    """Oldest input sample a delay uses (``d + 1`` for a fractional delay ``d + f``)."""
    d, f = _split_delay(dly)
    return d + (1 if f > 0 else 0)


class _StaticRows:
    """What every candidate lag's :class:`DelayScan` shares: per segment the regressors that
    are not delayed inputs (the structure's other features, the bias, then the outputs one
    step ahead) as rows ``(n_stat, n - 1)``, None when not finite, and the Gram of their
    columns from ``k_max + 1`` on."""

    def __init__(self, segments: Sequence[Segment], structure: Structure, k_max: int) -> None:
        st = structure
        self.others = [f for f in st.features if f != library.BIAS and f not in st.inputs]
        self.outputs = list(st.outputs)
        self.has_bias = library.BIAS in st.features
        self.k_max = k_max
        self.rows: list[np.ndarray | None] = []
        self.tail: list[np.ndarray | None] = []
        n_stat = len(self.others) + int(self.has_bias) + len(self.outputs)
        for seg in segments:
            n = len(seg)
            if n < 2:
                self.rows.append(None)
                self.tail.append(None)
                continue
            w = np.empty((n_stat, n - 1))
            c = 0
            for v in self.others:
                w[c] = np.asarray(segment_column(seg, v)[0], float)[:-1]
                c += 1
            if self.has_bias:
                w[c] = 1.0
                c += 1
            for v in self.outputs:
                w[c] = np.asarray(segment_column(seg, v)[0], float)[1:]
                c += 1
            if not np.isfinite(w).all():
                self.rows.append(None)
                self.tail.append(None)
                continue
            head = min(k_max + 1, n - 1)
            self.rows.append(w)
            self.tail.append(w[:, head:] @ w[:, head:].T)


class DelayScan:
    """One-step mean squared residual of a structure at many input delays, from one Gram.

    Parameters
    ----------
    segments : sequence of Segment
    structure : Structure
        Discrete time, linear features (states, inputs, bias); its ``delay`` is ignored.
    max_shift : int
        Largest delay (whole samples, a fractional delay ``d + f`` needs ``d + 1``).
    inputs : list of numpy.ndarray, optional
        The structure's inputs per segment, already filtered by ``structure.filters``.
    static : _StaticRows, optional
        The rows no lag changes, shared by the scans of every candidate lag (built here when
        not given).

    Raises
    ------
    ValueError
        When the structure is not linear and discrete, or rows are not finite (callers then
        score candidates one by one).
    """

    def __init__(self, segments: Sequence[Segment], structure: Structure, max_shift: int,
                 inputs: Sequence[np.ndarray] | None = None,
                 static: _StaticRows | None = None) -> None:
        st = structure
        if st.continuous or not library.is_linear(st.features):
            raise ValueError("fast delay scan needs a linear discrete-time structure")
        self.structure = st
        self.max_shift = k_max = int(max_shift)
        ins = [f for f in st.features if f in st.inputs]
        others = [f for f in st.features if f != library.BIAS and f not in st.inputs]
        self._ins, self._others = ins, others
        has_bias = library.BIAS in st.features
        if static is None:
            static = _StaticRows(segments, st, k_max)
        elif (static.others, static.outputs, static.has_bias, static.k_max) != (
                others, list(st.outputs), has_bias, k_max):
            raise ValueError("static rows of another structure")
        q = len(others) + len(ins) * (k_max + 1) + int(has_bias) + len(st.outputs)
        suffix = np.zeros((k_max + 2, q, q))
        n_oth, k1 = len(others), k_max + 1
        # the regressors that are not delayed inputs: others, bias, outputs
        stat = np.r_[np.arange(n_oth), np.arange(n_oth + len(ins) * k1, q)].astype(int)
        dyn = np.arange(n_oth, n_oth + len(ins) * k1)
        self._blocks = (np.ix_(stat, stat), np.ix_(stat, dyn), np.ix_(dyn, stat))
        self._lengths = []
        for si, seg in enumerate(segments):
            n = len(seg)
            self._lengths.append(n)
            if n < 2:
                continue
            if inputs is not None:
                u = inputs[si]
            elif ins:
                u = filtered_inputs(seg, ins, st.filters)[-n:]
            else:
                u = np.empty((n, 0))
            srows, stat_gram = static.rows[si], static.tail[si]
            if srows is None or stat_gram is None:
                raise ValueError("non-finite rows")
            if ins and not np.isfinite(u[: n - 1]).all():
                raise ValueError("non-finite rows")
            head = min(k_max + 1, n - 1)
            # the rows as columns (one contiguous row per regressor): the first ``head``
            # rows, where the delayed inputs are held at their first value
            wh = np.empty((q, head))
            wh[stat] = srows[:, :head]
            # u[k - j] for j = 0 … k_max, held at u[0] before it starts
            held = np.maximum(np.arange(head)[None, :] - np.arange(k1)[:, None], 0)
            for i in range(len(ins)):
                wh[n_oth + i * k1 : n_oth + (i + 1) * k1] = np.asarray(u[:, i], float)[held]
            suffix[:head] += np.einsum("ir,jr->rij", wh, wh)
            if head == k1 and ins and n - 1 > head:
                suffix[head] += self._tail_gram(srows, stat_gram, head, u, stat, dyn)
            else:  # every row is in the head (short record) or nothing is delayed
                wt = np.empty((q, n - 1 - head))
                wt[stat] = srows[:, head:]
                c = n_oth
                for i in range(len(ins)):
                    for j in range(k1):
                        wt[c] = u[head - j : n - 1 - j, i]
                        c += 1
                suffix[head] += wt @ wt.T
        # suffix[r]: row r alone (r < head) or every row from head on; summed from the end,
        # _cum[l] is the Gram of the rows k >= l of every segment
        self._cum = np.cumsum(suffix[::-1], axis=0)[::-1]
        self._has_bias = has_bias

    def _tail_gram(self, srows: np.ndarray, stat_gram: np.ndarray, head: int, u: np.ndarray,
                   stat: np.ndarray, dyn: np.ndarray) -> np.ndarray:
        """The entries of the Gram of the rows ``head …`` that candidates use: the
        undelayed regressors against each other (``stat_gram``, the same for every lag) and
        against every delayed input (one product), and the delayed inputs against each other
        only at shifts at most one apart (a delay ``d + f`` uses ``u[k-d]`` and
        ``u[k-d-1]``), as sums of lagged products over shifted windows: the whole sum less
        the few terms each window leaves out at either end. Other entries stay zero (no
        candidate reads them)."""
        n = srows.shape[1] + 1
        q = len(stat) + len(dyn)
        k1 = self.max_shift + 1
        n_oth = len(self._others)
        g = np.zeros((q, q))
        ss, sd, ds = self._blocks
        g[ss] = stat_gram
        # each undelayed regressor against u[k - j], j = 0 … k_max, over the rows
        # k = head … n-2 (head = k_max + 1): one correlation per pair, its lags reversed
        part = np.empty((len(stat), len(dyn)))
        for i in range(len(self._ins)):
            ui = u[1 : n - 1, i]
            for r, row in enumerate(srows[:, head:]):
                part[r, i * k1 : (i + 1) * k1] = np.correlate(ui, row, "valid")[::-1]
        g[sd] = part
        g[ds] = part.T
        js = np.arange(k1)
        ms = np.arange(n - 2 - k1, n - 1)  # the last k1 + 1 terms of a lagged product
        for i in range(len(self._ins)):
            for i2 in range(len(self._ins)):
                for lag in (0, 1):
                    if lag == 0 and i2 < i:
                        continue
                    # sum over rows k of u_i[k - j] u_i2[k - j - lag], j = 0 … k_max - lag:
                    # m = k - j runs over [head - j, n - 2 - j]; prod[m] = u_i[m] u_i2[m - lag]
                    # (0 for m < lag), summed whole by one product, its ends apart
                    total = float(u[lag : n - 1, i] @ u[: n - 1 - lag, i2])
                    first = np.zeros(k1 + 1)
                    first[lag:] = u[lag : k1 + 1, i] * u[: k1 + 1 - lag, i2]
                    last = np.where(ms >= lag, u[ms, i] * u[ms - lag, i2], 0.0)
                    pre = np.concatenate([[0.0], np.cumsum(first)])
                    post = np.concatenate([[0.0], np.cumsum(last[::-1])])
                    j = js[: k1 - lag]
                    vals = total - pre[head - j] - post[j]
                    at_r = n_oth + i * k1 + j
                    at_c = n_oth + i2 * k1 + j + lag
                    g[at_r, at_c] = vals
                    g[at_c, at_r] = vals
        return g

    def _grams(self, dlys: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
        """The Grams ``[Z Y]ᵀ[Z Y]`` of the rows fits at the delays ``dlys`` (samples) use,
        stacked (k, p + m, p + m), and their row counts (k,)."""
        st = self.structure
        split = [_split_delay(v) for v in dlys]
        leads = np.array([d + (1 if f > 0 else 0) for d, f in split], dtype=int)
        if len(leads) and leads.max() > self.max_shift:
            bad = float(np.asarray(dlys)[int(np.argmax(leads))])
            raise ConfigError(f"delay {bad:g} beyond the scan's {self.max_shift} samples")
        k = len(split)
        q = self._cum.shape[1]
        p, m = len(st.features), len(st.outputs)
        whole = np.array([d for d, _ in split], dtype=int)
        frac = np.array([f for _, f in split], dtype=float)
        t = np.zeros((k, q, p + m))
        n_oth, k1 = len(self._others), self.max_shift + 1
        cand = np.arange(k)
        for j, feat in enumerate(st.features):
            if feat == library.BIAS:
                t[:, n_oth + len(self._ins) * k1, j] = 1.0
            elif feat in st.inputs:
                base = n_oth + self._ins.index(feat) * k1
                t[cand, base + whole, j] = 1.0 - frac
                on = frac > 0
                t[cand[on], base + whole[on] + 1, j] = frac[on]
            else:
                t[:, self._others.index(feat), j] = 1.0
        for i in range(m):
            t[:, q - m + i, p + i] = 1.0
        full = np.transpose(t, (0, 2, 1)) @ self._cum[leads] @ t
        lengths = np.asarray(self._lengths, dtype=int)
        rows = np.maximum(lengths[None, :] - 1 - leads[:, None], 0).sum(axis=1)
        return full, rows

    def gram(self, dly: float) -> Gram:
        """The Gram ``[Z Y]ᵀ[Z Y]`` of the rows a fit at delay ``dly`` (samples) uses."""
        full, rows = self._grams([dly])
        p = len(self.structure.features)
        return Gram(full[0, :p, :p], full[0, :p, p:], full[0, p:, p:], int(rows[0]))

    def mse(self, dly: float) -> float | None:
        """Mean squared one-step residual (over rows and outputs) of the least-squares fit at
        ``dly``; None when no segment is long enough."""
        return self.mse_many([dly])[0]

    def mse_many(self, dlys: Sequence[float]) -> list[float | None]:
        """:meth:`mse` of every delay in ``dlys``, the candidates' Grams projected and solved
        together (the same numbers as one by one)."""
        if not len(dlys):
            return []
        full, rows = self._grams(dlys)
        p = len(self.structure.features)
        zz, zy, yy = full[:, :p, :p], full[:, :p, p:], full[:, p:, p:]
        n = np.maximum(rows, 1).astype(float)
        # the least-squares solution of the (tiny) unit-RMS-scaled Gram; solve()'s Cholesky
        # path would give the same numbers at ten times the call overhead
        s = np.sqrt(np.clip(np.diagonal(zz, axis1=1, axis2=2), 0, None) / n[:, None])
        s = np.where(s > 0, s, 1.0)
        try:
            coef = (np.linalg.solve(zz / (s[:, :, None] * s[:, None, :]), zy / s[:, :, None])
                    / s[:, :, None])
        except np.linalg.LinAlgError:  # one singular candidate: each on its own
            coef = np.stack([self._coef(Gram(a, b, c, int(r)))
                             for a, b, c, r in zip(zz, zy, yy, rows, strict=True)])
        sse = (np.diagonal(yy, axis1=1, axis2=2) - 2 * np.sum(coef * zy, axis=1)
               + np.sum(coef * (zz @ coef), axis=1)).sum(axis=1)
        m = zy.shape[2]
        return [max(float(v), 0.0) / (int(r) * m) if r >= 1 else None
                for v, r in zip(sse, rows, strict=True)]

    @staticmethod
    def _coef(g: Gram) -> np.ndarray:
        s = np.sqrt(np.clip(np.diag(g.zz), 0, None) / max(g.n, 1))
        s = np.where(s > 0, s, 1.0)
        try:
            return np.asarray(np.linalg.solve(g.zz / np.outer(s, s), g.zy / s[:, None])
                              / s[:, None])
        except np.linalg.LinAlgError:
            return solve(g) if g.n >= 1 else np.zeros_like(g.zy)


def _slow_mse(segments: Sequence[Segment], structure: Structure, dly: float) -> float | None:
    d, f = _split_delay(dly)
    st = replace(structure, delay=d, delay_frac=f)
    try:
        reg = stack(segments, st)
    except NoExcitationError:
        return None
    grams = block_grams(reg)
    g = sum(grams[1:], grams[0])
    check_identifiable(reg, g)
    resid = reg.y - reg.z @ solve(g)
    return float(np.mean(resid**2))


def _scorer(segments: Sequence[Segment], structure: Structure, max_shift: int,
            inputs: Sequence[np.ndarray] | None = None, static: _StaticRows | None = None
            ) -> tuple[Callable[[Sequence[float]], list[float | None]], DelayScan | None]:
    """Candidate delays -> their one-step mean squared residuals (None: no rows), and the
    scan behind it (None when candidates are refitted one by one)."""
    try:
        scan = DelayScan(segments, structure, max_shift, inputs, static)
    except ValueError:
        return (lambda dlys: [_slow_mse(segments, structure, d) for d in dlys]), None
    return scan.mse_many, scan


def select_delay(segments: Sequence[Segment], structure: Structure, delays: Iterable[float]
                 ) -> tuple[float, dict[float, float]]:
    """The delay (samples, possibly fractional) with the smallest one-step mean squared
    residual of a least-squares fit.

    Returns the best delay and the mean squared residual for every candidate.
    """
    delays = [float(v) for v in delays]
    if not delays:
        raise ConfigError("no candidate delay given")
    if min(delays) < 0:
        raise ConfigError(f"delays must be >= 0 samples, got {min(delays):g}")
    score, _ = _scorer(segments, structure, max(_shift_needed(v) for v in delays))
    scan = {dly: v for dly, v in zip(delays, score(delays), strict=True) if v is not None}
    if not scan:
        raise NoExcitationError("segments too short for every candidate delay")
    return min(scan, key=scan.__getitem__), scan


@dataclass(frozen=True)
class StructureChoice:
    """What :func:`search_structure` chose.

    Attributes
    ----------
    structure : Structure
        The input structure with the chosen lag filter appended and the chosen delay.
    lag_s : float
        Time constant of the chosen first-order input lag (0: none).
    delay : float
        Chosen delay, samples (whole plus fraction).
    scan : dict of str to float
        ``"lag=…s,delay=…"`` -> mean squared one-step residual of every candidate.
    by_lag : dict of float to (float, float)
        Per candidate lag (s): the lowest mean squared one-step residual over its delays and
        the delay chosen for it (the shortest within ``structure_tol`` of that lowest).
    ls_coef : dict of float to numpy.ndarray
        Per candidate lag: the least-squares coefficients (p, m) at its chosen delay, solved
        from the search's Gram (the rows' sums a fit at that structure forms again); empty
        when the candidates were refitted one by one.
    inputs : dict of float to list of dict
        Per candidate lag: per segment, its inputs (name -> column) through the known
        filters and that lag, not delayed, from the segment's input history on
        (:func:`~mavsid.estimators.regressors.filtered_inputs`: what a fit of that lag
        filters again).
    """

    structure: Structure
    lag_s: float
    delay: float
    scan: dict[str, float]
    by_lag: dict[float, tuple[float, float]] = field(default_factory=dict)
    ls_coef: dict[float, np.ndarray] = field(default_factory=dict, repr=False)
    inputs: dict[float, list[dict[str, np.ndarray]]] = field(default_factory=dict, repr=False,
                                                            compare=False)


def search_structure(
    segments: Sequence[Segment],
    structure: Structure,
    *,
    delay: float | None = None,
    delays: Iterable[float] | None = None,
    delay_step: float = DEFAULT_DELAY_STEP,
    max_delay_s: float = DEFAULT_MAX_DELAY_S,
    lags_s: Iterable[float] | None = DEFAULT_LAGS_S,
    structure_tol: float = DEFAULT_STRUCTURE_TOL,
) -> StructureChoice:
    """Choose the input lag and delay of ``structure`` from the data.

    Parameters
    ----------
    segments : sequence of Segment
    structure : Structure
        Its ``filters`` are the known ones; the lag filter is appended after them.
    delay : float, optional
        Fix the delay (samples) instead of searching it.
    delays : iterable of float, optional
        Candidate delays (samples, fractions allowed). Default: whole samples up to
        ``max_delay_s``, then steps of ``delay_step`` around the best.
    delay_step : float
        Resolution of the default delay search, samples (1: whole samples only).
    max_delay_s : float
        Longest delay searched by default, s.
    lags_s : iterable of float, optional
        Candidate time constants (s) of a first-order input lag; 0 is always a candidate;
        None: no lag. Lags whose corner lies above the Nyquist frequency are left out (they
        cannot be told from a fraction of a sample of delay). :data:`LONG_LAGS_S` are searched
        too when the default grid's longest lag scores best by more than ``structure_tol``.
    structure_tol : float
        Parsimony: the simplest (shortest lag, then shortest delay) candidate whose mean
        squared one-step residual is within this fraction of the best is chosen.
    """
    segments = list(segments)
    if not segments:
        raise NoExcitationError("no segments to fit")
    dt = float(segments[0].dt)
    nyquist_hz = 0.5 / dt
    lag_grid = [0.0] if lags_s is None else sorted(
        {0.0, *(lag for lag in map(float, lags_s) if lag * 2 * np.pi * nyquist_hz > 1.0)})
    top = round(max_delay_s / dt)
    if delay is not None:
        fixed: list[float] | None = [float(delay)]
    elif delays is not None:
        fixed = [float(v) for v in delays]
    else:
        fixed = None
    if fixed is not None:
        max_shift = max(map(_shift_needed, fixed))
    else:
        max_shift = top + 1
    # the known filters run once; each lag filters their output again (exactly what
    # filtering by the whole chain does: every filter starts in steady state), from each
    # segment's input history on (the scan reads the segment's own rows)
    ins = [f for f in structure.features if f in structure.inputs]
    base: list[np.ndarray] | None = None
    if ins:
        base = [filtered_inputs(s, ins, structure.filters) for s in segments]
    # the regressors no lag changes (states, bias, outputs), built once for every lag
    static = None
    if not structure.continuous and library.is_linear(structure.features):
        static = _StaticRows(segments, structure, max_shift)
    cands: list[tuple[float, float, float]] = []  # (mse, lag, delay)
    scans: dict[float, DelayScan | None] = {}
    filtered: dict[float, list[dict[str, np.ndarray]]] = {}
    scan: dict[str, float] = {}

    def add(lag: float) -> None:  # the delays of one lag scored, into cands
        extra = lag_filter(lag)
        st = replace(structure, filters=structure.filters + extra)
        pre = None if base is None else [filter_inputs(u, s.dt, extra)
                                         for u, s in zip(base, segments, strict=True)]
        score, scans[lag] = _scorer(
            segments, st, max_shift,
            None if pre is None else [u[len(u) - len(s):]
                                      for u, s in zip(pre, segments, strict=True)], static)
        if pre is not None:
            filtered[lag] = [{v: u[:, i] for i, v in enumerate(ins)} for u in pre]
        if fixed is not None:
            d_scan = {dly: v for dly, v in zip(fixed, score(fixed), strict=True)
                      if v is not None}
        else:  # whole samples first, then fractions around the best
            ints = [float(k) for k in range(top + 1)]
            d_scan = {k: v for k, v in zip(ints, score(ints), strict=True) if v is not None}
            if d_scan and delay_step < 1:
                d0 = int(min(d_scan, key=d_scan.__getitem__))
                fine = [float(k) for k in
                        np.arange(max(d0 - 1, 0), min(d0 + 1, top) + 1e-9, delay_step)]
                d_scan.update({k: v for k, v in zip(fine, score(fine), strict=True)
                               if v is not None})
        scan.update({f"lag={lag:g}s,delay={k:g}": v for k, v in d_scan.items()})
        cands.extend((v, lag, k) for k, v in d_scan.items())

    for lag in lag_grid:
        add(lag)
    best = {lg: min((c[0] for c in cands if c[1] == lg), default=np.inf) for lg in lag_grid}
    if (lags_s is DEFAULT_LAGS_S and len(lag_grid) > 1 and lag_grid[-1] == DEFAULT_LAGS_S[-1]
            and best[lag_grid[-1]] < best[lag_grid[-2]] * (1 - structure_tol)):
        # the grid's longest lag scores best, and clearly (not a flat score: a yaw plant's
        # slow pole tells lags apart little): the motors may be slower than it reaches
        longer = [lag for lag in LONG_LAGS_S if lag * 2 * np.pi * nyquist_hz > 1.0]
        for lag in longer:
            add(lag)
        lag_grid += longer
    if not cands:
        raise NoExcitationError("segments too short for every candidate delay")
    floor = min(c[0] for c in cands)
    _, lag, dly = min((c for c in cands if c[0] <= floor * (1 + structure_tol)),
                      key=lambda c: (c[1], c[2]))
    whole, frac = _split_delay(dly)
    chosen = replace(structure, filters=structure.filters + lag_filter(lag), delay=whole,
                     delay_frac=frac)
    by_lag: dict[float, tuple[float, float]] = {}
    for lg in lag_grid:
        mine = [c for c in cands if c[1] == lg]
        if mine:
            low = min(c[0] for c in mine)
            d = min(c[2] for c in mine if c[0] <= low * (1 + structure_tol))
            by_lag[lg] = (low, float(d))
    ls_coef: dict[float, np.ndarray] = {}
    for lg, (_, d) in by_lag.items():
        lag_scan = scans.get(lg)
        if lag_scan is not None:
            g = lag_scan.gram(d)
            if g.n >= len(structure.features):
                ls_coef[lg] = solve(g)
    return StructureChoice(chosen, lag, float(dly), scan, by_lag, ls_coef, filtered)


def with_lag(structure: Structure, lag_s: float, delay: float) -> Structure:
    """``structure`` (its known filters) with a first-order input lag and a delay (samples)."""
    whole, frac = _split_delay(delay)
    return replace(structure, filters=structure.filters + lag_filter(lag_s), delay=whole,
                   delay_frac=frac)
