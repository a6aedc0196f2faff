"""Why a window was rejected, as a value: a kind, the numbers, a message made from them.

A :class:`Reason` is what the segment gates (:mod:`mavsid.excitation`) say about a window;
the verdict, ``mavsid segments`` and its ``--json`` read the kind and the numbers, and only
people read the message. :func:`summarize` groups reasons of one kind into one line with the
range of their numbers.

Examples
--------
>>> r = Reason("injection_coverage", {"coverage_pct": 2.0, "need_pct": 30.0,
...            "lo_hz": 0.5, "hi_hz": 10.0}, {"output": "r"})
>>> r.message
'r is coherent with the injection (SIDD.Targ) over 2 % of its 0.5–10 Hz band (need 30 %)'
>>> summarize([r, Reason("injection_coverage", {**r.numbers, "coverage_pct": 28.0}, r.names)])
'2× coherence with the injection too low (2–28 % of the band, need 30 %)'
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal, get_args

if TYPE_CHECKING:
    from mavsid.data import SysidRun

__all__ = ["KINDS", "Reason", "ReasonKind", "format_number", "group", "injected_nothing",
           "summarize"]

ReasonKind = Literal[
    "missing_channel", "not_airborne", "mode_change", "attitude_bound", "input_saturated",
    "thrust_limits", "too_short", "input_below_floor", "response_below_floor",
    "ill_conditioned", "injection_coverage", "injection_coherence", "coverage", "coherence",
    "too_little_data", "not_attitude_axis", "injected_nothing", "target_not_exogenous",
    "feedback_dominated",
]

#: every reason kind, in the order the gates check them (the closed-loop response's two last)
KINDS: tuple[ReasonKind, ...] = get_args(ReasonKind)


def format_number(x: float) -> str:
    """A number as the messages write it (3 significant digits, 2 when large).

    >>> format_number(0.00021), format_number(123456.0)
    ('0.00021', '1.2e+05')
    """
    return f"{x:.3g}" if abs(x) < 1e4 else f"{x:.2g}"


def _band(n: Mapping[str, float]) -> str:
    return f"{n['lo_hz']:.3g}–{n['hi_hz']:.3g} Hz"


def _ill_conditioned(n: Mapping[str, float], w: Mapping[str, str]) -> str:
    u, y = w["input"], w["output"]
    cause = w["cause"]
    if cause == "constant":
        why = f"{u} or {y} does not vary"
    elif cause == "other_axis":
        why = (f"{u} carries {n['input_share_pct']:.0f} % of the window's input spread: "
               "another axis is being excited, not this one")
    else:
        why = (f"{u} follows {y}, correlation {n['correlation']:+.2f}: closed-loop "
               "feedback, no independent excitation")
    return (f"ill-conditioned regressors [{y}, {u}]: Gram condition number "
            f"{format_number(n['condition'])} above {format_number(n['max_condition'])} ({why})")


_Message = Callable[[Mapping[str, float], Mapping[str, str]], str]

#: kind -> the message made from the numbers and the names
_MESSAGES: dict[str, _Message] = {
    "missing_channel": lambda n, w: f"the log has no {w['channel']} {w['role']} "
                                    f"(preset {w['preset']})",
    "not_airborne": lambda n, w: f"on the ground or disarmed for {n['grounded_pct']:.0f} % of "
                                 f"the window (must be airborne for {n['need_pct']:.0f} %)",
    "mode_change": lambda n, w: f"flight mode changes inside the window ({w['from']}→{w['to']} "
                                f"at {n['at_s']:.1f} s)",
    "attitude_bound": lambda n, w: f"|{w['angle']}| reaches {n['peak_deg']:.0f}° "
                                   f"(bound {n['bound_deg']:g}°)",
    "input_saturated": lambda n, w: f"{w['input']} saturated (|u| >= {n['saturation']:g}) for "
                                    f"{n['saturated_pct']:.0f} % of the window "
                                    f"(limit {n['limit_pct']:.0f} %)",
    "thrust_limits": lambda n, w: f"u_thrust at its limits for {n['saturated_pct']:.0f} % of "
                                  f"the airborne window (limit {n['limit_pct']:.0f} %)",
    "too_short": lambda n, w: f"window too short ({n['samples']:.0f} samples)",
    "input_below_floor": lambda n, w: (
        f"input RMS {format_number(n['rms'])} below {n['need_ratio']:g}× noise floor "
        f"{format_number(n['floor'])} ({w['input']})"),
    "response_below_floor": lambda n, w: (
        f"response RMS {format_number(n['rms'])} below {n['need_ratio']:g}× its noise floor "
        f"{format_number(n['floor'])} ({w['output']} where {w['input']} is quiet; input RMS "
        f"{n['input_ratio']:.1f}× its floor)"),
    "ill_conditioned": _ill_conditioned,
    "injection_coverage": lambda n, w: (
        f"{w['output']} is coherent with the injection (SIDD.Targ) over "
        f"{n['coverage_pct']:.0f} % of its {_band(n)} band (need {n['need_pct']:.0f} %)"),
    "injection_coherence": lambda n, w: (
        f"injection (SIDD.Targ)→{w['output']} coherence {n['coherence']:.2f} below "
        f"{n['min_coherence']:g} in {_band(n)}"),
    "coverage": lambda n, w: f"input covers {n['coverage_pct']:.0f} % of the {_band(n)} band "
                             f"(need {n['need_pct']:.0f} %)",
    "coherence": lambda n, w: f"{w['input']}→{w['output']} coherence {n['coherence']:.2f} "
                              f"below {n['min_coherence']:g} in {_band(n)}",
    "too_little_data": lambda n, w: (
        f"too little data: the longest contiguous block has {n['samples']:.0f} samples "
        f"({n['seconds']:.2f} s), a window needs {n['need_samples']:.0f}"),
    "not_attitude_axis": lambda n, w: (
        f"SYSTEMID run on {w['axis']} ({w['injection']}, SID_AXIS {n['sid_axis']:.0f}) does "
        "not excite roll, pitch or yaw"),
    "injected_nothing": lambda n, w: (
        f"SYSTEMID mode (SID_AXIS {n['sid_axis']:.0f}) {n['start_s']:.1f}–{n['stop_s']:.1f} s "
        f"injected nothing (SIDD.Targ is 0 throughout{w['sids']})"),
    "target_not_exogenous": lambda n, w: (
        f"{n['left_out_s']:.0f} s left out of {w['target']} -> {w['actual']} ({w['spans']}): "
        "the rate target there is the controller's answer to the injected disturbance, not a "
        "command"),
    "feedback_dominated": lambda n, w: (
        f"the step starts at {n['dip']:.2g}, below zero beyond its band (-{n['max_dip']:g}): "
        "the target is not independent of the actual (it answers it through the outer loop, "
        "with no commands to speak of), so this is not the loop's step response"),
}

#: kind -> (label of a group, the number whose range it states, its unit, the bound's number)
_GROUPS: dict[str, tuple[str, str, str, str]] = {
    "missing_channel": ("missing channel", "", "", ""),
    "not_airborne": ("on the ground or disarmed", "grounded_pct", " % of the window", "need_pct"),
    "mode_change": ("mode change inside", "", "", ""),
    "attitude_bound": ("attitude beyond bound", "peak_deg", "°", "bound_deg"),
    "input_saturated": ("input saturated", "saturated_pct", " % of the window", "limit_pct"),
    "thrust_limits": ("thrust at its limits", "saturated_pct", " % of the window", "limit_pct"),
    "too_short": ("too short", "samples", " samples", ""),
    "input_below_floor": ("input RMS below noise floor", "", "", ""),
    "response_below_floor": ("response below its noise floor", "", "", ""),
    "ill_conditioned": ("ill-conditioned regressors", "", "", ""),
    "injection_coverage": ("coherence with the injection too low", "coverage_pct",
                           " % of the band", "need_pct"),
    "injection_coherence": ("mean coherence with the injection too low", "coherence", "",
                            "min_coherence"),
    "coverage": ("narrow band coverage", "coverage_pct", " % of the band", "need_pct"),
    "coherence": ("low coherence", "coherence", "", "min_coherence"),
    "too_little_data": ("too little data", "", "", ""),
    "not_attitude_axis": ("SYSTEMID run off the attitude axes", "", "", ""),
    "injected_nothing": ("SYSTEMID run that injected nothing", "", "", ""),
    "target_not_exogenous": ("target answering an injection left out", "left_out_s", " s", ""),
    "feedback_dominated": ("target answering the actual", "dip", "", "max_dip"),
}


@dataclass(frozen=True)
class Reason:
    """One gate a window failed: its kind, the numbers it measured and the names it speaks of.

    Parameters
    ----------
    kind : ReasonKind
        Which gate (one of :data:`KINDS`).
    numbers : mapping of str to float
        What it measured and the bound it applied (percentages as ``*_pct``).
    names : mapping of str to str
        The channels, modes or axes it names (``input``, ``output``, ...).
    """

    kind: ReasonKind
    numbers: Mapping[str, float] = field(default_factory=dict)
    names: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.kind not in _MESSAGES:
            raise ValueError(f"unknown reason kind {self.kind!r} (known: {', '.join(KINDS)})")

    @property
    def message(self) -> str:
        """The sentence for people, made from the numbers and names."""
        return _MESSAGES[self.kind](self.numbers, self.names)

    @property
    def label(self) -> str:
        """The kind as a group's label (``"ill-conditioned regressors"``)."""
        return _GROUPS[self.kind][0]

    def to_dict(self) -> dict[str, object]:
        """JSON-safe dict (``kind numbers names message``)."""
        return {"kind": self.kind, "numbers": {k: float(v) for k, v in self.numbers.items()},
                "names": dict(self.names), "message": self.message}


def injected_nothing(run: SysidRun) -> Reason:
    """Why a SYSTEMID run whose waveform stayed zero (``injected`` False) gives nothing.

    Examples
    --------
    >>> from mavsid.data import SysidRun
    >>> print(injected_nothing(SysidRun(3899.27, 3908.8, "PARM", axis=1)).message)
    SYSTEMID mode (SID_AXIS 1) 3899.3–3908.8 s injected nothing (SIDD.Targ is 0 throughout, \
SIDS not logged)
    """
    return Reason("injected_nothing", {"sid_axis": float(run.sid_axis), "start_s": run.start_s,
                                       "stop_s": run.stop_s},
                  {"sids": "" if run.settings_from == "SIDS" else ", SIDS not logged"})


def _num(x: float, unit: str) -> str:
    return f"{x:.2f}" if unit == "" else f"{x:.0f}"


def summarize(reasons: Sequence[Reason]) -> str:
    """``N× label (range of the kind's number, bound)`` for reasons of one group.

    Examples
    --------
    >>> summarize([Reason("mode_change", {"at_s": 3.0}, {"from": "ALT_HOLD", "to": "LOITER"})])
    '1× mode change inside'
    >>> summarize([Reason("coherence", {"coherence": c, "min_coherence": 0.5, "lo_hz": 0.5,
    ...            "hi_hz": 10.0}, {"input": "u_roll", "output": "p"}) for c in (0.2, 0.41)])
    '2× low coherence (0.20–0.41, need 0.5)'
    """
    label, key, unit, bound = _GROUPS[reasons[0].kind]
    text = f"{len(reasons)}× {label}"
    values = [r.numbers[key] for r in reasons if key and key in r.numbers]
    if not values:
        return text
    lo, hi = _num(min(values), unit), _num(max(values), unit)
    span = lo if lo == hi else f"{lo}–{hi}"
    limits = {r.numbers[bound] for r in reasons if bound and bound in r.numbers}
    need = f", need {next(iter(limits)):g}{unit.split(' of')[0]}" if len(limits) == 1 else ""
    return f"{text} ({span}{unit}{need})"


def group(reasons: Sequence[Reason]) -> list[str]:
    """One :func:`summarize` line per group, most frequent first.

    Examples
    --------
    >>> m = Reason("mode_change", {"at_s": 3.0}, {"from": "A", "to": "B"})
    >>> t = Reason("too_short", {"samples": 5.0})
    >>> group([t, m, m])
    ['2× mode change inside', '1× too short (5 samples)']
    """
    by: dict[str, list[Reason]] = {}
    for r in reasons:
        by.setdefault(r.kind, []).append(r)
    return [summarize(rs) for rs in sorted(by.values(), key=lambda rs: -len(rs))]
