"""The known plant: rigid-body rate dynamics of a multicopter and its gyro chain.

Per axis ``i`` (roll p, pitch q, yaw r, rad/s)::

    m_i' = (u_i(t - delay) - m_i) / motor_tau          first-order motor lag
    p_i' = -damping_i * p_i + effectiveness_i * m_i
           + sum_j coupling[i][j] * m_j + w_i            weak cross coupling, disturbance

``u`` is the mixer input (the rate controller's output plus any SYSTEMID mixer injection:
ArduPilot's RATE.ROut/POut/YOut), dimensionless. ``w`` is a white angular-acceleration
disturbance (rad/s², held over each loop step). The system is linear and is advanced with an
exact zero-order-hold discretisation, including a delay that is not a multiple of the step.

The gyro measures the true rate plus a constant bias and white noise; ArduPilot then low-passes
it with a second-order Butterworth filter at ``INS_GYRO_FILTER`` Hz (``LowPassFilter2p``, a
bilinear-transform biquad with pre-warping). The filtered gyro is what the rate controller uses
and what RATE.R/P/Y (deg/s), IMU.GyrX/Y/Z (rad/s) and MAVLink ATTITUDE.rollspeed record; SIDD
records the unfiltered gyro (deg/s).

Examples
--------
>>> p = PlantParams()
>>> disc = discretise(p, dt=0.0025)
>>> disc.phi.shape, disc.gamma_now.shape
((6, 6), (6, 3))
>>> round(float(p.effective_delay_s[0]), 4)
0.02
>>> b = lowpass2p_coefficients(20.0, 400.0)
>>> round(float(sum(b[0]) / sum(b[1])), 6)   # unit DC gain
1.0
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from mavsid.axes import AXES
from mavsid.errors import ConfigError
from mavsid.numerics.filters import Lowpass2p, lowpass2p_coefficients
from mavsid.numerics.lti import c2d

__all__ = [
    "AXES",
    "VEHICLES",
    "DiscretePlant",
    "Lowpass2p",
    "PlantParams",
    "discretise",
    "lowpass2p_coefficients",
    "lowpass2p_filter",
]



def _triple(x: tuple[float, float, float], name: str) -> tuple[float, float, float]:
    if len(x) != 3:
        raise ConfigError(f"{name} needs one value per axis (roll, pitch, yaw), got {x!r}")
    return (float(x[0]), float(x[1]), float(x[2]))


@dataclass(frozen=True)
class PlantParams:
    """All true parameters of the simulated vehicle (SI units).

    Parameters
    ----------
    damping : (float, float, float)
        Aerodynamic rate damping per axis (1/s).
    effectiveness : (float, float, float)
        Control effectiveness per unit of mixer input (rad/s² per unit).
    coupling : 3x3 tuple
        Off-diagonal input coupling (rad/s² per unit of the other axes' inputs); diagonal ignored.
    motor_tau_s : float
        First-order motor/ESC time constant (s); 0 for none.
    delay_s : float
        Pure transport delay from controller output to motor command (s).
    gyro_noise : float
        White gyro noise standard deviation per sample (rad/s).
    gyro_bias : (float, float, float)
        Constant gyro bias (rad/s).
    accel_noise : float
        White accelerometer noise (m/s²).
    disturbance : float
        White angular-acceleration disturbance standard deviation (rad/s²).
    gyro_filter_hz : float
        ``INS_GYRO_FILTER`` cutoff (Hz) of the second-order gyro low pass; 0 disables it.
    hover_throttle : float
        ``MOT_THST_HOVER`` (0-1).
    vibration : float
        Amplitude (rad/s) of a frame vibration seen by the gyro (motor/propeller imbalance),
        a sine at ``vibration_hz`` on each axis (phases differ per axis); 0 for none.
    vibration_hz : float
        Its frequency (Hz); above the loop's Nyquist frequency it aliases as on a real IMU.
    """

    damping: tuple[float, float, float] = (4.0, 4.5, 1.5)
    effectiveness: tuple[float, float, float] = (180.0, 160.0, 25.0)
    coupling: tuple[tuple[float, float, float], ...] = (
        (0.0, 0.0, 0.0),
        (0.0, 0.0, 0.0),
        (0.0, 0.0, 0.0),
    )
    motor_tau_s: float = 0.015
    delay_s: float = 0.005
    gyro_noise: float = 0.004
    gyro_bias: tuple[float, float, float] = (0.002, -0.0015, 0.001)
    accel_noise: float = 0.05
    disturbance: float = 0.5
    gyro_filter_hz: float = 20.0
    hover_throttle: float = 0.39
    vibration: float = 0.0
    vibration_hz: float = 170.0

    def __post_init__(self) -> None:
        _triple(self.damping, "damping")
        _triple(self.effectiveness, "effectiveness")
        _triple(self.gyro_bias, "gyro_bias")
        if len(self.coupling) != 3 or any(len(row) != 3 for row in self.coupling):
            raise ConfigError("coupling must be a 3x3 matrix")
        for name in ("motor_tau_s", "delay_s", "gyro_noise", "accel_noise", "disturbance",
                     "gyro_filter_hz", "vibration", "vibration_hz"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"plant parameter {name} must be >= 0")
        if not 0 < self.hover_throttle < 1:
            raise ConfigError("hover_throttle must lie in (0, 1)")

    @property
    def effective_delay_s(self) -> np.ndarray:
        """Transport delay plus motor time constant (s) per axis: the delay a first-order
        model without motor state absorbs the lag into."""
        return np.full(3, self.delay_s + self.motor_tau_s)

    def scaled_noise(self, factor: float) -> PlantParams:
        """A copy with gyro/accel noise, bias and disturbance multiplied by ``factor``."""
        from dataclasses import replace

        if not factor >= 0:
            raise ConfigError(f"noise factor must be >= 0, got {factor}")
        return replace(
            self,
            gyro_noise=self.gyro_noise * factor,
            gyro_bias=tuple(b * factor for b in self.gyro_bias),  # type: ignore[arg-type]
            accel_noise=self.accel_noise * factor,
            disturbance=self.disturbance * factor,
        )

    def to_dict(self) -> dict[str, object]:
        """JSON-safe dict of all fields."""
        d = asdict(self)
        d["coupling"] = [list(r) for r in self.coupling]
        for k in ("damping", "effectiveness", "gyro_bias"):
            d[k] = list(d[k])
        return d

    def continuous(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Continuous-time ``(A, B, E)`` of ``x' = A x + B u(t - delay) + E w``.

        State ``x = (p, q, r, m_roll, m_pitch, m_yaw)`` with a motor lag, else ``(p, q, r)``.
        """
        d = np.diag(self.damping)
        b = np.array(self.coupling, dtype=float)
        np.fill_diagonal(b, self.effectiveness)
        if self.motor_tau_s > 0:
            k = 1.0 / self.motor_tau_s
            a = np.block([[-d, b], [np.zeros((3, 3)), -k * np.eye(3)]])
            bu = np.vstack([np.zeros((3, 3)), k * np.eye(3)])
            e = np.vstack([np.eye(3), np.zeros((3, 3))])
        else:
            a, bu, e = -d, b, np.eye(3)
        return a, bu, e


#: Named vehicles for ``mavsid simulate --vehicle``: the default small quad, a heavier X quad
#: (more inertia: lower control effectiveness and damping, slower motors, a lower gyro filter),
#: a hexacopter (six motors: more authority than the heavy quad, yaw weaker), a traditional
#: helicopter and a fixed-wing plane. For the last two the input is not a motor mix:
#:
#: - ``heli``: effectiveness per unit of the rate controller's normalised output (cyclic
#:   roll/pitch through the swashplate, tail-rotor pitch for yaw); rotor-head damping
#:   stronger than a small quad's in yaw, the tail rotor much stronger in yaw; the lag is the
#:   swashplate servos' (25 ms) rather than motors spinning up.
#: - ``plane``: a small fixed wing at cruise, per unit of normalised surface deflection
#:   (aileron, elevator, rudder: -1..1 over the servo's travel); roll damping strong (8 1/s,
#:   the wing's roll damping), pitch and yaw weaker (short-period and dutch-roll reduced to
#:   first order), authority lower than a multicopter's; the lag is the surface servos'
#:   (30 ms). ``hover_throttle`` stands for the cruise throttle.
#: - ``racer``: a small, light quad with a high thrust-to-weight ratio (3x the default
#:   quad's authority, stronger damping, fast motors, 40 Hz gyro filter, hovering at 25 %
#:   throttle), flown with rate gains tuned to it (:data:`RATE_GAIN_SCALE`).
#: - ``heavy-lift``: a large multirotor on big propellers: motors with a 120-ms time
#:   constant, a quarter of the default quad's authority, weak damping, a 10-Hz gyro filter;
#:   flown with twice the default rate gains.
VEHICLES: dict[str, PlantParams] = {
    "quad": PlantParams(),
    "heavy-x": PlantParams(damping=(2.5, 2.8, 0.8), effectiveness=(95.0, 80.0, 9.0),
                           motor_tau_s=0.03, delay_s=0.0075, gyro_filter_hz=15.0,
                           hover_throttle=0.5),
    "hexa": PlantParams(damping=(3.2, 3.0, 1.1), effectiveness=(130.0, 120.0, 14.0),
                        motor_tau_s=0.022, delay_s=0.005, gyro_filter_hz=20.0,
                        hover_throttle=0.45),
    "heli": PlantParams(damping=(3.5, 3.0, 2.0), effectiveness=(120.0, 100.0, 60.0),
                        motor_tau_s=0.025, delay_s=0.005, gyro_filter_hz=20.0,
                        hover_throttle=0.5),
    "plane": PlantParams(damping=(8.0, 3.0, 1.2), effectiveness=(90.0, 45.0, 15.0),
                         motor_tau_s=0.03, delay_s=0.005, gyro_filter_hz=20.0,
                         hover_throttle=0.55),
    "racer": PlantParams(damping=(6.0, 6.0, 2.5), effectiveness=(540.0, 500.0, 75.0),
                         motor_tau_s=0.01, delay_s=0.003, gyro_filter_hz=40.0,
                         hover_throttle=0.25),
    # large propellers: slow motors (120 ms), little authority, a 10-Hz gyro filter
    "heavy-lift": PlantParams(damping=(1.5, 1.5, 0.5), effectiveness=(40.0, 36.0, 8.0),
                              motor_tau_s=0.12, delay_s=0.01, gyro_filter_hz=10.0,
                              hover_throttle=0.55),
}

#: Vehicles flown with their own rate tuning: the default rate P, I and D (and their
#: ``IMAX``-free gains only) multiplied by this, so that the loop gain (gain × control
#: effectiveness) is the default quad's, as its owner's tuning would make it. The others fly
#: the default gains.
RATE_GAIN_SCALE: dict[str, float] = {"racer": 1.0 / 3.0, "heavy-lift": 2.0}


@dataclass(frozen=True)
class DiscretePlant:
    """Exact zero-order-hold discretisation with a fractional input delay.

    ``x[k+1] = phi x[k] + gamma_prev u[k-n-1] + gamma_now u[k-n] + gamma_w w[k]`` with
    ``n = floor(delay / dt)``.
    """

    phi: np.ndarray
    gamma_prev: np.ndarray
    gamma_now: np.ndarray
    gamma_w: np.ndarray
    delay_steps: int
    dt: float
    n_state: int = field(default=3)


def discretise(p: PlantParams, dt: float) -> DiscretePlant:
    """Discretise the plant for loop period ``dt`` (s)."""
    a, bu, e = p.continuous()
    steps = p.delay_s / dt
    n = int(np.floor(steps + 1e-9))
    frac = steps - n if steps - n > 1e-9 else 0.0
    phi, _ = c2d(a, bu, dt)
    # over one step the delayed input is u[k-n-1] for the first frac*dt, then u[k-n]
    phi_late, g_late = c2d(a, bu, (1 - frac) * dt)
    _, g_early = c2d(a, bu, frac * dt)
    _, gw = c2d(a, e, dt)
    return DiscretePlant(
        phi=phi, gamma_prev=phi_late @ g_early, gamma_now=g_late, gamma_w=gw,
        delay_steps=n, dt=dt, n_state=a.shape[0],
    )


def lowpass2p_filter(x: np.ndarray, cutoff_hz: float, sample_hz: float) -> np.ndarray:
    """Filter the rows of ``x`` (samples first) with :class:`Lowpass2p`.

    Examples
    --------
    >>> y = lowpass2p_filter(np.ones((5, 1)), 20.0, 400.0)
    >>> np.allclose(y, 1.0)
    True
    """
    x = np.asarray(x, dtype=float)
    f = Lowpass2p(cutoff_hz, sample_hz, x.shape[1] if x.ndim > 1 else 1)
    out = np.empty_like(x)
    for i in range(x.shape[0]):
        out[i] = f(x[i])
    return out
