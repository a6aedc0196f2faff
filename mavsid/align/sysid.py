"""ArduPilot SYSTEMID runs: each run's settings and the span of its injected waveform, and
the waveform itself on the grid.

From a DataFlash log's SIDS and SIDD records (or, without SIDS, the stays in SYSTEMID mode
and the SID_* parameters); from a ``.tlog``, the stays in the mode and the SID_* parameter
values a ground station received before them. The one place a log's SYSTEMID runs are
found (``mavsid info`` lists these).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from mavsid.align.boots import boot_records
from mavsid.align.grid import held_known
from mavsid.autopilot.ardupilot import SID_PARAMS, SIDS_FIELDS, SYSTEM_ID_DELAY_S, SYSTEMID_MODE
from mavsid.autopilot.presets import INJECTION_CHANNEL
from mavsid.channels import evaluate
from mavsid.data import RawLog, SysidRun
from mavsid.errors import MavsidError

__all__ = ["SIDD_BEFORE_MODE_S", "sysid_injection", "sysid_runs"]

def _mode_spans(raw: RawLog, name: str) -> list[tuple[float, float]]:
    """[entry, exit) times of every stay in the mode called ``name``."""
    modes = sorted(raw.modes, key=lambda m: m.time_s)
    spans = []
    for i, m in enumerate(modes):
        if (m.name or "").upper() == name and (i == 0 or modes[i - 1].name != m.name):
            nxt = next((n.time_s for n in modes[i + 1:] if n.name != m.name), np.inf)
            spans.append((m.time_s, nxt))
    return spans


def _sid_axis_number(value: float) -> int:
    """A logged SID_AXIS as its whole number; 0 (no axis) when it is not a finite number.

    >>> _sid_axis_number(10.0), _sid_axis_number(float("nan"))
    (10, 0)
    """
    return int(value) if math.isfinite(value) else 0


def sysid_runs(raw: RawLog) -> tuple[SysidRun, ...]:
    """ArduPilot SYSTEMID runs: settings and the span of the injected waveform.

    From DataFlash: one per SIDS record, with SIDS's settings; the span is that of the SIDD
    samples after it whose waveform ``Targ`` is non-zero (the chirp itself, without the
    initial delay and the wait after it), else of all its SIDD samples, else the stay in
    SYSTEMID mode. From DataFlash with SIDD but no SIDS: one per stay in the mode
    (:func:`_runs_without_sids`; ``injected`` False when its waveform is zero throughout).
    From a .tlog: one
    per stay in SYSTEMID mode, the settings being the last SID_* PARAM_VALUE before it
    (``settings_from`` says which; a ground station may have sent the parameters only once,
    so segment selection checks that axis against the data); the span is then ArduCopter's
    injection: ``SYSTEM_ID_DELAY`` (1 s) after entering the mode, for ``SID_T_REC`` seconds.

    Examples
    --------
    >>> import numpy as np
    >>> from mavsid.data import MessageTable, ModeChange, RawLog, SourceInfo
    >>> sids = MessageTable("SIDS", {"Ax": np.array([10]), "Mag": np.array([0.05])},
    ...                     time_s=np.array([5.0]))
    >>> sidd = MessageTable("SIDD", {"Targ": np.array([0.0, 0.01, -0.02, 0.0])},
    ...                     time_s=np.array([5.1, 6.0, 8.0, 9.0]))
    >>> log = RawLog(SourceInfo("x.bin", "dataflash", 0), {"SIDS": sids, "SIDD": sidd},
    ...              modes=(ModeChange(5.0, 25, "SYSTEMID"), ModeChange(9.5, 0, "STABILIZE")))
    >>> sysid_runs(log)
    (SysidRun(start_s=6.0, stop_s=8.0, settings_from='SIDS', axis=10, magnitude=0.05, \
f_start_hz=None, f_stop_hz=None, t_fade_in_s=None, t_const_freq_s=None, t_record_s=None, \
t_fade_out_s=None, injected=True),)
    """
    runs: list[dict[str, Any]] = []
    path = raw.source.path
    spans = _mode_spans(raw, SYSTEMID_MODE)
    if "SIDS" in raw.messages and len(raw.messages["SIDS"]):
        sids = raw.messages["SIDS"]
        ts = np.asarray(sids.time_s, dtype=float)
        settings = {key: sids.numbers(f, path) for f, key in SIDS_FIELDS.items()
                    if f in sids.columns}
        sidd_t, active = np.empty(0), np.empty(0, dtype=bool)
        if "SIDD" in raw.messages:
            sidd = raw.messages["SIDD"]
            sidd_t = np.asarray(sidd.time_s, dtype=float)
            targ = (sidd.numbers("Targ", path) if "Targ" in sidd.columns
                    else np.ones(sidd_t.size))
            active = np.isfinite(targ) & (targ != 0)
        for k, t0 in enumerate(ts):
            t_next = ts[k + 1] if k + 1 < ts.size else np.inf
            mode_end = next((b for a, b in spans if a <= t0 + 0.5 < b), np.inf)
            end = min(t_next, mode_end)
            sel = (sidd_t >= t0) & (sidd_t < end)
            inside = sidd_t[sel & active] if np.count_nonzero(sel & active) >= 2 else sidd_t[sel]
            if inside.size >= 2:
                start, stop = float(np.min(inside)), float(np.max(inside))
            elif np.isfinite(mode_end):
                start, stop = float(t0), float(mode_end)
            else:
                continue
            run: dict[str, Any] = {"start_s": start, "stop_s": stop, "settings_from": "SIDS"}
            for key, values in settings.items():
                val = float(values[k])
                run[key] = _sid_axis_number(val) if key == "axis" else val
            if inside.size < 2:
                run["start_s"], run["stop_s"] = _chirp_span(start, stop, run)
            runs.append(run)
        return tuple(SysidRun(**r) for r in runs)
    if "SIDD" in raw.messages and len(raw.messages["SIDD"]):
        return tuple(SysidRun(**r) for r in _runs_without_sids(raw, spans))
    if not spans or "PARAM_VALUE" not in raw.messages:
        return ()
    pv = raw.messages["PARAM_VALUE"]
    names = np.asarray(pv.columns.get("param_id", []), dtype=object)
    values = (pv.numbers("param_value", path) if "param_value" in pv.columns
              else np.empty(0))
    times = np.asarray(pv.time_s, dtype=float)
    for a, b in spans:
        if not np.isfinite(b):
            continue
        run = {"start_s": float(a), "stop_s": float(b), "settings_from": "PARAM_VALUE"}
        for pname, key in SID_PARAMS.items():
            sel = np.flatnonzero((names == pname) & ~(times > a))
            if sel.size:
                val = float(values[sel[np.argmax(times[sel])]])
            elif pname in raw.params:
                val = float(raw.params[pname])
            else:
                continue
            run[key] = _sid_axis_number(val) if key == "axis" else val
        if "axis" in run:
            run["start_s"], run["stop_s"] = _chirp_span(a, b, run)
            runs.append(run)
    return tuple(SysidRun(**r) for r in runs)


#: How long before its MODE record a SYSTEMID stay's first SIDD record may come (the mode's
#: record is written after the mode has started: 0.09 s late on a real ArduCopter 4.6 log)
SIDD_BEFORE_MODE_S = 0.5


def _runs_without_sids(raw: RawLog, spans: Sequence[tuple[float, float]]
                       ) -> list[dict[str, Any]]:
    """SYSTEMID runs of a DataFlash log with SIDD but no SIDS record (its start not logged):
    one per stay in the mode holding SIDD records, the settings from the log's SID_*
    parameters (``settings_from`` ``"PARM"``), the span that of the records whose waveform
    ``Targ`` is non-zero; where none is, the stay itself and ``injected`` False (the mode
    was flown, nothing was injected).

    Examples
    --------
    >>> from mavsid.data import MessageTable, ModeChange, RawLog, SourceInfo
    >>> sidd = MessageTable("SIDD", {"Targ": np.zeros(4)}, time_s=np.array([5.0, 6, 8, 9]))
    >>> log = RawLog(SourceInfo("x.bin", "dataflash", 0), {"SIDD": sidd},
    ...              modes=(ModeChange(5.1, 25, "SYSTEMID"), ModeChange(9.5, 0, "STABILIZE")),
    ...              params={"SID_AXIS": 1.0})
    >>> [r.to_dict() for r in sysid_runs(log)]
    [{'start_s': 5.1, 'stop_s': 9.0, 'settings_from': 'PARM', 'axis': 1, 'injected': False}]
    """
    sidd = raw.messages["SIDD"]
    t = np.asarray(sidd.time_s, dtype=float)
    targ = (sidd.numbers("Targ", raw.source.path) if "Targ" in sidd.columns
            else np.ones(t.size))
    active = np.isfinite(targ) & (targ != 0)
    runs: list[dict[str, Any]] = []
    for a, b in spans:
        sel = (t >= a - SIDD_BEFORE_MODE_S) & (t < b)
        if np.count_nonzero(sel) < 2:
            continue
        injected = np.count_nonzero(sel & active) >= 2
        inside = t[sel & active] if injected else t[sel]
        run: dict[str, Any] = {
            "start_s": float(np.min(inside)) if injected else float(a),
            "stop_s": float(np.max(inside)) if injected else float(min(b, np.max(inside))),
            "settings_from": "PARM"}
        for pname, key in SID_PARAMS.items():
            if pname in raw.params:
                val = float(raw.params[pname])
                run[key] = _sid_axis_number(val) if key == "axis" else val
        if not injected:
            run["injected"] = False
        runs.append(run)
    return runs


def sysid_injection(raw: RawLog, t: np.ndarray, dt: float, boot: int = 0
                    ) -> np.ndarray | None:
    """SYSTEMID's logged waveform (``SIDD.Targ``,
    :data:`~mavsid.autopilot.presets.INJECTION_CHANNEL`) held on the grid ``t`` of step
    ``dt`` (its records of the grid's ``boot``), NaN where no record lies within two of its
    steps; None when the log has fewer than two records. The reference a SYSTEMID run's
    response is measured against (excitation, the plant's frequency response), whatever the
    injection point.

    Held: each record is the value the autopilot added over its loop tick. NaN, not 0,
    between records: SIDD is logged only while a run injects, so there the value is not in
    the log (0 outside SYSTEMID mode, but a gap in the records inside a run is unknown too),
    and a window that takes it in is not measured against the injection.

    Examples
    --------
    >>> from mavsid.data import MessageTable, RawLog, SourceInfo
    >>> sidd = MessageTable("SIDD", {"Targ": np.array([0.5, -0.5, 0.5])},
    ...                     time_s=np.array([1.0, 1.1, 1.2]))
    >>> log = RawLog(SourceInfo("x.bin", "dataflash", 0), {"SIDD": sidd})
    >>> sysid_injection(log, np.array([0.9, 1.0, 1.15, 1.3, 2.0]), 0.05).tolist()
    [nan, 0.5, -0.5, 0.5, nan]
    """
    if INJECTION_CHANNEL.message not in raw.messages:
        return None
    try:
        ts, v = evaluate(raw, INJECTION_CHANNEL, "SYSTEMID injection")
    except MavsidError:
        return None
    ts, v = boot_records(ts, v, boot)
    if ts.size < 2:
        return None
    return held_known(ts, v, t, dt)


def _chirp_span(enter: float, leave: float, run: Mapping[str, Any]) -> tuple[float, float]:
    """The injection inside a SYSTEMID mode stay: from SYSTEM_ID_DELAY after entry for
    SID_T_REC seconds, cut at the mode exit (the whole stay when SID_T_REC is unknown)."""
    start = min(enter + SYSTEM_ID_DELAY_S, leave)
    rec = run.get("t_record_s")
    stop = min(start + float(rec), leave) if rec else leave
    return float(start), float(stop)
