"""Window selection (mavsid.excitation) and ``mavsid segments``: simulated logs with known
excitation windows, the SITL SYSTEMID flight, every shared log."""

from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pytest
from helpers import FIXTURES, ids, require_shared, shared_logs, shared_path

from mavsid.align import load_flight
from mavsid.cli import main
from mavsid.data import FlightData, SourceInfo
from mavsid.errors import ConfigError, DataQualityWarning, MavsidError
from mavsid.excitation import AXES, ScanOptions, find_segments, select_segments
from mavsid.reasons import KINDS, Reason, group


def _fixture(name: str):
    path = FIXTURES / name
    if not path.exists():
        pytest.skip(f"{path} not generated (python fixtures/make_fixtures.py)")
    truth = json.loads(path.with_name(path.stem + ".truth.json").read_text(encoding="utf-8"))
    return path, truth


def _iou(a: tuple[float, float], b: tuple[float, float]) -> float:
    inter = max(0.0, min(a[1], b[1]) - max(a[0], b[0]))
    return inter / (max(a[1], b[1]) - min(a[0], b[0]))


# --------------------------------------------------------------------------- simulated logs


@pytest.mark.parametrize("name", ["sysid_roll.bin", "sysid_pitch.bin", "sysid_yaw.bin",
                                  "sysid_roll.tlog"])
def test_simulated_sysid_runs_found(name):
    path, truth = _fixture(name)
    reports = find_segments(load_flight(path))
    for run in truth["sysid_runs"]:
        known = (run["waveform_start_s"], run["waveform_stop_s"])
        found = [r for r in reports if r.source == "sysid" and r.axis == run["axis"]]
        assert len(found) == 1 and found[0].kept
        assert _iou((found[0].start_s, found[0].stop_s), known) >= 0.95
        assert found[0].meta["sid_axis"] == run["sid_axis"]
        assert found[0].meta["sysid"]["magnitude"] == pytest.approx(
            run["settings"]["SID_MAGNITUDE"], rel=1e-6)
    # the other axes have no SYSTEMID run: scanned, and nothing is kept there
    axes_with_runs = {run["axis"] for run in truth["sysid_runs"]}
    for r in reports:
        if r.axis not in axes_with_runs:
            assert r.source == "scan" and not r.kept


def _doublet_window(truth) -> tuple[float, float]:
    """Where the simulator's pilot moved the stick (from its own stick generator)."""
    from mavsid.synthetic import Scenario
    from mavsid.synthetic.sysid import pilot_sticks

    sc = Scenario(manoeuvre="doublet", axis=truth["axis"])
    dt = 1.0 / truth["loop_hz"]
    n = round((truth["t_stop_s"] - truth["t_start_s"]) / dt) + 1
    stick = pilot_sticks("doublet", n, dt, np.random.default_rng(0), start_s=sc.hover_before_s)
    on = np.flatnonzero(stick != 0)
    return truth["t_start_s"] + on[0] * dt, truth["t_start_s"] + (on[-1] + 1) * dt


@pytest.fixture(scope="module")
def doublets():
    path, truth = _fixture("doublets.bin")
    return load_flight(path), truth


def test_simulated_doublets_found_by_scan(doublets):
    fd, truth = doublets
    known = _doublet_window(truth)
    kept = [r for r in find_segments(fd, "roll") if r.kept]
    assert len(kept) == 1 and kept[0].source == "scan"
    assert _iou((kept[0].start_s, kept[0].stop_s), known) >= 0.95


def test_one_input_window_rejected_for_other_axes_as_ill_conditioned(doublets):
    fd, truth = doublets
    known = _doublet_window(truth)
    for axis in ("pitch", "yaw"):
        inside = [r for r in find_segments(fd, axis)
                  if min(r.stop_s, known[1]) - max(r.start_s, known[0]) > 0.5 * (r.stop_s
                                                                                   - r.start_s)]
        assert inside
        for r in inside:
            assert not r.kept
            assert any("ill-conditioned" in x for x in r.reasons), r.reasons


def test_hover_rejected_for_low_response():
    path, truth = _fixture("hover.bin")
    assert truth["manoeuvre"] == "hover"
    reports = find_segments(load_flight(path))
    assert reports and not any(r.kept for r in reports)
    for r in reports:
        assert any(x.startswith("rejected: response RMS") and "noise floor" in x
                   for x in r.reasons), r.reasons


def test_kept_windows_become_segments_with_params(doublets):
    fd, _ = doublets
    segs = select_segments(fd)
    assert [s.axis for s in segs] == ["roll"]
    s = segs[0]
    assert s.source == "scan" and s.log.endswith("doublets.bin")
    assert len(s) > 100 and s.states.shape == (len(s), len(s.state_names))
    assert np.allclose(np.diff(s.time_s), s.dt)
    assert s.params["INS_GYRO_FILTER"] == fd.params["INS_GYRO_FILTER"]
    assert "ATC_RAT_RLL_P" in s.params


# --------------------------------------------------------------------------- hand-built


def _flight(u: np.ndarray, y: np.ndarray, blocks, dt=0.01) -> FlightData:
    n = u.size
    t = np.arange(n) * dt
    x = np.column_stack([np.zeros(n), np.zeros(n), np.zeros(n), y])
    return FlightData(t, x, u[:, None], ("roll", "pitch", "yaw", "p"), ("u_roll",),
                      ("rad",) * 3 + ("rad/s",), ("1",), dt, np.asarray(blocks),
                      {"armed": np.ones(n, bool), "airborne": np.ones(n, bool)},
                      SourceInfo("hand", "synthetic", 0), "hand")


def test_windows_never_cross_a_block_boundary():
    rng = np.random.default_rng(1)
    n = 4000
    u = 0.002 * rng.standard_normal(n)
    u[500:3500] += 0.1 * rng.standard_normal(3000)  # excited across the block boundary
    y = np.zeros(n)
    for k in range(1, n):
        y[k] = 0.9 * y[k - 1] + u[k - 1]
    reports = find_segments(_flight(u, y, [[0, 1500], [1500, n]]), "roll")
    kept = [r for r in reports if r.kept]
    assert any(r.i1 <= 1500 for r in kept) and any(r.i0 >= 1500 for r in kept)
    for r in reports:
        assert r.i1 <= 1500 or r.i0 >= 1500


def test_ground_and_attitude_gates_give_numbers():
    rng = np.random.default_rng(2)
    n = 2000
    u = 0.1 * rng.standard_normal(n)
    y = np.convolve(u, np.ones(5), "same")
    fd = _flight(u, y, [[0, n]])
    air = np.ones(n, bool)
    air[:1000] = False
    roll = np.zeros(n)
    roll[1500:] = np.radians(60)
    fd = FlightData(fd.time_s, np.column_stack([roll, fd.states[:, 1:]]), fd.inputs,
                    fd.state_names, fd.input_names, fd.state_units, fd.input_units, fd.dt,
                    fd.blocks, {"airborne": air, "armed": np.ones(n, bool)}, fd.source, "hand")
    reasons = [x for r in find_segments(fd, "roll") for x in r.reasons]
    assert any("on the ground or disarmed for 100 %" in x for x in reasons)
    assert any("|roll| reaches 60°" in x for x in reasons)


def test_unknown_axis_and_bad_options_are_config_errors(doublets):
    fd, _ = doublets
    with pytest.raises(ConfigError, match="unknown axis"):
        find_segments(fd, "thrust")
    with pytest.raises(ConfigError):
        ScanOptions(window_s=-1)


# --------------------------------------------------------------------------- real logs


@pytest.fixture(scope="module")
def sitl_reports():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataQualityWarning)
        return {suffix: find_segments(load_flight(shared_path("sitl", f"flightA_mixer.{suffix}")))
                for suffix in ("BIN", "tlog")}


@pytest.mark.slow
@pytest.mark.parametrize("suffix", ["BIN", "tlog"])
def test_sitl_systemid_flight_gives_the_chirps(sitl_reports, suffix):
    # README: SID_AXIS 10/11/12/13 entered at about 87, 173, 258, 344 s; SID_T_REC 60 s
    reports = sitl_reports[suffix]
    kept = [(r.axis, r.source) for r in reports if r.kept]
    assert kept == [("roll", "sysid"), ("pitch", "sysid"), ("yaw", "sysid")]
    for r, enter in zip([r for r in reports if r.kept], (87, 173, 258), strict=True):
        assert enter < r.start_s < enter + 2.5 and 59.0 < r.stop_s - r.start_s < 61.0
    thrust = [r for r in reports if r.axis == "thrust"]
    assert len(thrust) == 1 and not thrust[0].kept and 344 < thrust[0].start_s < 346.5


_LOGS = shared_logs(".bin", ".log", ".tlog", ".ulg")


@pytest.mark.slow
@pytest.mark.parametrize("path", _LOGS, ids=ids(_LOGS))
def test_every_shared_log_gives_reasons(path):
    require_shared()
    if path.stat().st_size > 50e6:
        pytest.skip("the big SITL log is covered by test_sitl_systemid_flight_gives_the_chirps")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            fd = load_flight(path)
        except MavsidError:
            return  # no attitude data, or unreadable: a typed error
        reports = find_segments(fd)
    assert reports
    for r in reports:
        assert r.reasons and all(isinstance(x, str) and x for x in r.reasons)
        assert r.axis in (*AXES, "thrust", "other") and r.start_s <= r.stop_s
        assert r.kept == r.reasons[0].startswith("kept")
        json.dumps(r.to_dict())


# --------------------------------------------------------------------------- CLI


def test_cli_segments_json(capsys, doublets):
    path, _ = _fixture("doublets.bin")
    assert main(["segments", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert {r["axis"] for r in out} == set(AXES)
    for r in out:
        assert {"axis", "start_s", "stop_s", "score", "kept", "source", "reasons"} <= set(r)
        assert r["source"] in ("sysid", "scan") and isinstance(r["kept"], bool)
    assert [r["axis"] for r in out if r["kept"]] == ["roll"]
    assert main(["segments", str(path), "--json", "--axis", "pitch"]) == 0
    assert {r["axis"] for r in json.loads(capsys.readouterr().out)} == {"pitch"}


def test_rejections_are_values_whose_numbers_are_the_metrics(capsys):
    """Each rejected window's gates carry the metric they judged (the same number as the
    window's ``metrics``) and the bound from the options; the sentence in ``reasons`` is the
    message made from them; ``--json`` holds both. Two of the SYSTEMID roll flight's yaw
    windows (over the roll chirp's injection) are rejected for too little coherence with it:
    one group, with their range."""
    path, _ = _fixture("sysid_roll.bin")
    opts = ScanOptions()
    reports = find_segments(load_flight(path), options=opts)
    rejected = [r for r in reports if not r.kept]
    assert rejected and all(r.checks for r in rejected)
    assert all(not r.checks for r in reports if r.kept)
    for r in rejected:
        assert r.reasons[: len(r.checks)] == tuple(f"rejected: {c.message}" for c in r.checks)
        for c in r.checks:
            if c.kind == "injection_coverage":
                assert c.numbers["coverage_pct"] == pytest.approx(
                    100 * r.metrics["injection_coverage"])
                assert c.numbers["need_pct"] == pytest.approx(100 * opts.min_coverage)
            if c.kind == "ill_conditioned":
                assert c.numbers["condition"] == r.metrics.get("condition", math.inf)
                assert c.numbers["condition"] > opts.max_condition
    yaw = [r for r in rejected if r.axis == "yaw"]
    low = sorted(round(r.checks[0].numbers["coverage_pct"]) for r in yaw
                 if r.checks[0].kind == "injection_coverage")
    assert len(low) == 2, [r.reasons for r in yaw]
    assert (f"2× coherence with the injection too low ({low[0]}–{low[1]} % of the band, "
            "need 30 %)") in group([r.checks[0] for r in yaw])
    assert main(["segments", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert [d["reason_kinds"] for d in out] == [[c.kind for c in r.checks] for r in reports]
    assert [[c["message"] for c in d["checks"]] for d in out] == [
        [c.message for c in r.checks] for r in reports]


def test_reason_kinds_are_known():
    """A kind outside the vocabulary is refused; each known kind has a group label."""
    with pytest.raises(ValueError, match="unknown reason kind"):
        Reason("too_windy")  # type: ignore[arg-type]
    assert len({Reason(k).label for k in KINDS}) == len(KINDS)


def test_cli_segments_text_and_errors(capsys, tmp_path):
    path, _ = _fixture("sysid_roll.bin")
    assert main(["segments", str(path)]) == 0
    out = capsys.readouterr().out
    assert "sysid" in out and "SID_AXIS 10" in out and "rejected" in out
    assert main(["segments", str(tmp_path / "missing.bin")]) == 1
    bad = tmp_path / "bad.toml"
    bad.write_text("[preset.x\n", encoding="utf-8")
    assert main(["segments", str(path), "--preset", str(bad)]) == 1
    assert "not valid TOML" in capsys.readouterr().err


def test_gram_condition_and_correlation_are_lapacks() -> None:
    """Each window's Gram condition, input share and correlation (closed forms of a 2x2)
    against numpy's ``eigvalsh`` and ``corrcoef`` of the same regressors: the rate and its
    input centred, the rate scaled by its spread, the input by the spread of all attitude
    inputs in the window."""
    fd = load_flight(FIXTURES / "doublets.bin")
    checked = 0
    for axis in AXES:
        for rep in find_segments(fd, axis, scan=True):
            m, i0, i1 = rep.metrics, rep.i0, rep.i1
            if "input_share" not in m:
                continue
            y = fd.states[i0:i1, fd.state_names.index({"roll": "p", "pitch": "q",
                                                       "yaw": "r"}[axis])]
            u = fd.inputs[i0:i1, fd.input_names.index(f"u_{axis}")]
            ref = np.sqrt(np.mean([np.var(fd.inputs[i0:i1, fd.input_names.index(f"u_{a}")])
                                   for a in AXES]))
            phi = np.column_stack([y - y.mean(), u - u.mean()])
            z = phi / np.array([phi[:, 0].std(), ref])
            ev = np.linalg.eigvalsh(z.T @ z / z.shape[0])
            assert m["condition"] == pytest.approx(ev[-1] / ev[0], rel=1e-9)
            assert m["correlation"] == pytest.approx(np.corrcoef(phi.T)[0, 1], rel=1e-9,
                                                     abs=1e-12)
            assert m["input_share"] == pytest.approx(u.std() / ref, rel=1e-12)
            checked += 1
    assert checked >= 10


@pytest.mark.parametrize("name", ["doublets.bin", "sysid_roll.bin", "px4_hexa_doublets.ulg"])
def test_windows_measured_together_are_measured_as_alone(name: str,
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """The scan measures its windows (Welch spectra, levels, Gram sums) in one call per
    batch of windows: every window's metrics, verdict and reasons are those of the window
    measured alone (input, output and the command's or injection's coherence). The metrics
    to 1e-9 of themselves (1e-12 absolute for those near zero, such as a correlation): a
    batch only changes the shapes of the detrending's matrix products, which a BLAS may sum
    in another order for one window than for 64 (a few roundings of sums of a window's
    samples)."""
    from mavsid import excitation

    fd = load_flight(FIXTURES / name)
    together = find_segments(fd, scan=True)
    monkeypatch.setattr(excitation, "_BATCH", 1)
    alone = find_segments(fd, scan=True)
    assert len(together) > 5
    assert name != "px4_hexa_doublets.ulg" or any("command_coherence" in r.metrics
                                                 for r in together)
    for a, b in zip(together, alone, strict=True):
        assert (a.axis, a.i0, a.i1, a.kept, a.reasons) == (b.axis, b.i0, b.i1, b.kept, b.reasons)
        assert a.metrics.keys() == b.metrics.keys()
        for key, value in a.metrics.items():
            assert (math.isnan(value) and math.isnan(b.metrics[key])) or value == pytest.approx(
                b.metrics[key], rel=1e-9, abs=1e-12), key


@pytest.mark.slow
def test_moving_average_by_slices_is_the_clipped_window_mean() -> None:
    """The centred moving average (high-pass and envelopes of every axis, taken by slices of
    the running sum) against its definition: each sample the mean of the ``n`` around it,
    the window clipped at either end, on random lengths and widths."""
    from mavsid.excitation_scores import moving_mean

    rng = np.random.default_rng(7)
    for _ in range(3000):
        size, n = int(rng.integers(0, 60)), int(rng.integers(0, 80))
        x = rng.standard_normal(size) * 10 ** rng.uniform(-4, 4)
        width = max(1, min(n, size))
        want = np.array([x[max(i - width // 2, 0) : max(i - width // 2, 0) + width].mean()
                         for i in range(size)])
        assert np.allclose(moving_mean(x, n), want, rtol=1e-12, atol=1e-9 * np.abs(x).max(
            initial=0)), (size, n)
