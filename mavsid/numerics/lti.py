"""Linear time-invariant systems: zero-order-hold discretisation and its inverse (the one
c2d and d2c of the package), the controllable canonical form of a transfer function, and the
matrix exponential and logarithm they rest on.

:func:`c2d`, :func:`d2c` and :func:`tf2ss` give the numbers of ``scipy.signal``'s
``cont2discrete`` (``method="zoh"``), its inverse and ``tf2ss`` to rounding
(tests/test_dsp.py and tests/test_synthetic.py compare them).

- :func:`c2d`: ``(Φ, Γ)`` of ``x' = A x + B u`` held over ``dt``, from the exponential of
  ``[[A, B], [0, 0]] dt`` (closed form for one state).
- :func:`d2c`: its inverse, ``A = ln Φ / dt`` and ``B = (Φ - I)⁻¹ A Γ`` (the logarithm of
  the whole block matrix where ``Φ - I`` is singular).
- :func:`expm` and :func:`logm`: ``scipy.linalg.expm`` and the real ``scipy.linalg.logm`` of
  a real square matrix, refusing infinities and NaN; the logarithm of a 1×1 matrix in
  closed form (scipy's takes about a millisecond, and a fit asks for dozens).

Examples
--------
>>> import numpy as np
>>> phi, gamma = c2d(np.array([[-2.0]]), np.array([[4.0]]), 0.1)
>>> round(float(phi[0, 0]), 6), round(float(gamma[0, 0]), 6)
(0.818731, 0.362538)
>>> a, b = d2c(phi, gamma, 0.1)
>>> round(float(a[0, 0]), 9), round(float(b[0, 0]), 9)
(-2.0, 4.0)
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

__all__ = ["c2d", "d2c", "expm", "logm", "tf2ss"]


def _pair(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A square matrix and its input matrix as floats, a 1-D input as one column."""
    a = np.atleast_2d(np.asarray(a, float))
    b = np.asarray(b, float)
    return a, (b[:, None] if b.ndim == 1 else b)


def c2d(a: np.ndarray, b: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Zero-order-hold discretisation of ``x' = A x + B u`` over ``dt``: ``(Φ, Γ)`` with
    ``Φ = e^{A dt}`` (n, n) and ``Γ = ∫₀^dt e^{A s} ds B`` (n, m)."""
    a, b = _pair(a, b)
    n, m = b.shape
    if n == 1:  # the exponential of [[A, B], [0, 0]] dt in closed form
        x = float(a[0, 0]) * dt
        e = np.eye(n + m)
        e[0, 0] = math.exp(x)
        e[0, 1:] = b[0] * dt * (math.expm1(x) / x if x != 0.0 else 1.0)
    else:
        big = np.zeros((n + m, n + m))
        big[:n, :n], big[:n, n:] = a, b
        e = expm(big * dt)
    return e[:n, :n], e[:n, n:]


def d2c(phi: np.ndarray, gamma: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The continuous system whose zero-order hold over ``dt`` is ``(Φ, Γ)``: ``(A, B)``.

    ``Φ`` must have a real logarithm (eigenvalues real and positive: a stable,
    non-oscillating discrete model's); the caller checks it."""
    phi, gamma = _pair(phi, gamma)
    n, m = gamma.shape
    ac = logm(phi) / dt
    shifted = phi - np.eye(n)
    if np.linalg.cond(shifted) < 1e12:
        return ac, np.linalg.solve(shifted, ac @ gamma)
    big = np.eye(n + m)  # (a pole at 1: the logarithm of [[Φ, Γ], [0, I]])
    big[:n, :n], big[:n, n:] = phi, gamma
    whole = logm(big) / dt
    return whole[:n, :n], whole[:n, n:]


def tf2ss(num: Sequence[float] | np.ndarray, den: Sequence[float] | np.ndarray
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``scipy.signal.tf2ss(num, den)`` of a proper single-input single-output transfer
    function: the controllable canonical form ``(A, B, C, D)``."""
    nu = np.atleast_1d(np.asarray(num, float))
    de = np.atleast_1d(np.asarray(den, float))
    if nu.ndim != 1 or de.ndim != 1 or nu.size > de.size or de[0] == 0:
        raise ValueError("tf2ss: a proper 1-D transfer function is needed")
    nu, de = nu / de[0], de / de[0]
    nu = np.r_[np.zeros(de.size - nu.size), nu]
    k = de.size - 1
    d = np.array([[nu[0]]])
    if k == 0:  # a static gain: scipy's zero-filled 1x1 state
        return np.zeros((1, 1)), np.zeros((1, 1)), np.zeros((1, 1)), d
    a = np.zeros((k, k))
    a[0] = -de[1:]
    a[np.arange(1, k), np.arange(k - 1)] = 1.0
    b = np.zeros((k, 1))
    b[0, 0] = 1.0
    c = (nu[1:] - nu[0] * de[1:]).reshape(1, k)
    return a, b, c, d


def _real_square(a: np.ndarray, name: str) -> np.ndarray:
    """``a`` as a float array, refused unless square and finite (never a NaN model)."""
    a = np.asarray(a, float)
    if a.ndim != 2 or a.shape[0] != a.shape[1]:
        raise ValueError(f"{name}: a square matrix, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: the matrix holds infinities or NaN")
    return a


def expm(a: np.ndarray) -> np.ndarray:
    """``scipy.linalg.expm(a)`` of a real square matrix.

    Examples
    --------
    >>> [round(float(v), 12) for v in expm(np.array([[0.0, 1.0], [0.0, 0.0]])).ravel()]
    [1.0, 1.0, 0.0, 1.0]
    >>> round(float(expm(np.array([[1.0]]))[0, 0]), 12)
    2.718281828459
    """
    a = _real_square(a, "expm")
    from scipy import linalg

    return np.asarray(linalg.expm(a))


def logm(a: np.ndarray) -> np.ndarray:
    """The real part of ``scipy.linalg.logm(a)``, the principal matrix logarithm, of a real
    square matrix (real itself when no eigenvalue is negative or zero: the stable,
    non-oscillating discrete models mavsid takes to continuous time); a 1×1 matrix's in
    closed form.

    Examples
    --------
    >>> round(float(logm(np.array([[np.e]]))[0, 0]), 12)
    1.0
    >>> [round(float(v), 12) + 0.0 for v in logm(np.array([[0.5, 0.25], [0.0, 1.0]])).ravel()]
    [-0.69314718056, 0.34657359028, 0.0, 0.0]
    """
    a = _real_square(a, "logm")
    if a.shape == (1, 1) and a[0, 0] > 0:
        return np.log(a)
    from scipy import linalg

    return np.asarray(np.real(linalg.logm(a)))
