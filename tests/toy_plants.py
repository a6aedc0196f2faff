"""A known discrete plant implementing the model interface, for validation/viz/report tests.

Each output ``i`` follows ``y[k+1] = a_i y[k] + b_i u_i[k-d] + c_i`` (diagonal, one input per
output). Its true frequency response is ``b e^{-jwTd} / (e^{jwT} - a)``, which the tests use
as the outside reference.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import signal

from mavsid.data import Segment, SysidRun


@dataclass(frozen=True)
class DiagonalPlant:
    a: tuple[float, ...]
    b: tuple[float, ...]
    c: tuple[float, ...] = ()
    state_names: tuple[str, ...] = ("p",)
    input_names: tuple[str, ...] = ("u_roll",)
    dt: float = 0.0025
    delay: int = 0
    expose_a: bool = True
    stderr: dict[str, float] = field(default_factory=dict)

    @property
    def _c(self) -> np.ndarray:
        return np.asarray(self.c if self.c else (0.0,) * len(self.a), dtype=float)

    @property
    def params(self) -> dict[str, float]:
        out: dict[str, float] = {}
        for i, s in enumerate(self.state_names):
            out[f"a_{s}"] = self.a[i]
            out[f"b_{s}"] = self.b[i]
            out[f"c_{s}"] = float(self._c[i])
        return out

    @property
    def units(self) -> dict[str, str]:
        return {k: "1" for k in self.params}

    def __getattr__(self, name: str) -> object:
        if name == "A" and self.expose_a:
            return np.diag(self.a)
        raise AttributeError(name)

    def _io(self, segment: Segment) -> tuple[np.ndarray, np.ndarray]:
        y = np.stack([segment.states[:, segment.state_names.index(s)] for s in self.state_names], 1)
        u = np.stack([segment.inputs[:, segment.input_names.index(s)] for s in self.input_names], 1)
        return y, u

    def _drive(self, u: np.ndarray, known_from: float = np.nan) -> np.ndarray:
        """w[k] = b u[k-d] + c; u before the segment is NaN (or ``known_from``)."""
        d = self.delay
        ud = np.full_like(u, known_from)
        ud[d:] = u[: len(u) - d] if d else u
        return ud * np.asarray(self.b) + self._c

    def simulate(self, segment: Segment) -> np.ndarray:
        y, u = self._io(segment)
        w = self._drive(np.nan_to_num(u), known_from=0)
        out = np.empty_like(y)
        for i, a in enumerate(self.a):
            # yhat[k+1] = a yhat[k] + w[k], yhat[0] = y[0]
            zi = np.array([a * y[0, i]])
            rest, _ = signal.lfilter([1.0], [1.0, -a], w[:-1, i], zi=zi)
            out[0, i] = y[0, i]
            out[1:, i] = rest
        return out

    def predict(self, segment: Segment, horizon: int = 1) -> np.ndarray:
        y, u = self._io(segment)
        w = self._drive(u)
        h = int(horizon)
        n = len(y)
        out = np.full_like(y, np.nan)
        if h >= n:
            return out
        for i, a in enumerate(self.a):
            # yhat[k] = a^h y[k-h] + sum_{m=1..h} a^(m-1) w[k-m]
            kernel = a ** np.arange(h)
            s = np.convolve(w[:, i], kernel)[: n]  # s[j] = sum_m a^m w[j-m], m=0..h-1
            out[h:, i] = a**h * y[: n - h, i] + s[h - 1 : n - 1]
        return out

    def response(self, freq_hz: np.ndarray, i: int = 0) -> np.ndarray:
        """The true frequency response of output i."""
        z = np.exp(1j * 2 * np.pi * freq_hz * self.dt)
        return self.b[i] * z ** (-self.delay) / (z - self.a[i])


def chirp(n: int, dt: float, f0: float = 0.5, f1: float = 20.0, amp: float = 0.05) -> np.ndarray:
    """Exponential sine sweep from f0 to f1 Hz over n samples."""
    t = np.arange(n) * dt
    duration = n * dt
    k = np.log(f1 / f0) / duration
    phase = 2 * np.pi * f0 * (np.exp(k * t) - 1.0) / k
    return amp * np.sin(phase)


def run_plant(
    plant: DiagonalPlant,
    u: np.ndarray,
    *,
    noise: float = 0.0,
    seed: int = 0,
    t0: float = 0.0,
    source: str = "scan",
    axis: str = "roll",
    sysid: SysidRun | None = None,
) -> Segment:
    """Drive the plant with inputs u (n, nu) plus equation noise; return the Segment."""
    u = np.asarray(u, dtype=float).reshape(len(u), -1)
    rng = np.random.default_rng(seed)
    n, ny = len(u), len(plant.a)
    w = plant._drive(u, known_from=0)
    y = np.zeros((n, ny))
    e = noise * rng.standard_normal((n, ny))
    for k in range(n - 1):
        y[k + 1] = np.asarray(plant.a) * y[k] + w[k] + e[k]
    return Segment(
        time_s=t0 + np.arange(n) * plant.dt,
        states=y,
        inputs=u,
        state_names=plant.state_names,
        input_names=plant.input_names,
        dt=plant.dt,
        axis=axis,
        source=source,
        sysid=sysid,
    )


def toy_flight(duration_s: float = 40.0, dt: float = 0.005, seed: int = 0):  # type: ignore[no-untyped-def]
    """A three-axis flight from three known first-order rate plants, with chirps on
    roll/pitch/yaw one after another, and the FitResult of fitting nothing (the true plants
    are the models) validated on alternate blocks. Returns (flight, result, plants)."""
    from mavsid.data import FlightData, SourceInfo
    from mavsid.pipeline import AxisFit, FitResult, split_segments
    from mavsid.validation import validate

    n = round(duration_s / dt)
    rng = np.random.default_rng(seed)
    axes = ("roll", "pitch", "yaw")
    rates = ("p", "q", "r")
    plants = {
        axis: DiagonalPlant(a=(a,), b=(b,), state_names=(rate,), input_names=(f"u_{axis}",),
                            dt=dt, delay=1)
        for axis, rate, a, b in zip(axes, rates, (0.97, 0.96, 0.99), (0.8, 0.7, 0.1), strict=True)
    }
    third = n // 3
    u = 0.002 * rng.standard_normal((n, 3))
    for i in range(3):
        u[i * third:(i + 1) * third, i] += chirp(third, dt, 0.5, 15.0, 0.1)
    x = np.zeros((n, 3))
    for i, axis in enumerate(axes):
        seg = run_plant(plants[axis], u[:, i], noise=1e-3, seed=seed + i)
        x[:, i] = seg.states[:, 0]
    att = np.cumsum(x, axis=0) * dt
    t = 100.0 + np.arange(n) * dt
    flight = FlightData(
        time_s=t, states=np.c_[att, x], inputs=u,
        state_names=("roll", "pitch", "yaw", "p", "q", "r"),
        input_names=("u_roll", "u_pitch", "u_yaw"),
        state_units=("rad",) * 3 + ("rad/s",) * 3, input_units=("1",) * 3,
        dt=dt, blocks=np.array([[0, n]]),
        flags={"armed": np.ones(n, bool), "airborne": np.ones(n, bool)},
        source=SourceInfo("toy.bin", "synthetic", 0), preset="toy",
    )
    fits = {}
    for i, axis in enumerate(axes):
        a, b = i * third, (i + 1) * third
        seg = Segment(
            time_s=t[a:b], states=flight.states[a:b], inputs=u[a:b],
            state_names=flight.state_names, input_names=flight.input_names, dt=dt,
            axis=axis, source="sysid", reasons=(f"SYSTEMID run on {axis}",),
            sysid=SysidRun(float(t[a]), float(t[b - 1]), "SIDS", f_start_hz=0.5,
                           f_stop_hz=15.0),
        )
        train, held = split_segments([seg], block_s=duration_s / 3 / 4)
        val = validate(plants[axis], held, fft_window_s=1.0)
        fits[axis] = AxisFit(axis, plants[axis], val, train, held, "ls")
    return flight, FitResult(fits, (flight,), ("toy.bin",)), plants
