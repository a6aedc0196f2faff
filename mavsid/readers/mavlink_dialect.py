"""MAVLink message definitions from a pymavlink dialect: how each message lies on the wire.

A MAVLink 2 payload holds a message's fields sorted by size (wire order), arrays inline,
char arrays as fixed-width bytes; its CRC is seeded with the message's CRC_EXTRA. Both come
from the pymavlink dialect module (``ardupilotmega`` by default), turned here into one
:class:`MessageDef` per message id: a structured numpy dtype of the payload, the field
names in definition order and the field that carries the vehicle's clock.

Examples
--------
>>> att = load_dialect()[30]
>>> att.name, att.crc_extra, field_units("ardupilotmega", 30)["roll"]
('ATTITUDE', 39, 'rad')
"""

from __future__ import annotations

import functools
import importlib
import re
from dataclasses import dataclass
from typing import Any

import numpy as np

from mavsid.errors import ConfigError

__all__ = ["MessageDef", "field_units", "load_dialect"]

_STRUCT_TO_NUMPY = {
    "c": "S1", "b": "i1", "B": "u1", "h": "<i2", "H": "<u2", "i": "<i4", "I": "<u4",
    "q": "<i8", "Q": "<u8", "f": "<f4", "d": "<f8",
}  # fmt: skip


@dataclass(frozen=True)
class MessageDef:
    """How one MAVLink message is laid out on the wire (from a pymavlink dialect class).

    Parameters
    ----------
    msgid : int
    name : str
        e.g. ``"ATTITUDE"``.
    crc_extra : int
        Seed byte appended to the CRC, a hash of the message's definition.
    dtype : numpy.dtype
        Structured, little-endian, fields in wire order (sorted by size), itemsize equal to
        the full payload length.
    fields : tuple of str
        Field names in definition order (the column order).
    strings : frozenset of str
        Char-array fields, given as ``str``.
    time_field : str or None
        ``"time_boot_ms"`` or ``"time_usec"`` when the message carries the vehicle's clock.
    """

    msgid: int
    name: str
    crc_extra: int
    dtype: np.dtype[Any]
    fields: tuple[str, ...]
    strings: frozenset[str]
    time_field: str | None


@functools.lru_cache(maxsize=8)
def load_dialect(dialect: str = "ardupilotmega") -> dict[int, MessageDef]:
    """Message id -> :class:`MessageDef` for a pymavlink MAVLink 2 dialect.

    Parameters
    ----------
    dialect : str
        Module name under ``pymavlink.dialects.v20`` (``ardupilotmega``, ``common``,
        ``development`` ...).

    Raises
    ------
    ConfigError
        No such dialect.

    Examples
    --------
    >>> att = load_dialect()[30]
    >>> att.name, att.dtype.itemsize, att.fields[:2], att.time_field
    ('ATTITUDE', 28, ('time_boot_ms', 'roll'), 'time_boot_ms')
    """
    if not re.fullmatch(r"[A-Za-z0-9_]+", dialect):
        raise ConfigError(f"dialect {dialect!r}: not a pymavlink dialect name")
    try:
        module = importlib.import_module(f"pymavlink.dialects.v20.{dialect}")
    except ImportError:
        raise ConfigError(f"dialect {dialect!r}: no such pymavlink dialect") from None
    defs = {}
    for msgid, cls in module.mavlink_map.items():
        defs[int(msgid)] = _message_def(int(msgid), cls)
    return defs


def _message_def(msgid: int, cls: Any) -> MessageDef:
    """Build the wire dtype of one pymavlink message class from its struct format."""
    tokens = re.findall(r"(\d*)([a-zA-Z])", cls.unpacker.format.lstrip("<"))
    names = list(cls.ordered_fieldnames)
    if len(tokens) != len(names):
        raise ConfigError(f"{cls.msgname}: struct format does not match its fields")
    spec: list[tuple[Any, ...]] = []
    strings = set()
    for name, (count, code), array_len in zip(names, tokens, cls.array_lengths, strict=True):
        if code == "s" or code == "c":
            spec.append((name, f"S{int(count or 1)}"))
            strings.add(name)
        elif array_len:
            spec.append((name, _STRUCT_TO_NUMPY[code], (int(array_len),)))
        else:
            spec.append((name, _STRUCT_TO_NUMPY[code]))
    dtype = np.dtype(spec)
    if dtype.itemsize != cls.unpacker.size:
        raise ConfigError(f"{cls.msgname}: payload size mismatch")
    fields = tuple(cls.fieldnames)
    time_field = next((f for f in ("time_boot_ms", "time_usec") if f in fields), None)
    return MessageDef(
        msgid, cls.msgname, int(cls.crc_extra), dtype, fields, frozenset(strings), time_field
    )


@functools.lru_cache(maxsize=1024)
def field_units(dialect: str, msgid: int) -> dict[str, str]:
    """Field units the dialect declares for one message; its instance field (e.g.
    ``RAW_IMU.id``, ``PID_TUNING.axis``) marked ``"instance"`` as DataFlash does."""
    cls = importlib.import_module(f"pymavlink.dialects.v20.{dialect}").mavlink_map[msgid]
    units = dict(getattr(cls, "fieldunits_by_name", {}) or {})
    if getattr(cls, "instance_field", None):
        units[cls.instance_field] = "instance"
    return units

