"""A fleet's logs on Dask: one :func:`mavsid.pipeline.fit` per log, results as tables, trends.

:func:`run_batch` sends one task per log (read → align → segment → fit → validate → verdict,
exactly what ``mavsid fit LOG`` does) to a ``dask.distributed`` cluster: a
``LocalCluster`` of worker processes on this machine by default (one thread each, so a
worker holds one log's arrays at a time; listening on 127.0.0.1 only), or the scheduler at
the address given (a multi-node cluster, contacted only then). Results arrive as tasks end
and are written after each one, atomically, to three Parquet tables (schema below): a run
interrupted by Ctrl-C leaves a valid table of what finished, and a rerun skips every log
whose ``(sha256, config_hash)`` is already there. A log that fails is a row with its one-
line error, never the end of the batch.

Tables (``SCHEMA_VERSION`` 1, in each table's ``schema_version`` column), for ``-o OUT.parquet``:

* ``OUT.parquet``, one row per log × axis: ``log, sha256, config_hash, vehicle,
  flight_date, axis, verdict`` (``good``, ``usable`` or ``not identified``; tables written
  before it was named so call it ``level``, read as ``verdict``), ``reasons, usable_for,
  estimator, dt_s,
  delay_s, input_lag_s``, every parameter as ``p:NAME`` and its σ as ``sigma:NAME``,
  ``fit_one_step, fit_0_5s, fit_free_run`` (%), ``closed_loop_fit, closed_loop_baseline``
  (%), ``schema_version``;
* ``OUT.logs.parquet``, one row per log: ``log, sha256, config_hash, status`` (``ok``,
  ``nothing identified`` or ``failed``), ``error, vehicle, firmware, autopilot,
  flight_date, duration_s, preset, axes_identified, segments, warnings, seconds,
  schema_version``;
* ``OUT.segments.parquet``, one row per segment used: ``log, sha256, axis, role``
  (``train``/``validation``), ``start_s, stop_s, source, schema_version``.

Trends (:func:`trends`): per vehicle (a mapping file ``log,vehicle[,date]``, else the log's
folder name) and axis, each parameter against flight date, and a change point: the split of
the flights (at least two on each side) with the largest jump in the mean relative to the
spread within the sides; flagged when that jump is over ``CHANGE_Z`` standard errors and
``CHANGE_REL`` of the mean.

Examples
--------
>>> config_hash(None) == config_hash(None)
True
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import errno
import hashlib
import json
import math
import os
import sys
import time
import warnings
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mavsid.errors import ConfigError, MavsidError, MavsidWarning, first_few
from mavsid.outputs import atomic_path

if TYPE_CHECKING:
    import pandas as pd

    from mavsid.pipeline_config import PipelineConfig
    from mavsid.pipeline_results import FitResult

__all__ = ["CHANGE_REL", "CHANGE_Z", "LOG_SUFFIXES", "SCHEMA_VERSION", "config_hash",
           "find_logs", "log_task", "read_tables", "run_batch", "summary_lines", "table_paths",
           "trends", "write_trends_html"]

SCHEMA_VERSION = 1
LOG_SUFFIXES = (".bin", ".log", ".tlog", ".ulg")
#: how long a batch waits to reach the scheduler given by address, s
SCHEDULER_TIMEOUT_S = 30
#: change point: jump over this many standard errors, and this fraction of the mean
CHANGE_Z, CHANGE_REL = 4.0, 0.05


def find_logs(inputs: Iterable[str | os.PathLike[str]]) -> list[str]:
    """Log files named or found (recursively, by suffix) under the directories named.

    Raises
    ------
    ConfigError
        A path that does not exist, or no log at all.
    """
    out: list[str] = []
    skipped: list[str] = []
    for item in inputs:
        p = Path(item)
        if p.is_dir():
            named = sorted(f for f in p.rglob("*") if f.suffix.lower() in LOG_SUFFIXES)
            out += [str(f) for f in named if f.is_file()]
            skipped += [f"{f} ({'a broken link' if f.is_symlink() else 'not a file'})"
                        for f in named if not f.is_file() and not f.is_dir()]
        elif p.exists():
            out.append(str(p))
        else:
            raise ConfigError(f"{p}: no such file or directory")
    if skipped:  # (named like logs, but nothing to read: said, not dropped)
        warnings.warn(f"{len(skipped)} entries named like logs skipped: {first_few(skipped)}",
                      MavsidWarning, stacklevel=2)
    if not out:
        raise ConfigError("no log found (" + ", ".join(map(str, inputs)) + ")")
    return list(dict.fromkeys(out))


def config_hash(config: PipelineConfig | None) -> str:
    """A short hash of the pipeline settings: results from other settings are not reused."""
    from mavsid.pipeline_config import PipelineConfig

    cfg = dataclasses.asdict(config or PipelineConfig())
    cfg.pop("path", None)
    text = json.dumps(cfg, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _sha256(path: str) -> str:
    """The log's sha256 (:func:`mavsid.estimators.model.file_sha256`, which the fit's
    provenance asks for again: hashed once); OSError when it cannot be read."""
    from mavsid.estimators.model import file_sha256

    got = file_sha256(path)
    if got is None:
        raise FileNotFoundError(errno.ENOENT, os.strerror(errno.ENOENT), path)
    return got


def _row_base(path: str, sha: str, chash: str, vehicle: str, date: str) -> dict[str, Any]:
    return {"log": path, "sha256": sha, "config_hash": chash, "vehicle": vehicle,
            "flight_date": date, "schema_version": SCHEMA_VERSION}


def _axis_rows(base: Mapping[str, Any], result: FitResult | None,
               verdicts: Mapping[str, Any]) -> list[dict[str, Any]]:
    rows = []
    for axis, verdict in verdicts.items():
        row: dict[str, Any] = {**base, "axis": axis, "verdict": verdict.level,
                               "reasons": "; ".join(verdict.reasons),
                               "usable_for": ", ".join(verdict.usable_for)}
        fitted = result.axes.get(axis) if result is not None else None
        if fitted is not None:
            d = fitted.to_dict()
            row.update({"estimator": d["estimator"], "dt_s": d["dt_s"],
                        "delay_s": d["delay_s"], "input_lag_s": d["input_lag_s"]})
            for name, value in d["params"].items():
                row[f"p:{name}"] = value
                row[f"sigma:{name}"] = d["stderr"].get(name)
            fp = d["fit_percent"]
            keys = list(fp)
            row["fit_one_step"] = fp.get("one_step")
            row["fit_0_5s"] = fp.get(keys[1]) if len(keys) > 2 else None
            row["fit_free_run"] = fp.get("free_run")
            cl = fitted.closed_loop
            row["closed_loop_fit"] = None if cl is None else cl.fit_percent
            row["closed_loop_baseline"] = None if cl is None else cl.baseline_percent
        rows.append(row)
    return rows


def log_task(path: str, config: PipelineConfig | None = None, vehicle: str = "",
             date: str = "") -> dict[str, list[dict[str, Any]]]:
    """Fit one log as ``mavsid fit`` does and return its table rows (never raises for a
    bad log: a failure is a ``logs`` row with status ``failed`` and the one-line error).

    Returns ``{"logs": [row], "axes": [rows], "segments": [rows]}`` of plain values.
    """
    from mavsid.errors import NoExcitationError
    from mavsid.pipeline import fit

    t0 = time.perf_counter()
    chash = config_hash(config)
    try:
        sha = _sha256(path)
    except OSError as exc:
        sha = ""
        error: str | None = f"{path}: cannot read: {exc.strerror or exc}"
    else:
        error = None
    vehicle = vehicle or Path(path).parent.name
    if not date:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                date = _dt.datetime.fromtimestamp(os.path.getmtime(path), _dt.UTC).isoformat()
            except OSError:
                date = ""
    base = _row_base(path, sha, chash, vehicle, date)
    log_row: dict[str, Any] = {**base, "status": "failed", "error": error, "firmware": None,
                               "autopilot": None, "duration_s": None, "preset": None,
                               "axes_identified": 0, "segments": 0, "warnings": 0}
    axes: list[dict[str, Any]] = []
    segments: list[dict[str, Any]] = []
    if error is None:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                result = fit([path], config)
            except NoExcitationError as exc:
                log_row.update(status="nothing identified", error=str(exc))
                axes = _axis_rows(base, None, getattr(exc, "verdicts", {}))
            except MavsidError as exc:
                log_row["error"] = str(exc)
            except Exception as exc:  # a bug must not end the batch either: say it
                log_row["error"] = f"{path}: internal error {type(exc).__name__}: {exc}"
            else:
                fd = result.flights[0]
                log_row.update(
                    status="ok", error=None, firmware=fd.firmware,
                    autopilot=fd.autopilot, preset=fd.preset,
                    duration_s=float(fd.time_s[-1] - fd.time_s[0]) if len(fd.time_s) else None,
                    axes_identified=len(result.axes))
                axes = _axis_rows(base, result, result.verdicts)
                for axis, f in result.axes.items():
                    for role, segs in (("train", f.train), ("validation", f.held_out)):
                        segments += [{"log": path, "sha256": sha, "axis": axis, "role": role,
                                      "start_s": s.start_s, "stop_s": s.stop_s,
                                      "source": s.source, "schema_version": SCHEMA_VERSION}
                                     for s in segs]
                log_row["segments"] = len(segments)
        log_row["warnings"] = len(caught)
    log_row["seconds"] = time.perf_counter() - t0
    log_row["peak_rss_mb"] = _peak_rss_mb()
    return {"logs": [log_row], "axes": axes, "segments": segments}


def _peak_rss_mb() -> float | None:
    """Peak resident memory of this (worker) process so far, MB (None where unknown)."""
    try:
        import resource
    except ImportError:  # pragma: no cover - not POSIX
        return None
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def table_paths(out: str | os.PathLike[str]) -> dict[str, str]:
    """The three tables of a batch written to ``out`` (per axis, per log, per segment).

    Examples
    --------
    >>> table_paths("results.parquet")["logs"]
    'results.logs.parquet'
    """
    o = os.fspath(out)
    stem = o[: -len(".parquet")] if o.endswith(".parquet") else o
    return {"axes": f"{stem}.parquet", "logs": f"{stem}.logs.parquet",
            "segments": f"{stem}.segments.parquet"}


def read_tables(out: str | os.PathLike[str]) -> dict[str, pd.DataFrame]:
    """The three tables of a batch (empty frames for those not written yet)."""
    import pandas as pd

    tables = {}
    for kind, path in table_paths(out).items():
        try:
            tables[kind] = pd.read_parquet(path) if os.path.exists(path) else pd.DataFrame()
        except (OSError, ValueError) as exc:
            raise ConfigError(f"{path}: not a mavsid batch table ({exc})") from None
        frame = tables[kind]
        if "level" in frame and "verdict" not in frame:  # (the column's former name)
            frame = tables[kind] = frame.rename(columns={"level": "verdict"})
        if len(frame) and int(frame["schema_version"].max()) > SCHEMA_VERSION:
            raise ConfigError(f"{path}: written by a newer mavsid (schema "
                              f"{int(frame['schema_version'].max())})")
    return tables


def _write(out: str | os.PathLike[str], rows: Mapping[str, list[dict[str, Any]]]) -> None:
    import pandas as pd

    for kind, path in table_paths(out).items():
        frame = pd.DataFrame(rows[kind])
        with atomic_path(path) as tmp:
            frame.to_parquet(tmp, index=False)


def _mapping(path: str | os.PathLike[str] | None) -> dict[str, tuple[str, str]]:
    """``log -> (vehicle, date)`` from a CSV ``log,vehicle[,date]`` (paths as given or by
    file name)."""
    if path is None:
        return {}
    import csv

    out: dict[str, tuple[str, str]] = {}
    line: dict[str, int] = {}
    try:
        with open(path, newline="", encoding="utf-8") as f:
            for k, rec in enumerate(csv.reader(f)):
                if not rec or rec[0].startswith("#") or (k == 0 and rec[0] == "log"):
                    continue
                where = f"{path}: line {k + 1}"
                if len(rec) < 2:
                    raise ConfigError(f"{where}: need log,vehicle[,date]")
                log, vehicle = rec[0].strip(), rec[1].strip()
                date = rec[2].strip() if len(rec) > 2 else ""
                if log in line:
                    raise ConfigError(f"{where}: {log} is named again (line {line[log]})")
                if date:
                    try:
                        _dt.datetime.fromisoformat(date)
                    except ValueError:
                        raise ConfigError(f"{where}: date {date!r} is not an ISO date "
                                          "(YYYY-MM-DD, or with a time)") from None
                out[log], line[log] = (vehicle, date), k + 1
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise ConfigError(f"{path}: not a UTF-8 CSV file ({exc})") from None
    return out


def run_batch(
    inputs: Sequence[str | os.PathLike[str]],
    out: str | os.PathLike[str],
    config: PipelineConfig | None = None,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    vehicles: str | os.PathLike[str] | None = None,
    progress: bool = False,
    on_done: Callable[[dict[str, Any]], None] | None = None,
) -> dict[str, pd.DataFrame]:
    """Fit every log on Dask, resuming a previous run; returns the tables.

    Parameters
    ----------
    inputs : sequence of path-like
        Logs, or folders searched recursively for ``.bin .log .tlog .ulg``.
    out : path-like
        ``OUT.parquet`` (see the module docstring for the three files).
    config : PipelineConfig, optional
        The same settings ``mavsid fit --config`` takes.
    workers : int, optional
        Worker processes of the local cluster (default: the machine's cores).
    scheduler : str, optional
        ``tcp://HOST:PORT`` of a running ``dask scheduler``: used instead of a local cluster.
    vehicles : path-like, optional
        CSV ``log,vehicle[,date]`` naming each log's aircraft (and flight date).
    progress : bool
        Show a progress bar (logs done, failed, rate, ETA) on stderr.
    """
    from dask.distributed import Client, LocalCluster, as_completed

    logs = find_logs(inputs)
    mapping = _mapping(vehicles)
    unused = sorted(set(mapping) - set(logs) - {os.path.basename(p) for p in logs})
    if unused:
        warnings.warn(f"{vehicles}: {len(unused)} log(s) named that are not in this batch: "
                      f"{first_few(unused)}", MavsidWarning, stacklevel=2)
    chash = config_hash(config)
    done = read_tables(out)
    rows: dict[str, list[dict[str, Any]]] = {
        k: (v.to_dict("records") if len(v) else []) for k, v in done.items()}
    have = {(r["sha256"], r["config_hash"]) for r in rows["logs"]}
    todo = []
    for path in logs:
        try:
            sha = _sha256(path)
        except OSError:
            sha = ""
        if (sha, chash) not in have:
            todo.append(path)
    if not todo:
        return done
    cluster = None
    if scheduler:
        try:
            client = Client(scheduler, timeout=f"{SCHEDULER_TIMEOUT_S}s")
        except (OSError, ValueError, TypeError) as exc:  # (asyncio's TimeoutError is an OSError)
            raise ConfigError(f"--scheduler {scheduler}: cannot connect: "
                              f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"
                              ) from None
    else:
        import logging

        n = workers or os.cpu_count() or 1
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                               host="127.0.0.1", dashboard_address=None,
                               silence_logs=logging.ERROR)
        client = Client(cluster)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(todo), unit="log", file=sys.stderr, dynamic_ncols=True)
    failed = 0
    try:
        futures = [client.submit(log_task, p, config, *mapping.get(p, mapping.get(
            os.path.basename(p), ("", ""))), pure=False) for p in todo]
        for future in as_completed(futures):
            got = future.result()
            for kind in rows:
                rows[kind] = [r for r in rows[kind] if kind == "segments" or not (
                    r["log"] == got["logs"][0]["log"] and r["config_hash"] == chash)]
                rows[kind] += got[kind]
            _write(out, rows)
            failed += got["logs"][0]["status"] == "failed"
            if bar is not None:
                bar.set_postfix(failed=failed)
                bar.update(1)
            if on_done is not None:
                on_done(got["logs"][0])
            future.release()
    finally:
        if bar is not None:
            bar.close()
        client.close()
        if cluster is not None:
            cluster.close()
    return read_tables(out)


# --------------------------------------------------------------------------- trends


def _change_point(values: np.ndarray) -> tuple[int, float, float] | None:
    """``(k, z, rel)``: the split before index ``k`` with the largest standardised jump in
    the mean (at least two flights each side), its z and relative size; None if too few."""
    n = values.size
    best = None
    for k in range(2, n - 1):
        a, b = values[:k], values[k:]
        spread = np.concatenate([a - a.mean(), b - b.mean()])
        sd = math.sqrt(float(np.sum(spread**2)) / max(n - 2, 1))
        se = sd * math.sqrt(1 / a.size + 1 / b.size)
        jump = abs(float(b.mean() - a.mean()))
        z = jump / se if se > 0 else (math.inf if jump > 0 else 0.0)
        rel = jump / max(abs(float(values.mean())), 1e-12)
        if best is None or z > best[1]:
            best = (k, z, rel)
    return best


def trends(axes: pd.DataFrame, params: Sequence[str] = ("B", "A")) -> pd.DataFrame:
    """Per vehicle, axis and parameter (continuous-time ``B[...]``/``A[...]``): the
    flights in date order, and the change point (``changed`` when over ``CHANGE_Z``
    standard errors and ``CHANGE_REL`` of the mean)."""
    import pandas as pd

    rows: list[dict[str, Any]] = []
    if not len(axes) or "verdict" not in axes:
        return pd.DataFrame(rows)
    ok = axes[axes["verdict"] != "not identified"]
    for (vehicle, axis), group in ok.groupby(["vehicle", "axis"]):
        group = group.sort_values("flight_date")
        for col in [c for c in group.columns if c.startswith("p:")
                    and c[2:].split("[")[0] in params and "_d" not in c]:
            values = group[col].to_numpy(dtype=float)
            keep = np.isfinite(values)
            if keep.sum() < 4:
                continue
            cp = _change_point(values[keep])
            if cp is None:
                continue
            k, z, rel = cp
            dates = group["flight_date"].to_numpy()[keep]
            rows.append({"vehicle": vehicle, "axis": axis, "param": col[2:],
                         "flights": int(keep.sum()), "change_after": str(dates[k - 1]),
                         "before": float(values[keep][:k].mean()),
                         "after": float(values[keep][k:].mean()), "z": z, "relative": rel,
                         "changed": bool(z > CHANGE_Z and rel > CHANGE_REL)})
    return pd.DataFrame(rows)


def write_trends_html(tables: Mapping[str, pd.DataFrame], path: str | os.PathLike[str]) -> None:
    """A page with each vehicle's parameters against flight date (± σ) and the change
    points found (:func:`trends`), under a title; logs named relative to the page's folder,
    an empty cell where a log has no error."""
    import html

    import matplotlib.pyplot as plt

    from mavsid.report import figure_img, render_html_page

    axes = tables["axes"]
    logs = tables["logs"]
    found = trends(axes)
    vehicles = sorted({str(v) for v in logs.get("vehicle", ())}) if len(logs) else []
    counts = logs["status"].value_counts().to_dict() if len(logs) else {}
    sections = [
        f"<h1>mavsid batch: {len(logs)} log(s) of {len(vehicles)} vehicle(s)</h1>"
        f'<p class="meta">{html.escape(_counts_text(counts))}; parameters of the axes judged '
        "good or usable, against flight date (± σ); change points over "
        f"{CHANGE_Z:g} standard errors and {100 * CHANGE_REL:g} % of the mean.</p>"]
    if len(found):
        sections.append("<h2>Change points</h2>" + found.to_html(index=False, float_format="%.3g"))
    if len(axes):
        ok = axes[axes["verdict"] != "not identified"]
        for (vehicle, axis), group in ok.groupby(["vehicle", "axis"]):
            group = group.sort_values("flight_date")
            cols = [c for c in group.columns if c.startswith("p:B[") or c.startswith("p:A[")]
            cols = [c for c in cols if group[c].notna().any()]
            if not cols:
                continue
            fig, axs = plt.subplots(len(cols), 1, figsize=(7, 2.2 * len(cols)), squeeze=False)
            x = np.arange(len(group))
            for ax, col in zip(axs[:, 0], cols, strict=True):
                sig = group.get(f"sigma:{col[2:]}")
                ax.errorbar(x, group[col], yerr=None if sig is None else sig, fmt="o-")
                ax.set_ylabel(col[2:])
                ax.set_xticks(x, [str(d)[:10] for d in group["flight_date"]], rotation=30,
                              fontsize=7)
            axs[0, 0].set_title(f"{vehicle} — {axis}")
            fig.tight_layout()
            sections.append(figure_img(fig))
            plt.close(fig)
    if len(logs):
        here = os.path.dirname(os.path.abspath(path))
        shown = logs[["log", "status", "vehicle", "axes_identified", "error"]].copy()
        shown["error"] = [e.replace(str(p), _relative(str(p), here)) if isinstance(e, str)
                          else "" for p, e in zip(shown["log"], shown["error"], strict=True)]
        shown["log"] = [_relative(str(p), here) for p in shown["log"]]
        sections.append("<h2>Logs</h2>" + shown.to_html(index=False))
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8") as f:
        f.write(render_html_page("mavsid batch: trends", sections))


def _relative(log: str, folder: str) -> str:
    """``log`` relative to ``folder`` (as given when it lies on another drive).

    >>> _relative("/data/fleet/a.bin", "/data/out")
    '../fleet/a.bin'
    """
    try:
        return os.path.relpath(os.path.abspath(log), folder)
    except ValueError:
        return log


def _counts_text(counts: Mapping[str, int]) -> str:
    """``2 ok, 1 failed`` from the logs table's status counts.

    >>> _counts_text({"ok": 2, "failed": 1})
    '1 failed, 2 ok'
    """
    return ", ".join(f"{v} {k}" for k, v in sorted(counts.items())) or "no log"


def summary_lines(logs: pd.DataFrame, new: int, out: str) -> list[str]:
    """What ``mavsid batch`` says at the end: the counts, each log that failed or gave
    nothing with its one-line reason, or that nothing was new (``new`` logs fitted by
    this run).

    Examples
    --------
    >>> import pandas as pd
    >>> logs = pd.DataFrame({"log": ["a.bin", "b.bin"], "status": ["ok", "failed"],
    ...                      "error": [None, "b.bin: empty file"]})
    >>> print("\\n".join(summary_lines(logs, 2, "r.parquet")))
    2 log(s): 1 failed, 1 ok; wrote r.parquet
      failed: b.bin: empty file
    >>> summary_lines(logs, 0, "r.parquet")
    ['nothing new: all 2 log(s) are in r.parquet with these settings (1 failed, 1 ok)']
    """
    counts = logs["status"].value_counts().to_dict() if len(logs) else {}
    if not new:
        return [f"nothing new: all {len(logs)} log(s) are in {out} with these settings "
                f"({_counts_text(counts)})"]
    lines = [f"{len(logs)} log(s): {_counts_text(counts)}; wrote {out}"]
    for row in logs.to_dict("records"):
        if row["status"] != "ok":
            error = row.get("error")
            reason = error if isinstance(error, str) and error else "no reason recorded"
            if reason.startswith(f"{row['log']}: "):  # (the error names the log already)
                reason = reason[len(row["log"]) + 2:]
            lines.append(f"  {row['status']}: {row['log']}: {reason}")
    return lines
