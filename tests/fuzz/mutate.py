"""A mutation corpus built on the fly: seed logs (``fixtures/`` and ``../shared/logs``) and
deterministic mutations of them (bit flips, truncation, garbage, splices, corrupted
definitions, time jumps, NaN/inf values, repeated definitions, header floods, instance
units over fields that are none).

Every mutation is a pure function of ``(seed bytes, random.Random)``: a case is named by
``(seed name, mutator name, integer seed)`` and rebuilds byte for byte.
"""

from __future__ import annotations

import random
import struct
from collections.abc import Callable
from functools import cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FIXTURES = ROOT / "fixtures"
LOGS = ROOT.parent / "shared" / "logs"

#: seed logs: name -> (path, bytes kept from its start; a cut log is itself a valid case)
SEEDS: dict[str, tuple[Path, int]] = {
    "fix_roll.bin": (FIXTURES / "sysid_roll.bin", 1 << 20),
    "fix_doublets.bin": (FIXTURES / "doublets.bin", 1 << 20),
    "fix_roll.tlog": (FIXTURES / "sysid_roll.tlog", 1 << 20),
    "sitl.bin": (LOGS / "sitl" / "flightA_mixer.BIN", 600_000),
    "sitl.tlog": (LOGS / "sitl" / "flightA_mixer.tlog", 400_000),
    "mc80k.bin": (LOGS / "public" / "ArduPilot__MethodicConfigurator" / "backend_log_80k.bin",
                  1 << 20),
    "pymavlink.bin": (LOGS / "public" / "ArduPilot__pymavlink" / "test.BIN", 1 << 20),
    "nan.log": (LOGS / "public" / "ArduPilot__ardupilot" / "nan.log", 1 << 20),
    "heli.log": (LOGS / "public" / "ArduPilot__ardupilot" / "tradheli_brownout.log", 1 << 20),
    "vtol.tlog": (LOGS / "public" / "ArduPilot__UAVLogViewer" / "vtol.tlog", 300_000),
    "robologs.ulg": (LOGS / "public" / "roboto-ai__robologs-px4-actions" / "test.ulg", 1 << 20),
    "appended.ulg": (LOGS / "public" / "PX4__pyulog" / "sample_appended_multiple.ulg", 1 << 20),
}


@cache
def seed_bytes(name: str) -> bytes:
    """The seed's bytes (its first ``SEEDS[name][1]`` bytes); FileNotFoundError when absent."""
    path, keep = SEEDS[name]
    with open(path, "rb") as f:
        return f.read(keep)


def available_seeds() -> list[str]:
    return [n for n, (p, _) in SEEDS.items() if p.exists()]


Mutator = Callable[[bytes, random.Random], bytes]


def bit_flips(data: bytes, rng: random.Random) -> bytes:
    out = bytearray(data)
    for _ in range(rng.choice([1, 8, 64, 1024])):
        k = rng.randrange(len(out))
        out[k] ^= 1 << rng.randrange(8)
    return bytes(out)


def truncate(data: bytes, rng: random.Random) -> bytes:
    return data[: rng.randrange(1, len(data))]


def garbage(data: bytes, rng: random.Random) -> bytes:
    k = rng.randrange(len(data))
    junk = rng.randbytes(rng.choice([1, 17, 500, 20_000]))
    if rng.random() < 0.5:  # inserted
        return data[:k] + junk + data[k:]
    return data[:k] + junk + data[k + len(junk):]  # overwritten


def splice(data: bytes, rng: random.Random) -> bytes:
    """The data cut at a random point and joined to a random part of another seed (or of
    itself: a repeated stretch, as a concatenated log)."""
    other = seed_bytes(rng.choice(available_seeds()))
    a, b = rng.randrange(len(data)), rng.randrange(len(other))
    return data[:a] + other[b : b + rng.randrange(1, 200_000)]


def _dataflash_fmts(data: bytes) -> list[int]:
    out, k = [], data.find(b"\xa3\x95\x80")
    while 0 <= k and len(out) < 2000:
        out.append(k)
        k = data.find(b"\xa3\x95\x80", k + 3)
    return out


def corrupt_definitions(data: bytes, rng: random.Random) -> bytes:
    """Damage format definitions: DataFlash FMT fields (type, length, name, format,
    columns), ULog format/add-logged messages, MAVLink length bytes."""
    out = bytearray(data)
    if data[:4] == b"ULog":
        k = 16
        hits = []
        while k + 3 <= len(data) and len(hits) < 4000:
            size, kind = struct.unpack_from("<HB", data, k)
            if kind in b"FA":
                hits.append((k, size))
            k += 3 + size
        for k, size in rng.sample(hits, min(len(hits), rng.choice([1, 3, 20]))):
            j = k + 3 + rng.randrange(max(size, 1))
            if j < len(out):
                out[j] = rng.choice(b";:[]0 9zZ\x00\xff")
        return bytes(out)
    fmts = _dataflash_fmts(data)
    if fmts:
        for k in rng.sample(fmts, min(len(fmts), rng.choice([1, 3, 20]))):
            field, width = rng.choice([(3, 1), (4, 1), (5, 4), (9, 16), (25, 64)])
            j = k + field + rng.randrange(width)
            if j < len(out):
                out[j] = rng.choice(b"QqfdZNnaBbhHiIcCeELM,\x00\xffXyz")
        return bytes(out)
    for _ in range(20):  # .tlog / text: the length byte of a frame, or a text FMT line
        k = rng.randrange(len(out))
        if out[k] in (0xFE, 0xFD) and k + 1 < len(out):
            out[k + 1] = rng.randrange(256)
    text_fmt = data.find(b"FMT,", rng.randrange(len(data)))
    if text_fmt >= 0:
        out[text_fmt + rng.randrange(4, 40)] = rng.choice(b",QZaxf9 \n")
    return bytes(out)


def _dataflash_records(data: bytes, rng: random.Random, count: int) -> list[int]:
    positions = []
    for _ in range(count * 4):
        k = data.find(b"\xa3\x95", rng.randrange(len(data)))
        if k >= 0 and k + 3 < len(data) and data[k + 2] != 0x80:
            positions.append(k)
        if len(positions) >= count:
            break
    return positions


def time_jumps(data: bytes, rng: random.Random) -> bytes:
    """TimeUS (the 8 bytes after a DataFlash header) or MAVLink time fields set far off:
    future, past, zero, 2^32 - 1, 2^40."""
    out = bytearray(data)
    values = [0, 2**32 - 1, 2**40, 2**63, rng.randrange(2**64)]
    if data[:4] == b"ULog":
        for _ in range(rng.choice([1, 10, 100])):  # data messages: 'D', msg id, timestamp
            k = data.find(b"D", rng.randrange(len(data)))
            if 0 <= k and k + 11 <= len(out):
                out[k + 3 : k + 11] = struct.pack("<Q", rng.choice(values))
        return bytes(out)
    positions = _dataflash_records(data, rng, rng.choice([1, 10, 100]))
    for k in positions:
        if k + 11 <= len(out):
            out[k + 3 : k + 11] = struct.pack("<Q", rng.choice(values))
    if not positions:  # .tlog: time_boot_ms is the first payload field of most messages
        for _ in range(rng.choice([1, 10, 100])):
            k = data.find(b"\xfd", rng.randrange(len(data)))
            if 0 <= k and k + 14 <= len(out):
                out[k + 10 : k + 14] = struct.pack("<I", rng.choice(values) % 2**32)
    return bytes(out)


def non_finite(data: bytes, rng: random.Random) -> bytes:
    """NaN, ±inf and huge floats written over 4-byte slots inside records."""
    out = bytearray(data)
    pats = [struct.pack("<f", v) for v in (float("nan"), float("inf"), float("-inf"), 3e38)]
    for _ in range(rng.choice([1, 20, 500])):
        k = rng.randrange(len(out) - 4)
        out[k : k + 4] = rng.choice(pats)
    if data[:3] == b"\xa3\x95\x80" or b"\xa3\x95" in data[:4096]:
        for k in _dataflash_records(data, rng, rng.choice([5, 50])):
            j = k + 11 + 4 * rng.randrange(4)
            if j + 4 <= len(out):
                out[j : j + 4] = rng.choice(pats)
    return bytes(out)


def repeat_definition(data: bytes, rng: random.Random) -> bytes:
    """One FMT record (or any 89 bytes) inserted again and again: definition churn."""
    fmts = _dataflash_fmts(data)
    k = rng.choice(fmts) if fmts else rng.randrange(max(len(data) - 89, 1))
    rec = data[k : k + 89]
    at = rng.randrange(len(data))
    return data[:at] + rec * rng.choice([10, 1000]) + data[at:]


def instance_units(data: bytes, rng: random.Random) -> bytes:
    """DataFlash FMTU unit ids set to ``#`` (instance) over fields that are none: a
    message whose declared instance is a wide integer, a float or text (ArduPilot 4.5+'s
    AUXF.function and SCR.Name are such), which a summary reading for times only meets."""
    out = bytearray(data)
    fmtu = {data[k + 3] for k in _dataflash_fmts(data) if data[k + 5 : k + 9] == b"FMTU"}
    hits: list[int] = []
    for type_id in fmtu:
        k = data.find(b"\xa3\x95" + bytes([type_id]))
        while 0 <= k and len(hits) < 500:
            hits.append(k)
            k = data.find(b"\xa3\x95" + bytes([type_id]), k + 3)
    for k in rng.sample(hits, min(len(hits), rng.choice([1, 5, 50]))):
        units = k + 12  # header 3, TimeUS 8, FmtType 1: then 16 unit ids
        used = [j for j in range(units, min(units + 16, len(out))) if out[j] not in b"\x00#"]
        for j in rng.sample(used, min(len(used), rng.choice([1, 2]))):
            out[j] = ord("#")
    return bytes(out)


def header_flood(data: bytes, rng: random.Random) -> bytes:
    pat = rng.choice([b"\xa3\x95\x80", b"\xa3\x95", b"\xfe", b"\xfd\x09", b"ULog", b"FMT,"])
    at = rng.randrange(len(data))
    return data[:at] + pat * (rng.choice([1000, 100_000]) // len(pat)) + data[at:]


MUTATORS: dict[str, Mutator] = {
    "bit_flips": bit_flips,
    "truncate": truncate,
    "garbage": garbage,
    "splice": splice,
    "corrupt_definitions": corrupt_definitions,
    "time_jumps": time_jumps,
    "non_finite": non_finite,
    "repeat_definition": repeat_definition,
    "header_flood": header_flood,
    "instance_units": instance_units,
}


def mutate(seed: str, mutator: str, n: int) -> bytes:
    """The case ``(seed, mutator, n)``: deterministic."""
    rng = random.Random(f"{seed}/{mutator}/{n}")
    data = seed_bytes(seed)
    return MUTATORS[mutator](data, rng) or b"\0"


def suffix(seed: str) -> str:
    return "." + seed.rsplit(".", 1)[1]
