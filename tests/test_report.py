"""The HTML report: one self-contained file with real pictures and the parameter table."""

from __future__ import annotations

import base64
import re
import xml.etree.ElementTree as ET
from html.parser import HTMLParser

import numpy as np
import pytest
from toy_plants import toy_flight

from mavsid import report

_SVG = "{http://www.w3.org/2000/svg}"
#: the colours of frames, ticks and grids (matplotlib's defaults)
_FRAME = {"#000000", "#b0b0b0", "#cccccc", "#d9d9d9", "#ffffff"}


class _Collect(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.imgs: list[str] = []
        self.links: list[str] = []
        self.cells: list[list[str]] = []
        self._row: list[str] | None = None
        self._cell: list[str] | None = None

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        if tag == "img":
            self.imgs.append(a.get("src") or "")
        for key in ("href", "src"):
            if tag != "img" and a.get(key):
                self.links.append(a[key] or "")
        if tag == "tr":
            self._row = []
        if tag in ("td", "th"):
            self._cell = []

    def handle_endtag(self, tag: str) -> None:
        if tag in ("td", "th") and self._row is not None and self._cell is not None:
            self._row.append("".join(self._cell).strip())
            self._cell = None
        if tag == "tr" and self._row is not None:
            self.cells.append(self._row)
            self._row = None

    def handle_data(self, data: str) -> None:
        if self._cell is not None:
            self._cell.append(data)


@pytest.fixture(scope="module")
def page(tmp_path_factory):  # type: ignore[no-untyped-def]
    _, result, plants = toy_flight()
    path = tmp_path_factory.mktemp("report") / "fit.html"
    report.write_report(result, path)
    return path.read_text(encoding="utf-8"), result, plants


@pytest.mark.slow
def test_report_is_self_contained_with_real_figures(page) -> None:  # type: ignore[no-untyped-def]
    text, result, _ = page
    parsed = _Collect()
    parsed.feed(text)
    assert parsed.links == []  # no stylesheet, script or link to fetch
    assert not re.search(r"\bsrc=\"(?!data:)", text)
    # per axis: time plot, fit vs horizon, residuals, Bode (all toy axes are chirps)
    assert len(parsed.imgs) == 4 * len(result.axes)
    for src in parsed.imgs:
        head, data = src.split(",", 1)
        assert head == "data:image/svg+xml;base64"
        svg = ET.fromstring(base64.b64decode(data))
        assert svg.tag == f"{_SVG}svg"
        width, height = (float(svg.get(k, "0").removesuffix("pt")) for k in ("width", "height"))
        assert width > 300 and height > 150
        # a plot: data curves (coloured, several points: not the frame, ticks or grid) and
        # its labels as text
        curves = [e for e in svg.iter(f"{_SVG}path")
                  if (m := re.search(r"stroke: (#\w+)", e.get("style") or ""))
                  and m.group(1) not in _FRAME and len(re.findall(r"[ML]", e.get("d", ""))) >= 8]
        assert curves
        words = " ".join("".join(e.itertext()) for e in svg.iter(f"{_SVG}text"))
        assert re.search(r"[A-Za-z]{3}", words) and re.search(r"\d", words)


def test_parameter_table_shows_the_true_plant(page) -> None:  # type: ignore[no-untyped-def]
    text, _, plants = page
    parsed = _Collect()
    parsed.feed(text)
    rows = {r[0]: r[1:] for r in parsed.cells if r}
    for plant in plants.values():
        rate = plant.state_names[0]
        assert float(rows[f"a_{rate}"][0]) == pytest.approx(plant.a[0])
        assert float(rows[f"b_{rate}"][0]) == pytest.approx(plant.b[0])
    # the summary: one row per axis with the three fit figures, all high for the true plant
    for axis in ("roll", "pitch", "yaw"):
        cells = rows[axis]
        fits = [float(c) for c in cells[1:4]]
        assert all(80 < f <= 100 for f in fits)


def test_report_leads_with_aircraft_verdicts_and_physics(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """What a tuner reads first: the aircraft and log (firmware, frame, SYSTEMID run,
    the ATC_/INS_/MOT_/SID_ parameters in force), each axis's verdict, and the physical
    parameters — time constant, bandwidth, B in rad/s² per unit, delay — near the truth."""
    import html as html_mod
    import json
    import re
    import warnings

    from helpers import FIXTURES

    from mavsid.pipeline import fit
    from mavsid.report import render_html

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = fit([str(FIXTURES / "sysid_roll.bin")])
    page = html_mod.unescape(re.sub(r"<[^>]+>", " ", render_html(result)))
    text = " ".join(page.split())
    assert "Aircraft and log" in text and "ArduCopter V4.5.7" in text
    assert "FRAME_CLASS 1, FRAME_TYPE 1" in text and "SYSTEMID run" in text
    # (the parameters in force: a table of name and value)
    for p in ("ATC_RAT_RLL_P 0.135", "INS_GYRO_FILTER 20", "MOT_SPIN_MIN 0.15", "SID_AXIS 10"):
        assert p in text, p
    assert "roll good" in text and "pitch not identified" in text
    truth = json.loads((FIXTURES / "sysid_roll.truth.json").read_text())["axes"]["roll"]
    tau = re.search(r"time constant 1/damping ([\d.]+)", text)
    b = re.search(r"control effectiveness B \(u_roll → p′\) ([\d.]+)", text)
    assert tau and b and "rad/s² per unit" in text
    assert float(tau.group(1)) == pytest.approx(1 / truth["damping"], rel=0.1)
    assert float(b.group(1)) == pytest.approx(truth["effectiveness"], rel=0.05)
    assert text.index("Aircraft and log") < text.index("physical parameter") < text.index(
        "fitted parameter")


def test_log_axes_keep_their_minor_grid_and_ticks_without_tick_objects() -> None:
    """The report draws a log axis's minor grid and tick marks as two artists (2-9 of each
    decade inside the limits), not as matplotlib's per-tick objects; fixed margins keep
    every label inside the figure."""
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure

    fig = Figure(figsize=(5.2, 3.4))
    ax = fig.subplots()
    ax.semilogx([0.5, 20.0], [0.0, 1.0])
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("|H| [dB]")
    ax.set_title("t", y=1.0)
    report._layout(fig)
    lines = [c for c in ax.collections if isinstance(c, LineCollection)]
    assert len(lines) == 1
    xs = sorted(seg[0][0] for seg in lines[0].get_segments())
    lo, hi = ax.get_xlim()
    want = [m * 10.0**d for d in (-1, 0, 1) for m in range(2, 10) if lo <= m * 10.0**d <= hi]
    assert xs == pytest.approx(want)
    assert ax.xaxis.get_minor_locator()() == []  # no per-tick minor objects
    fig.draw_without_rendering()
    inside, box = fig.get_tightbbox(), fig.bbox_inches  # every drawn label, in inches
    assert box.x0 <= inside.x0 and inside.x1 <= box.x1
    assert box.y0 <= inside.y0 and inside.y1 <= box.y1


@pytest.mark.slow
def test_one_bode_figure_serves_the_validation_and_the_loop(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The axis section's Bode figure carries the loop analysis's curves (the SYSTEMID runs
    measured with the injection as reference, the TF fit, the broken loop at the mixer
    against its prediction); the loop section, analysed once with it, points there instead
    of drawing the plant's Bode a second time."""
    import warnings

    from helpers import FIXTURES

    from mavsid.pipeline import fit

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = fit([str(FIXTURES / "sysid_roll.bin")])
    from mavsid.loop.tune import tune_analysis

    lp = tune_analysis(result)
    assert lp.error is None and "plant" in lp.measured["roll"] and "roll" in lp.analyses
    cols = report._bode_columns(result.axes["roll"], lp)
    assert [c["title"] for c in cols] == ["u_roll → p",
                                          "broken loop at the mixer (rate and attitude loops)"]
    names = [c[0] for c in cols[0]["curves"]]
    assert names == ["model", "measured, whole SYSTEMID runs", "TF fit"]
    an = lp.analyses["roll"]  # the prediction drawn is the one the text's margins come from
    f_pred = cols[1]["curves"][0][1]
    assert np.all(np.isin(f_pred, an.freq_hz))
    path = tmp_path / "fit.html"
    report.write_report(result, path)
    text = path.read_text(encoding="utf-8")
    sections, loop = text.split("<h2>loop</h2>")
    assert loop.count("<img") == 1  # the twin; the Bode is the roll section's
    assert "in the roll section's frequency-response figure" in loop
    # time, horizon, residual, Bode, and the gains' step and broken-loop figure
    assert sections.count("<img") == 5 * len(result.axes)


@pytest.mark.slow
def test_the_warm_up_builds_the_figures_a_report_draws(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """:func:`report.warm_up` (done by the report worker while the logs are fitted) builds
    and draws every figure layout of a SYSTEMID flight's report beforehand: the report then
    builds none of its own (the first drawing of a layout was ~0.6 s of the SITL report's
    1.9 s), and is the same, byte for byte, as one drawn without it."""
    import threading
    import warnings

    from helpers import FIXTURES

    from mavsid.pipeline import fit

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = fit([str(FIXTURES / "sysid_roll.bin")])
    got: dict[str, object] = {}

    def draw(warm: bool, name: str) -> None:  # (in a thread of its own: an empty pool)
        if warm:
            report.warm_up()
            got["warm"] = set(report._POOL.figures)
        report.write_report(result, tmp_path / name)
        got[name] = set(report._POOL.figures)

    for warm, name in ((True, "warm.html"), (False, "cold.html")):
        thread = threading.Thread(target=draw, args=(warm, name))
        thread.start()
        thread.join()
    assert got["warm.html"] == got["warm"]  # no layout built by the report itself
    assert got["cold.html"] <= got["warm"]
    assert (tmp_path / "warm.html").read_bytes() == (tmp_path / "cold.html").read_bytes()


@pytest.mark.slow
def test_the_loop_analysis_is_asked_for_after_every_axis_s_other_figures(page) -> None:  # type: ignore[no-untyped-def]
    """Every axis's figures but the Bode ones are drawn before the loop analysis is first
    asked for (the report worker draws them while the command works it out), and the
    page is the same as one drawn with the analysis at hand."""
    from mavsid.loop.tune import tune_analysis

    _, result, _ = page
    analysis = tune_analysis(result)
    drawn: list[str] = []
    asked: list[int] = []
    img = report.figure_img

    def counted(fig):  # type: ignore[no-untyped-def]
        drawn.append(fig)
        return img(fig)

    def lp():  # type: ignore[no-untyped-def]
        asked.append(len(drawn))
        return analysis

    report.figure_img = counted  # type: ignore[assignment]
    try:
        later = report.render_html(result, lp)
    finally:
        report.figure_img = img  # type: ignore[assignment]
    assert len(result.axes) == 3 and asked and asked[0] == 3 * len(result.axes)
    assert len(drawn) == 4 * len(result.axes)  # then a Bode figure per axis
    assert later == report.render_html(result, analysis)


@pytest.mark.slow
def test_each_axis_leads_with_its_gains_and_the_loop_has_no_preformatted_text(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The report's loop section was a ``<pre>`` running off the page, last on the page,
    without a gain table. Now each axis's section opens with its verdict and the current
    against the suggested gains (or why none) and the limits, before the model's tables,
    with the step and broken-loop figure; nothing is preformatted."""
    import warnings

    from helpers import FIXTURES

    from mavsid.pipeline import PipelineConfig, fit
    from mavsid.report import write_report

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = fit([str(FIXTURES / "sysid_roll.bin")], PipelineConfig(axes=("roll",)))
    out = tmp_path / "r.html"
    write_report(result, out)
    page = out.read_text()
    assert "<pre" not in page
    section = page[page.index("<h2>roll</h2>"):]
    gains, fitted = section.index("roll: gains (verdict good)"), section.index("fitted parameter")
    assert gains < section.index("<th>current</th>") < section.index("phase margin") < fitted
    assert "ATC_RAT_RLL_P" in section[gains:fitted] and "×0.97" in section[gains:fitted]
    assert section[gains:fitted].count("<img") == 1  # step response and broken-loop Bode
