"""The defaults (gates, thresholds, delay/lag search, block length, verdict) on the variety of
simulated vehicles in ``fixtures/``: noisy gyros fed back through the rate controller, a
heavier X quad, a hexacopter (also as a PX4 ULog), manual stick flying, SYSTEMID, and a 10 Hz
log.

Truth comes from each fixture's ``*.truth.json`` (the simulator's plant), never from mavsid.
Parameters are tested against the stated tolerances below, over every vehicle alike (not
tuned to one log), and against the σ mavsid reports (statistical, coloured residuals, plus
the lag's grid resolution): the truth within 2.5 σ on every vehicle.
"""

from __future__ import annotations

import dataclasses
import json
import re
import warnings

import numpy as np
import pytest
from helpers import FIXTURES

from mavsid import pipeline
from mavsid.cli_format import format_result
from mavsid.errors import NoExcitationError
from mavsid.pipeline import fit, validate_logs
from mavsid.pipeline_config import PipelineConfig

#: Stated tolerances on every vehicle (relative to the truth). Measured: effectiveness
#: within 3.7 % and damping within 11 % on all of them, noisy ones included (the lag chosen
#: by output error there); before that choice, noisy vehicles came back 5-10 % low in B.
B_TOLERANCE = 0.05
DAMPING_TOLERANCE = 0.15

#: (fixture, axis that must be identified)
IDENTIFIABLE = [
    ("noisy_sysid.bin", "roll"),
    ("noisy_sysid.bin", "pitch"),
    ("heavy_sysid.bin", "pitch"),
    ("hexa_doublets.bin", "pitch"),
    ("sysid_roll.bin", "roll"),
    ("sysid_pitch.bin", "pitch"),
    ("sysid_yaw.bin", "yaw"),
    ("doublets.bin", "roll"),
    ("px4_hexa_doublets.ulg", "pitch"),
]

_RESULTS: dict[str, pipeline.FitResult] = {}


def _fit(name: str) -> pipeline.FitResult:
    if name not in _RESULTS:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            _RESULTS[name] = fit([str(FIXTURES / name)])
    return _RESULTS[name]


def _truth(name: str) -> dict:
    return json.loads((FIXTURES / f"{name.rsplit('.', 1)[0]}.truth.json").read_text())


@pytest.mark.slow
@pytest.mark.parametrize(("name", "axis"), IDENTIFIABLE, ids=[f"{n}-{a}" for n, a in IDENTIFIABLE])
def test_every_vehicle_is_identified_near_its_truth(name: str, axis: str) -> None:
    result = _fit(name)
    assert axis in result.axes, result.verdicts[axis].line()
    f = result.axes[axis]
    assert f.verdict is not None and f.verdict.identified, f.verdict
    y = f.output
    truth = _truth(name)["axes"][axis]
    b = f.model.params[f"B[{y},u_{axis}]"]
    damping = -f.model.params[f"A[{y},{y}]"]
    assert abs(b / truth["effectiveness"] - 1) < B_TOLERANCE, (b, truth["effectiveness"])
    assert abs(damping / truth["damping"] - 1) < DAMPING_TOLERANCE, (damping, truth["damping"])
    assert f.validation.stable is True
    # the truth within the σ it reports (measured: 0-1.9 σ; the statistical σ alone left it
    # up to 6.7 σ away on the hexacopters)
    se = f.model.stderr
    assert abs(b - truth["effectiveness"]) <= 2.5 * se[f"B[{y},u_{axis}]"]
    assert abs(damping - truth["damping"]) <= 2.5 * se[f"A[{y},{y}]"]


def test_noisy_systemid_chirps_are_judged_by_the_injection() -> None:
    result = _fit("noisy_sysid.bin")
    assert set(result.axes) == {"roll", "pitch"}  # not only yaw, not yaw at all
    for axis in ("roll", "pitch"):
        kept = [w for w in result.axes[axis].windows if w.kept]
        assert kept and all(w.source == "sysid" for w in kept)
        assert all("injection (SIDD.Targ)" in w.reasons[0] for w in kept)
        # the controller output carries the fed-back gyro noise: its own level would fail
        assert all(w.metrics["power_ratio"] < 5 for w in kept)
        assert all(w.metrics["injection_coherence"] > 0.8 for w in kept)
        assert result.verdicts[axis].numbers["excitation_coherence"] > 0.8


def test_every_axis_asked_for_has_a_verdict_that_points_somewhere() -> None:
    result = _fit("noisy_sysid.bin")
    assert list(result.verdicts) == ["roll", "pitch", "yaw"]
    yaw = result.verdicts["yaw"]
    assert not yaw.identified
    assert "mavsid segments" in yaw.reasons[0] and "--all" in yaw.reasons[0]
    assert any("SID_AXIS 12" in a for a in yaw.advice)
    assert "yaw: not identified" in format_result(result)


def test_a_10_hz_log_says_why_and_which_logging_setting() -> None:
    with pytest.raises(NoExcitationError) as err, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit([str(FIXTURES / "slow_10hz.bin")])
    text = " ".join((str(err.value), *err.value.details))
    for axis in ("roll", "pitch", "yaw"):
        assert f"{axis}: not identified: rates/outputs logged at 10 Hz" in text
    assert "LOG_BITMASK" in text and "ATTITUDE_FAST" in text


def _unstable(val):  # type: ignore[no-untyped-def]
    return dataclasses.replace(val, stable=False, eigenvalues=np.array([1.01]))


def test_an_unstable_model_is_refused_and_the_bounded_fit_offered(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    real = pipeline._validate
    calls = []

    def validate(model, segments, cfg):  # type: ignore[no-untyped-def]
        calls.append(model)
        val = real(model, segments, cfg)
        return _unstable(val) if len(calls) == 1 else val  # only the unconstrained fit

    monkeypatch.setattr(pipeline, "_validate", validate)
    result = fit([str(FIXTURES / "sysid_roll.bin")], PipelineConfig(axes=("roll",)))
    f = result.axes["roll"]
    assert f.estimator == "bounded ls"
    prov = dict(f.model.provenance)
    assert set(prov["bounds"]) == {"A_d[p,p]", "B_d[p,u_roll]"}
    assert prov["bounds_active"] == []  # the true plant is stable: no bound needed
    assert result.verdicts["roll"].reasons[0].startswith(
        "the unconstrained fit was unstable (eigenvalue 1.01")
    truth = _truth("sysid_roll.bin")["axes"]["roll"]["effectiveness"]
    assert abs(f.model.params["B[p,u_roll]"] / truth - 1) < B_TOLERANCE


def test_unstable_everywhere_is_an_error_naming_the_eigenvalue(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    real = pipeline._validate
    monkeypatch.setattr(pipeline, "_validate", lambda m, s, c: _unstable(real(m, s, c)))
    with pytest.raises(NoExcitationError, match=r"unstable: eigenvalue 1\.01") as err:
        fit([str(FIXTURES / "sysid_roll.bin")], PipelineConfig(axes=("roll",)))
    assert re.search(r"unstable: eigenvalue 1\.01.*refused", " ".join(err.value.details))
    kept = fit([str(FIXTURES / "sysid_roll.bin")],
               PipelineConfig(axes=("roll",), allow_unstable=True))
    assert kept.axes["roll"].verdict is not None
    assert kept.axes["roll"].verdict.level == "not identified"


def test_validate_re_discretises_a_model_for_a_log_of_another_rate() -> None:
    """A 200 Hz model on a 100 Hz log runs at the log's own step (not on interpolated
    samples, which made the one-step fit look better than the log supports)."""
    model = _fit("sysid_roll.bin").axes["roll"].model
    assert 1 / model.dt == pytest.approx(200.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = validate_logs({"roll": model}, [str(FIXTURES / "noisy_sysid.bin")])
    f = result.axes["roll"]
    assert 1 / f.model.dt == pytest.approx(100.0)
    assert all(s.dt == pytest.approx(0.01) for s in f.held_out)
    reasons = " ".join(result.verdicts["roll"].reasons)
    assert "re-discretised from 200 Hz to the log's 100 Hz" in reasons
    # the same physics: continuous-time damping and effectiveness, delay in seconds
    for name in ("A[p,p]", "B[p,u_roll]"):
        assert f.model.params[name] == pytest.approx(model.params[name], rel=1e-6)
    assert f.model.delay_s == pytest.approx(model.delay_s)
    # the two simulated vehicles share the roll plant: the model predicts the other log
    truth = _truth("noisy_sysid.bin")["axes"]["roll"]
    assert abs(f.model.params["B[p,u_roll]"] / truth["effectiveness"] - 1) < B_TOLERANCE
    assert f.validation.fit_free_run[0] > 80.0


def test_validate_says_so_when_a_model_cannot_be_re_discretised() -> None:
    """A_d < 0 has no continuous-time equivalent: the log goes onto the model's grid,
    its samples interpolated, and the verdict says both."""
    from mavsid.estimators.model import Model

    model = Model(("p",), ("u_roll",), ("p", "u_roll", "1"),
                  np.array([[-0.2], [0.9], [0.0]]), dt=0.005)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = validate_logs({"roll": model}, [str(FIXTURES / "noisy_sysid.bin")])
    reasons = " ".join(result.verdicts["roll"].reasons)
    assert "no continuous-time equivalent" in reasons
    assert "noisy_sysid.bin logged at 100 Hz, resampled onto the model's 200 Hz grid" in reasons


def test_plots_survive_a_diverging_model(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """Fit % of -2e6 and free runs of 1e12 rad/s: the .rrd and the HTML are still written
    (no million-tick axis, no 'Maximum allowed size exceeded')."""
    from mavsid.report import render_html
    from mavsid.viz.recording import save_rrd

    result = _fit("sysid_roll.bin")
    f = result.axes["roll"]
    v = f.validation
    segs = tuple(dataclasses.replace(s, free_run=s.free_run * 1e12 + 1e9)
                 for s in v.segments)
    bad = dataclasses.replace(v, fit_free_run=np.full_like(v.fit_free_run, -2.245833e6),
                              fit_vs_horizon=v.fit_vs_horizon - 2.2e8, segments=segs)
    diverging = dataclasses.replace(result, axes={"roll": dataclasses.replace(f, validation=bad)})
    save_rrd(diverging, tmp_path / "x.rrd", flight=False)
    assert (tmp_path / "x.rrd").stat().st_size > 1000
    html = render_html(diverging)
    assert "<html" in html.lower()
    assert "diverges" in format_result(diverging)
    assert "-2245833" not in format_result(diverging)


def test_advice_is_for_the_autopilot_that_flew() -> None:
    """A PX4 log is not told to fly ArduPilot's SYSTEMID mode, nor an ArduPilot log PX4's."""
    px4 = _fit("px4_hexa_doublets.ulg").verdicts["roll"]
    assert px4.level == "not identified"
    assert any("ACRO (PX4 has no SYSTEMID" in a for a in px4.advice)
    assert not any("SID_AXIS" in a for a in px4.advice)
    ap = _fit("doublets.bin").verdicts["pitch"]
    assert any("SID_AXIS 11" in a for a in ap.advice)


#: known since SYSTEMID chirps are cut into interleaved training/validation blocks (four, not
#: the slow and fast halves): the time-domain fit of the octaquad's yaw chirp is biased by
#: the feedback (B 3.7-4.3 % low as .bin at 400 and 50 Hz and as .tlog alike, more so on the
#: chirp's faster blocks, which training now holds: 13.52 ± 0.08 and 12.44 ± 0.39 on its two);
#: in a .bin the response against the injection joins σ and covers it (0.9-1.1 σ), a .tlog
#: holds neither the injection nor the commanded attitude: nothing joins its σ; strict, so a
#: fix shows
_INTERLEAVED = pytest.mark.xfail(strict=True, reason="a feedback-biased effectiveness with "
                                 "nothing in a .tlog to widen its σ (see _INTERLEAVED)")


@pytest.mark.parametrize(("name", "axis"), [("noisy_sysid.bin", "roll"),
                                            ("noisy_sysid.bin", "pitch"),
                                            ("heavy_sysid.bin", "pitch")])
def test_noisy_gyros_get_their_motor_lag_and_a_good_verdict(name: str, axis: str) -> None:
    """With 2-3 deg/s of gyro noise fed back, the one-step score cannot see the motor lag.
    These are SYSTEMID chirps: the lag is chosen against the FRF measured from the injection
    (the feedback does not bias it) and comes out at the truth (measured: 15, 15, 30 ms;
    the output-error choice gave 20, 20, 30 ms), and the model predicts held-out data.

    The chirps are cut into interleaved blocks: a held-out block's input filters start from
    the inputs before it (cold, the filters' transient integrated by the slow plant drifted
    the free run over the chirp's fast end: 84.1 and 77.7 % on the pitch axes), and the FRF's
    pick stands where the one-step score agrees with it (heavy_sysid pitch was relabelled
    and rescored by output error)."""
    f = _fit(name).axes[axis]
    prov = dict(f.model.provenance)
    truth = _truth(name)["axes"][axis]
    assert prov["lag_chosen_by"] == "frequency response"
    assert float(prov["lag_s"]) == pytest.approx(truth["motor_tau_s"], abs=1e-6)
    assert f.verdict is not None and f.verdict.level == "good"
    # measured: 88.4, 88.2, 91.2 % (by output error, halves: 84.0, 85.0, 83.3 %)
    assert f.validation.fit_summary(f.output)["free_run"] > 86.0


@pytest.mark.slow
def test_a_25_hz_log_gives_a_usable_model_and_says_what_it_misses(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """25 Hz (4+ samples per period of a 5 Hz loop): the slow dynamics are there to fit, so
    a model with the cap said, not a refusal; 10 Hz stays refused (the test above)."""
    from mavsid.synthetic.run import scenario_from_options, simulate

    path = tmp_path / "r25.bin"
    simulate(scenario_from_options(sid_axes=(10,), rate_hz=25.0, gyro_noise_dps=2.0, seed=24),
             [path])
    truth = json.loads(path.with_name("r25.truth.json").read_text())["axes"]["roll"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = fit([str(path)], PipelineConfig(axes=("roll",)))
    f = result.axes["roll"]
    assert f.verdict is not None and f.verdict.level == "usable"
    assert any("logged at 25 Hz: only the slow part" in r for r in f.verdict.reasons)
    assert f.model.params["B[p,u_roll]"] == pytest.approx(truth["effectiveness"], rel=0.10)


def _simulated(tmp_path, name: str, layout: str | None = None, **options):  # type: ignore[no-untyped-def]
    """A log simulated from ``options`` (:func:`scenario_from_options`), its truth and fit."""
    from mavsid.synthetic.run import scenario_from_options, simulate

    path = tmp_path / name
    simulate(scenario_from_options(**options), [path], layout=layout)
    axis = options.get("axis", "roll")
    truth = json.loads(path.with_suffix(".truth.json").read_text())["axes"][axis]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = fit([str(path)], PipelineConfig(axes=(axis,)))
    return path, truth, result


@pytest.mark.slow
def test_an_old_log_whose_metadata_has_no_time_is_armed_from_its_first_record(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """ArduCopter 3.3 writes EV, MODE and PARM without a time field, the ARM event first.
    With no SYSTEMID run (a stick doublet) no metadata record has a time at all: the ARM
    event belongs at the log's first timed record, not nowhere (which left the whole flight
    "disarmed" and every window rejected)."""
    from mavsid.readers import read_log

    path, truth, result = _simulated(tmp_path, "d33.bin", "copter-3.3", manoeuvre="doublet",
                                     axis="roll", rate_hz=50.0, seed=14)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        raw = read_log(path)
    arm = raw["EV"].time_s[raw["EV"].columns["Id"] == 10]
    assert arm.tolist() == [float(raw["ATT"].time_s[0])]
    f = result.axes["roll"]
    assert f.verdict is not None and f.verdict.level in ("good", "usable")
    b, se = f.model.params["B[p,u_roll]"], f.model.stderr["B[p,u_roll]"]
    assert abs(b - truth["effectiveness"]) < 2.5 * se  # (50 Hz: -6.8 %, 1.6 σ)


@pytest.mark.slow
def test_a_centidegree_rate_log_is_screened_in_si_units(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """ArduCopter 3.4-dev logs RATE in centidegrees/s: the physical range (4000 deg/s) is
    judged once the scale is settled. Screened before, every sample above 40 deg/s was
    "impossible" and excluded: 0.9 s left to train on, B -15 % and a raw numpy error from
    the twin."""
    _, truth, result = _simulated(tmp_path, "c34.bin", "copter-3.4-dev", manoeuvre="3211",
                                     axis="pitch", rate_hz=200.0, gyro_noise_dps=6.0,
                                     vibration_dps=2.0, seed=28)
    f = result.axes["pitch"]
    assert not result.flights[0].excluded_samples
    assert f.model.params["B[q,u_pitch]"] == pytest.approx(truth["effectiveness"],
                                                          rel=B_TOLERANCE)
    assert -f.model.params["A[q,q]"] == pytest.approx(truth["damping"], rel=DAMPING_TOLERANCE)
    assert f.closed_loop is not None, f.closed_loop_note


def test_a_short_low_rate_log_is_judged_by_its_sigma_not_its_sample_count(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """5 s of a 25 Hz log (133 training samples for 3 parameters) hold the slow dynamics as
    well as 5 s at 400 Hz; whether the effectiveness is determined is its σ's to say. It
    was refused for its sample count; now a capped model, the truth within 3 σ."""
    _, truth, result = _simulated(tmp_path, "r25.bin", "copter-3.4-dev", manoeuvre="random",
                                     axis="roll", vehicle="heavy-x", rate_hz=25.0,
                                     vibration_dps=5.0, seed=227)
    f = result.axes["roll"]
    assert f.verdict is not None and f.verdict.level == "usable"
    b, se = f.model.params["B[p,u_roll]"], f.model.stderr["B[p,u_roll]"]
    assert abs(b - truth["effectiveness"]) < 3 * se
    assert f.verdict.numbers["effectiveness_rel_se"] < 0.25


def test_an_undetermined_effectiveness_is_not_identified() -> None:
    from types import SimpleNamespace as NS

    from mavsid.verdict import judge

    val = NS(state_names=("p",), fit_free_run=np.array([85.0]), fit_vs_horizon=None,
             fit_one_step=np.array([95.0]), fit_at=lambda s: np.array([90.0]), stable=True,
             eigenvalues=np.array([0.99]), dt=0.0025, residuals=None)
    for se, level in ((20.0, "good"), (60.0, "not identified")):
        model = NS(params={"A[p,p]": -4.0, "B[p,u_roll]": 180.0, "c[p]": 0.0},
                   stderr={"A[p,p]": 0.2, "B[p,u_roll]": se, "c[p]": 0.01}, provenance={})
        v = judge("roll", val, "p", model=model)
        assert v.level == level, v.reasons
    assert "control effectiveness not determined: B[p,u_roll] 180 ± 60" in v.reasons[0]


def test_the_baseline_survives_blocks_shorter_than_its_delay() -> None:
    from mavsid.loop.twin import baseline_fit

    t = np.sin(np.arange(400) * 0.05)
    short = np.sin(np.arange(5) * 0.05)
    fit_pct, delay, preds = baseline_fit([(t, t), (short, short)], [(short, short), (t, t)],
                                         dt=0.01)
    assert delay == 0.0 and fit_pct == pytest.approx(100.0)
    assert [p.shape for p in preds] == [(5,), (400,)]


@pytest.mark.slow
def test_a_systemid_chirp_is_judged_by_its_injection_not_the_noise_floor(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """6 deg/s of gyro noise fed back: the pitch response is 4.7× its noise floor, under the
    5× that scanned windows need, but the logged injection (SIDD.Targ) is coherent with it
    over 91 % of its band (mean 0.92). A SYSTEMID run is judged by that coherence,
    not rejected by the floor."""
    _, truth, result = _simulated(tmp_path, "n6.bin", axis="pitch", sid_axes=(11,),
                                  gyro_noise_dps=6.0, seed=633)
    f = result.axes["pitch"]
    assert f.model is not None and [w.kept for w in f.windows] == [True]
    assert f.model.params["B[q,u_pitch]"] == pytest.approx(truth["effectiveness"],
                                                          rel=B_TOLERANCE)


@pytest.mark.slow
def test_random_flights_give_no_wrong_model_and_no_crash(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A dozen flights drawn by ``benchmarks/bench_variety.py`` (manoeuvre, vehicle, noise,
    vibration, 25-400 Hz, ten layouts; fixed seed): no model off the truth by more than 10 %
    and 2.5 σ is called ``good``, nothing crashes, and most are identified near the truth.
    (The sweep itself runs 40+ flights per seed; see the README.)"""
    import importlib.util
    import random
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_variety.py"
    spec = importlib.util.spec_from_file_location("bench_variety", path)
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    rng = random.Random(11)
    outcomes = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for i in range(12):
            outcome, line = bench.run_one(tmp_path, i, bench.draw(rng))
            outcomes.append((outcome, line))
    assert not [o for o in outcomes if o[0] in ("WRONG", "CRASH")], outcomes
    assert sum(o[0] == "ok" for o in outcomes) >= 8, outcomes


@pytest.mark.slow
def test_lags_the_data_cannot_tell_apart_widen_the_sigma(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A heavy quad's chirp in a 3.3-layout log (no SYSTEMID records: scanned windows, the
    chirp's slow part): lags 0-20 ms score within 0.5 % of each other and the shortest is
    chosen, B 10 % low. With only the grid neighbours in the σ the truth was 15 σ away; the
    farthest of the indistinguishable lags now joins it (measured 4.2 σ)."""
    _, truth, result = _simulated(tmp_path, "h5.bin", "copter-3.3", axis="roll",
                                  sid_axes=(10,), vehicle="heavy-x", gyro_noise_dps=1.0,
                                  vibration_dps=2.0, rate_hz=200.0, seed=5)
    m = result.axes["roll"].model
    assert "cannot tell apart" in str(dict(m.provenance)["stderr_includes"])
    b, se = m.params["B[p,u_roll]"], m.stderr["B[p,u_roll]"]
    assert abs(b - truth["effectiveness"]) < 5 * se


@pytest.mark.slow
@pytest.mark.parametrize(("vehicle", "gyro", "vibration", "rate", "seed"),
                         [("quad", 1.0, 2.0, 200.0, 61), ("heavy-x", 3.0, 0.0, 400.0, 774)],
                         ids=["quad-1dps", "heavy-x-3dps"])
def test_a_little_fed_back_gyro_noise_does_not_shorten_the_motor_lag(
        tmp_path, vehicle: str, gyro: float, vibration: float, rate: float, seed: int
) -> None:  # type: ignore[no-untyped-def]
    """SYSTEMID roll chirps with 1-3 deg/s of gyro noise fed back: the best one-step residual
    is 1.3-1.7 % of the output's spread, under the 2 % that used to call data noisy, so the
    one-step score chose the lag and picked 0-5 ms (truth 15 / 30 ms): B -5.7 % (4.7 σ) and
    -9.1 % (8.3 σ), free run 67 / 43 % where the true plant reaches 93 / 87 % on the same
    held-out block (found by ``bench_variety.py --seed 101`` / ``--seed 202``)."""
    _, truth, result = _simulated(tmp_path, "n.bin", axis="roll", sid_axes=(10,),
                                  vehicle=vehicle, gyro_noise_dps=gyro,
                                  vibration_dps=vibration, rate_hz=rate, seed=seed)
    f = result.axes["roll"]
    # noisy: not the one-step score (a SYSTEMID chirp: against the injection's FRF)
    assert dict(f.model.provenance)["lag_chosen_by"] == "frequency response"
    b, se = f.model.params["B[p,u_roll]"], f.model.stderr["B[p,u_roll]"]
    assert abs(b / truth["effectiveness"] - 1) < B_TOLERANCE
    assert abs(b - truth["effectiveness"]) < 2.5 * se
    assert -f.model.params["A[p,p]"] == pytest.approx(truth["damping"], rel=DAMPING_TOLERANCE)
    assert f.validation.fit_summary("p")["free_run"] > 80.0


def test_a_slow_telemetry_log_is_told_about_its_streams_not_only_the_sd_card_log(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A ground station's .tlog at 10 Hz is refused for its rate, as a .bin would be; but
    its rate is the telemetry streams' (SRn_EXTRA1 sends ATTITUDE, SRn_RC_CHAN
    SERVO_OUTPUT_RAW), which LOG_BITMASK does not touch: the advice named only LOG_BITMASK
    (found by ``bench_variety.py --seed 101`` once it drew .tlog layouts)."""
    from mavsid.synthetic.run import scenario_from_options, simulate

    path = tmp_path / "t10.tlog"
    simulate(scenario_from_options(manoeuvre="random", axis="roll", rate_hz=10.0, seed=515),
             [path])
    with pytest.raises(NoExcitationError) as err, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit([str(path)], PipelineConfig(axes=("roll",)))
    advice = err.value.details[-1]
    assert "roll: not identified: rates/outputs logged at 10 Hz" in err.value.details[0]
    assert "SRn_EXTRA1" in advice and "SRn_RC_CHAN" in advice
    assert "flight controller's own log" in advice and "LOG_BITMASK" in advice


@pytest.mark.slow
@pytest.mark.parametrize("manoeuvre", ["doublet", "3211"])
def test_a_light_racer_flown_with_its_own_tuning_is_identified_near_its_truth(
        tmp_path, manoeuvre: str) -> None:  # type: ignore[no-untyped-def]
    """Three times the default quad's authority, 10 ms motors, a 40 Hz gyro filter and rate
    gains a third of the default (its owner's tuning): none of the defaults was chosen on
    such a vehicle. Measured: B -0.5 / +0.0 %, damping -0.7 / +0.1 %, free run 97 %."""
    _, truth, result = _simulated(tmp_path, "racer.bin", manoeuvre=manoeuvre, axis="roll",
                                  vehicle="racer", gyro_noise_dps=1.0, seed=3)
    f = result.axes["roll"]
    assert truth["effectiveness"] == 540.0
    assert f.verdict is not None and f.verdict.level == "good", f.verdict
    b, se = f.model.params["B[p,u_roll]"], f.model.stderr["B[p,u_roll]"]
    assert abs(b / truth["effectiveness"] - 1) < B_TOLERANCE
    assert abs(b - truth["effectiveness"]) < 2.5 * se
    assert -f.model.params["A[p,p]"] == pytest.approx(truth["damping"], rel=DAMPING_TOLERANCE)
    assert f.closed_loop is not None and f.closed_loop.fit_percent > 90.0


@pytest.mark.slow
def test_a_feedback_biased_effectiveness_is_not_called_certain(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A chirp that stops at 3 Hz with 3 deg/s of gyro noise fed back (and 3x the default
    bias and gusts): the time-domain fit's effectiveness comes back 12 % low (the feedback's
    noise in the input) and was called `good` at 3.2 σ (B 158.7 ± 6.6, truth 180). The FRF
    against the injection, which that noise does not bias, puts B at 172: the spread
    between the two joins the σ (± 15.3), the truth 1.4 σ away."""
    _, truth, result = _simulated(tmp_path, "n3.bin", axis="roll", sid_axes=(10,),
                                  f_stop_hz=3.0, noise=3.0, seed=4)  # (3x noise, bias, gusts)
    f = result.axes["roll"]
    b, se = f.model.params["B[p,u_roll]"], f.model.stderr["B[p,u_roll]"]
    assert "frequency response against the injection" in str(
        dict(f.model.provenance)["stderr_includes"])
    assert abs(b - truth["effectiveness"]) < 2.5 * se


@pytest.mark.slow
@pytest.mark.parametrize("seed", [7, 8, 288])
def test_a_noisy_manual_flight_is_judged_by_the_pilots_command(tmp_path, seed: int) -> None:  # type: ignore[no-untyped-def]
    """A light racer flown by stick (3-2-1-1 in pitch) with 6 deg/s of gyro noise and 5 deg/s
    of vibration fed back, logged at 100 Hz. Its response sat at 4-4.5x the rate's noise
    floor, under the 5x gate, and every window was refused (seeds 7, 8) — while the rate
    was 0.93 coherent with the commanded pitch (ATT.DesPitch, from the sticks: the noise
    does not reach it). Windows coherent with the command are now kept, say why, and give
    B within 2.5 σ of the truth (measured 495.7 ± 26, 481.8 ± 22, 459.0 ± 21 against 500;
    seed 288, kept before on one window, was 439 ± 19 and called `good` at 3.2 σ); the
    commanded attitude also serves as instrument, its estimate in the σ."""
    _, truth, result = _simulated(tmp_path, "r.bin", "copter-3.3", manoeuvre="3211",
                                  axis="pitch", vehicle="racer", gyro_noise_dps=6.0,
                                  vibration_dps=5.0, rate_hz=100.0, seed=seed)
    f = result.axes["pitch"]
    assert any("coherent with the commanded attitude" in r for w in f.windows if w.kept
               for r in w.reasons)
    assert "commanded attitude as instrument" in str(dict(f.model.provenance)["stderr_includes"])
    b, se = f.model.params["B[q,u_pitch]"], f.model.stderr["B[q,u_pitch]"]
    assert abs(b - truth["effectiveness"]) < 2.5 * se


@pytest.mark.slow
@pytest.mark.parametrize(("layout", "seed"), [("px4-1.14", 288), ("px4-1.14", 7),
                                           ("px4-1.8", 8)])
def test_a_noisy_manual_px4_flight_is_judged_by_its_attitude_setpoint(
        tmp_path, layout: str, seed: int) -> None:  # type: ignore[no-untyped-def]
    """The same noisy racer's 3-2-1-1 logged by PX4, which publishes its commanded attitude
    as ``vehicle_attitude_setpoint.q_d`` (in the attitude-stabilised modes). Before the
    simulator wrote that topic, mavsid met these flights without a command: seed 288 came
    back B 438.8 ± 17.4 against 500, called `good` at 3.5 σ (the feedback's noise in the
    input), seeds 7 and 8 had every window refused below the noise floor. With the setpoint
    (measured: 460.4 ± 21.0, 469.1 ± 28.7; px4-1.8 seed 8 485.8 ± 25.4) the truth is within
    2.5 σ."""
    _, truth, result = _simulated(tmp_path, "r.ulg", layout, manoeuvre="3211",
                                  axis="pitch", vehicle="racer", gyro_noise_dps=6.0,
                                  vibration_dps=5.0, rate_hz=100.0, seed=seed)
    f = result.axes["pitch"]
    assert any("coherent with the commanded attitude" in r for w in f.windows if w.kept
               for r in w.reasons)
    b, se = f.model.params["B[q,u_pitch]"], f.model.stderr["B[q,u_pitch]"]
    assert abs(b - truth["effectiveness"]) < 2.5 * se


def test_px4s_attitude_setpoint_is_not_ramped_across_a_gap(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """PX4 publishes no attitude setpoint in ACRO (rates from the sticks): across such a gap
    the commanded attitude is unknown (NaN), not a line drawn from one side to the other;
    elsewhere it is the setpoint's roll (PX4's own ``roll_body``, px4-1.11 layout)."""
    from dataclasses import replace

    from mavsid.align.commanded import commanded_attitude
    from mavsid.data import MessageTable

    raw = _simulated_raw(tmp_path / "s.ulg", "px4-1.11", manoeuvre="doublet", axis="roll",
                         seed=3)
    sp = raw["vehicle_attitude_setpoint"]
    t0, t1 = float(sp.time_s[0]), float(sp.time_s[-1])
    cut = (sp.time_s > t0 + 0.4 * (t1 - t0)) & (sp.time_s < t0 + 0.6 * (t1 - t0))
    keep = ~cut
    table = MessageTable(sp.name, {k: np.asarray(v)[keep] for k, v in sp.columns.items()},
                         sp.time_s[keep], sp.units)
    raw = replace(raw, messages={**raw.messages, sp.name: table})
    t = np.linspace(t0, t1, 4001)
    cmd = commanded_attitude(raw, t)[0]["roll"]
    lo, hi = sp.time_s[cut][[0, -1]]
    # (within three of its intervals of a sample it is interpolated: 0.1 s is more)
    assert np.isnan(cmd[(t > lo + 0.1) & (t < hi - 0.1)]).all()
    outside = (t < lo - 0.1) | (t > hi + 0.1)
    assert np.isfinite(cmd[outside]).all()
    ref = np.interp(t[outside], table.time_s, np.asarray(table["roll_body"], float))
    np.testing.assert_allclose(cmd[outside], ref, atol=1e-5)
    assert np.ptp(ref) > 0.05  # (the doublet moves it)


def test_a_second_estimate_that_differs_is_said_in_the_verdict() -> None:
    """When the instrument (or an injection's frequency response) puts the effectiveness
    5 % or more away, the verdict says so and that the σ include it."""
    from types import SimpleNamespace as NS

    from mavsid.verdict import judge

    val = NS(state_names=("p",), fit_free_run=np.array([85.0]), fit_vs_horizon=None,
             fit_one_step=np.array([95.0]), fit_at=lambda s: np.array([90.0]), stable=True,
             eigenvalues=np.array([0.99]), dt=0.0025, residuals=None)
    said = []
    for other in (182.0, 195.0):
        model = NS(params={"A[p,p]": -4.0, "B[p,u_roll]": 180.0, "c[p]": 0.0},
                   stderr={"A[p,p]": 0.2, "B[p,u_roll]": 9.0, "c[p]": 0.01},
                   provenance={"other_estimate": {"by": "the instrument",
                                                  "params": {"B[p,u_roll]": other}}})
        said.append([r for r in judge("roll", val, "p", model=model).reasons
                     if "the instrument" in r])
    assert said[0] == []
    assert said[1] == ["B[p,u_roll] 195 by the instrument against 180 (+8 %): its σ include "
                       "the difference"]


@pytest.mark.slow
@pytest.mark.parametrize(("manoeuvre", "vehicle", "axis", "seed"),
                         [("doublet", "quad", "roll", 2), ("random", "hexa", "pitch", 3),
                          ("3211", "heavy-x", "roll", 4)])
def test_the_commanded_attitude_agrees_where_the_fit_is_not_biased(
        tmp_path, manoeuvre: str, vehicle: str, axis: str, seed: int) -> None:  # type: ignore[no-untyped-def]
    """Stick manoeuvres on other vehicles, little or no noise at 200 Hz: the instrument
    estimate is made and agrees with the fit (measured within 0.5 %), so it widens no σ
    there (no false alarm)."""
    _, _, result = _simulated(tmp_path, "s.bin", "copter-3.3", manoeuvre=manoeuvre,
                              axis=axis, vehicle=vehicle, gyro_noise_dps=1.0, rate_hz=200.0,
                              seed=seed)
    m = result.axes[axis].model
    key = f"B[{'p' if axis == 'roll' else 'q'},u_{axis}]"
    other = dict(m.provenance)["other_estimate"]["params"][key]  # type: ignore[index]
    assert other == pytest.approx(m.params[key], rel=0.02)


def test_a_slow_logs_sub_sample_lags_widen_the_sigma(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A plane (30 ms servo lag, 5 ms delay) logged at 25 Hz: a lag under one 40-ms sample
    is not told from a fraction of a sample of delay, and the search came back with no lag
    and half a sample of delay, B 80.4 ± 1.6 against 90 (6 σ; at 50 and 100 Hz the 30-ms lag
    is found, B 89.3). The fits at the other sub-sample lags now join the σ (± 5.1, 1.9 σ);
    the verdict says the log is too slow for `good`."""
    _, truth, result = _simulated(tmp_path, "p25.bin", "plane", manoeuvre="random",
                                  vehicle="plane", axis="roll", rate_hz=25.0, seed=415)
    f = result.axes["roll"]
    b, se = f.model.params["B[p,u_roll]"], f.model.stderr["B[p,u_roll]"]
    assert "cannot tell apart" in str(dict(f.model.provenance)["stderr_includes"])
    assert abs(b - truth["effectiveness"]) < 2.5 * se
    assert f.verdict is not None and f.verdict.level == "usable"


def test_a_yaw_chirp_whose_trim_moves_is_not_refused(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A heavy X quad's yaw SYSTEMID chirp (pole 0.8 1/s: nearly an integrator): the model's
    B is within 0.1 σ of the truth, but the held-out half of the chirp holds another trim,
    and with the training half's the free run drifted to -34 %; the axis was refused as "the
    model does not predict this axis". Each held-out window now runs with its own trim
    (mavsid.validation.segment_trim). Since chirps are cut into interleaved blocks, training
    and validation hold the same trims (free run 87 % with either, measured), so the test
    keeps what matters: not refused, B within its σ."""
    _, truth, result = _simulated(tmp_path, "yaw.bin", "copter-3.4-dev", manoeuvre="sysid",
                                  axis="yaw", vehicle="heavy-x", vibration_dps=2.0,
                                  rate_hz=100.0, seed=250, f_stop_hz=15.0, sid_axes=(12,))
    f = result.axes["yaw"]
    assert f.model is not None and f.verdict is not None
    assert f.verdict.level != "not identified", f.verdict.reasons
    b, se = f.model.params["B[r,u_yaw]"], f.model.stderr["B[r,u_yaw]"]
    assert abs(b - truth["effectiveness"]) <= 2.5 * se
    assert f.validation.fit_summary("r")["free_run"] > 80.0


@pytest.mark.slow
@pytest.mark.parametrize(("frame", "axis"), [("hexa-x", "pitch"), ("y6b", "roll"),
                                             # B 13.40 ± 0.16 against 14 (3.6 σ, 4.3 %)
                                             # since the interleaved split
                                             pytest.param("octaquad-x", "yaw",
                                                          marks=_INTERLEAVED)])
def test_telemetry_of_other_frames_is_unmixed_as_ardupilot_mixes_them(
        tmp_path, frame: str, axis: str) -> None:  # type: ignore[no-untyped-def]
    """A .tlog holds only the motors' PWM (SERVO_OUTPUT_RAW): the inputs come from
    inverting the frame's mixer. A hexa-X's pitch was unmixed with its factors scaled as
    roll's (B 101 for a truth of 120, 10 σ off, called `usable`); a coaxial Y6 or X8
    (FRAME_CLASS 5, 4) had no mixer at all (no inputs). Measured: B within 2.5 % of the
    truth on each, within 2 σ."""
    _, truth, result = _simulated(tmp_path, f"{frame}.tlog", manoeuvre="sysid", axis=axis,
                                  vehicle="hexa", frame=frame, seed=3)
    f = result.axes[axis]
    rate = {"roll": "p", "pitch": "q", "yaw": "r"}[axis]
    assert f.model is not None and f.verdict is not None and f.verdict.level != "not identified"
    b, se = f.model.params[f"B[{rate},u_{axis}]"], f.model.stderr[f"B[{rate},u_{axis}]"]
    assert abs(b / truth["effectiveness"] - 1) < B_TOLERANCE
    assert abs(b - truth["effectiveness"]) < 2.5 * se


@pytest.mark.slow
def test_a_quadplanes_vtol_flight_is_fitted_with_its_vtol_controller(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """An ArduPlane QuadPlane hovering (QSTABILIZE, a pilot's 3-2-1-1 on roll): its VTOL
    rate controller logs PIQR/PIQP/PIQY (rad/s; P+I+D+FF is the motor mixer's input), the
    fixed-wing PIDR/PIDP/PIDY idle. The fixed-wing preset was the only one for an ArduPlane
    log: every axis `not identified`. Now the VTOL preset is chosen (said), the model is
    near the truth and the closed-loop twin runs the Q_A_RAT_* controller. Measured: B -1.2 %,
    damping -2.3 %, twin 96 %."""
    from mavsid.loop.controllers import controller_from_params, gain_params

    with pytest.warns(Warning, match="a QuadPlane, its VTOL controllers flying 100 %.*"
                      "preset ardupilot-quadplane fitted; --preset ardupilot-plane-pid"):
        path, truth, result = _simulated_warned(
            tmp_path, "qp.bin", "quadplane", manoeuvre="3211", axis="roll", vehicle="hexa",
            frame="hexa-x", gyro_noise_dps=2.0, seed=6)
    f = result.axes["roll"]
    assert result.flights[0].preset == "ardupilot-quadplane"
    assert f.model is not None and f.verdict is not None and f.verdict.level == "good"
    b, se = f.model.params["B[p,u_roll]"], f.model.stderr["B[p,u_roll]"]
    assert abs(b / truth["effectiveness"] - 1) < B_TOLERANCE
    assert abs(b - truth["effectiveness"]) < 2.5 * se
    assert -f.model.params["A[p,p]"] == pytest.approx(truth["damping"], rel=DAMPING_TOLERANCE)
    assert f.closed_loop is not None and f.closed_loop.fit_percent > 90.0
    ctrl = controller_from_params(result.flights[0].params, "roll", "ardupilot")
    assert set(gain_params(ctrl)) == {"Q_A_RAT_RLL_P", "Q_A_RAT_RLL_I", "Q_A_RAT_RLL_D"}
    # an axis not flown: the advice is for a QuadPlane's VTOL modes
    with warnings.catch_warnings(), pytest.raises(NoExcitationError) as err:
        warnings.simplefilter("ignore")
        fit([str(path)], PipelineConfig(axes=("pitch",)))
    assert "on pitch in QACRO or QSTABILIZE" in " ".join(err.value.details)


def test_a_quadplane_flying_mostly_as_a_wing_is_fitted_as_one(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """When the VTOL controllers flew less than half of the attitude records, the fixed-wing
    preset is chosen, and the warning names the other."""
    from mavsid.align import align

    raw = _simulated_raw(tmp_path / "qp.bin", "quadplane", manoeuvre="doublet", axis="roll",
                         seed=2)
    piqr = raw.messages["PIQR"]
    cut = len(piqr) // 3
    short = dataclasses.replace(piqr, columns={k: v[:cut] for k, v in piqr.columns.items()},
                                time_s=piqr.time_s[:cut])
    raw = dataclasses.replace(raw, messages={**raw.messages, "PIQR": short})
    with pytest.warns(Warning, match=r"flying 33 % .*preset ardupilot-plane-pid fitted; "
                      r"--preset ardupilot-quadplane fits the VTOL flight"):
        fd = align(raw)
    assert fd.preset == "ardupilot-plane-pid"


def _simulated_warned(tmp_path, name: str, layout: str | None = None, **options):  # type: ignore[no-untyped-def]
    """:func:`_simulated` letting the fit's warnings through (``pytest.warns`` sees them)."""
    from mavsid.synthetic.run import scenario_from_options, simulate

    path = tmp_path / name
    simulate(scenario_from_options(**options), [path], layout=layout)
    axis = options.get("axis", "roll")
    truth = json.loads(path.with_suffix(".truth.json").read_text())["axes"][axis]
    return path, truth, fit([str(path)], PipelineConfig(axes=(axis,)))


def _simulated_raw(path, layout: str | None, **options):  # type: ignore[no-untyped-def]
    """The log simulated from ``options`` in ``layout`` at ``path``, read (warnings muted)."""
    from mavsid.readers import read_log
    from mavsid.synthetic.run import scenario_from_options, simulate

    simulate(scenario_from_options(**options), [path], layout=layout)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_log(path)


@pytest.mark.slow
def test_a_tlog_without_frame_parameters_is_not_unmixed_as_a_quad_when_it_is_not_one(
        tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A .tlog whose ground station fetched no parameters holds no FRAME_CLASS: a quad-X was
    assumed, and a hexa's first four motors unmixed as a quad's gave a wrong model. Outputs
    beyond the fourth that move (motors, or a quad's servos: they cannot be told apart) now
    stop the guess; a quad with idle outputs 5-8 is still unmixed as one."""
    from mavsid.align import align

    for frame, vehicle, unmixed in (("hexa-x", "hexa", False), ("quad-x", "quad", True)):
        raw = _simulated_raw(tmp_path / f"{frame}.tlog", None, manoeuvre="doublet",
                             axis="pitch", vehicle=vehicle, frame=frame, seed=1)
        raw = dataclasses.replace(raw, params={})
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            fd = align(raw)
        assert bool(fd.input_names) is unmixed
        said = [str(w.message) for w in caught if "cannot be told from a quad" in str(w.message)]
        assert bool(said) is not unmixed and (unmixed or "output(s) 5, 6" in said[0])


@pytest.mark.slow
def test_a_toml_mixer_of_raw_factors_unmixes_a_frame_the_log_does_not_name(
        tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A Y6B's .tlog whose ground station fetched no parameters: no inputs (its outputs 5-6
    move). A TOML file with the frame's motor matrix, as ArduPilot's ``add_motor_raw`` gives
    it (raw roll and pitch factors; a TOML mixer took only ``angle_deg`` before), and a
    preset naming it: the inputs are the ones the frame's parameters give, and the model's
    B is near the truth."""
    from mavsid.align import align
    from mavsid.autopilot.config import load_presets

    raw = _simulated_raw(tmp_path / "y6b.tlog", None, manoeuvre="sysid", axis="roll",
                         vehicle="hexa", frame="y6b", seed=3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        named = align(raw)  # FRAME_CLASS 5, FRAME_TYPE 10: the built-in Y6B
        bare = dataclasses.replace(raw, params={})
        assert not align(bare).input_names
    toml = tmp_path / "y6.toml"
    toml.write_text(
        '[mixer.my-y6b]\n'
        'roll = [-1, -1, 0, 0, 1, 1]\npitch = [0.5, 0.5, -1, -1, 0.5, 0.5]\n'
        'yaw = [-1, 1, -1, 1, -1, 1]\n'
        '[preset.my-tlog]\nformats = ["tlog"]\nmixer = "my-y6b"\n'
        'motors = { message = "SERVO_OUTPUT_RAW", field = "servo{i}_raw", unit = "pwm" }\n'
        '[preset.my-tlog.states]\n'
        + "".join(f'{s} = {{ message = "ATTITUDE", field = "{f}", unit = "{u}" }}\n'
                  for s, f, u in (("roll", "roll", "rad"), ("pitch", "pitch", "rad"),
                                  ("yaw", "yaw", "rad"), ("p", "rollspeed", "rad/s"),
                                  ("q", "pitchspeed", "rad/s"), ("r", "yawspeed", "rad/s"))),
        encoding="utf-8")
    presets, mixers = load_presets(toml)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mine = align(bare, presets=presets, mixers=mixers)
    assert mine.preset == "my-tlog" and mine.input_names == named.input_names
    assert np.allclose(mine.inputs, named.inputs, equal_nan=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = fit([str(tmp_path / "y6b.tlog")], PipelineConfig(
            axes=("roll",), presets=presets, mixers=mixers, preset="my-tlog"))
    truth = json.loads((tmp_path / "y6b.truth.json").read_text())["axes"]["roll"]
    f = result.axes["roll"]
    assert f.model is not None
    b, se = f.model.params["B[p,u_roll]"], f.model.stderr["B[p,u_roll]"]
    assert abs(b / truth["effectiveness"] - 1) < B_TOLERANCE
    assert abs(b - truth["effectiveness"]) < 2.5 * se


def test_a_heavy_lift_frames_slow_motors_are_searched_for(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """Motors with a 120-ms time constant (large propellers) lie beyond the default lags
    (up to 60 ms): the search took the longest with a long delay, and a stick doublet gave
    B 20 % low at 4.3 σ and damping a fifth of the truth, called `good`. When the longest
    default lag scores best, longer ones (to 170 ms) are searched too. Measured: B +3.7 %
    (0.2 σ), damping +11 %."""
    _, truth, result = _simulated(tmp_path, "lift.bin", manoeuvre="doublet", axis="roll",
                                  vehicle="heavy-lift", seed=5)
    f = result.axes["roll"]
    assert truth["motor_tau_s"] == 0.12 and f.model is not None
    b, se = f.model.params["B[p,u_roll]"], f.model.stderr["B[p,u_roll]"]
    assert abs(b / truth["effectiveness"] - 1) < 2 * B_TOLERANCE
    assert abs(b - truth["effectiveness"]) < 2.5 * se
    assert -f.model.params["A[p,p]"] == pytest.approx(truth["damping"], rel=0.3)


_STIRRED = [(axis, layout, manoeuvre, rate)
            for layout in (None, "copter-3.3", "px4-1.14") for manoeuvre in ("random", "3211")
            for axis, rate in (("yaw", 400.0),)] + [
    ("pitch", None, "random", 25.0), ("roll", "px4-1.11", "random", 25.0),
    ("roll", "tlog", "random", 50.0), ("yaw", "tlog", "3211", 50.0)]


@pytest.mark.slow
@pytest.mark.parametrize(("axis", "layout", "manoeuvre", "rate_hz"), _STIRRED)
def test_a_pilot_who_never_lets_go_of_the_stick_is_fitted(  # type: ignore[no-untyped-def]
        tmp_path, axis: str, layout: str | None, manoeuvre: str, rate_hz: float) -> None:
    """Manual flying without a hover (the stick never left centred for long) leaves no quiet
    stretch: the response's noise floor and the input's, measured where the input is
    quietest, are then the manoeuvre itself. Every yaw window sat under 5x its response
    floor ("nothing identifiable"; roll and pitch were kept by their coherence with the
    commanded attitude), and a 25 Hz random stick's input covered 0 % of the band above
    its floor. The commanded heading's rate (ATT.DesYaw, PX4's attitude setpoint) is the
    pilot's yaw command; a response coherent with the command over the band is kept
    whatever those floors say, and the command is the instrument that checks the
    feedback's bias. A .tlog carries no command: its sticks stand in (RC_CHANNELS; its
    windows were all refused below the floors before)."""
    from mavsid.synthetic.run import scenario_from_options, simulate

    sc = dataclasses.replace(scenario_from_options(manoeuvre=manoeuvre, axis=axis, seed=7,
                                                   duration_s=30.0, rate_hz=rate_hz),
                             hover_before_s=0.0, hover_after_s=0.0)
    path = tmp_path / ("stir.ulg" if layout and layout.startswith("px4")
                       else "stir.tlog" if layout == "tlog" else "stir.bin")
    simulate(sc, [path], layout=None if layout == "tlog" else layout)
    truth = json.loads(path.with_suffix(".truth.json").read_text())["axes"][axis]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = fit([str(path)], PipelineConfig(axes=(axis,)))
    f = result.axes[axis]
    assert f.model is not None and f.verdict is not None
    assert f.verdict.level in ("good", "usable")
    key = f"B[{f.output},u_{axis}]"
    b, se = f.model.params[key], f.model.stderr[key]
    assert abs(b / truth["effectiveness"] - 1) < B_TOLERANCE
    assert abs(b - truth["effectiveness"]) < 2.5 * se
    by = f.model.provenance["other_estimate"]["by"]
    assert "commanded" in by and (layout != "tlog" or "the pilot's sticks" in by), by
    what = "yaw rate" if axis == "yaw" else "attitude"
    kept = [r for w in f.windows if w.kept for r in w.reasons]
    assert any(f"coherent with the commanded {what}" in r for r in kept), kept


@pytest.mark.slow
@pytest.mark.parametrize(("layout", "name"), [(None, "yaw.bin"), ("px4-1.14", "yaw.ulg")])
def test_the_commanded_yaw_is_the_rate_of_the_commanded_heading(tmp_path, layout: str | None,  # type: ignore[no-untyped-def]
                                                                name: str) -> None:
    """Alignment's commanded yaw (``FlightData.commanded["yaw"]``, rad/s) follows the
    simulator's own heading target's rate, across the heading's wrap at 360 deg."""
    from mavsid.align import load_flight
    from mavsid.synthetic.run import scenario_from_options, simulate

    sc = scenario_from_options(manoeuvre="random", axis="yaw", seed=3, duration_s=30.0)
    path = tmp_path / name
    flight = simulate(sc, [path], layout=layout).flight
    target = np.unwrap(flight.attitude_target[:, 2])
    assert np.ptp(np.mod(flight.attitude_target[:, 2], 2 * np.pi)) > 6  # it wraps
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fd = load_flight(str(path))
    got = fd.commanded["yaw"]
    # (ATT is logged at 10 Hz in ArduCopter's default layout: its rate is the heading's
    # central differences over ±0.1 s, which scale a 1-Hz rate by sin(ωh)/(ωh) ≈ 0.9; the
    # reference is the simulator's heading target differenced at the same instants)
    from mavsid.readers import read_log

    message = fd.commanded_from["yaw"].split(".")[0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ts = read_log(path)[message].time_s
    heading = np.interp(ts, flight.t_s, target)
    want = np.interp(fd.time_s, ts, np.gradient(heading, ts))
    ok = np.isfinite(got)
    assert ok.mean() > 0.9
    assert np.corrcoef(got[ok], want[ok])[0, 1] > 0.999
    assert float(got[ok] @ want[ok] / (want[ok] @ want[ok])) == pytest.approx(1.0, abs=1e-3)


#: (fixture, axis) of the simulated airframes whose plant passes its gates (verdict good)
#: and the phase margin aimed at: 50 deg (on these airframes the gain-margin and Ms limits
#: or the cap hold the gains before it), 80 deg (reached: the target binds)
TUNED = [(n, a, 50.0) for n, a in (
    ("noisy_sysid.bin", "roll"), ("noisy_sysid.bin", "pitch"), ("heavy_sysid.bin", "pitch"),
    ("hexa_doublets.bin", "pitch"), ("sysid_roll.bin", "roll"), ("sysid_pitch.bin", "pitch"),
    ("sysid_yaw.bin", "yaw"), ("doublets.bin", "roll"))] + [
    ("sysid_roll.bin", "roll", 80.0), ("noisy_sysid.bin", "pitch", 80.0)]


@pytest.mark.slow
@pytest.mark.parametrize(("name", "axis", "target"), TUNED,
                         ids=[f"{n}-{a}-{t:g}" for n, a, t in TUNED])
def test_tune_suggestions_are_capped_meet_their_limits_and_fly_as_promised(
        name: str, axis: str, target: float) -> None:
    """Every simulated airframe: a suggestion within the per-flight cap (or saying it is
    capped), meeting every limit it prints, flown in the twin as predicted, and flown in
    the simulator — its own controller, the vehicle's true plant — at the phase margin
    promised within ±3 deg (the target's, unless the cap or another limit holds it)."""
    from loop_plants import fly_rate_loop

    from mavsid.loop.tune import tune

    e = tune(_fit(name), target, samples=0)[axis]
    assert e["verdict"] == "good"
    if not e["gains"]:
        assert e["no_gains_reason"] and "\n" not in e["no_gains_reason"]
        return
    for g in e["gains"]:
        assert 0.5 - 1e-3 <= g["ratio"] <= 2.0 + 1e-3
        assert g["capped"] == (not 0.5 <= e["wanted_ratio"] <= 2.0)
    assert all(r["ok"] for r in e["limits"])
    assert e["twin_step"]["agree"]
    promised = e["suggested_loop_check"]["phase_margin_deg"]
    if not e["capped"] and "limited_by" not in e:
        assert promised == pytest.approx(target, abs=0.1)
    else:
        assert target == 50.0  # (80 deg: the target itself sets the gains)
    gains = {g["name"]: g["suggested"] for g in e["gains"]}
    flown = fly_rate_loop(_truth(name), axis, gains)["phase_deg"]
    assert flown == pytest.approx(promised, abs=3.0)
