"""A fleet's identified parameters against flight date as a rerun recording, with the
change points of :func:`mavsid.batch.trends`."""

from __future__ import annotations

import os
import re
from typing import TYPE_CHECKING

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from mavsid.viz.series import (
    AXIS_COLOURS,
    FREE_RUN,
    rrd_file,
)

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["save_trends_rrd"]


def save_trends_rrd(axes: pd.DataFrame, path: str | os.PathLike[str]) -> rrb.Blueprint:
    """A fleet's parameters against flight date: per vehicle and axis, each continuous-time
    ``A``/``B`` parameter with its ±σ band, on the timelines ``flight_date`` (the flight's
    date, where known) and ``flight`` (its index in that vehicle's date order), and the
    change points of :func:`mavsid.batch.trends` as text-log entries.

    ``axes`` is the per-axis table of :func:`mavsid.batch.run_batch`.
    """
    import pandas as pd

    from mavsid.batch import trends

    views: list[rrb.View] = []
    sends: list[tuple[str, str, tuple[int, int, int], float, list[rr.TimeColumn], np.ndarray]] = []
    ok = axes[axes["verdict"] != "not identified"] if len(axes) and "verdict" in axes else axes[:0]
    for (vehicle, axis), group in ok.groupby(["vehicle", "axis"]):
        group = group.sort_values("flight_date")
        when = pd.to_datetime(group["flight_date"], errors="coerce")
        index = np.arange(len(group))
        safe = str(vehicle).encode("ascii", "replace").decode() or "vehicle"
        base = f"trends/{safe}/{axis}"
        colour = AXIS_COLOURS.get(str(axis), FREE_RUN)
        for col in [c for c in group.columns if c.startswith(("p:B[", "p:A["))]:
            value = group[col].to_numpy(dtype=float)
            if not np.isfinite(value).any():
                continue
            sigma = group.get(f"sigma:{col[2:]}")
            sig = (np.zeros(len(group)) if sigma is None else
                   np.nan_to_num(pd.to_numeric(sigma, errors="coerce").to_numpy(float), nan=0.0))
            name = col[2:]
            part = "_".join(filter(None, re.split(r"[^A-Za-z0-9_]+", name)))  # B_p_u_roll
            indexes = [rr.TimeColumn("flight", sequence=index)]
            if when.notna().all():
                indexes.append(rr.TimeColumn(
                    "flight_date", timestamp=when.to_numpy(dtype="datetime64[ns]")))
            for kind, label, series, width in (
                    ("value", name, value, 2.0), ("upper", f"{name} +1 sd", value + sig, 0.5),
                    ("lower", f"{name} -1 sd", value - sig, 0.5)):
                sends.append((f"{base}/{part}/{kind}", label, colour, width, indexes, series))
            # (no legend: rerun draws it over the points)
            views.append(rrb.TimeSeriesView(origin=f"{base}/{part}",
                                            name=f"{safe} {axis}: {name}, thin: ±1 sd",
                                            plot_legend=rrb.PlotLegend(visible=False)))
    changes = rrb.TextLogView(origin="changes", name="change points")
    bp = rrb.Blueprint(
        rrb.Vertical(rrb.Grid(*views), changes, row_shares=[4, 1]) if views else changes,
        rrb.TimePanel(timeline="flight"),
        collapse_panels=True,
    )
    with rrd_file(path, bp) as rec:
        _log_trends(rec, ok, sends, trends(axes))
    return bp


def _log_trends(rec: rr.RecordingStream, ok: pd.DataFrame,
                sends: list[tuple[str, str, tuple[int, int, int], float, list[rr.TimeColumn],
                                  np.ndarray]],
                found: pd.DataFrame) -> None:
    """:func:`save_trends_rrd`'s series and change points, into ``rec``."""
    for entity, label, colour, width, indexes, series in sends:
        rec.log(entity, rr.SeriesLines(colors=[colour], names=[label], widths=[width]),
                static=True)
        if entity.endswith("/value"):
            rec.log(entity, rr.SeriesPoints(colors=[colour], names=[label], markers=["circle"],
                                            marker_sizes=[3.0]), static=True)
        rr.send_columns(entity, indexes=indexes, columns=rr.Scalars.columns(scalars=series),
                        recording=rec)
    for r in found[found["changed"]].to_dict("records") if len(found) else []:
        mine = ok[(ok["vehicle"] == r["vehicle"]) & (ok["axis"] == r["axis"])]
        at = int((mine["flight_date"].astype(str) <= str(r["change_after"])).sum())
        text = (f"{r['vehicle']} {r['axis']} {r['param']}: {r['before']:.4g} -> "
                f"{r['after']:.4g} after {r['change_after']} ({r['z']:.1f} standard errors)")
        rec.set_time("flight", sequence=at)  # the first flight after the change
        rec.log("changes", rr.TextLog(text.encode("ascii", "replace").decode(), level="WARN"))
