"""Write decoded messages to files for ``mavsid extract``.

* ``.npz``: one array per ``MESSAGE.field`` (log order, all instances of a type together, the
  instance column included) plus ``MESSAGE.time_s``; text columns become fixed-width unicode
  (``bytes`` columns fixed-width bytes), so the file loads without pickle.
* ``.parquet`` / ``.csv``: one table of exactly one message type: ``time_s`` then the fields;
  an array field (format ``a``) becomes columns ``Name[0]``, ``Name[1]``, ...

Examples
--------
>>> import numpy as np, os, tempfile
>>> from mavsid.data import MessageTable, RawLog, SourceInfo
>>> log = RawLog(SourceInfo("x.bin", "dataflash", 0), {"ATT": MessageTable(
...     "ATT", {"Roll": np.array([1.5, 2.0])}, time_s=np.array([0.1, 0.2]))})
>>> out = os.path.join(tempfile.mkdtemp(), "att.npz")
>>> sorted(np.load(write(log, out)).files)
['ATT.Roll', 'ATT.time_s']
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mavsid.data import MessageTable, RawLog
from mavsid.errors import ConfigError, MissingMessageError

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["SUFFIXES", "table_frame", "write"]

SUFFIXES = (".npz", ".parquet", ".csv")


def _plain(column: np.ndarray) -> np.ndarray:
    """Object columns (str/bytes) as fixed-width arrays so that no pickle is needed."""
    if column.dtype.kind != "O":
        return column
    if column.size and all(isinstance(v, bytes) for v in column.tolist()):
        return column.astype(bytes)
    return column.astype(str)


def table_frame(table: MessageTable) -> pd.DataFrame:
    """One message type as a pandas DataFrame: ``time_s`` then the fields."""
    import pandas as pd

    data: dict[str, np.ndarray] = {"time_s": np.asarray(table.time_s)}
    for name in table.fields:
        col = table[name]
        if col.ndim == 1:
            data[name] = col
        else:
            flat = col.reshape(col.shape[0], -1)
            for k in range(flat.shape[1]):
                data[f"{name}[{k}]"] = flat[:, k]
    return pd.DataFrame(data)


def write(
    log: RawLog, path: str | os.PathLike[str], messages: Sequence[str] | None = None
) -> Path:
    """Write ``messages`` (default: all) of ``log`` to ``path``; the suffix picks the format.

    Raises
    ------
    MissingMessageError
        A requested message is not in the log.
    ConfigError
        Unknown suffix, or ``.parquet``/``.csv`` asked for other than exactly one type.
    """
    out = Path(path)
    suffix = out.suffix.lower()
    if suffix not in SUFFIXES:
        raise ConfigError(f"{out}: output must end in {', '.join(SUFFIXES)}")
    names = list(log.messages) if messages is None else list(messages)
    for name in names:
        log[name]  # raises MissingMessageError listing what the log has
    if not names:
        raise MissingMessageError("(any)", available=())
    if suffix != ".npz" and len(names) != 1:
        raise ConfigError(f"{out}: {suffix} holds exactly one message type, got "
                          f"{len(names)}; choose one with --messages or write .npz")
    try:
        if suffix == ".npz":
            arrays: dict[str, Any] = {}
            for name in names:
                table = log[name]
                for f in table.fields:
                    arrays[f"{name}.{f}"] = _plain(table[f])
                arrays[f"{name}.time_s"] = np.asarray(table.time_s)
            with open(out, "wb") as fh:
                np.savez(fh, **arrays)
        elif suffix == ".csv":
            table_frame(log[names[0]]).to_csv(out, index=False)
        else:
            table_frame(log[names[0]]).to_parquet(out, index=False)
    except OSError as exc:
        raise ConfigError(f"{out}: cannot write: {exc.strerror or exc}") from None
    return out
