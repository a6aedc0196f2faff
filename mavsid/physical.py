"""What a tuner reads first of an axis's model: the rate response's time constant and its
corner (the open-loop pole, as a bandwidth), the control effectiveness B, the input delay
and lag, the known filters; and the order the fitted parameters are shown in (the
continuous-time ones before the discrete-time coefficients ``A_d``, ``B_d``, ``c_d``).

The HTML report and the rerun summary show these rows (:func:`physical_rows`) above the
fitted parameters (:func:`parameter_order`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from mavsid.estimators.select import is_lag_filter

if TYPE_CHECKING:
    from mavsid.pipeline_results import AxisFit

__all__ = ["PhysicalRow", "is_discrete", "parameter_order", "physical_rows", "physical_table"]


@dataclass(frozen=True)
class PhysicalRow:
    """One physical parameter: its name, value and σ (NaN where the model gives none) in
    ``unit``."""

    name: str
    value: float
    sigma: float
    unit: str


def is_discrete(name: str) -> bool:
    """Whether a parameter is a discrete-time coefficient (``A_d[..]``, ``B_d[..]``,
    ``c_d[..]``).

    Examples
    --------
    >>> is_discrete("A_d[p,p]"), is_discrete("A[p,p]")
    (True, False)
    """
    return "_d[" in name


def parameter_order(names: Iterable[str]) -> list[str]:
    """``names`` with the continuous-time parameters first (in their order), the
    discrete-time coefficients last.

    Examples
    --------
    >>> parameter_order(["A_d[p,p]", "B_d[p,u_roll]", "A[p,p]", "B[p,u_roll]"])
    ['A[p,p]', 'B[p,u_roll]', 'A_d[p,p]', 'B_d[p,u_roll]']
    """
    return sorted(names, key=is_discrete)


def physical_table(axis: str, output: str, params: Mapping[str, float],
                   stderr: Mapping[str, float], delay_s: float,
                   lag_s: float | None = None) -> list[PhysicalRow]:
    """The physical rows of a first-order rate model ``output′ = A·output + B·u_axis``:
    time constant -1/A and its corner -A/2π (when A < 0), effectiveness B, delay, lag.

    Examples
    --------
    >>> rows = physical_table("roll", "p", {"A[p,p]": -4.0, "B[p,u_roll]": 180.0},
    ...                       {"A[p,p]": 0.2, "B[p,u_roll]": 3.0}, 0.005, 0.015)
    >>> [(r.name, round(r.value, 4), round(r.sigma, 4), r.unit) for r in rows]
    ... # doctest: +NORMALIZE_WHITESPACE
    [('time constant 1/damping', 0.25, 0.0125, 's'),
     ('open-loop pole (bandwidth)', 0.6366, 0.0318, 'Hz'),
     ('control effectiveness B (u_roll → p′)', 180.0, 3.0, 'rad/s² per unit'),
     ('input delay', 5.0, nan, 'ms'), ('input lag (motor/ESC)', 15.0, nan, 'ms')]
    """
    u = f"u_{axis}"
    rows = []
    a, sa = params.get(f"A[{output},{output}]"), stderr.get(f"A[{output},{output}]", np.nan)
    b, sb = params.get(f"B[{output},{u}]"), stderr.get(f"B[{output},{u}]", np.nan)
    if a is not None and np.isfinite(a) and a < 0:
        tau = -1.0 / a
        rows.append(PhysicalRow("time constant 1/damping", tau, tau * sa / abs(a), "s"))
        rows.append(PhysicalRow("open-loop pole (bandwidth)", -a / (2 * np.pi),
                                sa / (2 * np.pi), "Hz"))
    if b is not None:
        rows.append(PhysicalRow(f"control effectiveness B ({u} → {output}′)", b, sb,
                                "rad/s² per unit"))
    rows.append(PhysicalRow("input delay", delay_s * 1e3, np.nan, "ms"))
    if isinstance(lag_s, (int, float)) and lag_s > 0:
        rows.append(PhysicalRow("input lag (motor/ESC)", float(lag_s) * 1e3, np.nan, "ms"))
    return rows


def physical_rows(fit: AxisFit) -> list[PhysicalRow]:
    """:func:`physical_table` of ``fit``'s model, then its known filters (cutoff in Hz)."""
    m = fit.model
    prov = dict(getattr(m, "provenance", {}) or {})
    rows = physical_table(fit.axis, fit.output, m.params, getattr(m, "stderr", {}) or {},
                          float(getattr(m, "delay_s", 0.0) or 0.0), prov.get("lag_s"))
    for f in getattr(m, "filters", ()):
        if is_lag_filter(f.source):
            continue  # (the input lag's row above)
        rows.append(PhysicalRow(f"known filter ({f.source})", f.cutoff_hz, np.nan,
                                f"Hz, order {f.order}"))
    return rows
