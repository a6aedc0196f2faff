"""rerun output: the .rrd read back holds exactly the computed series; the real viewer
renders it headless to a picture with plots in it."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from helpers import FIXTURES
from rerun.chunk import RrdReader
from toy_plants import toy_flight

from mavsid.viz import recording, series, viewer


@pytest.fixture(scope="module")
def toy():  # type: ignore[no-untyped-def]
    return toy_flight()


@pytest.fixture(scope="module")
def rrd(toy, tmp_path_factory) -> Path:  # type: ignore[no-untyped-def]
    path = tmp_path_factory.mktemp("viz") / "fit.rrd"
    recording.save_rrd(toy[1], path)
    return path


def _read(path: Path) -> tuple[dict[str, dict[str, list[np.ndarray]]], int]:
    """entity -> column name -> list of arrays (one per chunk row), and blueprint count."""
    reader = RrdReader(path)
    out: dict[str, dict[str, list[np.ndarray]]] = defaultdict(lambda: defaultdict(list))
    for chunk in reader.stream().to_chunks():
        batch = chunk.to_record_batch()
        for name in batch.schema.names:
            if name == "rerun.controls.RowId":
                continue
            col = batch.column(name)
            out[chunk.entity_path][name].extend(col.to_pylist())
    return out, len(reader.blueprints())


def _ms(t_s: np.ndarray) -> np.ndarray:
    """Seconds as the timeline holds them: whole milliseconds."""
    return np.round(np.asarray(t_s, dtype=float) * 1000) / 1000


def _series(data: dict[str, dict[str, list]], entity: str) -> tuple[np.ndarray, np.ndarray]:
    """A series' (time [s], value), sorted, without the NaN sample that anchors it on a
    whole ``ANCHOR_S`` (there whenever the series starts elsewhere)."""
    cols = data[entity]
    t = np.array(cols[series.TIMELINE], dtype=float) / 1000
    v = np.array([np.nan if x is None else x[0] for x in cols["Scalars:scalars"]], dtype=float)
    order = np.argsort(t, kind="stable")
    t, v = t[order], v[order]
    if len(t) > 1 and np.isnan(v[0]) and t[0] % series.ANCHOR_S == 0 and t[0] < t[1]:
        return t[1:], v[1:]
    assert t[0] % series.ANCHOR_S == 0, f"{entity}: no anchor before {t[0]} s"
    return t, v


def test_rrd_holds_exactly_the_computed_series(toy, rrd) -> None:  # type: ignore[no-untyped-def]
    flight, result, _ = toy
    data, n_blueprints = _read(rrd)
    assert n_blueprints == 1
    # a complete file (footer/manifest written) whose only timeline is the log's clock
    RrdReader(rrd).store()
    timelines = {t for c in RrdReader(rrd).stream().to_chunks() for t in c.timeline_names}
    assert timelines == {series.TIMELINE}
    for axis, fit in result.axes.items():
        v = fit.validation
        for j, state in enumerate(v.state_names):
            for kind in ("measured", "one_step", "free_run"):
                t, got = _series(data, f"/axes/{axis}/{state}/{kind}")
                sep = np.isnan(got) & ~np.isin(np.round(t, 6), np.round(
                    _ms(np.concatenate([s.time_s for s in v.segments])), 6))
                want_t = _ms(np.concatenate([s.time_s for s in v.segments]))
                want = np.concatenate([getattr(s, kind)[:, j] for s in v.segments])
                # one NaN separator between consecutive segments, nothing else added
                assert sep.sum() == len(v.segments) - 1
                np.testing.assert_allclose(t[~sep], want_t, atol=1e-9)
                np.testing.assert_allclose(got[~sep], want, rtol=0, atol=0, equal_nan=True)
        _, u_in = _series(data, f"/axes/{axis}/inputs/u_{axis}")
        want_u = np.concatenate([s.inputs[:, s.input_names.index(f"u_{axis}")]
                                 for s in fit.held_out])
        np.testing.assert_array_equal(u_in[np.isfinite(u_in)], want_u)
        texts = data[f"/segments/{axis}"]["TextLog:text"]
        starts = [x for x in texts if "segment starts" in str(x)]
        assert len(starts) == len(fit.train) + len(fit.held_out)
        assert all(f"SYSTEMID run on {axis}" in str(x) for x in starts)
        assert f"/fit/{axis}/p fit" in data or any(k.startswith(f"/fit/{axis}/") for k in data)
        assert any(k.startswith(f"/frequency/{axis}/") for k in data)
    for j, name in enumerate(flight.state_names):
        t, got = _series(data, f"/flight/{recording.series_kind(name)}/{name}")
        np.testing.assert_allclose(t, _ms(flight.time_s), atol=1e-9)
        np.testing.assert_array_equal(got, flight.states[:, j])
    # the summary: each axis's structure and every parameter with σ and unit
    summary = " ".join(str(x) for x in data["/summary"]["TextDocument:text"])
    assert "| parameter | value | σ | unit |" in summary and "delay" in summary
    assert all(f"| {k} |" in summary for f in result.axes.values() for k in f.model.params)
    # attitude of the data as 3-D transforms, decimated to <= 50 Hz
    quats = data["/world/data"]["Transform3D:quaternion"]
    assert 0 < len(quats) <= flight.time_s.size // 4 + 1
    assert any(k.startswith("/world/model/roll/") for k in data)


def test_model_attitude_integrates_euler_kinematics() -> None:
    from scipy.integrate import solve_ivp

    from mavsid.data import Segment

    def rates(t: float) -> np.ndarray:
        return np.array([0.8 * np.sin(2 * np.pi * t), 0.3 * np.cos(3 * t), 0.2])

    def kinematics(t: float, a: np.ndarray) -> list[float]:
        phi, theta, _ = a
        p, q, r = rates(t)
        return [
            p + (q * np.sin(phi) + r * np.cos(phi)) * np.tan(theta),
            q * np.cos(phi) - r * np.sin(phi),
            (q * np.sin(phi) + r * np.cos(phi)) / np.cos(theta),
        ]

    dt = 0.001
    t = np.arange(0.0, 3.0, dt)
    ref = solve_ivp(kinematics, (0, 3), [0.1, -0.2, 0.5], t_eval=t, rtol=1e-10, atol=1e-12).y.T
    pqr = np.array([rates(x) for x in t])
    seg = Segment(t, np.c_[ref, pqr], np.zeros((len(t), 1)),
                  ("roll", "pitch", "yaw", "p", "q", "r"), ("u_roll",), dt, "roll", "scan")
    att = recording.model_attitude(seg, "p", pqr[:, 0])
    assert att is not None
    assert np.max(np.abs(att - ref)) < 5e-3
    # a model rate 10 % too large shows up in the roll angle, not the others' inputs
    att_big = recording.model_attitude(seg, "p", 1.1 * pqr[:, 0])
    assert att_big is not None and np.max(np.abs(att_big[:, 0] - ref[:, 0])) > 0.02


def test_blueprint_has_one_view_set_per_axis() -> None:
    import rerun.blueprint as rrb

    def origins(node: object) -> list[str]:
        if isinstance(node, rrb.View):
            return [str(node.origin)]
        return [o for child in getattr(node, "contents", []) for o in origins(child)]

    found = origins(recording.blueprint(["roll", "yaw"]).root_container)
    for origin in ("bands", "axes/roll", "axes/yaw", "axes/roll/inputs", "fit/roll",
                   "frequency/yaw", "world", "segments", "summary", "flight/attitude",
                   "flight/rates", "flight/inputs", "flight/heading", "flight/thrust"):
        assert origin in found
    assert not any("pitch" in o for o in found)


#: Where the Vulkan loader looks for drivers (ICD manifests).
VULKAN_ICD_DIRS = (
    "/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d", "/usr/local/share/vulkan/icd.d",
)


def _screenshot(rrd: Path, out: Path) -> None:
    """Render ``rrd`` with the real viewer, headless (software Vulkan), to ``out``.

    The recording goes in on stdin: a file argument is loaded lazily through the viewer's
    catalog and the screenshot can be taken before any chunk has arrived.
    """
    exe = shutil.which("rerun")
    if exe is None:
        pytest.skip("rerun CLI not installed")
    icds = [p for d in VULKAN_ICD_DIRS for p in Path(d).glob("*.json")]
    if not icds:
        pytest.skip("no Vulkan driver for the headless viewer "
                    "(apt-get install mesa-vulkan-drivers)")
    env = {**os.environ, "XDG_RUNTIME_DIR": str(out.parent)}
    with open(rrd, "rb") as stdin:
        proc = viewer.run_viewer(
            [exe, "--headless", "--screenshot-to", str(out), "--window-size", "1400x900",
             "--port", "auto", "--bind", "127.0.0.1", "--hide-welcome-screen", "-"],
            stdin=stdin, timeout_s=180, env=env,
        )
    if proc.returncode != 0 or not out.exists():
        tail = (proc.stderr or proc.stdout)[-800:]
        pytest.fail(f"rerun --headless failed ({proc.returncode}): {tail}")


@pytest.mark.slow
def test_headless_viewer_renders_plots(rrd, tmp_path) -> None:  # type: ignore[no-untyped-def]
    import matplotlib.image as mpimg

    png = tmp_path / "shot.png"
    _screenshot(rrd, png)
    img = mpimg.imread(png)[..., :3]
    assert img.shape[0] >= 800 and img.shape[1] >= 1200
    flat = (img.reshape(-1, 3) * 255).round().astype(int)
    # Thresholds from screenshots of this recording at this size: with its views laid out
    # but no prediction or input series (log_validation skipped) the picture has ~90
    # colours (in 8-level bins), one-step blue and input green on none of the pixels; with
    # them ~1200 colours, blue on 0.18 % and green on 0.10 %. A blank or error screen has
    # fewer colours still. (Measured grey is mostly text: it tells little.)
    _, counts = np.unique(flat // 8, axis=0, return_counts=True)
    assert len(counts) > 600, "picture nearly uniform: blank or error screen"
    assert counts.max() / len(flat) < 0.95

    def share(colour: tuple[int, int, int]) -> float:
        return float(np.mean(np.all(np.abs(flat - np.array(colour)) <= 40, axis=1)))

    assert share(series.ONE_STEP) > 0.0009, "no one-step prediction lines drawn"
    assert share(series.INPUT) > 0.0005, "no input lines drawn"
    assert share(series.MEASURED) > 0.005, "no measured lines drawn"


def test_recording_is_not_global() -> None:
    rec = series.new_recording()
    assert rr.get_global_data_recording() is not rec


def test_bands_phase_and_focus(toy, rrd) -> None:  # type: ignore[no-untyped-def]
    """Segments and flight modes as bands on the time axis, Bode phase beside magnitude, and
    the time panel opening on the first validation segment."""
    flight, result, _ = toy
    data, _ = _read(rrd)
    for axis, fit in result.axes.items():
        for role, segs in (("train", fit.train), ("validation", fit.held_out)):
            t, level = _series(data, f"/bands/{axis}/{role}")
            spans = recording.merged_spans((s.start_s, s.stop_s) for s in segs)
            # each span drawn as its two ends at the axis's level, NaN between spans
            ends = t[np.isfinite(level)]
            np.testing.assert_allclose(ends, _ms(np.ravel(spans)), atol=1e-9)
            assert set(level[np.isfinite(level)]) == {recording.BAND_LEVELS[axis]}
        for fr in fit.validation.frequency:
            base = f"/frequency/{axis}/{fr.output_name}_{fr.input_name}"
            assert f"{base}/phase/measured_phase" in data
            assert f"{base}/magnitude/legend" in data
    # flight modes as bands, named after the modes (a log's text made safe for the font)
    import dataclasses

    modes = np.where(flight.time_s < flight.time_s[len(flight.time_s) // 3], 0, 25)
    fd = dataclasses.replace(flight, flags={**flight.flags, "mode": modes},
                             mode_names={0: "STABILIZE", 25: "SYS→ID"})
    path = rrd.parent / "bands.rrd"
    rec = series.new_recording()
    rec.save(path)
    recording.log_bands(rec, fd)
    rec.flush()
    rec.disconnect()
    bands, _ = _read(path)
    for m, name in ((0, "STABILIZE"), (25, "SYS?ID")):
        t, level = _series(bands, f"/bands/mode/{m}")
        inside = (_ms(flight.time_s) >= t[0]) & (_ms(flight.time_s) < t[-1])
        assert np.all(modes[inside] == m)
        assert set(level[np.isfinite(level)]) == {recording.BAND_LEVELS["mode"]}
        assert bands[f"/bands/mode/{m}"]["SeriesLines:names"] == [[f"mode {name}"]]
    data.update(bands)
    # nothing the viewer's font cannot draw (an unknown glyph in a label panics it)
    labels = [str(x) for cols in data.values() for name, xs in cols.items()
              if name.endswith((":labels", ":names")) for x in xs if x is not None]
    assert labels and all(s.isascii() for s in labels), [s for s in labels if not s.isascii()]
    focus = recording.focus_span({a: (f.train, f.held_out) for a, f in result.axes.items()})
    first = min((s.start_s, s.stop_s) for f in result.axes.values() for s in f.held_out)
    assert focus == first


def test_band_runs_and_merge() -> None:
    t = np.arange(6.0)
    assert recording.value_spans(t, np.array([0, 0, 5, 5, 0, 0])) == {0: [(0.0, 2.0), (4.0, 5.0)],
                                                         5: [(2.0, 4.0)]}
    assert recording.merged_spans([(2.0, 3.0), (0.0, 2.5)]) == [(0.0, 3.0)]


def test_a_long_flight_is_decimated_outside_the_segments(toy, tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """Outside the segments the flight's series keep their envelope (every bucket's min and
    max) within the point budget; inside the segments every sample is kept."""
    flight, _, _ = toy
    monkeypatch.setattr(recording, "MAX_FLIGHT_POINTS", 300)
    path = tmp_path / "small.rrd"
    spans = [(110.0, 112.0)]
    rec = series.new_recording()
    rec.save(path)
    recording.log_flight(rec, flight, keep_spans=spans)
    rec.flush()
    rec.disconnect()
    data, _ = _read(path)
    inside = np.zeros(len(flight.time_s), bool)
    for a, b in spans:
        inside |= (flight.time_s >= a) & (flight.time_s <= b)
    assert len(flight.time_s) > 300 + inside.sum()  # the toy flight is long enough to cut
    for j, name in enumerate(flight.state_names):
        t, got = _series(data, f"/flight/{recording.series_kind(name)}/{name}")
        ok = np.isfinite(got)
        t, got = t[ok], got[ok]
        want = flight.states[:, j]
        assert len(t) <= 300 + inside.sum() + 2 * len(flight.blocks) + 4
        # every sample in a segment, with its value
        k = np.searchsorted(t, _ms(flight.time_s[inside]) - 1e-9)
        np.testing.assert_allclose(t[k], _ms(flight.time_s[inside]), atol=1e-9)
        np.testing.assert_array_equal(got[k], want[inside])
        # nothing invented, and the extremes survive
        assert set(np.round(got, 12)) <= set(np.round(want, 12))
        assert got.max() == np.nanmax(want) and got.min() == np.nanmin(want)


def test_each_series_keeps_every_sample_only_in_its_own_spans(toy, tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """Spans given per series (as a fit gives them: each axis's model's own series inside
    that axis's segments): a series keeps every sample in its spans and is decimated
    elsewhere, its envelope kept; a series without spans is decimated throughout."""
    flight, _, _ = toy
    monkeypatch.setattr(recording, "MAX_FLIGHT_POINTS", 300)
    path = tmp_path / "per_series.rrd"
    mine, other = flight.state_names[0], flight.state_names[1]
    rec = series.new_recording()
    rec.save(path)
    recording.log_flight(rec, flight, keep_spans={mine: [(110.0, 112.0)]})
    rec.flush()
    rec.disconnect()
    data, _ = _read(path)
    inside = (flight.time_s >= 110.0) & (flight.time_s <= 112.0)
    assert inside.sum() > 100
    t, got = _series(data, f"/flight/{recording.series_kind(mine)}/{mine}")
    k = np.searchsorted(t, _ms(flight.time_s[inside]) - 1e-9)
    np.testing.assert_allclose(t[k], _ms(flight.time_s[inside]), atol=1e-9)
    np.testing.assert_array_equal(got[k], flight.states[inside, 0])
    t, got = _series(data, f"/flight/{recording.series_kind(other)}/{other}")
    ok = np.isfinite(got)
    assert ok.sum() <= 300 + 2 * len(flight.blocks) + 4  # decimated, in the spans too
    assert np.isin(_ms(flight.time_s[inside]), t).sum() < inside.sum() / 2
    want = flight.states[:, 1]
    assert got[ok].max() == np.nanmax(want) and got[ok].min() == np.nanmin(want)


def test_several_flights_keep_their_own_series(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """Two logs fitted together: each flight's series and bands are entities of their own
    (named after the log), not one series interleaving two clocks."""
    import warnings

    from mavsid.pipeline import PipelineConfig, fit

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = fit([str(FIXTURES / "sysid_roll.bin"), str(FIXTURES / "doublets.bin")],
                     PipelineConfig(axes=("roll",)))
    path = tmp_path / "two.rrd"
    recording.save_rrd(result, path)
    data, _ = _read(path)
    for fd, stem in zip(result.flights, ("sysid_roll", "doublets"), strict=True):
        t, got = _series(data, f"/flight/rates/p/{stem}")
        ok = np.isfinite(got)
        assert set(np.round(t[ok], 6)) <= set(np.round(_ms(fd.time_s), 6))
        assert f"/bands/roll/validation/{stem}" in data or f"/bands/roll/train/{stem}" in data
    assert "/flight/rates/p" not in data


def test_a_timed_out_viewer_goes_with_its_wrapper(tmp_path: Path) -> None:
    """``rerun`` on PATH is a Python wrapper that runs the viewer binary as its child:
    killing the wrapper on a timeout left the viewer running (listening on its port). A
    fake wrapper of the same shape: on the timeout its child is gone too."""
    import time

    pid_file = tmp_path / "child.pid"
    wrapper = tmp_path / "rerun"
    wrapper.write_text(
        f"#!{sys.executable}\n"
        "import subprocess, sys\n"
        "child = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(300)'])\n"
        f"open({str(pid_file)!r}, 'w').write(str(child.pid))\n"
        "child.wait()\n")
    wrapper.chmod(0o755)
    with pytest.raises(subprocess.TimeoutExpired):
        viewer.run_viewer([str(wrapper), "--headless"], timeout_s=3)
    child = int(pid_file.read_text())

    def alive(pid: int) -> bool:
        try:
            with open(f"/proc/{pid}/stat") as f:
                return f.read().split(")")[-1].split()[0] != "Z"  # (a zombie is dead)
        except OSError:
            return False

    deadline = time.monotonic() + 5
    while alive(child) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not alive(child), "the wrapper's child outlived the timeout"


def test_time_series_keep_a_fast_chirp_when_zoomed_out(rrd) -> None:  # type: ignore[no-untyped-def]
    """Every measured, predicted and input series is drawn MinMax where samples share a
    pixel (rerun's default averages them: an 18-Hz chirp of ±0.2 drew flat)."""
    from rerun.components import AggregationPolicy

    policies: dict[str, list[int]] = {}
    for chunk in RrdReader(rrd).stream().to_chunks():
        batch = chunk.to_record_batch()
        if "SeriesLines:names" in batch.schema.names and not chunk.entity_path.startswith(
                "/bands"):
            column = ("SeriesLines:aggregation_policy"
                      if "SeriesLines:aggregation_policy" in batch.schema.names else None)
            policies[chunk.entity_path] = ([] if column is None else
                                           [x for r in batch.column(column).to_pylist()
                                            for x in r or []])
    assert {"/axes/roll/p/measured", "/axes/roll/p/one_step", "/flight/rates/p"} <= set(policies)
    assert all(p == [AggregationPolicy.MinMax.value] for p in policies.values()), policies


def test_each_axis_has_its_rate_target_against_the_measured_rate(tmp_path: Path) -> None:
    """The rate target the controller was given (the log's RATE.RDes ...) against the
    measured rate, per fitted axis, with a plot of its own: the values are the log's."""
    import rerun.blueprint as rrb

    from mavsid.pipeline import fit
    from mavsid.readers import read_log

    log = FIXTURES / "sysid_roll.bin"
    result = fit([str(log)], None)
    path = tmp_path / "t.rrd"
    bp = recording.save_rrd(result, path)
    series, _ = _read(path)
    target = np.concatenate(series["/targets/roll/target"]["Scalars:scalars"]).ravel()
    rate = read_log(log, messages=["RATE"])["RATE"]
    # (RATE.RDes in deg/s; the flight's grid holds it between samples)
    logged = np.deg2rad(np.asarray(rate["RDes"], dtype=float))
    finite = target[np.isfinite(target)]
    assert finite.size > 100
    assert np.isin(np.round(finite, 9), np.round(logged, 9)).mean() > 0.99
    assert "/targets/roll/measured" in series

    def origins(node: object) -> list[str]:
        if isinstance(node, rrb.View):
            return [str(node.origin)]
        return [o for child in getattr(node, "contents", []) for o in origins(child)]

    assert "/targets/roll" in origins(bp.root_container) or "targets/roll" in origins(
        bp.root_container)


def test_the_summary_shows_each_axis_gains_current_and_suggested(toy, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The viewer's summary has the gains ``tune`` suggests (current, suggested, ratio) or
    the one line why none, per axis."""
    result = toy[1]
    axes = list(result.axes)
    gains = {axes[0]: {"gains": [{"name": "ATC_RAT_RLL_P", "current": 0.135,
                                  "suggested": 0.1312, "ratio": 0.972, "capped": False}]},
             axes[-1]: {"gains": [], "no_gains_reason": "the plant model is usable"}}
    path = tmp_path / "g.rrd"
    recording.save_rrd(result, path, gains=gains)
    data, _ = _read(path)
    summary = " ".join(str(x) for x in data["/summary"]["TextDocument:text"])
    assert "| parameter | current | suggested | ratio |" in summary
    assert "| ATC_RAT_RLL_P | 0.135 | 0.1312 | ×0.97 |" in summary
    assert "no gains: the plant model is usable" in summary


def _blueprint_rows(path: Path) -> dict[str, dict[str, list]]:
    """The blueprint stored in an ``.rrd``: blueprint entity -> component -> values."""
    reader = RrdReader(path)
    out: dict[str, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    for chunk in reader.stream(store=reader.blueprints()[0]).to_chunks():
        batch = chunk.to_record_batch()
        for name in batch.schema.names:
            if ":" in name:
                out[chunk.entity_path][name].extend(batch.column(name).to_pylist())
    return out


def test_time_reads_as_milliseconds_and_every_plot_opens_on_the_focus(toy, rrd) -> None:  # type: ignore[no-untyped-def]
    """The timeline is a sequence of whole milliseconds on the log's clock (rerun drew the
    duration it was as ``+1m 40s``); every time plot's axis is the shared one, which the
    blueprint sets to the first validation segment, as it selects it on the time panel
    (unset, a linked plot opens on ±1 000 ticks around the cursor at the log's start)."""
    import pyarrow as pa

    result = toy[1]
    kinds = {c.to_record_batch().schema.field(series.TIMELINE).type
             for c in RrdReader(rrd).stream().to_chunks()
             if series.TIMELINE in c.to_record_batch().schema.names}
    assert series.TIMELINE == "time_ms" and kinds == {pa.int64()}
    data, _ = _read(rrd)
    raw = np.array(data["/flight/rates/p"][series.TIMELINE], dtype=float)
    assert np.all(raw == np.round(raw))  # whole milliseconds
    t, _ = _series(data, "/flight/rates/p")
    np.testing.assert_allclose(t, toy[0].time_s, atol=5e-4)

    bp = _blueprint_rows(rrd)
    focus = recording.result_focus(result)
    assert focus is not None
    want = {"start": round(focus[0] * 1000), "end": round(focus[1] * 1000)}
    assert bp[f"/{series.SHARED_VIEW}/TimeAxis"]["TimeAxis:view_range"] == [[want]]
    panel = bp["/time_panel"]
    assert panel["TimePanelBlueprint:timeline"] == [[series.TIMELINE]]
    assert panel["TimePanelBlueprint:time_selection"] == [[{"min": want["start"],
                                                            "max": want["end"]}]]
    links = [v for k, cols in bp.items() if k.endswith("/TimeAxis")
             for v in cols.get("TimeAxis:link", [])]
    assert links and all(x == [2] for x in links)  # LinkAxis.LinkToGlobal


def test_no_legend_over_the_data_and_plots_with_room(toy, rrd) -> None:  # type: ignore[no-untyped-def]
    """rerun draws a time plot's legend over its data: no time plot of a fit has one (the
    titles name the colours); no column stacks more than four time plots (ten stacked
    were 45 pixels tall each, ticked at 0 only); the 2-D plots are framed."""
    import rerun.blueprint as rrb

    bp = _blueprint_rows(rrd)
    legends = [v for k, cols in bp.items() if k.endswith("/PlotLegend")
               for v in cols.get("PlotLegend:visible", [])]
    assert legends and all(v == [False] for v in legends)
    assert len([k for k in bp if k.endswith("/VisualBounds2D")]) == 2 * len(toy[1].axes)

    def stacks(node: object) -> list[int]:
        kids = list(getattr(node, "contents", []))
        here = sum(isinstance(k, rrb.TimeSeriesView) for k in kids)
        return [here if not isinstance(node, rrb.Tabs) else 0,
                *(n for k in kids for n in stacks(k))]

    layout = recording.blueprint(list(toy[1].axes), targets=list(toy[1].axes))
    assert 0 < max(stacks(layout.root_container)) <= 4


def test_fixed_y_ranges_hold_the_data_and_two_labelled_ticks(toy) -> None:  # type: ignore[no-untyped-def]
    """Where a plot's y range is set, it holds every value shown there and at least two
    ticks on the decade step rerun labels (a range of 0 ± 0.067 holds one, 0); thrust is
    on 0 ... 1."""
    flight, result, _ = toy
    ranges = recording.value_ranges(result)
    assert ranges["flight/thrust"][0] < 0 and ranges["flight/thrust"][1] > 1
    assert {f"axes/{a}/inputs" for a in result.axes} <= set(ranges)
    names = (*flight.state_names, *flight.input_names)
    values = np.c_[flight.states, flight.inputs]
    for origin, (lo, hi) in ranges.items():
        if origin == "flight/thrust":  # (a known range, whatever the data)
            continue
        if origin.startswith("flight/"):
            kind = origin.split("/")[1]
            shown = values[:, [names.index(n) for n in recording.KINDS[kind] if n in names]]
        else:
            axis = origin.split("/")[1]
            fit = result.axes[axis]
            shown = np.concatenate([s.inputs[:, [s.input_names.index(n)
                                                 for n in fit.validation.input_names]]
                                    for s in fit.held_out])
        assert lo <= np.nanmin(shown) and np.nanmax(shown) <= hi, origin
        spread = np.nanmax(shown) - np.nanmin(shown) or abs(np.nanmax(shown)) or 1.0
        step = 10.0 ** np.floor(np.log10(spread))
        inside = np.arange(np.ceil(lo / step), np.floor(hi / step) + 1)
        assert 2 <= len(inside) <= 11, (origin, lo, hi, step)
    assert series.nice_range([-0.067, 0.067]) == (-0.116, 0.116)


#: rerun's 2-D labels in the Bode view of a 1600 × 1000 window (about 1.6 pixels per plot
#: unit), measured on its screenshots: a box about 12 units tall below its point, 4.3 units
#: a character and 4 of padding wide.
LABEL_HEIGHT, LABEL_CHAR, LABEL_PAD = 12.0, 4.3, 4.0


def test_bode_labels_do_not_overlap(rrd) -> None:  # type: ignore[no-untyped-def]
    """The Bode plot's tick labels and legends (text drawn at a fixed pixel size) neither
    overlap each other nor the plots' areas, and lie inside the view's frame (beside the
    plot, 11 units apart, the legend's entries overlapped each other and the data)."""
    data, _ = _read(rrd)
    (x_lo, x_hi), (y_lo, y_hi) = recording.BODE_FRAME
    plots = [k.removesuffix("/magnitude/ticks") for k in data if k.startswith("/frequency/")
             and k.endswith("/magnitude/ticks")]
    assert plots
    for plot in plots:
        boxes: list[tuple[str, float, float, float, float]] = []
        areas: list[tuple[float, float, float, float]] = []
        for panel in ("magnitude", "phase", "coherence"):
            grid = np.concatenate([np.asarray(strip, dtype=float) for row in
                                   data[f"{plot}/{panel}/grid"]["LineStrips2D:strips"]
                                   for strip in row])
            areas.append((grid[:, 0].min(), grid[:, 0].max(), grid[:, 1].min(),
                          grid[:, 1].max()))
            for part in ("ticks", "legend"):
                cols = data[f"{plot}/{panel}/{part}"]
                for (x, y), text in zip(cols["Points2D:positions"][0],
                                        cols["Points2D:labels"][0], strict=True):
                    w = LABEL_CHAR * len(text) + LABEL_PAD
                    boxes.append((f"{panel} {text}", x - w / 2, x + w / 2, y, y + LABEL_HEIGHT))
        for i, (a, a0, a1, b0, b1) in enumerate(boxes):
            assert x_lo <= a0 and a1 <= x_hi and y_lo <= b0 and b1 <= y_hi, (a, a0, a1, b0, b1)
            for c, c0, c1, d0, d1 in boxes[i + 1:]:
                assert a1 <= c0 or c1 <= a0 or b1 <= d0 or d1 <= b0, (a, c)
            if " " in a and a.split(" ", 1)[1] in ("measured |H|", "model |H|",
                                                    "measured phase", "model phase",
                                                    "coherence"):
                for p0, p1, q0, q1 in areas:
                    assert a1 <= p0 or p1 <= a0 or b1 <= q0 or q1 <= b0, (a, "plot area")


def _views(path: Path) -> dict[str, dict[str, object]]:
    """The blueprint's views by origin: class and visual bounds (several of one origin:
    the last)."""
    bp = _blueprint_rows(path)
    out: dict[str, dict[str, object]] = {}
    for entity, cols in bp.items():
        if "ViewBlueprint:space_origin" in cols:
            out[cols["ViewBlueprint:space_origin"][0][0]] = {
                "class": cols["ViewBlueprint:class_identifier"][0][0],
                "bounds": (bp.get(f"{entity}/VisualBounds2D", {})
                           .get("VisualBounds2D:range", [[None]])[0][0]),
                "y_range": (bp.get(f"{entity}/ScalarAxis", {})
                            .get("ScalarAxis:range", [[None]])[0][0])}
    return out


def test_the_bands_plot_has_no_tick_for_its_rows(rrd) -> None:  # type: ignore[no-untyped-def]
    """The bands' y values are rows, not values: its fixed y range holds every row and no
    whole number, the step rerun labels at a band plot's height (from -0.7 to 4.7 it
    labelled a lone "0")."""
    data, _ = _read(rrd)
    lo, hi = _views(rrd)["bands"]["y_range"]  # type: ignore[misc]
    rows = {x[0] for k, cols in data.items() if k.startswith("/bands/")
            for x in cols.get("Scalars:scalars", []) if x and np.isfinite(x[0])}
    assert rows and all(lo < r < hi for r in rows)
    assert np.floor(lo) == np.floor(hi) and lo > np.floor(lo)


@pytest.mark.slow
def test_an_axis_without_a_bode_plot_says_why(toy, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """On a real flight whose yaw segments are no SYSTEMID run, the yaw Bode tab is a text
    saying so (it read "No data available"); roll's is the plot; the toy's chirps give every
    axis a plot and no note."""
    import warnings

    from helpers import real_path

    from mavsid.pipeline import fit

    assert all(recording.bode_note(f) is None for f in toy[1].axes.values())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = fit([str(real_path("keita", "00000071.BIN"))])
    assert {"roll", "yaw"} <= set(result.axes)
    assert not any(s.source == "sysid" for s in result.axes["yaw"].held_out)
    path = tmp_path / "k.rrd"
    recording.save_rrd(result, path, flight=False)
    data, _ = _read(path)
    views = _views(path)
    note = " ".join(x[0] for x in data["/frequency/yaw"]["TextDocument:text"])
    assert "no validation segment is a SYSTEMID run" in note
    assert result.axes["yaw"].frequency_note in note
    assert views["frequency/yaw"]["class"] == "TextDocument"
    assert views["frequency/roll"]["class"] == "2D"
    assert any(k.startswith("/frequency/roll/") for k in data)


def test_response_spectra_are_framed_and_a_missing_one_says_why(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """Each spectra plot of ``response --rrd`` has its frame set and holds every point it
    logs (labels included) inside it (fitted by rerun, the labels lost their room); an axis
    with no spectrum shows why instead of "No data available"."""
    import dataclasses
    import warnings

    from mavsid import response
    from mavsid.viz.response import save_response_rrd

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        found = response.read_response(FIXTURES / "sysid_3axis.bin", ("roll", "pitch", "yaw"))
    assert {"roll", "yaw"} <= set(found.spectra)
    bare = dataclasses.replace(found, spectra={k: v for k, v in found.spectra.items()
                                               if k != "yaw"})
    path = tmp_path / "r.rrd"
    save_response_rrd([bare], path)
    data, _ = _read(path)
    views = _views(path)
    for axis in ("roll", "pitch"):
        bounds = views[f"spectrum/{axis}"]["bounds"]
        assert views[f"spectrum/{axis}"]["class"] == "2D" and bounds is not None
        (x0, x1), (y0, y1) = bounds["x_range"], bounds["y_range"]  # type: ignore[index]
        pts = [np.asarray(p, dtype=float).reshape(-1, 2) for k, cols in data.items()
               if k.startswith(f"/spectrum/{axis}/")
               for col in ("Points2D:positions", "LineStrips2D:strips")
               for row in cols.get(col, []) for p in row]
        every = np.concatenate(pts)
        assert len(pts) > 3
        assert (x0 <= every[:, 0].min() and every[:, 0].max() <= x1
                and y0 <= every[:, 1].min() and every[:, 1].max() <= y1)
    assert views["spectrum/yaw"]["class"] == "TextDocument"
    assert "No spectrum for yaw" in data["/spectrum/yaw"]["TextDocument:text"][0][0]
