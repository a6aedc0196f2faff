"""Multirotor motor geometry: ArduPilot's motor matrices and the logged frame.

Mixers
------
Logs that only carry motor PWMs (``.tlog`` SERVO_OUTPUT_RAW, old RCOU/MOT) give inputs by
inverting the vehicle's motor mixer, as ArduPilot's ``AP_MotorsMatrix`` defines it. Motor
``i`` sits at ``angle_deg[i]`` from the nose (positive to the right) and spins with
``yaw[i]`` (+1 counter-clockwise, -1 clockwise); its roll factor is ``cos(angle + 90°)``,
pitch factor ``cos(angle)``, yaw factor ``yaw[i]`` (some frames give raw roll and pitch
factors instead); roll, pitch and yaw factors are each scaled so the largest is 0.5
(ArduPilot's ``normalise_rpy_factors``). The firmware sets each motor's thrust to
``u_thrust + u_roll·roll_i + u_pitch·pitch_i + u_yaw·yaw_i``; mavsid turns PWM back into
thrust (``MOT_PWM_MIN/MAX``, ``MOT_SPIN_MIN/MAX`` and the ``MOT_THST_EXPO`` thrust curve
from the log's parameters, ArduPilot defaults otherwise) and solves that linear system in
the least-squares sense, so ``u_roll`` etc. are on the scale of RATE.ROut. The frame comes
from ``FRAME_CLASS``/``FRAME_TYPE`` when the log has them (:data:`MIXERS`: every multirotor
matrix of ArduCopter 4.x), quad-X otherwise; motor ``i``'s output from ``SERVOn_FUNCTION``
(:func:`mavsid.autopilot.ardupilot.motor_channels`).

Examples
--------
>>> m = MIXERS["quad-x"]
>>> np.round(m.factors(), 3).tolist()[0]  # motor 1, front right: roll, pitch, yaw factors
[-0.5, 0.5, 0.5]
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from mavsid.autopilot.ardupilot import whole_param
from mavsid.errors import ConfigError

__all__ = ["MIXERS", "Mixer", "frame_name", "frame_of", "has_mixer", "matrix_mixer"]


@dataclass(frozen=True)
class Mixer:
    """A multirotor's motor geometry, as ArduPilot's motor matrix defines it.

    Each motor is given either by its direction (``angle_deg``, as ArduPilot's ``add_motor``)
    or by raw roll and pitch factors (``roll``, ``pitch``, as ``add_motor_raw``), and by its
    yaw factor. :meth:`factors` scales each axis's factors so the largest is 0.5, as
    ArduPilot's ``normalise_rpy_factors`` does (roll, pitch and yaw each on its own).

    Parameters
    ----------
    name : str
    angle_deg : tuple of float
        Each motor's direction from the nose, degrees, positive to the right (motor 1 first);
        empty when ``roll`` and ``pitch`` are given.
    yaw : tuple of float
        Each motor's yaw factor: +1 counter-clockwise propeller, -1 clockwise.
    pitch_angle_deg : tuple of float, optional
        The direction its pitch factor is taken from when it differs from ``angle_deg``
        (ArduPilot's V-tail quads).
    roll, pitch : tuple of float, optional
        Raw roll and pitch factors (before scaling), instead of ``angle_deg``.
    """

    name: str
    angle_deg: tuple[float, ...]
    yaw: tuple[float, ...]
    pitch_angle_deg: tuple[float, ...] = ()
    roll: tuple[float, ...] = ()
    pitch: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        n = len(self.yaw)
        raw = bool(self.roll or self.pitch)
        ok = n >= 3 and (
            (raw and not self.angle_deg and not self.pitch_angle_deg
             and len(self.roll) == len(self.pitch) == n)
            or (not raw and len(self.angle_deg) == n
                and len(self.pitch_angle_deg) in (0, n)))
        if not ok:
            raise ConfigError(
                f"mixer {self.name!r}: need the same number (>= 3) of yaw factors and of "
                "angle_deg, or of roll and pitch factors"
            )

    @property
    def n_motors(self) -> int:
        """Number of motors."""
        return len(self.yaw)

    def factors(self) -> np.ndarray:
        """Roll, pitch and yaw factor of each motor, shape ``(n_motors, 3)``, each axis's
        largest magnitude 0.5 (an axis with no factor stays zero)."""
        if self.roll:
            roll, pitch = np.array(self.roll, float), np.array(self.pitch, float)
        else:
            a = np.deg2rad(np.asarray(self.angle_deg, dtype=float))
            b = np.deg2rad(np.asarray(self.pitch_angle_deg or self.angle_deg, dtype=float))
            roll, pitch = np.cos(a + np.pi / 2), np.cos(b)
        f = np.column_stack([roll, pitch, np.asarray(self.yaw, dtype=float)])
        f[np.abs(f) < 1e-9] = 0.0
        top = np.abs(f).max(axis=0)
        return 0.5 * f / np.where(top > 0, top, 1.0)

    def unmix(self, thrust: np.ndarray) -> np.ndarray:
        """Motor thrusts ``(n, n_motors)`` (0..1) -> ``(n, 4)`` u_roll, u_pitch, u_yaw, u_thrust.

        Least-squares inverse of ``thrust_i = u_thrust + f_i · (u_roll, u_pitch, u_yaw)``.

        Examples
        --------
        >>> m = MIXERS["quad-plus"]
        >>> u = np.array([[0.1, -0.05, 0.02, 0.4]])
        >>> motors = u[:, 3:] + u[:, :3] @ m.factors().T
        >>> np.allclose(m.unmix(motors), u)
        True
        """
        mix = np.column_stack([self.factors(), np.ones(self.n_motors)])
        return np.asarray(thrust, dtype=float) @ np.linalg.pinv(mix).T


_CW, _CCW = -1.0, 1.0


def _alternating(n: int, first: float = _CCW) -> tuple[float, ...]:
    return tuple(first if i % 2 == 0 else -first for i in range(n))


#: built-in mixers: ArduPilot's motor matrices (AP_MotorsMatrix, ArduCopter 4.x), motor 1
#: first; named by frame class and FRAME_TYPE (:func:`matrix_mixer`)
MIXERS: dict[str, Mixer] = {
    m.name: m
    for m in (
        Mixer("quad-plus", (90, -90, 0, 180), (_CCW, _CCW, _CW, _CW)),
        Mixer("quad-x", (45, -135, -45, 135), (_CCW, _CCW, _CW, _CW)),
        Mixer("quad-v", (45, -135, -45, 135), (0.7981, 1.0, -0.7981, -1.0)),
        Mixer("quad-h", (45, -135, -45, 135), (_CW, _CW, _CCW, _CCW)),
        Mixer("quad-vtail", (60, 0, -60, 0), (0.0, _CW, 0.0, _CCW), (60, -160, -60, 160)),
        Mixer("quad-atail", (60, 0, -60, 0), (0.0, _CCW, 0.0, _CW), (60, -160, -60, 160)),
        Mixer("quad-plusrev", (90, -90, 0, 180), (_CW, _CW, _CCW, _CCW)),
        Mixer("quad-bf-x", (135, 45, -135, -45), (_CW, _CCW, _CCW, _CW)),
        Mixer("quad-dji-x", (45, -45, -135, 135), _alternating(4)),
        Mixer("quad-cw-x", (45, 135, -135, -45), _alternating(4)),
        Mixer("quad-bf-x-rev", (135, 45, -135, -45), (_CCW, _CW, _CW, _CCW)),
        Mixer("quad-y4", (), (_CCW, _CW, _CCW, _CW), roll=(-1, 0, 0, 1), pitch=(1, -1, -1, 1)),
        Mixer("hexa-plus", (0, 180, -120, 60, -60, 120), (_CW, _CCW, _CW, _CCW, _CCW, _CW)),
        Mixer("hexa-x", (90, -90, -30, 150, 30, -150), (_CW, _CCW, _CW, _CCW, _CCW, _CW)),
        Mixer("hexa-h", (), (_CW, _CCW, _CW, _CCW, _CCW, _CW),
              roll=(-1, 1, 1, -1, -1, 1), pitch=(0, 0, 1, -1, 1, -1)),
        Mixer("hexa-dji-x", (30, -30, -90, -150, 150, 90), _alternating(6)),
        Mixer("hexa-cw-x", (30, 90, 150, -150, -90, -30), _alternating(6)),
        Mixer("octa-plus", (0, 180, 45, 135, -45, -135, -90, 90),
              (_CW, _CW, _CCW, _CCW, _CCW, _CCW, _CW, _CW)),
        Mixer("octa-x", (22.5, -157.5, 67.5, 157.5, -22.5, -112.5, -67.5, 112.5),
              (_CW, _CW, _CCW, _CCW, _CCW, _CCW, _CW, _CW)),
        Mixer("octa-v", (), (_CW, _CW, _CCW, _CCW, _CCW, _CCW, _CW, _CW),
              roll=(0.83, -0.67, 0.67, -0.5, 1.0, -0.83, -1.0, 0.5),
              pitch=(0.34, -0.32, -0.32, -1.0, 1.0, 0.34, 1.0, -1.0)),
        Mixer("octa-h", (), (_CW, _CW, _CCW, _CCW, _CCW, _CCW, _CW, _CW),
              roll=(-1, 1, -1, -1, 1, 1, 1, -1),
              pitch=(1, -1, 0.333, -1, 1, -0.333, 0.333, -0.333)),
        Mixer("octa-i", (), (_CW, _CW, _CCW, _CCW, _CCW, _CCW, _CW, _CW),
              roll=(0.333, -0.333, 1, 0.333, -0.333, -1, -1, 1),
              pitch=(-1, 1, -1, 1, -1, 1, -1, 1)),
        Mixer("octa-dji-x", (22.5, -22.5, -67.5, -112.5, -157.5, 157.5, 112.5, 67.5),
              _alternating(8)),
        Mixer("octa-cw-x", (22.5, 67.5, 112.5, 157.5, -157.5, -112.5, -67.5, -22.5),
              _alternating(8)),
        Mixer("octaquad-plus", (0, -90, 180, 90, -90, 0, 90, 180), _alternating(8)),
        Mixer("octaquad-x", (45, -45, -135, 135, -45, 45, 135, -135), _alternating(8)),
        Mixer("octaquad-v", (45, -45, -135, 135, -45, 45, 135, -135),
              (0.7981, -0.7981, 1.0, -1.0, 0.7981, -0.7981, 1.0, -1.0)),
        Mixer("octaquad-h", (45, -45, -135, 135, -45, 45, 135, -135), _alternating(8, _CW)),
        Mixer("octaquad-cw-x", (45, 45, 135, 135, -135, -135, -45, -45),
              (_CCW, _CW, _CW, _CCW, _CCW, _CW, _CW, _CCW)),
        Mixer("octaquad-bf-x", (135, 45, -135, -45, 135, 45, -135, -45),
              (_CW, _CCW, _CCW, _CW, _CCW, _CW, _CW, _CCW)),
        Mixer("octaquad-bf-x-rev", (135, 45, -135, -45, 135, 45, -135, -45),
              (_CCW, _CW, _CW, _CCW, _CW, _CCW, _CCW, _CW)),
        Mixer("dodecahexa-plus", (0, 0, 60, 60, 120, 120, 180, 180, -120, -120, -60, -60),
              (_CCW, _CW, _CW, _CCW, _CCW, _CW, _CW, _CCW, _CCW, _CW, _CW, _CCW)),
        Mixer("dodecahexa-x", (30, 30, 90, 90, 150, 150, -150, -150, -90, -90, -30, -30),
              (_CCW, _CW, _CW, _CCW, _CCW, _CW, _CW, _CCW, _CCW, _CW, _CW, _CCW)),
        Mixer("y6", (), (_CCW, _CW, _CCW, _CW, _CW, _CCW),
              roll=(-1, 1, 1, 0, -1, 0), pitch=(0.666, 0.666, 0.666, -1.333, 0.666, -1.333)),
        Mixer("y6b", (), _alternating(6, _CW),
              roll=(-1, -1, 0, 0, 1, 1), pitch=(0.5, 0.5, -1, -1, 0.5, 0.5)),
        Mixer("y6f", (), (_CCW, _CCW, _CCW, _CW, _CW, _CW),
              roll=(0, -1, 1, 0, -1, 1), pitch=(-1, 0.5, 0.5, -1, 0.5, 0.5)),
        Mixer("deca-plus", (0, 36, 72, 108, 144, 180, -144, -108, -72, -36), _alternating(10)),
        Mixer("deca-x", (18, 54, 90, 126, 162, -162, -126, -90, -54, -18), _alternating(10)),
    )
}

#: ArduPilot FRAME_TYPE -> the mixer name's suffix (AP_Motors_Class.h's motor_frame_type;
#: 16 and 17, no yaw torque, are QuadPlane frames)
_AP_TYPES = {0: "plus", 1: "x", 2: "v", 3: "h", 4: "vtail", 5: "atail", 6: "plusrev",
             10: "b", 11: "f", 12: "bf-x", 13: "dji-x", 14: "cw-x", 15: "i", 18: "bf-x-rev",
             19: "y4"}
#: ArduPilot FRAME_CLASS -> the mixer name's prefix (the classes with a motor matrix)
_AP_MATRIX_CLASSES = {1: "quad", 2: "hexa", 3: "octa", 4: "octaquad", 5: "y6", 12: "dodecahexa",
                      14: "deca"}


def matrix_mixer(key: tuple[int, int]) -> str | None:
    """The built-in mixer of an ArduPilot ``(FRAME_CLASS, FRAME_TYPE)``; None if none.

    >>> matrix_mixer((2, 1)), matrix_mixer((5, 1)), matrix_mixer((5, 10)), matrix_mixer((14, 14))
    ('hexa-x', 'y6', 'y6b', 'deca-x')
    >>> matrix_mixer((6, 0)) is None, matrix_mixer((1, 15)) is None
    (True, True)
    """
    cls, kind = _AP_MATRIX_CLASSES.get(key[0]), _AP_TYPES.get(key[1], "")
    if cls == "y6":  # Y6B and Y6F; every other type is the default Y6
        return "y6" + kind if kind in ("b", "f") else "y6"
    if cls == "deca" and kind == "cw-x":  # (ArduPilot's deca X and CW-X are one frame)
        kind = "x"
    name = f"{cls}-{kind}" if cls else ""
    return name if name in MIXERS else None


#: Motor count -> ArduPilot FRAME_CLASS (for logs older than FRAME_CLASS, ArduCopter < 3.5,
#: whose frame class was the firmware build).
_CLASS_BY_MOTORS = {4: 1, 6: 2, 8: 3}


def frame_of(params: Mapping[str, float], n_motors: int | None = None
             ) -> tuple[tuple[int, int], str]:
    """ArduPilot ``(FRAME_CLASS, FRAME_TYPE)`` and where it came from.

    ArduCopter >= 3.5 logs ``FRAME_CLASS``/``FRAME_TYPE``; 3.2-3.4 only ``FRAME`` (the
    orientation, numbered as ``FRAME_TYPE`` is: 0 plus, 1 X, ...), the class being the build
    (quad, hexa, octa): then taken from the motor outputs logged (``n_motors``), else quad.

    Examples
    --------
    >>> frame_of({"FRAME_CLASS": 2, "FRAME_TYPE": 0})
    ((2, 0), 'FRAME_CLASS/FRAME_TYPE')
    >>> frame_of({"FRAME": 0}, n_motors=6)
    ((2, 0), 'FRAME (ArduCopter < 3.5) and 6 motor outputs')
    >>> frame_of({})
    ((1, 1), 'no frame parameters (FRAME_CLASS/FRAME_TYPE or FRAME): quad-X assumed')
    """
    cls_p, type_p, frame_p = (whole_param(params, k)
                              for k in ("FRAME_CLASS", "FRAME_TYPE", "FRAME"))
    if cls_p is not None:
        if type_p is None and "FRAME_TYPE" in params:
            return (cls_p, 1), "FRAME_CLASS (FRAME_TYPE not a number: X assumed)"
        return (cls_p, 1 if type_p is None else type_p), "FRAME_CLASS/FRAME_TYPE"
    if frame_p is not None:
        cls = _CLASS_BY_MOTORS.get(n_motors or 0)
        where = (f"FRAME (ArduCopter < 3.5) and {n_motors} motor outputs" if cls else
                 "FRAME (ArduCopter < 3.5), class unknown: quad assumed")
        return (cls or 1, frame_p), where
    if {"FRAME_CLASS", "FRAME_TYPE", "FRAME"} & set(params):
        return (1, 1), "frame parameters that are not numbers (a damaged log): quad-X assumed"
    return (1, 1), "no frame parameters (FRAME_CLASS/FRAME_TYPE or FRAME): quad-X assumed"


#: ArduPilot FRAME_CLASS names (for messages about frames without a mixer here)
_FRAME_CLASSES = {1: "quad", 2: "hexa", 3: "octa", 4: "octaquad", 5: "Y6", 6: "heli",
                  7: "tri", 8: "single copter", 9: "coax copter", 10: "bicopter",
                  11: "dual heli", 12: "dodecahexa", 13: "heli quad", 14: "deca",
                  15: "scripting matrix", 16: "6-DoF scripting", 17: "dynamic scripting"}


def frame_name(key: tuple[int, int]) -> str:
    """A frame class's name, e.g. ``heli`` for FRAME_CLASS 6.

    >>> frame_name((6, 0)), frame_name((1, 16))
    ('heli', 'quad, type 16')
    """
    cls = _FRAME_CLASSES.get(key[0], f"class {key[0]}")
    return cls if key[0] not in _AP_MATRIX_CLASSES else f"{cls}, type {key[1]}"


def has_mixer(params: Mapping[str, float], n_motors: int | None = None) -> bool:
    """Whether the logged frame (:func:`frame_of`) has a motor mixer here.

    >>> has_mixer({"FRAME_CLASS": 1, "FRAME_TYPE": 1}), has_mixer({"FRAME_CLASS": 6})
    (True, False)
    """
    return matrix_mixer(frame_of(params, n_motors)[0]) is not None
