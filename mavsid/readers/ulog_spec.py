"""The PX4 ULog format: the facts its reader and the simulator's writer share.

A file opens with :data:`MAGIC`, a version byte and the 8-byte start time; every message is
``uint16 size, uint8 type`` and its payload. A topic's format names fields of the basic types
below (or of other formats, nested). The compiled pass (``mavsid/readers/_scan.c``) keeps its
own copy of the basic types in the same order (their order is the code it gives a field);
tests/test_ulog.py reads a log holding a field of every basic type all three ways against
pyulog.

Examples
--------
>>> BASIC_TYPES["uint16_t"].size, BASIC_TYPES["uint16_t"].code, BASIC_TYPES["char"].dtype
(2, 'H', dtype('int8'))
>>> list(BASIC_TYPES)[:3]
['int8_t', 'uint8_t', 'int16_t']
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

__all__ = ["BASIC_TYPES", "MAGIC", "SYNC", "BasicType"]

#: the first seven bytes of a ULog file (then the version byte)
MAGIC = b"ULog\x01\x12\x35"
#: the payload of a synchronisation message
SYNC = b"\x2f\x73\x13\x20\x25\x0c\xbb\x12"


@dataclass(frozen=True)
class BasicType:
    """One basic field type: its little-endian numpy dtype and ``struct`` code (pyulog's)."""

    dtype: np.dtype
    code: str

    @property
    def size(self) -> int:
        """Bytes of one value."""
        return int(self.dtype.itemsize)


def _basic(t: type[np.generic], code: str) -> BasicType:
    return BasicType(np.dtype(t).newbyteorder("<"), code)


#: basic field types, in the compiled pass's order
BASIC_TYPES: Mapping[str, BasicType] = {
    "int8_t": _basic(np.int8, "b"), "uint8_t": _basic(np.uint8, "B"),
    "int16_t": _basic(np.int16, "h"), "uint16_t": _basic(np.uint16, "H"),
    "int32_t": _basic(np.int32, "i"), "uint32_t": _basic(np.uint32, "I"),
    "int64_t": _basic(np.int64, "q"), "uint64_t": _basic(np.uint64, "Q"),
    "float": _basic(np.float32, "f"), "double": _basic(np.float64, "d"),
    "bool": _basic(np.int8, "?"), "char": _basic(np.int8, "c"),
}  # fmt: skip
