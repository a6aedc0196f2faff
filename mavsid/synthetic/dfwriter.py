"""Write a simulated flight as an ArduPilot DataFlash ``.bin`` log.

Every record is ``0xA3 0x95 <type id>`` followed by its little-endian payload. The log opens
like ArduCopter 4.x's: FMT of FMT, UNIT and MULT tables, then FMT + FMTU for every message
type, PARM (all parameters), MSG (firmware string, frame), then the data in time order.
Message layouts (type ids, format characters, field names, units and multipliers) are those
of ArduCopter 4.7 as found in a real SITL log, so that readers see what they will meet in
the field: ATT, RATE, IMU, RCOU, RCIN, MODE, SIDS, SIDD, PARM, MSG.

Other layouts (``layout=``, :data:`LAYOUTS`): ArduCopter 4.0-4.4 (``copter-4.4``: the 4.x
records, a 4.4 banner, the RATE target without a SYSTEMID rate injection, as those versions
log it), ArduCopter 4.5-4.7 (``copter-4.6``, from a
real 4.6.2 log's FMT/FMTU records: the unit tables and MODE renumbered, AUXF with
pos/source/result, PIDR/PIDP/PIDY with DFF and Flags and ANG written with RATE, ARM, EV,
VER, two IMUs, FMTU for every type, every ``SERVOn_FUNCTION``), older ArduCopter
generations (3.2 without
RATE, 3.3 with TimeMS, 3.4-dev in centidegrees, 3.6 without unit records), a traditional
helicopter (``heli``: the 4.x records, FRAME_CLASS 6, swashplate servo PWMs on RCOU) and
ArduPlane 4.x (``plane``: no RATE nor SYSTEMID records; PIDR/PIDP/PIDY and the aileron,
elevator, throttle and rudder servos on RCOU) and an ArduPlane QuadPlane hovering
(``quadplane``: the multicopter controller's PIQR/PIQP/PIQY, the fixed-wing PIDR/PIDP/PIDY
idle, the surfaces on outputs 1-4 and the motors from 5, ``Q_*`` parameters).

Records are built column-wise in numpy structured arrays and merged into one buffer by a
stable sort on time; nothing is packed one record at a time.

Examples
--------
>>> import tempfile, os
>>> from mavsid.synthetic.flight import Scenario, fly
>>> fl = fly(Scenario(manoeuvre="hover", duration_s=1.0))
>>> path = os.path.join(tempfile.mkdtemp(), "h.bin")
>>> write_dataflash(fl, path) > 10_000
True
>>> open(path, "rb").read(3) == bytes([0xA3, 0x95, 0x80])
True
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from mavsid.errors import ConfigError
from mavsid.readers.dataflash_spec import FMT_COLUMNS, FMT_FORMAT, FMT_TYPE, FORMAT_CHARS, HEAD
from mavsid.synthetic.controller import PID_LOG_FIELDS
from mavsid.synthetic.faults import Faults
from mavsid.synthetic.flight import ESC_TYPES, GRAVITY, MODE_SYSTEMID, RCOU_CHANNELS, Flight

__all__ = ["FORMATS", "LAYOUTS", "MULTS", "UNITS", "WITHOUT_RATE_INJECTION", "DataFlashBuilder",
           "MessageFormat", "write_dataflash"]

@dataclass(frozen=True)
class MessageFormat:
    """One DataFlash message type: FMT plus its FMTU unit and multiplier ids."""

    type_id: int
    name: str
    fmt: str
    columns: tuple[str, ...]
    units: str = ""
    mults: str = ""

    def __post_init__(self) -> None:
        if len(self.name) > 4 or len(self.fmt) > 16 or len(",".join(self.columns)) > 64:
            raise ConfigError(
                f"message {self.name!r}: FMT allows a 4-char name, 16 format characters "
                "and 64 characters of column names"
            )
        if len(self.columns) != len(self.fmt) or not set(self.fmt) <= set(FORMAT_CHARS):
            raise ConfigError(f"message {self.name!r}: format {self.fmt!r} does not match "
                              f"its {len(self.columns)} columns")

    @property
    def dtype(self) -> np.dtype:
        """Structured dtype of a whole record (3 header bytes + payload)."""
        fields: list[Any] = [("_head", "u1", (3,))]
        fields += [(c, FORMAT_CHARS[ch].dtype)
                   for c, ch in zip(self.columns, self.fmt, strict=True)]
        return np.dtype(fields)

    @property
    def length(self) -> int:
        """Record length in bytes, header included (FMT.Length)."""
        return int(self.dtype.itemsize)


def _fmt(type_id: int, name: str, fmt: str, columns: str, units: str = "", mults: str = ""
         ) -> MessageFormat:
    return MessageFormat(type_id, name, fmt, tuple(columns.split(",")), units, mults)


#: Layouts of ArduCopter 4.7 (from a SITL log's own FMT/FMTU records).
FORMATS: dict[str, MessageFormat] = {
    f.name: f
    for f in (
        MessageFormat(FMT_TYPE, "FMT", FMT_FORMAT, FMT_COLUMNS),
        _fmt(116, "FMTU", "QBNN", "TimeUS,FmtType,UnitIds,MultIds"),
        _fmt(117, "UNIT", "QbZ", "TimeUS,Id,Label"),
        _fmt(118, "MULT", "Qbd", "TimeUS,Id,Mult"),
        _fmt(32, "PARM", "QNff", "TimeUS,Name,Value,Default", "s---", "F---"),
        _fmt(59, "MSG", "QZ", "TimeUS,Message", "s-", "F-"),
        _fmt(120, "MODE", "QMBB", "TimeUS,Mode,ModeNum,Rsn", "s---", "F---"),
        _fmt(72, "ATT", "QffffffB", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,AEKF",
             "sddddhh-", "F000000-"),
        _fmt(75, "RATE", "Qfffffffffffff",
             "TimeUS,RDes,R,ROut,PDes,P,POut,YDes,Y,YOut,ADes,A,AOut,AOutSlew",
             "skk-kk-kk-oo--", "F?????????BB--"),
        _fmt(163, "IMU", "QBffffffIIfBBHH",
             "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz",
             "s#EEEooo--O--zz", "F-000000-----00"),
        _fmt(62, "RCOU", "QHHHHHHHHHHHHHH",
             "TimeUS," + ",".join(f"C{i}" for i in range(1, 15)), "sYYYYYYYYYYYYYY",
             "F--------------"),
        _fmt(60, "RCIN", "QHHHHHHHHHHHHHH",
             "TimeUS," + ",".join(f"C{i}" for i in range(1, 15)), "sYYYYYYYYYYYYYY",
             "F--------------"),
        _fmt(10, "SIDS", "QBfffffff", "TimeUS,Ax,Mag,FSt,FSp,TFin,TC,TR,TFout", "s--ssssss",
             "F--------"),
        _fmt(9, "SIDD", "Qfffffffff", "TimeUS,Time,Targ,F,Gx,Gy,Gz,Ax,Ay,Az", "ss-zkkkooo",
             "F---------"),
    )
}

#: ArduCopter 4.5-4.7 (from a real 4.6.2 log's own FMT/FMTU records): the unit tables and
#: MODE renumbered, the PID records with DFF and Flags, the attitude controller's ANG,
#: the auxiliary-function record AUXF with its position, source and result, arming (ARM,
#: EV) and the firmware's VER; the other types as :data:`FORMATS`.
FORMATS_46: dict[str, MessageFormat] = {
    **FORMATS,
    **{f.name: f for f in (
        MessageFormat(FMT_TYPE, "FMT", FMT_FORMAT, FMT_COLUMNS, "-b---", "-----"),
        _fmt(118, "FMTU", "QBNN", "TimeUS,FmtType,UnitIds,MultIds", "s---", "F---"),
        _fmt(119, "UNIT", "QbZ", "TimeUS,Id,Label", "s--", "F--"),
        _fmt(120, "MULT", "Qbd", "TimeUS,Id,Mult", "s--", "F--"),
        _fmt(122, "MODE", "QMBB", "TimeUS,Mode,ModeNum,Rsn", "s---", "F---"),
        _fmt(195, "ANG", "Qfffffff", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,Dt",
             "sddddhhs", "F0000000"),
        *(_fmt(n, name, "QffffffffffB", "TimeUS,Tar,Act,Err,P,I,D,FF,DFF,Dmod,SRate,Flags",
               "s-----------", "F-----------")
          for n, name in ((105, "PIDR"), (106, "PIDP"), (107, "PIDY"))),
        _fmt(248, "AUXF", "QHBBB", "TimeUS,function,pos,source,result", "s#---", "F----"),
        _fmt(181, "EV", "QB", "TimeUS,Id", "s-", "F-"),
        _fmt(186, "ARM", "QBIBB", "TimeUS,ArmState,ArmChecks,Forced,Method", "s----",
             "F----"),
        _fmt(206, "VER", "QBHBBBBIZHBB", "TimeUS,BT,BST,Maj,Min,Pat,FWT,GH,FWS,APJ,BU,FV",
             "s-----------", "F-----------"),
    )},
}
#: the 4.6 layout's data types, in the order their FMT records are written
_DATA_TYPES_46 = ("PARM", "MSG", "VER", "MODE", "EV", "ARM", "AUXF", "ATT", "ANG", "RATE",
                  "PIDR", "PIDP", "PIDY", "IMU", "RCOU", "RCIN", "SIDS", "SIDD")
#: the arm/disarm auxiliary function (RC option 153) and EV ids of arming and disarming
_AUX_ARMDISARM, _EV_ARMED, _EV_DISARMED = 153, 10, 11

#: UNIT table (id -> label) as ArduPilot 4.x writes it
UNITS: dict[str, str] = {
    "-": "", "?": "UNKNOWN", "A": "A", "a": "Ah", "d": "deg", "b": "B", "B": "B/s",
    "k": "deg/s", "D": "deglatitude", "e": "deg/s/s", "E": "rad/s", "G": "Gauss",
    "h": "degheading", "i": "A.s", "J": "W.s", "l": "l", "L": "rad/s/s", "m": "m",
    "n": "m/s", "o": "m/s/s", "O": "degC", "%": "%", "S": "satellites", "s": "s", "t": "N.m",
    "q": "rpm", "r": "rad", "U": "deglongitude", "u": "ppm", "v": "V", "P": "Pa", "w": "Ohm",
    "W": "Watt", "X": "W.h", "y": "l/s", "Y": "us", "z": "Hz", "#": "instance",
}
#: MULT table (id -> multiplier)
MULTS: dict[str, float] = {
    "-": 0.0, "?": 1.0, "2": 1e2, "1": 1e1, "0": 1.0, "A": 1e-1, "B": 1e-2, "C": 1e-3,
    "D": 1e-4, "E": 1e-5, "F": 1e-6, "G": 1e-7, "I": 1e-9, "!": 3.6, "/": 3600.0,
}

#: message types written before the data, in this order
_HEADER_TYPES = ("FMT", "FMTU", "UNIT", "MULT")
_DATA_TYPES = ("PARM", "MSG", "MODE", "ATT", "RATE", "IMU", "RCOU", "RCIN", "SIDS", "SIDD")


class DataFlashBuilder:
    """Collects DataFlash records column-wise and merges them into one byte buffer.

    Examples
    --------
    >>> b = DataFlashBuilder()
    >>> b.add("MSG", [1_000_000], Message=["hello"])
    >>> data = b.to_bytes()
    >>> data[:3] == HEAD + bytes([59]) and b"hello" in data
    True
    """

    def __init__(self) -> None:
        self._chunks: list[tuple[np.ndarray, np.ndarray]] = []  # (time key, records)
        self.formats: dict[str, MessageFormat] = dict(FORMATS)

    def define(self, f: MessageFormat) -> None:
        """Register a message type and write its FMT record (before all data)."""
        self.formats[f.name] = f
        self.add("FMT", [-1], Type=f.type_id, Length=f.length, Name=f.name, Format=f.fmt,
                 Columns=",".join(f.columns))

    def add(self, name: str, time_us: Any, **columns: Any) -> None:
        """Add records of message ``name``; columns by field name, values in display units
        (the writer applies the format character's scaling, e.g. x100 for ``c``).

        ``time_us`` gives the TimeUS field and the ordering (use -1 for header records, which
        keep their insertion order before all data). Missing columns are zero.
        """
        f = self.formats[name]
        t = np.asarray(time_us, dtype=np.int64)
        rec = np.zeros(t.shape[0], dtype=f.dtype)
        rec["_head"] = (*HEAD, f.type_id)
        if "TimeUS" in f.columns:
            rec["TimeUS"] = np.maximum(t, 0)
        for key, values in columns.items():
            if key not in f.columns:
                raise ConfigError(f"{name} has no field {key!r}")
            ch = f.fmt[f.columns.index(key)]
            v = np.asarray(values)
            if ch in "nNZ":
                v = np.array([s.encode() if isinstance(s, str) else s for s in np.ravel(v)],
                             dtype=FORMAT_CHARS[ch].dtype)
            elif (scale := FORMAT_CHARS[ch].scale) is not None:
                v = np.round(v.astype(float) * scale)
            elif ch in "bBMhHiIqQa":
                v = np.round(v.astype(float))
            rec[key] = np.broadcast_to(v, rec.shape[:1] + np.shape(rec[key])[1:])
        self._chunks.append((t, rec))

    def to_bytes(self) -> bytes:
        """All records: headers first in insertion order, then by time (stable)."""
        if not self._chunks:
            return b""
        times = np.concatenate([t for t, _ in self._chunks])
        chunk_of = np.concatenate([np.full(len(t), i) for i, (t, _) in enumerate(self._chunks)])
        row_of = np.concatenate([np.arange(len(t)) for t, _ in self._chunks])
        # headers (time -1) keep insertion order; data sorted by time, ties by insertion
        order = np.lexsort((row_of, chunk_of, times))
        lengths = np.array([r.dtype.itemsize for _, r in self._chunks])[chunk_of[order]]
        offsets = np.zeros(len(order), dtype=np.int64)
        offsets[1:] = np.cumsum(lengths)[:-1]
        dest = np.empty(len(order), dtype=np.int64)
        dest[order] = offsets
        out = np.zeros(int(lengths.sum()), dtype=np.uint8)
        start = 0
        for t, rec in self._chunks:
            n, size = len(t), rec.dtype.itemsize
            raw = np.frombuffer(rec.tobytes(), dtype=np.uint8).reshape(n, size)
            idx = dest[start:start + n, None] + np.arange(size)
            out[idx] = raw
            start += n
        return out.tobytes()


def _header(b: DataFlashBuilder, time_us: int,
            data_types: tuple[str, ...] = _DATA_TYPES) -> None:
    """FMT, UNIT, MULT and FMTU records for every type this writer uses."""
    for name in _HEADER_TYPES + data_types:
        b.define(b.formats[name])
        if name == "MULT":
            b.add("UNIT", np.full(len(UNITS), -1), Id=[ord(k) for k in UNITS],
                  Label=list(UNITS.values()), TimeUS=time_us)
            b.add("MULT", np.full(len(MULTS), -1), Id=[ord(k) for k in MULTS],
                  Mult=list(MULTS.values()), TimeUS=time_us)
    for name in (_HEADER_TYPES + data_types) if b.formats["FMT"].units else data_types:
        f = b.formats[name]  # (4.5+: every type's units, the header types' too)
        b.add("FMTU", [-1], TimeUS=time_us, FmtType=f.type_id, UnitIds=f.units,
              MultIds=f.mults)


def _every(flight: Flight, name: str, lo: int, hi: int) -> np.ndarray:
    """Loop indices in [lo, hi) at which message ``name`` is logged."""
    step = flight.scenario.rates.step(name, flight.scenario.controller.loop_hz)
    first = lo + (-lo) % step
    return np.arange(first, hi, step)


def rate_indices(flight: Flight, lo: int, hi: int) -> np.ndarray:
    """Loop indices in [lo, hi) at which RATE (and the 4.6 layout's PID and ANG records) are
    logged: every ``rates.rate`` step in SYSTEMID, every ``rates.rate_idle`` step outside
    (the same step throughout when ``rate_idle`` is not set)."""
    inside = _every(flight, "rate", lo, hi)
    if flight.scenario.rates.rate_idle is None:
        return inside
    outside = _every(flight, "rate_idle", lo, hi)
    sysid = flight.mode == MODE_SYSTEMID
    return np.union1d(inside[sysid[inside]], outside[~sysid[outside]])


def _build(flight: Flight, lo: int, hi: int, shift_s: float, faults: Faults,
           layout: str = "copter-4") -> bytes:
    """Records for loop samples [lo, hi) with TimeUS = (t - shift_s) * 1e6, later by the
    logging gap's length from the gap on."""
    sc = flight.scenario
    loop_hz = sc.controller.loop_hz
    tus = np.round((flight.t_s - shift_s) * 1e6).astype(np.int64)
    gap_k = None
    if faults.gap is not None:
        gap_k = round(faults.gap[0] / flight.dt)
        if not 0 < gap_k < len(flight):
            raise ConfigError(f"logging gap at {faults.gap[0]} s is outside the flight")
        tus[gap_k:] += round(faults.gap[1] * 1e6)
    t0 = int(tus[lo])
    plane, vtol, v46 = layout == "plane", layout == "quadplane", layout == "copter-4.6"
    b = DataFlashBuilder()
    b.formats.update(_PLANE_PID)
    if v46:
        b.formats.update(FORMATS_46)
    _header(b, t0, _PLANE_TYPES if plane else _QUADPLANE_TYPES if vtol
            else _DATA_TYPES_46 if v46 else _DATA_TYPES)
    params = layout_params(flight, layout)
    b.add("PARM", np.full(len(params), -1), TimeUS=t0, Name=list(params),
          Value=list(params.values()), Default=list(params.values()))
    texts = [
        _BANNER.get(layout, "ArduCopter V4.5.7 (mavsid00)"),
        *_output_texts(flight, layout),
        *_FRAME_TEXT.get(layout, ("Frame: QUAD/X",)),
        f"mavsid synthetic flight: manoeuvre={sc.manoeuvre} axis={sc.axis} seed={sc.seed}",
    ]
    b.add("MSG", np.full(len(texts), -1), TimeUS=t0, Message=texts)
    data = DataFlashBuilder()
    data.formats.update(_PLANE_PID)
    if v46:
        data.formats.update(FORMATS_46)
        _arming_records(data, flight, tus, lo, hi, gap_k)

    def add(name: str, idx: np.ndarray, **cols: Any) -> None:
        keep = faults.keep_mask(len(idx), salt=name) if faults.drop_fraction else slice(None)
        cols = {k: (v if np.ndim(v) == 0 else np.asarray(v)[keep]) for k, v in cols.items()}
        data.add(name, tus[idx][keep], **cols)

    retune = flight.retuned(lambda f: layout_params(f, layout))
    if retune is not None and lo <= retune[0] < hi and retune[1]:  # (set in flight)
        changed = retune[1]
        data.add("PARM", np.full(len(changed), tus[retune[0]]), Name=list(changed),
                 Value=list(changed.values()), Default=list(changed.values()))
    # mode changes (the first sample states the current mode)
    m = (np.full(len(flight), _PLANE_FBWA) if plane
         else np.full(len(flight), _QSTABILIZE) if vtol else flight.mode)
    change = np.flatnonzero(np.r_[True, m[1:] != m[:-1]])
    change = change[(change >= lo) & (change < hi)]
    if not len(change) or change[0] != lo:
        change = np.r_[lo, change]
    data.add("MODE", tus[change], Mode=m[change], ModeNum=m[change], Rsn=1)
    # SYSTEMID setup records and texts at each run's start / finish
    run = flight.run_index
    starts = np.flatnonzero((run >= 0) & np.r_[True, run[1:] != run[:-1]])
    starts = starts[(starts >= lo) & (starts < hi)]
    for k in ([] if plane or vtol else starts):
        s = sc.runs[run[k]]
        data.add("SIDS", tus[[k]], Ax=s.axis, Mag=s.magnitude, FSt=s.f_start_hz,
                 FSp=s.f_stop_hz, TFin=s.t_fade_in, TC=s.t_const_freq, TR=s.t_rec,
                 TFout=s.t_fade_out)
        data.add("MSG", tus[[k]], Message=[f"SystemID Starting: axis={s.axis}"])
    ends = np.flatnonzero((run >= 0) & np.r_[run[1:] != run[:-1], True])
    stopped = {int(run[k]) for k, _ in flight.texts if run[k] >= 0}
    ends = ends[(ends >= lo) & (ends < hi) & ~np.isin(run[ends], list(stopped))]
    if not plane and not vtol:
        data.add("MSG", tus[ends], Message=["SystemID Finished"] * len(ends))
    events = [(k, text) for k, text in flight.texts if lo <= k < hi]
    if events:
        data.add("MSG", tus[[k for k, _ in events]], Message=[t for _, t in events])

    deg = np.degrees
    i = rate_indices(flight, lo, hi)
    rt = flight.rate_target[i]
    if layout in WITHOUT_RATE_INJECTION:
        rt = rt - flight.rate_injection[i]
    g, rt, u = deg(flight.gyro[i]), deg(rt), flight.u[i]
    if plane:  # ArduPlane: no RATE; the roll/pitch/yaw controllers' PID records instead
        for a, pid in enumerate(("PIDR", "PIDP", "PIDY")):
            # the simulator's controller gives its output sum only: logged as P; the sum
            # is the surface demand in degrees, +-45 full deflection (AP_RollController)
            add(pid, i, Tar=rt[:, a], Act=g[:, a], Err=rt[:, a] - g[:, a],
                P=u[:, a] * _PLANE_SURFACE_DEG, I=0.0, D=0.0, FF=0.0, Dmod=1.0, SRate=0.0,
                Limit=0)
    elif vtol:  # QuadPlane in VTOL flight: the multicopter controller's PIDs (rad/s; their
        # output sum is the mixer input), the fixed-wing ones idle (nothing to the surfaces)
        rt_r, g_r = flight.rate_target[i], flight.gyro[i]
        for a, (piq, pid) in enumerate((("PIQR", "PIDR"), ("PIQP", "PIDP"),
                                        ("PIQY", "PIDY"))):
            add(piq, i, Tar=rt_r[:, a], Act=g_r[:, a], Err=rt_r[:, a] - g_r[:, a], P=u[:, a],
                I=0.0, D=0.0, FF=0.0, Dmod=1.0, SRate=0.0, Limit=0)
            add(pid, i, Tar=0.0, Act=g[:, a], Err=-g[:, a], P=0.0, I=0.0, D=0.0, FF=0.0,
                Dmod=1.0, SRate=0.0, Limit=0)
    else:
        acc_up = -(flight.accel[i, 2] + GRAVITY) * 100.0  # cm/s/s (multiplier 0.01)
        add("RATE", i, RDes=rt[:, 0], R=g[:, 0], ROut=u[:, 0], PDes=rt[:, 1], P=g[:, 1],
            POut=u[:, 1], YDes=rt[:, 2], Y=g[:, 2], YOut=u[:, 2], ADes=0.0, A=acc_up,
            AOut=flight.throttle[i], AOutSlew=0.0)
        if v46:  # the attitude controller's targets and each rate PID's terms, with RATE
            a, at = deg(flight.attitude[i]), deg(flight.attitude_target[i])
            add("ANG", i, DesRoll=at[:, 0], Roll=a[:, 0], DesPitch=at[:, 1], Pitch=a[:, 1],
                DesYaw=np.mod(at[:, 2], 360.0), Yaw=np.mod(a[:, 2], 360.0), Dt=flight.dt)
            for ax, pid in enumerate(("PIDR", "PIDP", "PIDY")):
                terms = flight.pid_terms[i, ax].astype(np.float64)
                add(pid, i, **{f: terms[:, c] for c, f in enumerate(PID_LOG_FIELDS)})
        j = i[flight.mode[i] == MODE_SYSTEMID]
        graw = deg(flight.gyro_raw[j])
        add("SIDD", j, Time=flight.sid_time[j], Targ=flight.sid_targ[j], F=flight.sid_freq[j],
            Gx=graw[:, 0], Gy=graw[:, 1], Gz=graw[:, 2], Ax=flight.accel[j, 0],
            Ay=flight.accel[j, 1], Az=flight.accel[j, 2])
    i = _every(flight, "att", lo, hi)
    a, at = deg(flight.attitude[i]), deg(flight.attitude_target[i])
    add("ATT", i, DesRoll=at[:, 0], Roll=a[:, 0], DesPitch=at[:, 1], Pitch=a[:, 1],
        DesYaw=np.mod(at[:, 2], 360.0), Yaw=np.mod(a[:, 2], 360.0), AEKF=3)
    i = _every(flight, "imu", lo, hi)
    for imu in (0, 1) if v46 else (0,):  # (4.6: a flight controller's two IMUs)
        add("IMU", i, I=imu, GyrX=flight.gyro[i, 0], GyrY=flight.gyro[i, 1],
            GyrZ=flight.gyro[i, 2], AccX=flight.accel[i, 0], AccY=flight.accel[i, 1],
            AccZ=flight.accel[i, 2], EG=0, EA=0, T=45.0, GH=1, AH=1, GHz=int(loop_hz),
            AHz=int(loop_hz))
    i = _every(flight, "rcou", lo, hi)
    out = servo_outputs(flight, layout)[i]
    add("RCOU", i, **{f"C{c + 1}": out[:, c] for c in range(out.shape[1])})
    i = _every(flight, "rcin", lo, hi)
    rc = flight.rc_in()[i]
    add("RCIN", i, **{f"C{c + 1}": rc[:, c] for c in range(rc.shape[1])})
    if layout not in ("copter-4", "copter-4.4", "copter-4.6", "heli", "plane", "quadplane"):
        return _as_layout(data, b, layout)
    return b.to_bytes() + data.to_bytes()


#: Layouts the writer can produce (``mavsid simulate --layout``): ArduCopter generations
#: (``copter-4.6``: the 4.5-4.7 records, :data:`FORMATS_46`), a traditional helicopter
#: (ArduCopter 4.x heli) and ArduPlane 4.x.
LAYOUTS = ("copter-4", "copter-4.4", "copter-4.6", "copter-3.6", "copter-3.3",
           "copter-3.4-dev", "copter-3.2", "heli", "plane", "quadplane")
#: layouts whose RATE target leaves out a SYSTEMID rate injection (SID_AXIS 7-9): ArduCopter
#: 4.0-4.4 add it to the target inside the rate controller, and the attitude controller has
#: replaced that target by the time RATE is written; 4.5+ log the target with it
#: (:func:`mavsid.autopilot.ardupilot.rate_target_logs_injection`)
WITHOUT_RATE_INJECTION = ("copter-4.4",)

#: ArduPlane's roll/pitch/yaw controllers log PIDR/PIDP/PIDY (``log_PID`` of
#: libraries/AP_Logger/LogStructure.h: TimeUS,Tar,Act,Err,P,I,D,FF,Dmod,SRate,Limit, no
#: declared units). Plane's Tar/Act are deg/s and P+I+D+FF is the surface demand in degrees
#: (x100 centidegrees, limited to +-4500: libraries/APM_Control/AP_RollController.cpp).
_PLANE_PID: dict[str, MessageFormat] = {
    f.name: f
    for f in (
        _fmt(n, name, "QfffffffffB", "TimeUS,Tar,Act,Err,P,I,D,FF,Dmod,SRate,Limit",
             "s----------", "F----------")
        for n, name in ((48, "PIDR"), (49, "PIDP"), (50, "PIDY"), (51, "PIQR"), (52, "PIQP"),
                        (53, "PIQY"))
    )
}
_PLANE_TYPES = ("PARM", "MSG", "MODE", "ATT", "PIDR", "PIDP", "PIDY", "IMU", "RCOU", "RCIN")
#: ArduPlane QuadPlane: also the VTOL attitude controller's PIDs (logged while it flies)
_QUADPLANE_TYPES = (*_PLANE_TYPES[:7], "PIQR", "PIQP", "PIQY", *_PLANE_TYPES[7:])
#: ArduPlane mode number of QSTABILIZE (VTOL, sticks set bank and pitch angles)
_QSTABILIZE = 17
#: the surface demand (degrees) of a full deflection: ArduPlane's +-4500 centidegrees
_PLANE_SURFACE_DEG = 45.0
#: ArduPlane mode number of FBWA (fly-by-wire: sticks set bank and pitch angles)
_PLANE_FBWA = 5
_BANNER = {"copter-3.2": "ArduCopter V3.2.1 (mavsid00)",
           "copter-4.4": "ArduCopter V4.4.4 (mavsid00)",
           "copter-4.6": "ArduCopter V4.6.2 (mavsid00)",
           "plane": "ArduPlane V4.3.8 (mavsid00)", "quadplane": "ArduPlane V4.5.7 (mavsid00)"}
#: the frame texts each firmware writes after its banner (ArduPlane writes none)
_FRAME_TEXT: dict[str, tuple[str, ...]] = {"copter-3.2": ("Frame: QUAD",),
                                           "heli": ("Frame: HELI",), "plane": (),
                                           "quadplane": ()}
#: servo functions (SERVOn_FUNCTION, SRV_Channel::Aux_servo_function_t) of the outputs
_PLANE_SERVOS = {1: 4, 2: 19, 3: 70, 4: 21}  # aileron, elevator, throttle, rudder
_HELI_SERVOS = {1: 33, 2: 34, 3: 35, 4: 36, 8: 31}  # swash 1-3 (motor1-3), tail, RSC
_SERVO_MIN, _SERVO_TRIM, _SERVO_MAX = 1100.0, 1500.0, 1900.0
#: AP_MotorsHeli_Swash H3_120 (H_SW_TYPE 3): roll and pitch factor of swash servos 1-3
_H3_120 = ((0.866025, 0.5), (-0.866025, 0.5), (0.0, -1.0))


def _output_texts(flight: Flight, layout: str) -> tuple[str, ...]:
    """The 4.6 banner's line naming each output group's protocol (``RCOut: PWM:1-8
    DS150:9-12 PWM:13-16``) when the motors run DShot; nothing otherwise."""
    sc = flight.scenario
    if layout != "copter-4.6" or sc.esc == "pwm":
        return ()
    first, last = sc.motor_output, sc.motor_output + flight.motors.shape[1] - 1
    groups = [(1, first - 1, "PWM"), (first, last, "DS150"), (last + 1, 16, "PWM")]
    return ("RCOut: " + " ".join(f"{kind}:{a}-{b}" for a, b, kind in groups if a <= b),)


def _arming_records(data: DataFlashBuilder, flight: Flight, tus: np.ndarray, lo: int,
                    hi: int, gap_k: int | None = None) -> None:
    """The 4.6 layout's firmware version (VER) and the arming by the arm/disarm switch at
    the first sample (AUXF, ARM, EV), the disarming at the last (or after a crash); around
    a logging gap, a disarm before it and an arm after."""
    major, minor, patch = 4, 6, 2
    data.add("VER", tus[[lo]], BT=10, BST=0, Maj=major, Min=minor, Pat=patch, FWT=255, GH=0,
             FWS=[_BANNER["copter-4.6"]], APJ=0, BU=0, FV=2)
    off = hi - 1 if flight.disarm_index is None else flight.disarm_index
    switches = [(lo, 1, _EV_ARMED), (off, 0, _EV_DISARMED)]
    if gap_k is not None:
        switches += [(gap_k - 1, 0, _EV_DISARMED), (gap_k, 1, _EV_ARMED)]
    for k, state, ev in switches:
        if not lo <= k < hi:
            continue
        data.add("AUXF", tus[[k]], function=_AUX_ARMDISARM, pos=2 * state, source=1, result=1)
        data.add("ARM", tus[[k]], ArmState=state, ArmChecks=0, Forced=0, Method=2)
        data.add("EV", tus[[k]], Id=ev)


#: ArduCopter 4.6's LOG_BITMASK of a SYSTEMID flight (ATTITUDE_MED, GPS, PM, CTUN, NTUN,
#: RCIN, IMU, CMD, CURRENT, RCOU, OPTFLOW, PID, COMPASS, CAMERA, MOTBATT), the ATTITUDE
#: bits (0, 1) set by the logging rate
_LOG_BITMASK_46 = 180222


def layout_params(flight: Flight, layout: str = "copter-4") -> dict[str, float]:
    """The parameters (PARM) a log of ``layout`` holds for ``flight``, by that firmware's names.

    ``copter-3.2``: the rate PIDs as ``RATE_{RLL,PIT,YAW}_{P,I,D,IMAX}`` (per centidegree/s
    to the +-4500 output: the ``ATC_RAT`` gains / (18000/pi/4500), IMAX x4500), the angle
    gains as ``STB_*_P``, ``FRAME`` (1: X) instead of ``FRAME_CLASS/FRAME_TYPE``, the motor
    range as ``RC3_MIN/RC3_MAX`` and ``THR_MIN/THR_MAX`` (0-1000) instead of ``MOT_PWM_*`` and
    ``MOT_SPIN_*``, ``TRIM_THROTTLE``; no ``MOT_THST_EXPO`` (outputs linear in thrust), no
    ``ATC_*``, ``INS_*``, ``SID_*``. ``heli``: ``FRAME_CLASS`` 6, the swashplate (``H_SW_*``,
    H3-120), ``SERVOn_FUNCTION`` 33-35 (swash servos), 36 (tail), 31 (rotor speed controller)
    with their ranges; no ``MOT_*``. ``plane``: ``SERVOn_FUNCTION`` 4 aileron, 19 elevator, 70
    throttle, 21 rudder with ``SERVOn_MIN/TRIM/MAX/REVERSED``, the gyro filter, the loop rate,
    FBWA for the mode switch; no copter controller gains.

    >>> from mavsid.synthetic.flight import Scenario, fly
    >>> fl = fly(Scenario(manoeuvre="hover", duration_s=0.1))
    >>> p = layout_params(fl, "copter-3.2")
    >>> p["FRAME"], p["RC3_MIN"], p["THR_MIN"], "MOT_THST_EXPO" in p
    (1.0, 1000.0, 150.0, False)
    >>> layout_params(fl, "plane")["SERVO2_FUNCTION"], layout_params(fl, "heli")["FRAME_CLASS"]
    (19.0, 6.0)
    """
    p = flight.params()
    if layout == "copter-4.6":  # every ATC_ parameter of 4.6, every output's function
        q = {**p, **flight.scenario.controller.params(full=True)}
        q["LOG_BITMASK"] = float((_LOG_BITMASK_46 & ~3) | (int(p["LOG_BITMASK"]) & 3))
        sc = flight.scenario
        for out in range(1, RCOU_CHANNELS + 1):
            m = out - sc.motor_output
            q[f"SERVO{out}_FUNCTION"] = float(33 + m if 0 <= m < flight.motors.shape[1] else 0)
        q["MOT_PWM_TYPE"] = float(ESC_TYPES[sc.esc])
        return dict(sorted(q.items()))
    if layout == "copter-3.2":
        scale = (18000.0 / math.pi) / 4500.0
        old: dict[str, float] = {}
        for ax in ("RLL", "PIT", "YAW"):
            for k in ("P", "I", "D"):
                old[f"RATE_{ax}_{k}"] = round(p[f"ATC_RAT_{ax}_{k}"] / scale, 6)
            old[f"RATE_{ax}_IMAX"] = p[f"ATC_RAT_{ax}_IMAX"] * 4500.0
            old[f"STB_{ax}_P"] = p[f"ATC_ANG_{ax}_P"]
        old.update(FRAME=p["FRAME_TYPE"], RC3_MIN=p["MOT_PWM_MIN"], RC3_MAX=p["MOT_PWM_MAX"],
                   THR_MIN=float(round(p["MOT_SPIN_MIN"] * 1000.0)),
                   THR_MAX=float(round(p["MOT_SPIN_MAX"] * 1000.0)),
                   TRIM_THROTTLE=float(round(p["MOT_THST_HOVER"] * 1000.0)),
                   ANGLE_MAX=p["ANGLE_MAX"],
                   LOG_BITMASK=p["LOG_BITMASK"], FLTMODE1=p["FLTMODE1"], FLTMODE6=p["FLTMODE6"])
        return dict(sorted(old.items()))
    if layout == "heli":
        q = {k: v for k, v in p.items() if not k.startswith(("MOT_", "FRAME_"))}
        q.update(FRAME_CLASS=6.0, H_SW_TYPE=3.0, H_SW_COL_DIR=0.0, H_SW_LIN_SVO=0.0,
                 H_RSC_MODE=1.0)
        q.update(_servo_params(_HELI_SERVOS))
        return dict(sorted(q.items()))
    if layout == "plane":
        q = {k: p[k] for k in ("INS_GYRO_FILTER", "INS_ACCEL_FILTER", "SCHED_LOOP_RATE",
                               "LOG_BITMASK")}
        q.update(FLTMODE1=float(_PLANE_FBWA), FLTMODE6=float(_PLANE_FBWA))
        q.update(_servo_params(_PLANE_SERVOS))
        return dict(sorted(q.items()))
    if layout == "quadplane":  # the VTOL controller's and motors' parameters as Q_*
        q = {k: p[k] for k in ("INS_GYRO_FILTER", "INS_ACCEL_FILTER", "SCHED_LOOP_RATE",
                               "LOG_BITMASK")}
        q.update({"Q_A_" + k[4:]: v for k, v in p.items() if k.startswith("ATC_")})
        q.update({"Q_M_" + k[4:]: v for k, v in p.items() if k.startswith("MOT_")})
        q.update(Q_ENABLE=1.0, Q_FRAME_CLASS=p["FRAME_CLASS"], Q_FRAME_TYPE=p["FRAME_TYPE"],
                 FLTMODE1=float(_QSTABILIZE), FLTMODE6=float(_QSTABILIZE))
        q.update(_servo_params(_PLANE_SERVOS))
        motors = {4 + m: 33 + m for m in range(flight.motors.shape[1])}
        q.update(_servo_params(motors))
        return dict(sorted(q.items()))
    return p


def _servo_params(functions: dict[int, int]) -> dict[str, float]:
    out: dict[str, float] = {}
    for n, fn in functions.items():
        out.update({f"SERVO{n}_FUNCTION": float(fn), f"SERVO{n}_MIN": _SERVO_MIN,
                    f"SERVO{n}_TRIM": _SERVO_TRIM, f"SERVO{n}_MAX": _SERVO_MAX,
                    f"SERVO{n}_REVERSED": 0.0})
    return out


def _angle_pwm(x: np.ndarray) -> np.ndarray:
    """A -1..1 angle output to PWM through SERVOn_MIN/TRIM/MAX, as SRV_Channel's
    ``pwm_from_angle`` maps it (not reversed), to whole microseconds."""
    x = np.clip(np.asarray(x, dtype=float), -1.0, 1.0)
    return np.round(_SERVO_TRIM + np.where(x > 0, x * (_SERVO_MAX - _SERVO_TRIM),
                                           x * (_SERVO_TRIM - _SERVO_MIN)))


def servo_outputs(flight: Flight, layout: str = "copter-4") -> np.ndarray:
    """The RCOU pulse widths (µs) of every loop sample, shape ``(n, channels)``.

    Multicopter layouts: the four motors (``copter-3.2``: linear in thrust, no
    ``MOT_THST_EXPO`` curve). ``heli``: swash servos 1-3 mixing roll and pitch (the rate
    controller's outputs) with a fixed mid collective as AP_MotorsHeli_Swash does for
    H3-120, the tail servo (yaw output) on 4, the rotor speed controller on 8. ``plane``:
    aileron, elevator (roll and pitch outputs), throttle, rudder (yaw output) on 1-4, each
    a -1..1 deflection through ``SERVOn_MIN/TRIM/MAX``.

    >>> from mavsid.synthetic.flight import Scenario, fly
    >>> fl = fly(Scenario(manoeuvre="hover", duration_s=0.1, seed=1))
    >>> servo_outputs(fl, "plane").shape, servo_outputs(fl, "heli").shape
    ((40, 4), (40, 8))
    """
    if layout == "copter-3.2":
        from dataclasses import replace

        return replace(flight.scenario.controller, thst_expo=0.0).motor_pwm(flight.motors)
    u = flight.u_eff
    if layout == "plane":
        thr = np.clip(flight.throttle, 0.0, 1.0)
        return np.column_stack([_angle_pwm(u[:, 0]), _angle_pwm(u[:, 1]),
                                np.round(_SERVO_MIN + thr * (_SERVO_MAX - _SERVO_MIN)),
                                _angle_pwm(u[:, 2])])
    if layout == "quadplane":  # surfaces at trim, throttle off; the motors on 5 and up
        n = flight.pwm.shape[0]
        surfaces = np.column_stack([np.full(n, _SERVO_TRIM), np.full(n, _SERVO_TRIM),
                                    np.full(n, _SERVO_MIN), np.full(n, _SERVO_TRIM)])
        return np.column_stack([surfaces, flight.pwm])
    if layout == "heli":
        out = np.zeros((len(flight), 8))
        collective = 0.5
        for k, (roll_f, pitch_f) in enumerate(_H3_120):
            servo = (roll_f * u[:, 0] + pitch_f * u[:, 1]) * 0.45 + collective
            out[:, k] = _angle_pwm(2.0 * servo - 1.0)
        out[:, 3] = _angle_pwm(u[:, 2])
        out[:, 7] = _SERVO_MAX  # rotor speed controller: governor at its set speed
        return out
    first = flight.scenario.motor_output
    if first == 1:
        return flight.pwm
    out = np.zeros((len(flight), RCOU_CHANNELS))  # outputs without a function log 0
    out[:, first - 1:first - 1 + flight.pwm.shape[1]] = flight.pwm
    return out

#: ArduCopter 3.5/3.6: the 4.x types and TimeUS, but no unit records (FMTU/UNIT/MULT), a
#: PARM without the Default column and no SYSTEMID messages (SIDS/SIDD came with 4.1).
_PARM_36 = _fmt(32, "PARM", "QNf", "TimeUS,Name,Value")

#: ArduCopter 3.3: TimeMS (ms, uint32) instead of TimeUS; no FMTU/UNIT/MULT records; PARM,
#: MODE and MSG without a time field; RCOU Ch1-Ch8; EV records; no SYSTEMID messages.
_OLD_33: dict[str, MessageFormat] = {
    f.name: f
    for f in (
        MessageFormat(FMT_TYPE, "FMT", FMT_FORMAT, FMT_COLUMNS),
        _fmt(129, "PARM", "Nf", "Name,Value"),
        _fmt(130, "MSG", "Z", "Message"),
        _fmt(131, "MODE", "Mh", "Mode,ThrCrs"),
        _fmt(132, "EV", "B", "Id"),
        _fmt(133, "ATT", "IccccCC", "TimeMS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw"),
        _fmt(134, "RATE", "Ifffffffffff",
             "TimeMS,RDes,R,ROut,PDes,P,POut,YDes,Y,YOut,ADes,A"),
        _fmt(135, "IMU", "Iffffff", "TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ"),
        _fmt(136, "RCOU", "IHHHHHHHH", "TimeMS," + ",".join(f"Ch{i}" for i in range(1, 9))),
    )
}
#: ArduCopter 3.2 (ArduCopter/Log.pde, libraries/DataFlash/LogStructure.h of that
#: release): TimeMS; the common types numbered 128-134 (FMT, PARM, -, IMU, MSG, RCIN, RCOU)
#: and the copter's own from 1 (ATT 1, MODE 3, EV 13); ATT in centidegrees with ErrRP/ErrYaw;
#: RCIN/RCOU Chan1-Chan8 as int16; no RATE, no PID records (the rate controller's outputs
#: are not logged), no units.
_OLD_32: dict[str, MessageFormat] = {
    f.name: f
    for f in (
        MessageFormat(FMT_TYPE, "FMT", FMT_FORMAT, FMT_COLUMNS),
        _fmt(129, "PARM", "Nf", "Name,Value"),
        _fmt(132, "MSG", "Z", "Message"),
        _fmt(3, "MODE", "Mh", "Mode,ThrCrs"),
        _fmt(13, "EV", "B", "Id"),
        _fmt(1, "ATT", "IccccCCCC", "TimeMS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,ErrRP,ErrYaw"),
        _fmt(131, "IMU", "Iffffff", "TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ"),
        _fmt(133, "RCIN", "Ihhhhhhhh", "TimeMS," + ",".join(f"Chan{i}" for i in range(1, 9))),
        _fmt(134, "RCOU", "Ihhhhhhhh", "TimeMS," + ",".join(f"Chan{i}" for i in range(1, 9))),
    )
}
_FIRMWARE = {"copter-3.2": "ArduCopter V3.2.1 (mavsid00)",
             "copter-3.3": "ArduCopter V3.3.3 (mavsid00)",
             "copter-3.4-dev": "ArduCopter V3.4-dev (mavsid00)",
             "copter-3.6": "ArduCopter V3.6.12 (mavsid00)"}


def _as_layout(data: DataFlashBuilder, header: DataFlashBuilder, layout: str) -> bytes:
    """The records of a 4.x-layout flight rewritten as an older firmware logged them.

    ``copter-3.3``: see ``_OLD_33`` (the ARM event is written before the first timed record,
    as those logs do). ``copter-3.2``: the same with ``_OLD_32`` (no RATE: the rate
    controller's outputs are in no record, only the motors' RCOU). ``copter-3.6``: see
    ``_PARM_36``. ``copter-3.4-dev``: the 4.x types but no unit records, ``RATE`` rates in
    centidegrees/s and ``ROut/POut/YOut`` on the ±4500 scale, as ArduCopter 3.4-dev wrote
    them.
    """
    by_id = {f.type_id: f.name for f in FORMATS.values()}
    out = DataFlashBuilder()
    if layout == "copter-3.6":
        out.formats = {**out.formats, "PARM": _PARM_36}
        for name in ("FMT", *_DATA_TYPES):
            if name not in ("SIDS", "SIDD"):
                out.define(_PARM_36 if name == "PARM" else FORMATS[name])
    elif layout == "copter-3.4-dev":
        for name in ("FMT", *_DATA_TYPES):
            out.define(FORMATS[name])
    else:
        old_fmt = _OLD_32 if layout == "copter-3.2" else _OLD_33
        out.formats = dict(old_fmt)
        for f in old_fmt.values():
            out.define(f)
        out.add("EV", [-1], Id=10)  # armed, before any timed record
    first_us = None
    for chunk in (*header._chunks, *data._chunks):
        t, rec = chunk
        if not len(rec) or rec.dtype.names is None:
            continue
        found = by_id.get(int(rec["_head"][0][2]))
        if found is None or found in _HEADER_TYPES:
            continue
        name = found
        cols: dict[str, Any] = {c: rec[c] for c in rec.dtype.names
                                if c not in ("_head", "TimeUS")}
        if name == "MSG":
            cols["Message"] = np.array([
                _FIRMWARE[layout] if m.startswith(b"ArduCopter V") else m
                for m in rec["Message"]])
        if layout in ("copter-3.6", "copter-3.4-dev") and "TimeUS" in rec.dtype.names:
            cols["TimeUS"] = rec["TimeUS"]  # (header records keep the time they were written)
        if layout == "copter-3.6":
            if name in ("SIDS", "SIDD"):
                continue
            if name == "PARM":
                cols.pop("Default", None)
            out.add(name, t, **cols)
            continue
        if layout == "copter-3.4-dev":
            if name == "RATE":
                for k in ("RDes", "R", "PDes", "P", "YDes", "Y"):
                    cols[k] = cols[k] * 100.0
                for k in ("ROut", "POut", "YOut"):
                    cols[k] = cols[k] * 4500.0
            out.add(name, t, **cols)
            continue
        if name not in old_fmt:
            continue  # SIDS, SIDD (and RCIN for 3.3, RATE for 3.2): not in this layout
        f = old_fmt[name]
        timed = "TimeMS" in f.columns
        keep: dict[str, Any] = {k: v for k, v in cols.items() if k in f.columns}
        if name in ("RCOU", "RCIN"):
            chan = "Chan" if layout == "copter-3.2" else "Ch"
            keep = {f"{chan}{i}": cols[f"C{i}"] for i in range(1, 9)}
        if name == "MODE":
            keep = {"Mode": cols["Mode"], "ThrCrs": 0}
        if timed:
            keep["TimeMS"] = np.maximum(t, 0) // 1000
            first_us = int(np.min(t)) if first_us is None else min(first_us, int(np.min(t)))
        out.add(name, t if timed else np.maximum(t, 0), **keep)
    if layout in ("copter-3.3", "copter-3.2") and first_us is not None:
        last = max(int(np.max(t)) for t, _ in data._chunks if len(t))
        out.add("EV", [last + 1], Id=11)  # disarmed
    return out.to_bytes()


def write_dataflash(
    flight: Flight, path: str | os.PathLike[str], faults: Faults | None = None,
    layout: str = "copter-4",
) -> int:
    """Write ``flight`` as a DataFlash ``.bin`` file; returns its size in bytes.

    Parameters
    ----------
    flight : Flight
    path : path-like
    faults : Faults
        Optional damage: dropped data records, a reboot (the clock restarts and the headers
        are written again, as when logs are concatenated), a truncated tail.
    layout : str
        One of :data:`LAYOUTS`: the ArduCopter generation whose log layout to write.
    """
    if layout not in LAYOUTS:
        raise ConfigError(f"unknown layout {layout!r}; choose from {', '.join(LAYOUTS)}")
    faults = faults or Faults()
    n = len(flight)
    if faults.reboot_at_s is not None:
        k = round(faults.reboot_at_s / flight.dt)
        if not 0 < k < n:
            raise ConfigError(f"reboot at {faults.reboot_at_s} s is outside the flight")
        # after the reboot the clock reads 5 s at the first sample
        shift = float(flight.t_s[k]) - 5.0
        data = (_build(flight, 0, k, 0.0, faults, layout)
                + _build(flight, k, n, shift, faults, layout))
    else:
        data = _build(flight, 0, n, 0.0, faults, layout)
    if faults.truncate_bytes:
        data = data[: max(0, len(data) - faults.truncate_bytes)]
    with open(path, "wb") as f:
        f.write(data)
    return len(data)
