"""Per-sample flags on the grid: ``armed`` and ``airborne`` from the log's events (DataFlash
EV/ARM, MAVLink HEARTBEAT and EXTENDED_SYS_STATE, PX4 actuator_armed and
vehicle_land_detected; assumed, and said so, where a log has none) and the flight ``mode``.

Examples
--------
>>> from mavsid.data import RawLog, SourceInfo
>>> raw = RawLog(SourceInfo("x.bin", "dataflash", 0), {})
>>> flags, notes = flags_on_grid(raw, np.arange(3.0), np.zeros((3, 0)), ())
>>> flags["armed"].tolist(), flags["mode"].tolist(), sorted(notes)
([True, True, True], [-1, -1, -1], ['airborne', 'armed'])
"""

from __future__ import annotations

import numpy as np

from mavsid.align.series import numeric_field
from mavsid.data import RawLog

__all__ = ["armed_events", "flags_on_grid"]


def _events_to_flag(events: list[tuple[float, bool]], t: np.ndarray, default: bool
                    ) -> np.ndarray:
    """Hold on/off events onto ``t``; before the first event, the opposite of it."""
    if not events:
        return np.full(t.shape, default)
    events.sort(key=lambda e: e[0])
    et = np.array([e[0] for e in events])
    ev = np.array([e[1] for e in events])
    i = np.searchsorted(et, t, side="right") - 1
    out = np.where(i >= 0, ev[np.clip(i, 0, None)], not ev[0])
    return out.astype(bool)


def _main_sysid(raw: RawLog) -> int | None:
    got = numeric_field(raw, "ATTITUDE", "_sysid")
    if got is None or not got[1].size:
        return None
    ids, counts = np.unique(got[1], return_counts=True)
    return int(ids[np.argmax(counts)])


def armed_events(raw: RawLog) -> list[tuple[float, bool]]:
    ev: list[tuple[float, bool]] = []
    got = numeric_field(raw, "EV", "Id")
    if got is not None:
        ev += [(float(t), i == 10) for t, i in zip(*got, strict=True) if i in (10, 11)]
    got = numeric_field(raw, "ARM", "ArmState")
    if got is not None:
        ev += [(float(t), bool(a)) for t, a in zip(*got, strict=True)]
    got = numeric_field(raw, "HEARTBEAT", "base_mode")
    if got is not None:
        sysid = _main_sysid(raw)
        ids = raw.messages["HEARTBEAT"].columns.get("_sysid")
        mask = np.ones(got[0].size, bool) if ids is None or sysid is None else ids == sysid
        pairs = zip(got[0][mask], got[1][mask], strict=True)
        ev += [(float(t), bool(int(b) & 128)) for t, b in pairs]
    got = numeric_field(raw, "actuator_armed", "armed")
    if got is not None:
        ev += [(float(t), bool(a)) for t, a in zip(*got, strict=True)]
    got = numeric_field(raw, "vehicle_status", "arming_state")
    if got is not None and not ev and np.any(got[1] > 0):  # all 0 (INIT): never set
        ev += [(float(t), int(a) == 2) for t, a in zip(*got, strict=True)]
    if not ev:
        for m in raw.texts:
            if m.text.startswith("Arming motors"):
                ev.append((m.time_s, True))
            elif m.text.startswith("Disarming motors"):
                ev.append((m.time_s, False))
    return ev


def _airborne_events(raw: RawLog) -> list[tuple[float, bool]]:
    ev: list[tuple[float, bool]] = []
    got = numeric_field(raw, "EV", "Id")
    if got is not None:
        ev += [(float(t), i == 28) for t, i in zip(*got, strict=True) if i in (18, 28)]
    got = numeric_field(raw, "EXTENDED_SYS_STATE", "landed_state")
    if got is not None:
        ev += [(float(t), int(s) in (2, 3, 4)) for t, s in zip(*got, strict=True) if int(s) != 0]
    got = numeric_field(raw, "vehicle_land_detected", "landed")
    if got is not None:
        ev += [(float(t), not bool(s)) for t, s in zip(*got, strict=True)]
    return ev


def flags_on_grid(raw: RawLog, t: np.ndarray, inputs: np.ndarray, input_names: tuple[str, ...]
           ) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    notes: dict[str, str] = {}
    arm_ev = armed_events(raw)
    armed = _events_to_flag(arm_ev, t, True)
    if not arm_ev:
        notes["armed"] = "no arming events in the log: assumed armed throughout"
    air_ev = _airborne_events(raw)
    if air_ev:
        airborne = _events_to_flag(air_ev, t, True) & armed
    elif "u_thrust" in input_names and np.ptp(inputs[:, input_names.index("u_thrust")]) > 0.05:
        thr = inputs[:, input_names.index("u_thrust")]
        on = thr[armed & (thr > 0.05)]
        level = 0.6 * float(np.median(on)) if on.size else np.inf
        airborne = armed & (thr > level)
        notes["airborne"] = (
            f"no landing events in the log: airborne where armed and u_thrust > {level:.3g} "
            "(60 % of its armed median)"
        )
    else:
        airborne = armed.copy()
        notes["airborne"] = "no landing events or thrust in the log: airborne assumed when armed"
    mode = np.full(t.shape, -1, dtype=np.int64)
    if raw.modes:
        mt = np.array([m.time_s for m in raw.modes])
        mv = np.array([m.mode for m in raw.modes], dtype=np.int64)
        order = np.argsort(mt, kind="stable")
        mt, mv = mt[order], mv[order]
        i = np.searchsorted(mt, t, side="right") - 1
        mode = np.where(i >= 0, mv[np.clip(i, 0, None)], -1)
    return {"armed": armed, "airborne": airborne, "mode": mode}, notes
