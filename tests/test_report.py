"""The HTML report: one self-contained file with real pictures and the parameter table."""

from __future__ import annotations

import base64
import io
import re
from html.parser import HTMLParser

import matplotlib.image as mpimg
import numpy as np
import pytest
from toy_plants import toy_flight

from mavsid import report


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
        assert head == "data:image/png;base64"
        img = mpimg.imread(io.BytesIO(base64.b64decode(data)), format="png")
        assert img.shape[0] > 150 and img.shape[1] > 300
        rgb = img[..., :3].reshape(-1, 3)
        # a plot: mostly white background, with dark axes and coloured lines
        assert np.mean(np.all(rgb > 0.95, axis=1)) > 0.4
        assert len(np.unique((rgb * 31).round(), axis=0)) > 20


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
