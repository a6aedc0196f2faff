"""SINDy-style candidate libraries: features named by small expressions, evaluated on arrays.

A *feature* is a product of factors written as text, so that a model saved as JSON can be
read by a person and rebuilt exactly: ``"p"``, ``"u_roll"``, ``"1"`` (the bias),
``"p^2"``, ``"p*u_roll"``, ``"sin(roll)"``, ``"cos(pitch)*q"``. A factor is a variable
name, optionally raised to an integer power (``^k``) or wrapped in ``sin``/``cos``.

Examples
--------
>>> import numpy as np
>>> names = polynomial(("p", "u_roll"), degree=2)
>>> names
('1', 'p', 'u_roll', 'p^2', 'p*u_roll', 'u_roll^2')
>>> evaluate(names, {"p": np.array([2.0]), "u_roll": np.array([3.0])}).tolist()
[[1.0, 2.0, 3.0, 4.0, 6.0, 9.0]]
>>> variables_of(("sin(roll)*p", "1", "q^2"))
('roll', 'p', 'q')
"""

from __future__ import annotations

import functools
import itertools
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from mavsid.errors import ConfigError

__all__ = [
    "BIAS",
    "Factor",
    "evaluate",
    "is_linear",
    "library",
    "parse",
    "polynomial",
    "state_input",
    "trigonometric",
    "variables_of",
]

#: The name of the constant feature.
BIAS = "1"

_FACTOR = re.compile(r"^(?:(sin|cos)\((\w+)\)|(\w+))(?:\^(\d+))?$")


@dataclass(frozen=True)
class Factor:
    """One factor of a feature: ``func(var) ** power`` (``func`` is ``""``, sin or cos)."""

    var: str
    power: int = 1
    func: str = ""

    def __call__(self, values: np.ndarray) -> np.ndarray:
        base = np.sin(values) if self.func == "sin" else np.cos(values) if self.func else values
        return base if self.power == 1 else base**self.power


@functools.lru_cache(maxsize=4096)
def parse(feature: str) -> tuple[Factor, ...]:
    """Split a feature name into its factors (``()`` for the bias ``"1"``).

    Examples
    --------
    >>> parse("sin(roll)*p^2")
    (Factor(var='roll', power=1, func='sin'), Factor(var='p', power=2, func=''))
    >>> parse("p+q")
    Traceback (most recent call last):
    ...
    mavsid.errors.ConfigError: feature 'p+q': cannot parse factor 'p+q'
    """
    if feature == BIAS:
        return ()
    out = []
    for text in feature.replace(" ", "").split("*"):
        m = _FACTOR.match(text)
        if m is None:
            raise ConfigError(f"feature {feature!r}: cannot parse factor {text!r}")
        func, fvar, var, power = m.groups()
        out.append(Factor(var=fvar or var, power=int(power or 1), func=func or ""))
    return tuple(out)


def variables_of(features: Iterable[str]) -> tuple[str, ...]:
    """The variables the features use, in order of first appearance."""
    seen: dict[str, None] = {}
    for f in features:
        for fac in parse(f):
            seen.setdefault(fac.var, None)
    return tuple(seen)


def is_linear(features: Iterable[str]) -> bool:
    """True when every feature is the bias or a single variable to the first power."""
    for f in features:
        facs = parse(f)
        if len(facs) > 1 or (facs and (facs[0].power != 1 or facs[0].func)):
            return False
    return True


def evaluate(features: Sequence[str], variables: Mapping[str, np.ndarray]) -> np.ndarray:
    """Evaluate features on equally long 1-D arrays of variables.

    Returns
    -------
    numpy.ndarray, shape (n, len(features))
    """
    n = len(next(iter(variables.values()))) if variables else 1
    out = np.empty((n, len(features)))
    for j, f in enumerate(features):
        col = np.ones(n)
        for fac in parse(f):
            try:
                col = col * fac(np.asarray(variables[fac.var], dtype=float))
            except KeyError:
                raise ConfigError(
                    f"feature {f!r} needs variable {fac.var!r}; have {sorted(variables)}"
                ) from None
        out[:, j] = col
    return out


def polynomial(variables: Sequence[str], degree: int = 2, bias: bool = True) -> tuple[str, ...]:
    """All monomials of the variables up to ``degree`` (graded, then lexicographic order)."""
    out = [BIAS] if bias else []
    for d in range(1, degree + 1):
        for combo in itertools.combinations_with_replacement(range(len(variables)), d):
            counts = {i: combo.count(i) for i in sorted(set(combo))}
            out.append(
                "*".join(variables[i] + (f"^{k}" if k > 1 else "") for i, k in counts.items())
            )
    return tuple(out)


def trigonometric(variables: Sequence[str]) -> tuple[str, ...]:
    """``sin(v)`` and ``cos(v)`` of each variable (angles, in rad).

    Examples
    --------
    >>> trigonometric(("roll",))
    ('sin(roll)', 'cos(roll)')
    """
    return tuple(f"{fn}({v})" for v in variables for fn in ("sin", "cos"))


def state_input(states: Sequence[str], inputs: Sequence[str]) -> tuple[str, ...]:
    """Products of each state with each input (``"p*u_roll"`` ...)."""
    return tuple(f"{x}*{u}" for x in states for u in inputs)


def library(*parts: Iterable[str]) -> tuple[str, ...]:
    """Concatenate feature lists, dropping duplicates but keeping the first order.

    Examples
    --------
    >>> library(("1", "p"), polynomial(("p",), 2))
    ('1', 'p', 'p^2')
    """
    seen: dict[str, None] = {}
    for part in parts:
        for f in part:
            seen.setdefault(f, None)
    return tuple(seen)
