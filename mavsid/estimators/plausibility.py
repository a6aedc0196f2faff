"""Whether arrays can support a rate plant's model, and whether a fitted one is physical.

A rate sampled well above its bandwidth changes little from one sample to the next: its
lag-1 autocorrelation ``r₁ = Σ x̃ₖ x̃ₖ₊₁ / Σ x̃ₖ²`` (``x̃`` the record less its mean) is near 1.
``r₁`` is the power-weighted mean of ``cos(2π f dt)`` over the signal's spectrum, so ``r₁ < 0``
means most of the output's power lies above a quarter of the sample rate (half the Nyquist
frequency): vibration aliased by the sampling (a raw gyro logged at 100 Hz, as
``SIDD.Gx`` often is), not the plant's response. White noise alone drives ``r₁`` towards 0,
never below it; an equation-error fit on such an output returns a negative control
effectiveness or a pole that alternates sign every sample, without a word.

:func:`check_sampled_rates` refuses such outputs before a fit, :func:`check_rate_plant` a
fitted one-input one-output model whose effectiveness is not positive or whose pole the
sampling cannot hold. :func:`mavsid.identify` calls both unless ``expect_positive=False``.

Examples
--------
>>> import numpy as np
>>> k = np.arange(200)
>>> round(lag1_autocorrelation([np.sin(2 * np.pi * 0.01 * k)]), 3)   # 1 Hz at 100 Hz
0.998
>>> round(lag1_autocorrelation([np.sin(2 * np.pi * 0.38 * k)]), 3)   # 162 Hz folded to 38 Hz
-0.729
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from mavsid.data import Segment
from mavsid.errors import ImplausibleModelError
from mavsid.estimators.model import Model

__all__ = ["ALIASED_LAG1", "FASTEST_GROWTH", "MIN_SAMPLES", "check_rate_plant",
           "check_sampled_rates", "lag1_autocorrelation"]

#: An output whose lag-1 autocorrelation is below this is dominated by content above a
#: quarter of the sample rate (aliased), not by a rate sampled above its bandwidth (near 1).
ALIASED_LAG1: float = 0.0

#: Fewest samples (all records together) for the autocorrelation test to mean anything.
MIN_SAMPLES: int = 20

#: A discrete pole beyond this grows e-fold within one sample: faster than the sampling can
#: resolve (continuous time: a real part above 1/dt).
FASTEST_GROWTH: float = math.e


def lag1_autocorrelation(records: Sequence[np.ndarray]) -> float:
    """``r₁`` of one signal over several records (each less its own mean, no product across
    a record's end); nan when the signal is constant."""
    num = den = 0.0
    for r in records:
        x = np.asarray(r, dtype=float)
        x = x[np.isfinite(x)] - np.nanmean(x) if x.size else x
        num += float(np.dot(x[1:], x[:-1]))
        den += float(np.dot(x, x))
    return num / den if den > 0 else math.nan


def check_sampled_rates(segments: Sequence[Segment], outputs: Sequence[str]) -> None:
    """Raise :class:`~mavsid.errors.ImplausibleModelError` when an output's lag-1
    autocorrelation is below :data:`ALIASED_LAG1` (see the module's text).

    Examples
    --------
    >>> import numpy as np
    >>> k = np.arange(500)
    >>> seg = Segment(k * 0.01, np.sin(2 * np.pi * 0.38 * k)[:, None], np.ones((500, 1)),
    ...               ("p",), ("u",), 0.01, "roll", "arrays")
    >>> check_sampled_rates([seg], ["p"])
    Traceback (most recent call last):
    ...
    mavsid.errors.ImplausibleModelError: p: lag-1 autocorrelation -0.73 < 0: the output is \
dominated by content above a quarter of the 100-Hz sample rate (aliased vibration), while a \
rate sampled well above its bandwidth has it near 1; low-pass it before it is sampled, or fit \
where it is coherent with the input (mavsid.identify_frequency)
    """
    for name in outputs:
        recs = [s.states[:, s.state_names.index(name)] for s in segments
                if name in s.state_names]
        if sum(len(r) for r in recs) < MIN_SAMPLES:
            continue
        r1 = lag1_autocorrelation(recs)
        if r1 < ALIASED_LAG1:
            fs = 1.0 / float(segments[0].dt)
            raise ImplausibleModelError(
                f"{name}: lag-1 autocorrelation {r1:.2f} < {ALIASED_LAG1:g}: the output is "
                f"dominated by content above a quarter of the {fs:g}-Hz sample rate (aliased "
                "vibration), while a rate sampled well above its bandwidth has it near 1; "
                "low-pass it before it is sampled, or fit where it is coherent with the "
                "input (mavsid.identify_frequency)")


def check_rate_plant(model: Model) -> None:
    """Raise :class:`~mavsid.errors.ImplausibleModelError` when a one-output one-input model
    (u → rate) has a non-positive effectiveness, or a pole the sampling cannot hold: a
    discrete pole ≤ 0 (the output alternates sign every sample; no continuous-time
    equivalent) or beyond :data:`FASTEST_GROWTH`. Other shapes pass unchecked.

    Examples
    --------
    >>> import numpy as np
    >>> check_rate_plant(Model(("p",), ("u",), ("p", "u"), np.array([[0.9], [0.5]]), 0.01))
    >>> check_rate_plant(Model(("p",), ("u",), ("p", "u"), np.array([[0.9], [-0.5]]), 0.01))
    Traceback (most recent call last):
    ...
    mavsid.errors.ImplausibleModelError: B_d[p,u] = -0.5 is not positive: a rate plant's \
effectiveness has the input's sign (expect_positive=False for a plant that reverses it)
    """
    if len(model.state_names) != 1 or len(model.input_names) != 1:
        return
    out, inp = model.state_names[0], model.input_names[0]
    if inp not in model.features:
        return
    name = "B" if model.continuous else "B_d"
    b = float(model.coef[model.features.index(inp), 0])
    if not b > 0:
        raise ImplausibleModelError(
            f"{name}[{out},{inp}] = {b:.3g} is not positive: a rate plant's effectiveness "
            "has the input's sign (expect_positive=False for a plant that reverses it)")
    if out not in model.features:
        return
    a = float(model.coef[model.features.index(out), 0])
    where = "A" if model.continuous else "A_d"
    if model.continuous and a * model.dt > 1.0:
        raise ImplausibleModelError(
            f"{where}[{out},{out}] = {a:.3g}/s grows e-fold within a sample "
            f"({model.dt:g} s): faster than the sampling can resolve")
    if not model.continuous and not 0.0 < a <= FASTEST_GROWTH:
        why = ("alternates sign every sample (no continuous-time equivalent)" if a <= 0
               else "grows e-fold within a sample: faster than the sampling can resolve")
        raise ImplausibleModelError(f"{where}[{out},{out}] = {a:.3g}: the pole {why}")
