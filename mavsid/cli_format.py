"""What the ``mavsid`` command line prints: the text of the loop commands (``mavsid tune``,
the report's loop section, ``mavsid response``, made from the data
:func:`mavsid.loop.tune.tune` and :func:`mavsid.response.read_response` return), a fit's
result (:func:`format_result`; a validation's lines, :func:`validate_line`) and the files
written, warnings, the progress bar, the one JSON document of a
failed ``--json`` command, and the lines of ``segments``, ``batch``, ``simulate`` and
``--version``."""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import TYPE_CHECKING, Any

from mavsid.errors import MavsidError, MavsidWarning, escape, escape_lines

if TYPE_CHECKING:
    from mavsid.data import FlightData
    from mavsid.loop.emulation import ControllerEmulation
    from mavsid.pipeline_results import AxisFit, FitResult
    from mavsid.response import FlightResponse, LoopResponse
    from mavsid.verdict import Verdict

__all__ = ["change_line", "error_document", "figure", "flight_line", "format_loop",
           "format_responses", "format_result", "format_tune", "gain_table", "limit_table",
           "print_error", "print_result", "progress", "readers_build", "simulate_command",
           "stages", "tune_notes", "validate_line", "validation_figures", "value_text",
           "warning_text"]


def figure(v: float | None, fmt: str, unit: str, sd: float | None = None) -> str:
    """A loop figure as ``mavsid tune`` prints it, with its σ; ``none`` where it does not
    exist (a loop whose gain never crosses 1 has no phase margin nor crossover; an unstable
    one no rise time).

    Examples
    --------
    >>> figure(34.12, ".1f", "deg", 1.5), figure(float("inf"), ".1f", "deg", 1.5)
    ('34.1 ± 1.5 deg', 'none')
    """
    if v is None or not math.isfinite(v):
        return "none"
    return f"{v:{fmt}}" + (f" ± {sd:{fmt}}" if sd is not None and math.isfinite(sd)
                           else "") + f" {unit}"


def value_text(v: float | bool | None, unit: str = "", digits: int = 3) -> str:
    """A limit's or gain's value to ``digits`` significant digits; ``–`` where there is none.

    Examples
    --------
    >>> value_text(45.8514, "deg"), value_text(None), value_text(True), value_text(0.04)
    ('45.9 deg', '–', 'yes', '0.04')
    """
    if isinstance(v, bool):
        return "yes" if v else "no"
    if v is None:
        return "–"
    if not math.isfinite(v):
        return "none"
    return f"{v:.{digits}g}" + (f" {unit}" if unit else "")


def gain_table(gains: Sequence[Mapping[str, Any]]) -> list[list[str]]:
    """Rows ``parameter, current, suggested, ratio`` of a suggestion (header first).

    >>> gain_table([{"name": "ATC_RAT_YAW_P", "current": 0.3, "suggested": 0.6,
    ...              "ratio": 2.0, "capped": True}])[1]
    ['ATC_RAT_YAW_P', '0.3', '0.6', '×2.00 (capped)']
    """
    rows = [["parameter", "current", "suggested", "ratio"]]
    for g in gains:
        rows.append([g["name"], f"{g['current']:.4g}", f"{g['suggested']:.4g}",
                     f"×{g['ratio']:.2f}" + (" (capped)" if g.get("capped") else "")])
    return rows


def limit_table(limits: Sequence[Mapping[str, Any]]) -> list[list[str]]:
    """Rows ``limit, required, current gains, suggested gains, met`` (header first)."""
    rows = [["limit", "required", "current", "suggested", "met"]]
    for r in limits:
        unit = r.get("unit", "")
        rows.append([r["name"], r["limit"], value_text(r["current"], unit),
                     value_text(r["suggested"], unit),
                     "yes" if r["ok"] else "no"])
    return rows


def _columns(rows: Sequence[Sequence[str]], indent: str = "  ") -> list[str]:
    """Rows as left-aligned text columns."""
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return [indent + "  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip()
            for r in rows]


def _answer(axis: str, e: Mapping[str, Any]) -> list[str]:
    """The first lines of an axis: verdict, then the gains (or why none), the limits, the
    margins the suggestion is about and the step response, the next flight."""
    verdict = e.get("verdict", "not identified")
    lines = []
    if e.get("gains"):
        capped = any(g.get("capped") for g in e["gains"])
        lines.append(f"{axis}: verdict {verdict}; suggested gains"
                     + (f" (capped: the loop wants ×{e['wanted_ratio']:.2g})" if capped else ""))
        lines += _columns(gain_table(e["gains"]))
        if e.get("suggested_note"):
            lines.append(f"  {e['suggested_note']}")
    else:
        lines.append(f"{axis}: verdict {verdict}; no gains: "
                     f"{e.get('no_gains_reason', 'none suggested')}")
    if e.get("limits"):
        lines += _columns(limit_table(e["limits"]))
    agree = e.get("loop_agreement")
    if agree:
        meas = figure(agree["measured_deg"], ".0f", "deg", agree["measured_sigma_deg"])
        pred = figure(agree["predicted_deg"], ".0f", "deg", agree["predicted_sigma_deg"])
        lines.append(f"  the margins are those of {e.get('aim', 'the rate loop')}")
        lines.append(f"  beside it, at the mixer (rate and attitude loops): phase margin "
                     f"measured {meas}, predicted {pred}"
                     + ("" if agree["agree"] else " (they disagree)"))
    elif e.get("aim"):
        lines.append(f"  the margins are those of {e['aim']}")
    for key, label in (("current_loop", "current"), ("suggested_loop_check", "suggested")):
        c = e.get(key)
        if c:
            lines.append(
                f"  step ({label} gains): rise {figure(c['rise_time_s'] * 1e3, '.0f', 'ms')}, "
                f"settling {figure(c['settling_time_s'] * 1e3, '.0f', 'ms')}, overshoot "
                f"{figure(c['overshoot_percent'], '.0f', '%')}")
    return lines + [f"  {n}" for n in tune_notes(e)]


def tune_notes(e: Mapping[str, Any]) -> list[str]:
    """An axis's last sentences (of ``mavsid tune`` and of the report): the suggested gains
    flown in the closed-loop twin, and what to change next flight.

    Examples
    --------
    >>> for n in tune_notes({"gains": [{}], "twin_step": {"max_difference": 0.031},
    ...                      "next_flight": "a longer chirp"}):
    ...     print(n)
    flown in the closed-loop twin: step within 3.1% of the predicted one
    next flight: a longer chirp
    """
    notes = []
    twin = e.get("twin_step")
    if twin and e.get("gains"):
        notes.append(f"flown in the closed-loop twin: step within {twin['max_difference']:.1%} "
                     "of the predicted one")
    if e.get("next_flight"):
        notes.append(f"next flight: {e['next_flight']}")
    return notes


def format_tune(report: Mapping[str, Any], answer: bool = True) -> str:
    """The text ``mavsid tune`` prints: per axis the answer first (:func:`_answer`; left
    out with ``answer=False``, as the report shows it as tables), then the loop with the
    logged gains, the measured loop and the advice."""
    lines = []
    for axis, e in report.items():
        if "error" in e:
            lines.append(f"{axis}: loop not analysed: {e['error']}")
            continue
        if answer:
            lines += _answer(axis, e)
        m, c, sd = e["margins"], e["closed_loop"], e.get("stderr", {})

        def pm(v: float, key: str, fmt: str, unit: str,
               sd: Mapping[str, float] = sd) -> str:
            return figure(v, fmt, unit, sd.get(key))

        lines.append(
            f"  logged gains: phase margin {pm(m['phase_deg'], 'phase_margin_deg', '.1f', 'deg')}, "
            f"gain margin {pm(m['gain_db'], 'gain_margin_db', '.1f', 'dB')}, crossover "
            f"{pm(m['crossover_hz'], 'crossover_hz', '.2f', 'Hz')}; closed-loop bandwidth "
            f"{pm(c['bandwidth_hz'], 'bandwidth_hz', '.2f', 'Hz')}, peak "
            f"{figure(c['peak_db'], '.1f', 'dB')}, rise "
            f"{figure(c['rise_time_s'] * 1e3, '.0f', 'ms')}, overshoot "
            f"{figure(c['overshoot_percent'], '.0f', '%')}")
        if "loop_frf_margins" in e:
            mm, pr = e["loop_frf_margins"], e["loop_predicted_margins"]
            cmp_ = e["loop_frf_vs_predicted"]
            lines.append(
                f"  at the mixer (rate and attitude loops): measured phase margin "
                f"{figure(mm['phase_deg'], '.1f', 'deg')} at "
                f"{figure(mm['crossover_hz'], '.2f', 'Hz')}, predicted "
                f"{figure(pr['phase_deg'], '.1f', 'deg')} at "
                f"{figure(pr['crossover_hz'], '.2f', 'Hz')}; prediction within "
                f"{cmp_['median_db']:.1f} dB / {cmp_['median_deg']:.1f} deg (median) over "
                f"{cmp_['band_hz'][0]:.2g}-{cmp_['band_hz'][1]:.2g} Hz")
        if e.get("gains_mismatch"):
            lines.append(f"  warning: {e['gains_mismatch']}")
        lines += [f"  advice: {a}" for a in e.get("advice", [])]
    return "\n".join(lines)


def format_loop(r: LoopResponse) -> str:
    """One loop's line: metrics in degrees, or the verdict alone."""
    import numpy as np

    head = f"  {r.axis} {r.loop}"
    if r.target:
        head += f" ({r.target} -> {r.actual}, {r.rate_hz:.3g} Hz)"
    if r.step is None:
        extra = ""
        if r.tracking_rms is not None:
            unit = "deg/s" if r.loop == "rate" else "deg"
            extra = f"; tracking RMS {math.degrees(r.tracking_rms):.3g} {unit}"
        return f"{head}: {r.verdict}{extra}"

    def num(v: float | None, fmt: str, unit: str, scale: float = 1.0) -> str:
        return "-" if v is None else f"{v * scale:{fmt}} {unit}"

    unit = "deg/s" if r.loop == "rate" else "deg"
    lo, hi = r.step.lower, r.step.upper
    parts = [
        f"rise {num(r.rise_s, '.3g', 'ms', 1e3)}",
        f"overshoot {num(r.overshoot_pct, '.3g', '%')}",
        f"settling {num(r.settling_s, '.3g', 'ms', 1e3)}",
        f"bandwidth {num(r.bandwidth_hz, '.3g', 'Hz')}"
        + (f" (phase delay {r.phase_delay_s * 1e3:.3g} ms)" if r.phase_delay_s is not None
           else ""),
        f"tracking RMS {math.degrees(r.tracking_rms or 0.0):.3g} {unit}",
        f"delay {num(r.delay_s, '.3g', 'ms', 1e3)}" if r.delay_s is not None or not r.delay_note
        else f"delay not found ({r.delay_note})",
        f"band ±{float(np.median(hi - lo) / 2):.2g} (median)",
    ]
    return f"{head}: " + ", ".join(parts) + f"\n    {r.verdict}; {r.step.method}"


def format_responses(found: Sequence[FlightResponse]) -> str:
    """``mavsid response``'s text: per log its loops, spectra's filters and settings; with
    several logs, the loops side by side."""
    import numpy as np

    lines = []
    for fr in found:
        lines.append(f"{fr.log}: {fr.autopilot}, preset {fr.preset}")
        lines += [format_loop(r) for r in fr.loops]
        for axis, spectra in fr.spectra.items():
            for sp in spectra:
                if sp.freq_hz.size > 2:
                    k = int(np.argmax(sp.psd[1:])) + 1
                    cuts = ", ".join(f"{n} {v:g} Hz" for n, v in sp.cutoffs.items()) or "none"
                    lines.append(f"  {axis} {sp.name} spectrum: peak at {sp.freq_hz[k]:.3g} Hz; "
                                 f"filters {cuts}")
                    break
        for i, st in enumerate(fr.settings):
            changed = ", ".join(f"{k}={v:g}" for k, v in st.changed.items()) or "as logged first"
            lines.append(f"  setting {i + 1} ({st.start_s:.1f}-{st.stop_s:.1f} s, {changed}):")
            lines += ["  " + format_loop(r) for r in st.loops]
        lines += [f"  note: {n}" for n in fr.notes]
    if len(found) > 1:
        lines.append("compared (rise ms / overshoot % / bandwidth Hz per log):")
        keys = dict.fromkeys((r.axis, r.loop) for fr in found for r in fr.loops)
        for axis, loop in keys:
            cells = []
            for fr in found:
                r = fr.loop(axis, loop)
                if r is None or r.step is None:
                    cells.append("-")
                    continue
                got = [(r.rise_s, 1e3), (r.overshoot_pct, 1.0), (r.bandwidth_hz, 1.0)]
                cells.append(" / ".join("-" if v is None else f"{v * k:.3g}" for v, k in got))
            lines.append(f"  {axis} {loop}: " + " | ".join(cells))
    return "\n".join(lines)


# --------------------------------------------------------------------------- the commands' lines


def warning_text(message: Warning | str) -> str:
    """A mavsid warning's one line.

    >>> warning_text(MavsidWarning("a.bin: 3 bytes skipped"))
    'warning: a.bin: 3 bytes skipped'
    """
    return f"warning: {escape(message)}"


@contextlib.contextmanager
def progress(args: argparse.Namespace, total: float) -> Iterator[Callable[..., None]]:
    """A progress bar on stderr over ``total`` units of work, the current stage named;
    nothing when stderr is not a terminal or with ``--quiet``. Yields the callable the
    pipeline calls, ``step(stage, weight=1)`` as a stage starts (the one before it is then
    done). While the bar is shown a warning is written above it (``tqdm.write``), the bar
    drawn again below: printed into it, it left a stale line on screen."""
    if getattr(args, "quiet", False) or not sys.stderr.isatty():
        yield lambda stage, weight=1: None
        return
    from tqdm import tqdm

    bar = tqdm(total=total, file=sys.stderr, dynamic_ncols=True, leave=False,
               mininterval=0, miniters=1,  # a few stages: show each as it starts
               smoothing=0,  # (the ETA from the whole run's rate: stages differ in length)
               bar_format="{l_bar}{bar}| [{elapsed}<{remaining}]")
    running: list[float] = []  # (the weight of the stage under way)

    def step(stage: str, weight: float = 1) -> None:  # a stage starts: the one before is done
        bar.set_description_str(escape(stage)[-60:], refresh=False)
        if running:
            bar.update(running.pop())
        else:
            bar.refresh()
        running.append(weight)

    def show(message, category, filename, lineno, file=None, line=None):
        text = (warning_text(message) if issubclass(category, MavsidWarning) else
                warnings.formatwarning(message, category, filename, lineno, line).rstrip("\n"))
        bar.write(text, file=sys.stderr)

    previous = warnings.showwarning
    warnings.showwarning = show
    try:
        yield step
    finally:
        warnings.showwarning = previous
        bar.close()


def error_document(exc: BaseException, kind: str | None = None) -> str:
    """The one JSON document a ``--json`` command prints on stdout when it fails: the error
    (its type and line) and, when the run judged axes, their verdicts and reasons.

    Examples
    --------
    >>> from mavsid.errors import ConfigError
    >>> print(error_document(ConfigError("--axis spin: unknown")))
    {"error": {"type": "ConfigError", "message": "--axis spin: unknown"}}
    """
    import json

    doc: dict[str, Any] = {"error": {"type": kind or type(exc).__name__, "message": str(exc)}}
    verdicts = getattr(exc, "verdicts", None)
    if verdicts:
        doc["axes"] = {}
        doc["verdicts"] = {a: v.to_dict() for a, v in verdicts.items()}
    if getattr(exc, "details", ()):
        doc["details"] = list(getattr(exc, "details", ()))
    return json.dumps(doc, ensure_ascii=True, allow_nan=False)


def print_error(exc: MavsidError, as_json: bool = False) -> None:
    """A failed command's answer: its JSON document (:func:`error_document`) or the
    verdicts behind it on stdout, and its one line on stderr."""
    if as_json:
        print(error_document(exc))
    elif exc.details:  # the why, as a successful run shows its verdicts: on stdout
        print("verdict:")
        for line in exc.details:
            print(f"  {escape(line)}")
    print(f"mavsid: error: {escape(exc)}", file=sys.stderr)


def readers_build() -> str:
    """Whether the readers' byte loops are compiled (``mavsid/readers/_scan.c``; the filter
    recursion, ``mavsid/_filter.c``, is built with them), found on disk without importing
    the readers (``--version`` loads no numpy)."""
    import importlib.machinery
    from pathlib import Path

    folder = Path(__file__).resolve().parent / "readers"
    built = any((folder / f"_scan{suffix}").is_file()
                for suffix in importlib.machinery.EXTENSION_SUFFIXES)
    return ("compiled readers" if built else
            "numpy readers: built without a C compiler, reading ~1.2x slower and filtering "
            "through scipy, ~0.3 s more per fit")


def stages(args: argparse.Namespace, axes: int, per_axis: int) -> tuple[int, int]:
    """The progress bar's total for a fit or validate run (reads, axes, outputs) and the
    weight of its ``.rrd`` stage: writing the ``.rrd`` takes about as long as the whole fit
    (the bundled roll flight on a busy 2-core machine: fit 2.7 s, ``.rrd`` 2.7 s), so it
    weighs as much as the fit's stages together; a bar that gave it one stage read 00:00
    left while most of the run was still to come.

    >>> stages(argparse.Namespace(logs=["a.bin"], rrd="a.rrd", report=None), 3, 4)
    (26, 13)
    """
    fitting = len(args.logs) + per_axis * axes
    weight = fitting if args.rrd else 0
    return fitting + weight + bool(args.report), weight


# --------------------------------------------------------------------------- a fit's result


def _pm(value: float, sigma: float | None) -> str:
    text = f"{value:.6g}" if math.isfinite(value) else "nan"
    if sigma is not None and math.isfinite(sigma):
        text += f" ± {sigma:.2g}"
    return text


def _structure(d: Mapping[str, Any]) -> str:
    """The modelled filters (beside the input lag), as the text table's head shows them."""
    from mavsid.estimators.select import is_lag_filter

    parts = []
    for flt in d.get("filters") or ():
        if not is_lag_filter(flt.get("source")):
            parts.append(f"{flt.get('source') or 'filter'} {flt.get('cutoff_hz', 0):.3g} Hz")
    return "".join(f", {p}" for p in parts)


def _frequency_line(f: AxisFit) -> str:
    """The transfer function fitted to the response measured against the injection, and the
    model's error against that response."""
    tf = f.frequency
    assert tf is not None
    sd = tf.stderr
    pole = ("" if tf.structure == "integrator"
            else f", pole {tf.pole:.3g} ± {sd.get('pole', math.nan):.2g} 1/s")
    text = (f"frequency response (against the injection): {tf.structure.replace('_', ' ')} "
            f"B {tf.gain:.4g} ± {sd['gain']:.2g}{pole}, lag {tf.lag_s * 1e3:.3g} ± "
            f"{sd['lag_s'] * 1e3:.2g} ms, delay {tf.delay_s * 1e3:.3g} ± {sd['delay_s'] * 1e3:.2g}"
            f" ms, J {tf.cost:.3g}, band {tf.band_hz[0]:.2g}–{tf.band_hz[1]:.3g} Hz")
    from mavsid.pipeline_frequency import model_response_check

    check = model_response_check(f.model, f.axis, tf)
    if check is not None:
        text += f"; model {check['rms_db']:.2g} dB / {check['rms_deg']:.2g}° RMS"
    return text


def _emulation_line(e: ControllerEmulation) -> str:
    """The controller emulation's figures, one line.

    Examples
    --------
    >>> from mavsid.loop.emulation import ControllerEmulation, TermFit
    >>> e = ControllerEmulation(93.4, 0.0031, True, "", 0.047, 1, 0.0, "RATE.ROut",
    ...                         (TermFit("P", "PIDR.P", 97.0, 0.001, 0.03, 0.03),))
    >>> _emulation_line(e)
    'controller emulation: 93.4 % of RATE.ROut (RMS 0.0031 of 0.047; pass >= 80 %); P 97.0 %'
    """
    def pct(x: float) -> str:
        return "n/a" if not math.isfinite(x) else f"{x:.1f} %"

    text = (f"controller emulation: {pct(e.fit_percent)} of {e.output_source} (RMS "
            f"{e.rms:.2g} of {e.output_rms:.2g}; pass >= {e.threshold_percent:g} %)")
    if e.terms:
        text += "; " + ", ".join(f"{t.term} {pct(t.fit_percent)}" for t in e.terms)
    if not e.passed:
        text += f": FAILED, {e.reason}"
    return text


def _closed_loop_line(f: AxisFit) -> str:
    """The closed-loop twin's figures (or why there are none), one line."""
    cl = f.closed_loop
    if cl is None:
        return f"closed loop: not run ({f.closed_loop_note or 'no rate target'})"

    def pct(x: float) -> str:
        return "n/a" if not math.isfinite(x) else f"{x:.1f}"

    text = (f"closed loop %  rate {pct(cl.fit_percent)}  output {pct(cl.output_fit_percent)}  "
            f"(baseline {pct(cl.baseline_percent)} at {cl.baseline_delay_s * 1e3:.0f} ms)")
    if cl.measurement_delay_loops:
        text += (f"; the controller read the rate {cl.measurement_delay_loops:g} loop after "
                 "the logged sample (replay on the training blocks)")
    if cl.defaults_used:
        text += f"; defaults used: {', '.join(cl.defaults_used)}"
    return text


def _si_unit(fd: FlightData, name: str) -> str:
    """The SI unit a flight channel is held in."""
    if name in fd.state_names:
        return fd.state_units[fd.state_names.index(name)]
    if name in fd.input_names:
        return fd.input_units[fd.input_names.index(name)]
    return "?"


def _physical_lines(axis: str, output: str, d: Mapping[str, Any]) -> list[str]:
    """What a tuner reads first: the rate response's time constant (and its corner, the
    open-loop bandwidth), the control effectiveness B, the delay and the input lag.

    Examples
    --------
    >>> d = {"params": {"A[p,p]": -3.98, "B[p,u_roll]": 177.76},
    ...      "stderr": {"A[p,p]": 0.12, "B[p,u_roll]": 3.7},
    ...      "units": {"B[p,u_roll]": "rad/s^2"}, "delay_s": 0.0056, "input_lag_s": 0.015}
    >>> print("\\n".join(_physical_lines("roll", "p", d)))
      time constant  0.251 ± 0.0076 s (bandwidth 0.63 Hz)
      effectiveness  B[p,u_roll] 177.8 ± 3.7 rad/s^2
      delay          5.6 ms, input lag 15.0 ms
    """
    from mavsid.physical import physical_table

    params, stderr = d["params"], d["stderr"]
    lines = []
    a = params.get(f"A[{output},{output}]")
    known = {k: math.nan if v is None else v for k, v in stderr.items()}  # (JSON: None)
    rows = physical_table(axis, output, params, known, 0.0, None)
    if rows[0].unit == "s":  # the time constant, then the pole (Hz)
        tau, pole = rows[0], rows[1]
        sigma = "" if not math.isfinite(tau.sigma) else f" ± {tau.sigma:.2g}"
        lines.append(f"  time constant  {tau.value:.3g}{sigma} s (bandwidth "
                     f"{pole.value:.2g} Hz)")
    elif a is not None and math.isfinite(a):
        lines.append(f"  time constant  none: A[{output},{output}] {a:.3g} 1/s >= 0 (an "
                     "integrator or unstable)")
    name = f"B[{output},u_{axis}]"
    b = params.get(name)
    if b is not None and math.isfinite(b):
        sb = stderr.get(name)
        sigma = "" if sb is None or not math.isfinite(sb) else f" ± {sb:.2g}"
        lines.append(f"  effectiveness  {name} {b:.4g}{sigma} {d['units'].get(name, '')}"
                     .rstrip())
    lag = d.get("input_lag_s")
    lines.append(f"  delay          {d['delay_s'] * 1e3:.1f} ms"
                 + (f", input lag {lag * 1e3:.1f} ms" if lag else ""))
    return lines


def validation_figures(v: Verdict) -> str:
    """An axis's fit % on a validation flight, for people (empty when it had no segment).

    Examples
    --------
    >>> from mavsid.verdict import Verdict
    >>> validation_figures(Verdict("roll", "good", numbers={
    ...     "fit_one_step_pct": 99.1, "fit_0.5s_pct": 93.0, "fit_free_run_pct": 92.8}))
    'one step 99.1 %, 0.5 s 93.0 %, free run 92.8 %'
    """
    n = v.numbers
    if "fit_free_run_pct" not in n:
        return ""
    text = ", ".join(f"{what} {_pct_text(n.get(key))}" for what, key in (
        ("one step", "fit_one_step_pct"), ("0.5 s", "fit_0.5s_pct"),
        ("free run", "fit_free_run_pct")))
    if n.get("fit_closed_loop_pct") is not None:
        text += (f", closed-loop twin {_pct_text(n['fit_closed_loop_pct'])} (baseline "
                 f"{_pct_text(n.get('baseline_closed_loop_pct'))})")
    return text


def validate_line(v: Verdict) -> str:
    """A verdict as ``mavsid validate`` says it: the model against this flight, with the
    numbers (no advice: that is for the flight a model is fitted from).

    Examples
    --------
    >>> from mavsid.verdict import Verdict
    >>> v = Verdict("roll", "not identified", ("free run diverges",), (),
    ...             {"fit_one_step_pct": 84.9, "fit_0.5s_pct": -3e5, "fit_free_run_pct": -3e5},
    ...             ("fly a chirp",))
    >>> validate_line(v)
    'roll: does not predict this flight: one step 84.9 %, 0.5 s diverges (< -100 %), free \
run diverges (< -100 %); free run diverges'
    """
    figures = validation_figures(v)
    said = "; ".join(v.reasons)
    if not figures and ("windows_rejected" in v.numbers
                        or any(w in said for w in ("no window", "no segment", "no body rate"))):
        return f"{v.axis}: nothing to validate on: {said}"
    if not figures:  # (validation ran and failed: the model's prediction is no number)
        return f"{v.axis}: does not predict this flight: {said}"
    if v.identified:
        head = f"{v.axis}: {v.level}" + (f" (for {', '.join(v.usable_for)})"
                                         if v.usable_for else "")
    else:
        head = f"{v.axis}: does not predict this flight"
    return f"{head}: {figures}" + "".join(f"; {r}" for r in v.reasons)


def _pct_text(value: float | None) -> str:
    """``93.4 %``, ``diverges (< -100 %)`` or ``n/a``."""
    from mavsid.verdict import format_fit

    text = format_fit(value)
    return text.replace(")", " %)") if text.startswith("diverges") else (
        text if text == "n/a" else f"{text} %")


def format_result(result: FitResult, validating: bool = False) -> str:
    """The compact per-axis table ``mavsid fit`` prints: the physical parameters a tuner
    reads (time constant, bandwidth, effectiveness, delay, lag), then every parameter ± σ
    (continuous-time, then the discrete-time coefficients), fit % on held-out data at one
    step, 0.5 s and free run, and the verdicts. ``validating``: as ``mavsid validate`` says
    them (the model against another flight: :func:`validate_line`).

    Examples
    --------
    >>> from mavsid.pipeline_results import FitResult
    >>> print(format_result(FitResult({}, (), ("x.bin",))))
    x.bin: no axis fitted
    """
    from mavsid.channels import source_text
    from mavsid.physical import parameter_order
    from mavsid.verdict import format_fit

    logs = ", ".join(result.logs)
    if not result.axes:
        return f"{logs}: no axis fitted"
    lines = [f"{logs}: {len(result.axes)} axis model(s), fit % on held-out segments"]
    for fd in result.flights:  # what of each log was used (align's boot and exclusions)
        boot = fd.boot
        excluded = fd.excluded_samples
        if boot and boot.of > 1:
            lines.append(f"{fd.source.path}: boot {boot.used} of {boot.of} used "
                         f"({boot.start_s:.1f}–{boot.stop_s:.1f} s, {boot.reason})")
        if excluded:
            lines.append(f"{fd.source.path}: samples excluded, never fitted: "
                         + ", ".join(f"{k} {v}" for k, v in excluded.items()))
        sources = fd.sources
        used = [n for ax in result.axes.values() for n in (ax.output, f"u_{ax.axis}")]
        units_from = fd.units_from
        if sources:  # where each channel came from, read in what unit (declared, preset's,
            # inferred), in which SI unit
            lines.append(f"{fd.source.path}: preset {fd.preset}; " + ", ".join(
                f"{n} [{_si_unit(fd, n)}] <- {escape(source_text(sources[n], units_from.get(n)))}"
                for n in dict.fromkeys(used) if n in sources))
    for axis, f in result.axes.items():
        d = f.to_dict()
        train_s = sum(s.stop_s - s.start_s for s in f.train)
        val_s = sum(s.stop_s - s.start_s for s in f.held_out)
        stable = {True: "stable", False: "UNSTABLE", None: "stability n/a"}[f.validation.stable]
        lines.append(
            f"{axis} ({f.output}; {f.estimator or 'model'}; {1 / f.validation.dt:.0f} Hz"
            f"{_structure(d)}; train {len(f.train)} seg "
            f"{train_s:.1f} s, validation {len(f.held_out)} seg {val_s:.1f} s; {stable})"
        )
        lines += _physical_lines(axis, f.output, d)
        width = max((len(k) for k in d["params"]), default=0)
        # continuous-time parameters first, the discrete-time coefficients after them
        for name in parameter_order(d["params"]):
            value = d["params"][name]
            sigma = d["stderr"].get(name)
            unit = d["units"].get(name, "")
            lines.append(
                f"  {name:<{width}}  {_pm(math.nan if value is None else value, sigma)} {unit}"
                .rstrip()
            )
        fp = d["fit_percent"]
        cells = "  ".join(f"{k.replace('_', '-')} {format_fit(fp[k])}" for k in fp)
        lines.append(f"  fit %  {cells}")
        if f.emulation is not None:
            lines.append(f"  {_emulation_line(f.emulation)}")
        lines.append(f"  {_closed_loop_line(f)}")
        if f.frequency is not None:
            lines.append(f"  {_frequency_line(f)}")
    verdicts = [validate_line(v) if validating else v.line()
                for v in result.verdicts.values()]
    if verdicts:
        lines.append("verdict:")
        lines += [f"  {v}" for v in verdicts]
    return "\n".join(lines)


def print_result(args: argparse.Namespace, result: FitResult, validating: bool = False,
                  error: MavsidError | None = None) -> None:
    """The result on stdout: its JSON (with ``error``, when the command fails on it, as
    :func:`error_document` has it) or its table and the files written."""
    import json

    if args.json:
        doc = result.to_dict()
        if error is not None:
            doc["error"] = {"type": type(error).__name__, "message": str(error)}
        print(json.dumps(doc, indent=1, ensure_ascii=True, allow_nan=False))
    else:
        print(escape_lines(format_result(result, validating=validating)))
        for flag, path in (("rrd", args.rrd), ("report", args.report)):
            if path:
                print(f"wrote {path}" + (f" (open it with: rerun --bind 127.0.0.1 {path})"
                                         if flag == "rrd" else ""))


def simulate_command(args: argparse.Namespace, vehicle: str) -> str:
    """The ``mavsid simulate`` command line that makes the same flight (written into the
    simulated log as its provenance): every option given, ``--layout`` last."""
    opts = [f"-o {o}" for o in args.output] + [f"--manoeuvre {args.manoeuvre}",
                                                 f"--axis {args.axis}"]
    if vehicle != "quad":
        opts.append(f"--vehicle {vehicle}")
    if args.frame != "quad-x":
        opts.append(f"--frame {args.frame}")
    opts += [f"--sid-axis {a}" for a in args.sid_axis or ()]
    for name in ("duration", "seed", "noise", "magnitude", "f_start", "f_stop", "t_rec",
                 "rate_hz", "gyro_noise", "vibration", "faults"):
        value = getattr(args, name)
        if value not in (None, ""):
            opts.append(f"--{name.replace('_', '-')} {value}")
    command = "mavsid simulate " + " ".join(opts)
    if args.layout is not None:
        opts.append(f"--layout {args.layout}")
        command = "mavsid simulate " + " ".join(opts)
    return command


def flight_line(log: str, flight: FlightData) -> str:
    """``mavsid segments``' first line: the log, its preset, rate, span and blocks."""
    span = flight.time_s[-1] - flight.time_s[0]
    return (f"{log}: preset {flight.preset}, {1 / flight.dt:.0f} Hz, "
            f"{span:.1f} s, {len(flight.blocks)} block(s)")


def change_line(row: Mapping[str, Any]) -> str:
    """``mavsid batch``'s line for a change point of :func:`mavsid.batch.trends`."""
    return (f"change: {row['vehicle']} {row['axis']} {row['param']} "
            f"{row['before']:.4g} -> {row['after']:.4g} after {row['change_after']} "
            f"({row['z']:.1f} standard errors)")
