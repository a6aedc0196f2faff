"""The controller emulation check: the rate controller rebuilt from the log's parameters,
fed the *logged* rate and target, against the logged controller output.

It runs before the closed-loop twin (:func:`mavsid.loop.twin.closed_loop_fit`): a twin
built on a controller that does not reproduce the logged output cannot reproduce the
flight, whatever its plant. :func:`emulation_check` replays the controller
(:func:`mavsid.loop.twin.replay_terms`) on the held-out blocks, with the target lag and
measurement delay the replay chooses on the training blocks, and compares its output with
the logged one (ArduPilot ``RATE.ROut/POut/YOut``, PX4's torque setpoint, minus any SYSTEMID
mixer injection): the fit % and the RMS of the difference. Where the log has the
controller's terms apart (ArduPilot ``PIDR/PIDP/PIDY`` ``P``, ``I``, ``D``, ``FF``,
``DFF``), each rebuilt term is compared with its logged column, and a failed check names the
term that does not match and what the rebuild may lack for it.

Examples
--------
>>> e = ControllerEmulation(95.2, 0.004, True, "", 0.0042, 1, 0.0, "RATE.ROut")
>>> e.to_dict()["passed"], e.to_dict()["fit_percent"]
(True, 95.2)
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from mavsid.errors import ConfigError
from mavsid.loop.controllers import AXIS_RATE, RateGains
from mavsid.loop.twin import (
    TERMS,
    LocatedBlock,
    TwinSignals,
    controller_timing,
    lagged,
    locate_blocks,
    replay_terms,
)

if TYPE_CHECKING:
    from mavsid.data import FlightData, Segment

__all__ = [
    "EMULATION_MIN_FIT_PCT",
    "TERM_MAX_OFF",
    "ControllerEmulation",
    "TermFit",
    "emulation_check",
]

#: the emulation passes at this fit % of the logged output or above. A rebuild with every
#: feature the firmware applies agrees to rounding (``tests/test_synthetic_controller.py``)
#: and a log's timing costs a few % (the SITL flight: 97.7 %); below 80 % a fifth of the
#: output's variation is something the rebuild does not know, and the twin would simulate
#: another controller than the one flown
EMULATION_MIN_FIT_PCT = 80.0
#: a rebuilt term whose RMS difference from its logged column exceeds this fraction of the
#: larger of the two RMS does not match it ...
TERM_MAX_OFF = 0.2
#: ... when that difference is also at least this fraction of the logged output's RMS (a
#: term too small to matter is not blamed)
_TERM_WEIGHT = 0.05
#: what the rebuild may lack when a term does not match
_LACKS = {
    "P": "the P gain, the target or error filter (FLTT, FLTE), an SMAX slew limit or PDMX "
         "(PD_MAX) the rebuild does not know",
    "I": "the I gain, IMAX or the integrator held while the motors saturate, which the "
         "rebuild does not know",
    "D": "a D filter (FLTD, FLTE), an SMAX slew limit or PDMX (PD_MAX) the rebuild does not "
         "know",
    "FF": "FF or the target filter FLTT the rebuild does not know",
    "DFF": "a D_FF (the target's derivative as feed-forward) the rebuild does not know",
}


@dataclass(frozen=True)
class TermFit:
    """One controller term, rebuilt against its logged column.

    Attributes
    ----------
    term : str
        ``P``, ``I``, ``D``, ``FF`` or ``DFF``.
    source : str
        The logged column (``PIDR.D``).
    fit_percent : float
        Fit % of the rebuilt term against the logged one (NaN when the logged one is
        constant).
    rms : float
        RMS of the difference (normalised output).
    logged_rms, rebuilt_rms : float
        RMS of each.
    """

    term: str
    source: str
    fit_percent: float
    rms: float
    logged_rms: float
    rebuilt_rms: float

    @property
    def off(self) -> float:
        """The difference's RMS as a fraction of the larger term's RMS (0 when both are 0)."""
        scale = max(self.logged_rms, self.rebuilt_rms)
        return self.rms / scale if scale > 0 else 0.0

    def to_dict(self) -> dict[str, Any]:
        """JSON form."""
        return {"source": self.source, "fit_percent": self.fit_percent, "rms": self.rms,
                "logged_rms": self.logged_rms, "rebuilt_rms": self.rebuilt_rms}


@dataclass(frozen=True)
class ControllerEmulation:
    """The rebuilt controller's replay against the logged controller output of one axis.

    Attributes
    ----------
    fit_percent : float
        Fit % of the replayed output against the logged one on the held-out blocks.
    rms : float
        RMS of their difference (normalised output).
    passed : bool
        ``fit_percent >= threshold_percent``.
    reason : str
        When it fails, which part did not match (empty when it passes).
    output_rms : float
        RMS of the logged output (what ``rms`` compares with).
    lag_loops, measurement_delay_loops
        The replay's timing (:func:`mavsid.loop.twin.controller_timing`).
    output_source : str
        The logged output compared with.
    terms : tuple of TermFit
        Per term, where the log has them apart.
    threshold_percent : float
    """

    fit_percent: float
    rms: float
    passed: bool
    reason: str
    output_rms: float
    lag_loops: int
    measurement_delay_loops: float
    output_source: str
    terms: tuple[TermFit, ...] = ()
    threshold_percent: float = EMULATION_MIN_FIT_PCT

    def to_dict(self) -> dict[str, Any]:
        """JSON form (``fit --json``: ``axes.<axis>.closed_loop.emulation``)."""
        return {
            "fit_percent": self.fit_percent,
            "rms": self.rms,
            "output_rms": self.output_rms,
            "passed": self.passed,
            "reason": self.reason,
            "threshold_percent": self.threshold_percent,
            "output_source": self.output_source,
            "lag_loops": self.lag_loops,
            "measurement_delay_loops": self.measurement_delay_loops,
            "terms": {t.term: t.to_dict() for t in self.terms},
        }


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x * x))) if x.size else float("nan")


def _term_fits(blocks: Sequence[LocatedBlock], rebuilt: Sequence[np.ndarray],
               sources: Mapping[str, str]) -> tuple[TermFit, ...]:
    """Each logged term against its rebuild, over the samples where it is logged."""
    from mavsid.validation import fit_percent

    out = []
    names = [t for t in ("P", "I", "D", "FF", "DFF") if all(t in b.terms for b in blocks)]
    for term in names:
        logged, mine = [], []
        for b, r in zip(blocks, rebuilt, strict=True):
            col = b.terms[term][b.warm:]
            ours = r[b.warm:, TERMS.index(term)] if term in TERMS else np.zeros(col.size)
            ok = np.isfinite(col)
            logged.append(col[ok])
            mine.append(ours[ok])
        lg, mn = np.concatenate(logged), np.concatenate(mine)
        if lg.size < 10:
            continue
        fit = float(fit_percent(lg, mn)) if np.ptp(lg) > 0 else float("nan")
        out.append(TermFit(term, sources.get(term, term), fit, _rms(lg - mn), _rms(lg),
                           _rms(mn)))
    return tuple(out)


def _diagnosis(fit: float, output_source: str, output_rms: float,
               terms: Sequence[TermFit], substeps: int = 1, ardupilot: bool = True,
               threshold: float = EMULATION_MIN_FIT_PCT) -> str:
    """Why the emulation failed: the terms that do not match, largest difference first."""
    head = (f"the rebuilt controller reproduces {output_source} to {fit:.1f} % "
            f"(< {threshold:g} %)")
    if substeps > 1:
        head += (f" from a log of 1 sample in {substeps} controller loops (the rate between "
                 "samples interpolated)")
    if not terms:
        lacks = ("an FF, D_FF, PD_MAX (PDMX), slew limit (SMAX) or notch" if ardupilot
                 else "a filter, a notch or the integrator's saturation hold")
        return (head + f": a parameter, {lacks} the rebuild does not know (the log has no "
                "PID terms apart to tell which)")
    parts = []
    for t in sorted(terms, key=lambda t: -t.rms):
        if t.off <= TERM_MAX_OFF or t.rms < _TERM_WEIGHT * output_rms:
            continue
        if t.logged_rms < 1e-3 * t.rebuilt_rms:
            parts.append(f"the logged {t.source} is 0 while the rebuild carries one: "
                         f"{_LACKS[t.term]}")
        elif t.rebuilt_rms < 1e-3 * t.logged_rms:
            parts.append(f"the logged {t.source} is not 0 (RMS {t.logged_rms:.3g}) while the "
                         f"rebuild has none: {_LACKS[t.term]}")
        else:
            parts.append(f"the rebuilt {t.term} term is {100 * t.off:.0f} % off the logged "
                         f"{t.source}: {_LACKS[t.term]}")
    if not parts:
        return (head + f": each term matches its logged column but their sum does not match "
                f"{output_source}: the output carries something the PID does not (an "
                "injection, an output limit, a notch, or another output)")
    return head + ": " + "; ".join(parts)


def emulation_check(
    axis: str,
    train: Sequence[Segment],
    held_out: Sequence[Segment],
    flights: Sequence[FlightData],
    signals: Sequence[TwinSignals],
    min_fit_pct: float = EMULATION_MIN_FIT_PCT,
) -> ControllerEmulation:
    """Replay ``axis``'s rebuilt controller on the held-out blocks' logged rate and target and
    compare it with the logged controller output.

    Parameters
    ----------
    axis : str
    train, held_out : sequence of Segment
        The timing (target lag, measurement delay) is chosen on ``train``; the figures are
        measured on ``held_out``.
    flights : sequence of FlightData
    signals : sequence of TwinSignals
        One per flight (:func:`mavsid.loop.twin.twin_signals`).
    min_fit_pct : float
        The pass threshold (fit %).

    Raises
    ------
    ConfigError
        No held-out block with a logged rate target.
    """
    from mavsid.validation import fit_percent

    tr = locate_blocks(train, axis, flights, signals)
    val = locate_blocks(held_out, axis, flights, signals)
    if not val:
        raise ConfigError(f"{axis}: no rate target logged for the held-out blocks: no "
                          "controller emulation")
    lag, meas_delay = controller_timing(tr, val)
    dt = val[0].seg.dt
    substeps = max(1, round(val[0].ctrl.loop_hz * dt))
    rebuilt, measured, replayed = [], [], []
    for b in val:
        terms = replay_terms(b.ctrl, dt, b.target, b.rate, b.u, b.injection, lag, substeps,
                             meas_delay)
        inj = lagged(np.repeat(b.injection, substeps), lag)[::substeps]
        rebuilt.append(terms)
        measured.append((b.u - inj)[b.warm:])
        replayed.append(terms.sum(axis=1)[b.warm:])
    m, r = np.concatenate(measured), np.concatenate(replayed)
    fit = float(fit_percent(m, r))
    out_rms = _rms(m)
    k = next(i for i, fd in enumerate(flights) if fd.index_of(val[0].seg) is not None)
    pre = f"term_{axis}_"
    fits = _term_fits(val, rebuilt, {name[len(pre):]: src for name, src
                                     in signals[k].sources.items() if name.startswith(pre)})
    output = _output_source(val[0], axis)
    passed = bool(np.isfinite(fit) and fit >= min_fit_pct)
    return ControllerEmulation(
        fit_percent=fit, rms=_rms(m - r), passed=passed,
        reason="" if passed else _diagnosis(fit, output, out_rms, fits, substeps,
                                            isinstance(val[0].ctrl.gains, RateGains),
                                            min_fit_pct),
        output_rms=out_rms, lag_loops=lag, measurement_delay_loops=meas_delay,
        output_source=output, terms=fits, threshold_percent=min_fit_pct)


def _output_source(b: LocatedBlock, axis: str) -> str:
    """The logged controller output's name, for messages."""
    if isinstance(b.ctrl.gains, RateGains):
        return {"roll": "RATE.ROut", "pitch": "RATE.POut", "yaw": "RATE.YOut"}[axis]
    return f"the logged torque setpoint ({AXIS_RATE[axis]} axis)"
