"""The ``mavsid`` command line: each subcommand is one call into the library.

Exit codes: 0 success; 1 a :class:`~mavsid.errors.MavsidError` (printed as one line on
stderr, with a traceback only under ``--debug``); 2 usage errors.

Examples
--------
>>> main(["--version"])  # doctest: +ELLIPSIS
mavsid ...
0
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import math
import os
import signal
import sys
import time
import traceback
import warnings
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, NoReturn

from mavsid import __version__
from mavsid.axes import AXES
from mavsid.cli_format import (
    change_line,
    error_document,
    flight_line,
    print_error,
    print_result,
    progress,
    readers_build,
    simulate_command,
    stages,
    validate_line,
    validation_figures,
    warning_text,
)
from mavsid.errors import (
    ConfigError,
    MavsidError,
    MavsidWarning,
    NoExcitationError,
    escape,
    escape_lines,
)
from mavsid.outputs import ReportWorker, atomic_path, check_outputs

if TYPE_CHECKING:
    from mavsid.loop.tune import TuneAnalysis
    from mavsid.pipeline_config import PipelineConfig
    from mavsid.pipeline_results import FitResult
    from mavsid.response import FlightResponse

__all__ = ["build_parser", "main"]

Handler = Callable[[argparse.Namespace], int]


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """Print mavsid's warnings as one plain line, others as Python would."""
    if issubclass(category, MavsidWarning):
        print(warning_text(message), file=sys.stderr)
    else:
        _default_showwarning(message, category, filename, lineno, file, line)


_default_showwarning = warnings.showwarning


# --------------------------------------------------------------------------- subcommands
# A subcommand is a handler ``_<name>``, which makes one library call and prints its result,
# and ``_add_<name>``, which declares its arguments; the handler's docstring is its help (the
# first paragraph in the list of ``mavsid --help``, the rest in its own ``--help``), and
# :data:`SUBCOMMANDS` lists them. Library modules are imported lazily so that ``mavsid
# --help`` stays fast.


def _dialect(args: argparse.Namespace) -> dict[str, Any]:
    """``dialect=`` for read_log when ``--dialect`` was given."""
    return {"dialect": args.dialect} if getattr(args, "dialect", None) else {}


def _add_info(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="flight log (.bin, .log, .tlog, .ulg)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--dialect", help="MAVLink dialect of a .tlog (default ardupilotmega)")
    _add_quiet_flag(p)


def _info(args: argparse.Namespace) -> int:
    """what a log holds: messages, rates, units, modes, SYSTEMID"""
    import json

    from mavsid.info import format_summary, read_for_summary, summarize

    _check_inputs([args.log])
    with progress(args, 2) as step:
        step(f"reading {args.log}")
        raw = read_for_summary(args.log, **_dialect(args))
        step("summarising")
        summary = summarize(raw)
    print(json.dumps(summary, indent=1, ensure_ascii=True) if args.json
          else escape_lines(format_summary(summary)))
    return 0


def _check_inputs(logs: Sequence[str], files: Sequence[str] = ()) -> None:
    """Refuse a log that is missing, a directory, empty or of no known format, and a file
    (a model) that cannot be opened, before the command imports its heavy modules or
    starts a report worker: a mistyped name is said at once, not after a second of
    start-up.

    Raises
    ------
    MavsidError
        One line naming the file: :class:`~mavsid.errors.LogFormatError` for a log (as
        reading it would say), :class:`~mavsid.errors.ConfigError` for another file.
    """
    from mavsid.readers import sniff_format

    for path in files:
        try:
            with open(path, "rb"):
                pass
        except OSError as exc:
            raise ConfigError(f"{path}: cannot read: {exc.strerror or exc}") from None
    for log in logs:
        sniff_format(log)


def _add_extract(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="flight log (.bin, .log, .tlog, .ulg)")
    p.add_argument("--messages", help="comma-separated message types (default: all)")
    p.add_argument("--start", type=float, help="first time to keep, s (log clock)")
    p.add_argument("--stop", type=float, help="last time to keep, s (log clock)")
    p.add_argument("-o", "--output", required=True, help="OUT.npz, OUT.parquet or OUT.csv")
    p.add_argument("--dialect", help="MAVLink dialect of a .tlog (default ardupilotmega)")
    p.add_argument("--aligned", action="store_true",
                   help="write the aligned FlightData (states, inputs, flags on one grid)")


def _extract(args: argparse.Namespace) -> int:
    """decoded messages to .npz (or one type to .parquet/.csv)"""
    from pathlib import Path

    from mavsid.export import SUFFIXES, write
    from mavsid.readers import read_log

    check_outputs([args.output], [args.log])
    names = [m.strip() for m in args.messages.split(",") if m.strip()] if args.messages else None
    if names == []:
        raise ConfigError(f"--messages {args.messages!r} names no message type")
    for flag, value in (("--start", args.start), ("--stop", args.stop)):
        if value is not None and not math.isfinite(value):
            raise ConfigError(f"{flag} {value}: not a time in seconds")
    if args.start is not None and args.stop is not None and args.start > args.stop:
        raise ConfigError(f"--start {args.start:g} s is after --stop {args.stop:g} s")
    # what the output can hold, said before the log is read (and naming the output, not the
    # temporary file it is written through)
    suffix = Path(args.output).suffix.lower()
    if suffix not in SUFFIXES:
        raise ConfigError(f"{args.output}: output must end in {', '.join(SUFFIXES)}")
    if suffix != ".npz" and not args.aligned and (names is None or len(names) != 1):
        raise ConfigError(f"{args.output}: {suffix} holds exactly one message type; choose one "
                          "with --messages, or write .npz")
    if args.aligned:
        from mavsid.align import flight_table, load_flight
        from mavsid.data import RawLog

        flight = load_flight(args.log)
        table = flight_table(flight, args.start, args.stop)
        with atomic_path(args.output) as tmp:
            write(RawLog(flight.source, {"FlightData": table}), tmp, ["FlightData"])
        print(f"wrote {args.output} (FlightData: {len(table)} samples at {1 / flight.dt:.0f} Hz, "
              f"preset {flight.preset})")
        return 0
    log = read_log(args.log, messages=names, start=args.start, stop=args.stop, **_dialect(args))
    with atomic_path(args.output) as tmp:
        write(log, tmp, names)
    n = len(names) if names is not None else len(log.messages)
    print(f"wrote {args.output} ({n} message type(s))")
    return 0


def _add_segments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="flight log (.bin, .log, .tlog, .ulg)")
    p.add_argument("--axis", choices=AXES, help="one axis only")
    p.add_argument("--json", action="store_true", help="print a JSON list of windows")
    p.add_argument("--all", action="store_true", help="list every rejected scan window")
    p.add_argument("--scan", action="store_true",
                   help="scan sliding windows also on axes that have a SYSTEMID run")
    p.add_argument("--window", type=float, default=5.0, help="scan window length, s (5)")
    _add_preset_flag(p)
    p.add_argument("--rate", type=float, help="grid rate, Hz (default: the rate channel's)")
    _add_quiet_flag(p)


def _segments(args: argparse.Namespace) -> int:
    """list the well-excited windows of a log, and why the others were rejected"""
    import json

    _check_inputs([args.log])
    from mavsid.align import load_flight
    from mavsid.excitation import ScanOptions, find_segments, format_reports

    preset, presets, mixers = _preset_arg(args.preset)
    with progress(args, 2) as step:
        step(f"reading {args.log}")
        flight = load_flight(args.log, preset, args.rate, presets=presets, mixers=mixers)
        step("scoring windows")
        reports = find_segments(flight, args.axis, scan=True if args.scan else None,
                                options=ScanOptions(window_s=args.window))
    if args.json:
        print(json.dumps([r.to_dict() for r in reports], indent=1, ensure_ascii=True))
    else:
        print(escape(flight_line(args.log, flight)))
        print(escape_lines(format_reports(reports, show_all=args.all)))
    return 0


def _add_simulate(p: argparse.ArgumentParser) -> None:
    p.add_argument("-o", "--output", action="append", required=True, metavar="OUT",
                   help="OUT.bin, OUT.tlog or OUT.ulg (repeat to write several from one "
                   "flight)")
    p.add_argument("--manoeuvre", default="sysid",
                   choices=("sysid", "doublet", "3211", "random", "hover"),
                   help="excitation (default sysid: an ArduPilot SYSTEMID chirp)")
    p.add_argument("--axis", choices=AXES, default="roll",
                   help="stick axis of a manoeuvre; mixer axis of the default chirp (roll)")
    p.add_argument("--sid-axis", type=int, action="append", metavar="N",
                   help="SID_AXIS 1-13 of a SYSTEMID run (repeat for several runs)")
    p.add_argument("--duration", type=float, metavar="S", help="log length, s")
    p.add_argument("--seed", type=int, default=0, help="random seed (0)")
    p.add_argument("--noise", type=float, default=1.0, metavar="K",
                   help="scale of sensor noise, gyro bias and disturbance (1; 0 = none)")
    p.add_argument("--magnitude", type=float, help="SID_MAGNITUDE")
    p.add_argument("--f-start", type=float, default=0.5, help="SID_F_START_HZ (0.5)")
    p.add_argument("--f-stop", type=float, default=15.0, help="SID_F_STOP_HZ (15)")
    p.add_argument("--t-rec", type=float, default=20.0, help="SID_T_REC, s (20)")
    p.add_argument("--rate-hz", type=float, default=400.0,
                   help="RATE/SIDD logging rate, must divide 400 Hz (400); below 25 Hz "
                   "every message is logged slowly")
    p.add_argument("--vehicle", choices=("quad", "heavy-x", "hexa", "heli", "plane", "racer",
                                         "heavy-lift"),
                   help="plant: small quad (default), heavier X quad, hexacopter inertia, "
                   "traditional helicopter, fixed-wing plane (default for --layout heli / "
                   "plane), light racer quad (flown with its own rate tuning), heavy-lift "
                   "(120-ms motors, flown with its own tuning)")
    p.add_argument("--frame", choices=("quad-x", "hexa-x", "y6b", "octaquad-x"),
                   default="quad-x",
                   help="multirotor frame the motors are mixed for and logged as "
                   "(FRAME_CLASS/FRAME_TYPE; RCOU, SERVO_OUTPUT_RAW): quad-x (default), "
                   "hexa-x, y6b (coaxial Y6), octaquad-x (coaxial X8)")
    p.add_argument("--gyro-noise", type=float, metavar="DEG_S",
                   help="gyro white noise, deg/s RMS per 400 Hz sample (fed back)")
    p.add_argument("--vibration", type=float, default=0.0, metavar="DEG_S",
                   help="frame vibration amplitude on the gyro, deg/s (0)")
    p.add_argument("--layout",
                   choices=("copter-4", "copter-4.4", "copter-4.6", "copter-3.6", "copter-3.3",
                            "copter-3.4-dev", "copter-3.2", "heli", "plane", "quadplane",
                            "px4-1.14", "px4-1.11", "px4-1.8"),
                   help="log layout. A .bin's ArduCopter generation: 4.x (default); 4.4 (as "
                   "4.x, its RATE target without a SYSTEMID rate injection, SID_AXIS 7-9); "
                   "4.6 (the "
                   "4.5-4.7 records: AUXF with pos/source/result, PIDR/PIDP/PIDY with DFF and "
                   "Flags, ANG, ARM, VER, two IMUs, every SERVOn_FUNCTION); 3.6 "
                   "(no unit records, PARM without Default, no SYSTEMID messages); 3.3 "
                   "(TimeMS, RCOU Ch1-8, no unit records, untimed PARM/MODE, ARM event first); "
                   "3.4-dev (RATE in centideg/s, outputs on +-4500); 3.2 (as 3.3 but no RATE: "
                   "inputs only from RCOU Chan1-8 motors, FRAME, RC3_MIN/MAX, THR_MIN/MAX); "
                   "heli (ArduCopter 4.x traditional helicopter: FRAME_CLASS 6, H_SW_*, "
                   "swashplate servos on RCOU, inputs from RATE); plane (ArduPlane 4.x: no "
                   "RATE nor SYSTEMID, PIDR/PIDP/PIDY, aileron/elevator/throttle/rudder "
                   "servos with SERVOn_FUNCTION; needs a pilot manoeuvre); quadplane (ArduPlane "
                   "4.5 QuadPlane hovering in QSTABILIZE: the VTOL controller's PIQR/PIQP/PIQY, "
                   "the fixed-wing PIDs idle, surfaces on outputs 1-4, motors from 5 by "
                   "SERVOn_FUNCTION, Q_* parameters; needs a pilot manoeuvre). A .ulg's PX4 "
                   "topic set: "
                   "1.14 (default; vehicle_torque_setpoint), 1.11 (actuator_controls_0), 1.8 "
                   "(rates in vehicle_attitude)")
    p.add_argument("--faults", default="", metavar="SPEC",
                   help="damage: drop=FRACTION,reboot=SECONDS,truncate=BYTES,gap=AT:SECONDS "
                   "(logging stops AT s after the first sample for SECONDS; .bin only)")


def _simulate(args: argparse.Namespace) -> int:
    """fly a known plant like ArduCopter and write real-format logs + truth JSON

    Simulate an ArduCopter-like quadrotor (known plant, ArduPilot-style controller, SYSTEMID
    chirps or pilot manoeuvres) and write a DataFlash .bin and/or a MAVLink .tlog (format from
    the suffix), with OUT.truth.json beside it. --layout writes other firmware: ArduCopter
    3.2-4.x, a traditional heli, ArduPlane 4.x (.bin), PX4 1.8-1.14 (.ulg).
    """
    from mavsid.synthetic.faults import Faults
    from mavsid.synthetic.run import scenario_from_options, simulate

    vehicle = args.vehicle or {"heli": "heli", "plane": "plane"}.get(args.layout, "quad")
    scenario = scenario_from_options(
        manoeuvre=args.manoeuvre, axis=args.axis, sid_axes=args.sid_axis or (),
        duration_s=args.duration, seed=args.seed, noise=args.noise, magnitude=args.magnitude,
        f_start_hz=args.f_start, f_stop_hz=args.f_stop, t_rec=args.t_rec, rate_hz=args.rate_hz,
        vehicle=vehicle, gyro_noise_dps=args.gyro_noise, vibration_dps=args.vibration,
        frame=args.frame,
    )
    faults = Faults.parse(args.faults, seed=args.seed)
    command = simulate_command(args, vehicle)
    result = simulate(scenario, args.output, faults, command=command, layout=args.layout)
    for path, size in zip(result.logs, result.sizes, strict=True):
        print(f"wrote {path} ({size} bytes)")
    for path in result.truths:
        print(f"wrote {path}")
    return 0


def _pipeline_config(args: argparse.Namespace) -> PipelineConfig:
    """The pipeline config from ``--config`` with the command line's overrides."""
    from mavsid.pipeline_config import PipelineConfig, load_config

    cfg = load_config(args.config) if args.config else PipelineConfig()
    axes = tuple(dict.fromkeys(args.axis)) if args.axis else None
    preset, presets, mixers = _preset_arg(getattr(args, "preset", None))
    if presets or mixers:  # (your presets, tried before the built-in ones)
        cfg = cfg.with_overrides(presets={**cfg.presets, **(presets or {})},
                                 mixers={**cfg.mixers, **(mixers or {})})
    return cfg.with_overrides(axes=axes, estimator=getattr(args, "estimator", None),
                              allow_unstable=getattr(args, "allow_unstable", None) or None,
                              preset=preset)


def _write_outputs(args: argparse.Namespace, result: FitResult,
                   step: Callable[..., None] = lambda stage, weight=1: None,
                   worker: ReportWorker | None = None, rrd_weight: float = 1) -> None:
    """The ``.rrd`` and the report; the report drawn by ``worker`` (a process started with
    the command, see :class:`~mavsid.outputs.ReportWorker`), which works out the loop
    analysis first and hands it back for the ``.rrd``'s gains while this one imports rerun;
    else here, the analysis worked out once for both. ``rrd_weight``: the ``.rrd``'s stage
    on the progress bar (:func:`mavsid.cli_format.stages`)."""
    with contextlib.ExitStack() as stack:
        report_tmp = None
        handed = False
        analysis: TuneAnalysis | None = None
        if args.report:
            step(f"writing {args.report}")
            report_tmp = stack.enter_context(atomic_path(args.report))
            handed = worker is not None and worker.start(result, report_tmp, args.report)
        if args.rrd:
            from mavsid.viz.recording import save_rrd

            step(f"writing {args.rrd}", rrd_weight)
            if args.report:  # (the gains the report shows, shown in the .rrd too)
                from mavsid.loop.tune import tune_analysis

                analysis = worker.analysis() if worker is not None and handed else None
                if analysis is None:  # (no worker, or one that could not hand it back)
                    analysis = tune_analysis(result)
            with atomic_path(args.rrd) as tmp:
                save_rrd(result, tmp, gains=analysis.report if analysis is not None else None)
        if report_tmp is not None:
            if handed:
                assert worker is not None
                worker.wait()
            else:
                from mavsid.report import write_report

                done = analysis
                write_report(result, report_tmp,
                             analysis=(lambda: done) if done is not None else None)


def _report_worker(args: argparse.Namespace) -> contextlib.AbstractContextManager[Any]:
    """A :class:`~mavsid.outputs.ReportWorker` when the command writes a report (and one can
    be started), else nothing (``None``)."""
    if args.report and ReportWorker.available():
        return ReportWorker()
    return contextlib.nullcontext()


def _preset_arg(preset: str | None) -> tuple[str | None, dict[str, Any] | None,
                                              dict[str, Any] | None]:
    """``--preset``: a preset's name, or a TOML file's presets and mixers (name None)."""
    if preset and preset.lower().endswith(".toml"):
        from mavsid.autopilot.config import load_presets

        presets, mixers = load_presets(preset)
        return None, dict(presets), dict(mixers)
    return preset, None, None


def _add_quiet_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument("-q", "--quiet", action="store_true",
                   help="no progress bar (there is none when stderr is not a terminal)")


def _add_preset_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument("--preset", metavar="NAME",
                   help="channel preset name (mavsid.autopilot.presets), or a TOML file of "
                   "presets and mixers to choose from (default: chosen from the log)")


def _add_axis_flag(p: argparse.ArgumentParser, help: str) -> None:
    p.add_argument("--axis", action="append", choices=AXES, help=help)


def _add_config_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", metavar="FILE.toml", help="pipeline settings (see pipelines/)")


def _add_output_flags(p: argparse.ArgumentParser,
                      axis: str = "axis to fit (repeat for several; default all with "
                      "excitation)", files: bool = True) -> None:
    """The flags of a command that fits: ``--axis`` (``axis`` its help), ``--config``,
    ``--preset``, with ``files`` ``--rrd`` and ``--report``, ``--json``, ``--quiet``."""
    _add_axis_flag(p, axis)
    _add_config_flag(p)
    _add_preset_flag(p)
    if files:
        p.add_argument("--rrd", metavar="OUT.rrd", help="write a rerun recording")
        p.add_argument("--report", metavar="OUT.html",
                       help="write a self-contained HTML report")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    _add_quiet_flag(p)


def _add_fit(p: argparse.ArgumentParser) -> None:
    p.add_argument("logs", nargs="+", metavar="LOG", help="flight log(s) (.bin .log .tlog .ulg)")
    p.add_argument("--estimator", choices=("ls", "ridge", "l1", "stlsq"),
                   help="regression: least squares (default), ridge, L1 (cvxpy) or stlsq "
                   "(sequential thresholded least squares, SINDy-style sparse)")
    p.add_argument("-o", "--output", metavar="model.json", help="write the fitted models")
    p.add_argument("--allow-unstable", action="store_true",
                   help="keep a rate model identified unstable (default: refuse it and use "
                   "the bounded fit: damping >= 0, effectiveness > 0)")
    _add_output_flags(p)


def _fit(args: argparse.Namespace) -> int:
    """log(s) -> validated attitude-dynamics model per axis

    Read, align, find excited segments, fit per axis on alternate blocks and validate on the
    held-out ones (one-step, 0.5 s and free-run fit %).
    """
    import json

    check_outputs([args.output, args.rrd, args.report], args.logs)
    _check_inputs(args.logs)
    with _report_worker(args) as worker:  # (first: it imports while this one does too)
        from mavsid.pipeline import FIT_STAGES, fit

        cfg = _pipeline_config(args)
        total, rrd_weight = stages(args, len(cfg.axes), len(FIT_STAGES))
        with progress(args, total) as step:
            try:
                result = fit(args.logs, cfg, progress=step)
            except NoExcitationError as exc:  # no plant: the outputs asked for still come
                _write_unidentified(args, cfg, exc, step)
                raise
            if args.output:
                with atomic_path(args.output) as tmp, open(tmp, "w", encoding="utf-8") as f:
                    json.dump(result.models_dict(), f, indent=1)
            _write_outputs(args, result, step, worker, rrd_weight)
    print_result(args, result)
    if args.output and not args.json:
        print(f"wrote {args.output}")
    return 0


def _write_unidentified(args: argparse.Namespace, cfg: PipelineConfig, exc: MavsidError,
                        step: Callable[[str], None]) -> None:
    """``fit``'s ``--report`` and ``--rrd`` when no plant was identified: the verdicts and
    each log's closed-loop response (:mod:`mavsid.response`), said as such on stderr."""
    if not (args.report or args.rrd):
        return
    notes = [f"no plant identified: {exc}", *exc.details]
    found = []
    for log in args.logs:
        step(f"closed-loop response of {log}")
        try:
            found.append(_read_response(log, cfg))
        except MavsidError as why:
            notes.append(f"no closed-loop response: {why}")
    _write_response_outputs(args, found, notes=notes, title="mavsid fit: no plant identified")
    for path in (args.report, args.rrd):
        if path:
            print(f"mavsid: wrote {path} (no plant identified: the verdicts and the "
                  "closed-loop response)", file=sys.stderr)


def _add_validate(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", metavar="MODEL", help="model.json written by mavsid fit -o")
    p.add_argument("logs", nargs="+", metavar="LOG", help="flight log(s) to validate on")
    _add_output_flags(p)


def _validate(args: argparse.Namespace) -> int:
    """apply saved models to another flight (all its segments held out)

    Apply the models of `mavsid fit -o` to other flights: every excited segment of theirs is
    held out; fit % at one step, 0.5 s and free run, residual checks, the closed-loop twin and a
    verdict per axis. A model fitted at another rate is re-discretised to the log's (said in the
    verdict).
    """
    check_outputs([args.rrd, args.report], [args.model, *args.logs])
    _check_inputs(args.logs, [args.model])
    with _report_worker(args) as worker:  # (first: it imports while this one does too)
        from mavsid.pipeline import VALIDATE_STAGES, load_models, validate_logs

        models = load_models(args.model)
        cfg = _pipeline_config(args)
        axes = len([a for a in models if a in cfg.axes])
        total, rrd_weight = stages(args, axes, len(VALIDATE_STAGES))
        with progress(args, total) as step:
            try:
                result = validate_logs(models, args.logs, cfg, progress=step)
            except NoExcitationError as exc:  # (no axis had a segment: said as validate does)
                verdicts = getattr(exc, "verdicts", {})
                exc.details = tuple(validate_line(v) for v in verdicts.values())
                raise
            _write_outputs(args, result, step, worker, rrd_weight)
    error = None
    if not any(v.identified for v in result.verdicts.values()):  # none predicts the flight
        error = NoExcitationError(
            f"{', '.join(args.logs)}: the model does not predict this flight ("
            + "; ".join(f"{a}: {validation_figures(v) or 'nothing to validate on'}"
                        for a, v in result.verdicts.items()) + ")")
    print_result(args, result, validating=True, error=error)
    if error is not None:
        print(f"mavsid: error: {escape(error)}", file=sys.stderr)
        return 1
    return 0


def _add_view(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", metavar="LOG", help="flight log (.bin .log .tlog .ulg)")
    p.add_argument("--model", metavar="model.json", help="models written by mavsid fit -o")
    _add_config_flag(p)
    _add_axis_flag(p, "axis to show (repeat for several)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--spawn", action="store_true",
                       help="start a native rerun viewer (the default)")
    where.add_argument("--serve", action="store_true",
                       help="serve a web viewer and print its address; Ctrl-C stops it")
    where.add_argument("--connect", action="store_true",
                       help="send to a viewer you started (see --url)")
    where.add_argument("--save", metavar="OUT.rrd", help="write a recording instead")
    where.add_argument("--stdout", action="store_true",
                       help="write the recording to stdout (pipe it into `rerun -`)")
    where.add_argument("--headless", action="store_true",
                       help="log nowhere (check that the log can be shown)")
    p.add_argument("--url", metavar="URL", default="rerun+http://127.0.0.1:9876/proxy",
                   help="viewer address for --connect (default %(default)s)")
    p.add_argument("--bind", default="127.0.0.1",
                   help="address a viewer mavsid starts listens on (default 127.0.0.1; "
                   "0.0.0.0 offers the flight to the network)")


def _view(args: argparse.Namespace) -> int:
    """show a log (and a model's predictions) in the rerun viewer

    Log the flight, its segments and, with --model, the model's one-step and free-run
    predictions to rerun: a native viewer by default, or a web viewer (--serve), a running
    viewer (--connect), a file (--save) or stdout (--stdout). A viewer mavsid starts listens on
    127.0.0.1 (unless --bind says otherwise), on free ports.
    """
    check_outputs([args.save], [args.log, *([args.model] if args.model else [])])
    _check_inputs([args.log], [args.model] if args.model else [])
    from mavsid.pipeline import find_windows, load_models, validate_logs
    from mavsid.viz.recording import (
        blueprint,
        flight_ranges,
        focus_span,
        log_fit_result,
        log_flight_windows,
        rate_targets,
        result_blueprint,
    )
    from mavsid.viz.series import new_recording, write_errors
    from mavsid.viz.viewer import open_sink, viewer_errors

    _check_viewer_address(args)
    cfg = _pipeline_config(args)
    rec = new_recording()
    sink = _sink_args(args)
    save = sink.pop("save")
    with contextlib.ExitStack() as stack:
        if save:
            sink["save"] = stack.enter_context(atomic_path(save))
            stack.enter_context(write_errors())
        if not (save or args.stdout or args.headless):
            stack.enter_context(viewer_errors(f"--url {args.url}" if args.connect else
                                              "the rerun viewer mavsid started"))
        if args.model:
            result = validate_logs(load_models(args.model), [args.log], cfg)
            targets = rate_targets(result)
            served = open_sink(rec, result_blueprint(result, targets), **sink)
            log_fit_result(rec, result, targets=targets)
        else:
            flight, windows = find_windows(args.log, cfg)
            served = open_sink(
                rec, blueprint([], with_flight=True, focus=focus_span(windows=windows),
                               y_ranges=flight_ranges([flight])), **sink)
            log_flight_windows(rec, flight, windows)
        rec.flush()
        if save:
            rec.disconnect()
    if served is not None and args.serve:
        print(f"web viewer: {served.url} (Ctrl-C to stop)", flush=True)
        try:
            while served.process.poll() is None:
                time.sleep(0.5)
        except KeyboardInterrupt:
            pass
        finally:
            served.close()
    if args.save:
        print(f"wrote {args.save}")
    return 0


#: the addresses a rerun viewer takes (``--url``)
_VIEWER_SCHEMES = ("rerun://", "rerun+http://", "rerun+https://")


def _check_viewer_address(args: argparse.Namespace) -> None:
    """``view``'s ``--url`` (with ``--connect``) or ``--bind`` (a viewer mavsid starts) before
    the log is read: a bad one was a traceback from rerun or from the socket layer."""
    if args.connect:
        if not args.url.startswith(_VIEWER_SCHEMES):
            raise ConfigError(f"--url {args.url}: not a rerun viewer address (one of "
                              f"{', '.join(s + '...' for s in _VIEWER_SCHEMES)})")
    elif not (args.save or args.stdout or args.headless):
        if (not args.serve and sys.platform.startswith("linux")
                and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))):
            raise ConfigError("no display for the rerun viewer (DISPLAY and WAYLAND_DISPLAY "
                              "unset): --serve offers a web viewer, --save OUT.rrd a file")
        from mavsid.viz.viewer import free_port

        try:
            free_port(args.bind)
        except OSError as exc:
            raise ConfigError(f"--bind {args.bind}: cannot listen there "
                              f"({exc.strerror or exc})") from None


def _sink_args(args: argparse.Namespace) -> dict[str, Any]:
    return {"save": args.save, "serve": args.serve, "connect": args.connect, "url": args.url,
            "stdout": args.stdout, "headless": args.headless, "bind": args.bind}


def _add_tune(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", metavar="LOG", help="flight log (.bin .log .tlog .ulg)")
    p.add_argument("--target-pm", type=float, default=50.0, metavar="DEG",
                   help="phase margin the suggested gains aim at and must reach (default 50)")
    p.add_argument("--max-step", type=float, default=2.0, metavar="X",
                   help="one flight changes the gains by at most this factor either way "
                   "(default 2: 0.5-2x); a larger step is capped and says so")
    p.add_argument("--params-out", metavar="FILE.parm",
                   help="write the suggested changes as a parameter file (ArduPilot: NAME "
                   "VALUE lines MAVProxy and Mission Planner load; PX4: a QGroundControl "
                   ".params file); refused when no gain is suggested")
    _add_output_flags(p, "axis to analyse (repeat for several; default all)", files=False)


def _tune(args: argparse.Namespace) -> int:
    """log -> rate-loop margins, bandwidth, suggested gains, next-flight advice

    Fit the plant per axis, put it in the vehicle's rate controller rebuilt from the log's
    parameters and report margins, closed-loop bandwidth and step response (± σ from the
    parameter covariance), gains for a target phase margin (only for axes whose model is good)
    and what to change next flight.
    """
    import json

    if not 0 < args.target_pm < 90:
        raise ConfigError(f"--target-pm {args.target_pm:g}: must lie in (0, 90) degrees")
    if not (math.isfinite(args.max_step) and args.max_step >= 1.0):
        raise ConfigError(f"--max-step {args.max_step:g}: must be at least 1")
    _check_inputs([args.log])
    check_outputs([args.params_out], [args.log])
    from mavsid.cli_format import format_tune
    from mavsid.loop.limits import Limits
    from mavsid.loop.tune import param_file, tune
    from mavsid.pipeline import FIT_STAGES, fit
    from mavsid.pipeline_results import json_safe

    cfg = _pipeline_config(args)
    with progress(args, 1 + len(FIT_STAGES) * len(cfg.axes) + 1) as step:
        result = fit([args.log], cfg, progress=step)
        step("loop analysis")
        report = tune(result, args.target_pm, limits=Limits(max_step=args.max_step))
    if args.params_out:
        text = param_file(report, args.log)  # (refuses, naming why, when nothing is suggested)
        with atomic_path(args.params_out) as tmp, open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
    if args.json:
        print(json.dumps({"axes": json_safe(report), "log": args.log,
                          "target_pm_deg": args.target_pm, "max_step": args.max_step,
                          "params_out": args.params_out}))
    else:
        print(format_tune(report))
    return 0


def _add_response(p: argparse.ArgumentParser) -> None:
    p.add_argument("logs", nargs="+", metavar="LOG", help="flight log(s) (.bin .log .tlog .ulg)")
    _add_output_flags(p)


def _response(args: argparse.Namespace) -> int:
    """how well the vehicle followed its commands: step, bandwidth, noise

    Per axis and controller loop (rate; attitude where logged): the step response from target to
    actual by regularised deconvolution over overlapping windows (mean and band), rise time,
    overshoot, settling, the closed-loop bandwidth with coherence, tracking error and delay,
    gyro and controller-output spectra with the configured filters, one response per
    rate-controller setting where parameters change in flight. Needs only a rate target and
    the rate: works on ordinary flights.
    """
    import json

    check_outputs([args.rrd, args.report], args.logs)
    from mavsid.pipeline_results import json_safe

    cfg = _pipeline_config(args)
    found: list[FlightResponse] = []
    docs: list[dict[str, Any]] = []
    errors: list[str] = []
    with progress(args, len(args.logs) + bool(args.rrd) + bool(args.report)) as step:
        for log in args.logs:
            step(f"reading {log}")
            try:
                _check_inputs([log])
                got = _read_response(log, cfg)
            except MavsidError as exc:
                if len(args.logs) == 1:
                    raise
                errors.append(str(exc))
                docs.append({"log": log, "error": json.loads(error_document(exc))["error"]})
                continue
            found.append(got)
            docs.append(json_safe(got.to_dict()))
        written = _write_response_outputs(args, found, step) if found else []
    code = 0 if found and not errors else 1
    if args.json:
        doc = docs[0] if len(docs) == 1 else {"logs": docs}
        print(json.dumps(doc, ensure_ascii=True, allow_nan=False))
        return code
    from mavsid.cli_format import format_responses

    print(escape_lines(format_responses(found)))
    for line in errors:
        print(f"mavsid: error: {escape(line)}", file=sys.stderr)
    for path in written:
        print(f"wrote {path}")
    if not found:
        print("mavsid: error: no log could be read", file=sys.stderr)
    return code


def _read_response(log: str, cfg: PipelineConfig) -> FlightResponse:
    """A log's closed-loop response on ``cfg``'s axes and channels."""
    from mavsid.response import read_response

    return read_response(log, cfg.axes, preset=cfg.preset, presets=cfg.presets,
                         mixers=cfg.mixers)


def _write_response_outputs(args: argparse.Namespace, found: Sequence[FlightResponse],
                            step: Callable[[str], None] = lambda stage: None,
                            notes: Sequence[str] = (), title: str = "mavsid response"
                            ) -> list[str]:
    """The ``.rrd`` and the report of ``mavsid response`` (of ``fit`` when no plant was
    identified: ``notes`` say why, first); the paths written."""
    def rrd(tmp: str) -> None:
        from mavsid.viz.response import save_response_rrd

        save_response_rrd(found, tmp, notes)

    def report(tmp: str) -> None:
        from mavsid.report import write_response_report

        write_response_report(found, tmp, title=title, notes=notes)

    written = []
    for path, write in ((args.rrd, rrd), (args.report, report)):
        if path:
            step(f"writing {path}")
            with atomic_path(path) as tmp:
                write(tmp)
            written.append(path)
    return written


def _add_batch(p: argparse.ArgumentParser) -> None:
    p.add_argument("inputs", nargs="+", metavar="LOG|DIR",
                   help="logs, or folders searched for .bin .log .tlog .ulg")
    p.add_argument("-o", "--output", default="results.parquet", metavar="OUT.parquet",
                   help="results table (also OUT.logs.parquet, OUT.segments.parquet)")
    _add_config_flag(p)
    p.add_argument("--workers", type=int, metavar="N",
                   help="worker processes of the local cluster (default: cores)")
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                   help="a running dask scheduler to use instead of a local cluster")
    p.add_argument("--vehicles", metavar="MAP.csv",
                   help="CSV log,vehicle[,date]: each log's aircraft (default: its folder)")
    p.add_argument("--report", metavar="OUT.html",
                   help="write the trends page (parameters against flight date, change points)")
    p.add_argument("--rrd", metavar="OUT.rrd",
                   help="write the trends as a rerun recording (timelines flight and "
                   "flight_date; parameters with ±σ, change points)")
    _add_quiet_flag(p)
    p.set_defaults(axis=None)


def _batch(args: argparse.Namespace) -> int:
    """fit many logs on Dask (locally, or on a cluster) into Parquet tables

    One `mavsid fit` per log on a dask.distributed cluster: a local cluster of worker processes
    by default (listening on 127.0.0.1), or the scheduler at --scheduler. Results (per log x
    axis, per log, per segment) go to Parquet after each log, atomically; a rerun skips logs
    already in the tables with the same settings; a failing log is a row with its error.
    """
    from mavsid.batch import run_batch, summary_lines, table_paths, trends, write_trends_html

    if not args.output.endswith(".parquet"):
        raise ConfigError(f"{args.output}: the results table must be a .parquet file")
    outs = list(table_paths(args.output).values())
    check_outputs([*outs, args.report, args.rrd], args.inputs)
    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"--workers {args.workers}: must be at least 1")
    fitted: list[dict[str, Any]] = []  # (the logs this run fitted, as each ends)
    tables = run_batch(args.inputs, args.output, _pipeline_config(args), workers=args.workers,
                       scheduler=args.scheduler, vehicles=args.vehicles,
                       progress=not args.quiet and sys.stderr.isatty(), on_done=fitted.append)
    for line in summary_lines(tables["logs"], len(fitted), outs[0]):
        print(escape(line))
    found = trends(tables["axes"])
    for row in found[found["changed"]].to_dict("records") if len(found) else []:
        print(escape(change_line(row)))
    if args.report:
        write_trends_html(tables, args.report)
        print(f"wrote {args.report}")
    if args.rrd:
        from mavsid.viz.trends import save_trends_rrd

        with atomic_path(args.rrd) as tmp:
            save_trends_rrd(tables["axes"], tmp)
        print(f"wrote {args.rrd} (open it with: rerun --bind 127.0.0.1 {args.rrd})")
    return 0


class UsageError(Exception):
    """A command line argparse refuses (exit 2): raised by :class:`_Parser` instead of
    exiting, so that :func:`main` can answer ``--json`` with a JSON document."""

    def __init__(self, message: str, text: str) -> None:
        super().__init__(message)
        self.text = text


class _Parser(argparse.ArgumentParser):
    """An argument parser that raises :class:`UsageError` (its subcommands' parsers too)."""

    def error(self, message: str) -> NoReturn:
        raise UsageError(message, f"{self.format_usage()}{self.prog}: error: {message}")


#: The subcommands (handler, its arguments), in the order ``mavsid --help`` lists them.
SUBCOMMANDS: tuple[tuple[Handler, Callable[[argparse.ArgumentParser], None]], ...] = (
    (_info, _add_info), (_extract, _add_extract), (_segments, _add_segments),
    (_simulate, _add_simulate), (_fit, _add_fit), (_validate, _add_validate),
    (_view, _add_view), (_tune, _add_tune), (_response, _add_response),
    (_batch, _add_batch),
)


def _add_subcommand(sub: argparse._SubParsersAction, handler: Handler,
                    add: Callable[[argparse.ArgumentParser], None]) -> None:
    """Declare the subcommand ``handler`` runs (named after it, its help from its docstring)
    with the arguments ``add`` declares."""
    summary, _, description = (handler.__doc__ or "").partition("\n\n")
    p = sub.add_parser(handler.__name__.lstrip("_"), help=" ".join(summary.split()),
                       description=" ".join(description.split()) or None)
    p.set_defaults(handler=handler)
    add(p)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every subcommand.

    ``--debug`` is taken before or after the subcommand:

    >>> build_parser().parse_args(["fit", "a.bin", "--debug"]).debug
    True
    >>> build_parser().parse_args(["--debug", "fit", "a.bin"]).debug
    True
    """
    parser = _Parser(
        prog="mavsid",
        description="Attitude-dynamics models from ArduPilot and PX4 flight logs.",
    )
    parser.add_argument("--version", action="store_true", help="print the version and exit")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for handler, add in SUBCOMMANDS:
        _add_subcommand(sub, handler, add)
    for command in sub.choices.values():  # (SUPPRESS: absent, it keeps the top level's)
        command.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                             help="show tracebacks on errors")
    return parser


#: The cyclic collector's thresholds for one command run from the command line: Python's
#: (700, 10, 10) collected 800 times during ``fit --rrd --report`` on the SITL flight (0.6 s,
#: a tenth of the run, mostly walking matplotlib's and the fit's long-lived objects); these
#: 60 times (0.17 s) for 12 MB more peak memory. Results do not depend on it.
_GC_THRESHOLDS = (20_000, 20, 20)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code.

    Without ``argv`` (the process's own command line: the ``mavsid`` script, ``python -m
    mavsid``) the process runs one command and exits, so the cyclic garbage collector runs
    less often (:data:`_GC_THRESHOLDS`) and the objects still alive at the end are frozen
    (the exit's collection skips them)."""
    for stream in (sys.stdout, sys.stderr):  # a non-UTF-8 terminal gets escapes, not a crash
        reconfigure = getattr(stream, "reconfigure", None)
        if reconfigure is not None:
            with contextlib.suppress(ValueError, OSError):
                reconfigure(errors="backslashreplace")
    parser = build_parser()
    words = sys.argv[1:] if argv is None else list(argv)
    try:
        args = parser.parse_args(words)
    except UsageError as exc:
        print(exc.text, file=sys.stderr)
        if "--json" in words:
            print(error_document(exc, "UsageError"))
        raise SystemExit(2) from None  # (as argparse exits on a usage error)
    if args.version:
        print(f"mavsid {__version__} ({readers_build()})")
        return 0
    if not getattr(args, "handler", None):
        parser.print_help(sys.stderr)
        return 2
    handler: Handler = args.handler
    warnings.showwarning = _show_warning
    previous = signal.getsignal(signal.SIGTERM)
    signal.signal(signal.SIGTERM, _terminate)  # like Ctrl-C: outputs and children cleaned up
    once = argv is None  # the process's own command line (not a caller's main([...]))
    if once:
        gc.set_threshold(*_GC_THRESHOLDS)
        from mavsid.threads import limit_process_blas

        limit_process_blas()
    as_json = bool(getattr(args, "json", False))  # (stdout: one JSON document, always)
    try:
        return handler(args)
    except MavsidError as exc:
        if args.debug:
            traceback.print_exc()
        print_error(exc, as_json)
        return 1
    except BrokenPipeError:  # the reader closed stdout (``mavsid ... | head``): stop quietly
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # (so the interpreter's flush at exit is quiet)
        return 141
    except KeyboardInterrupt as exc:
        if as_json:
            print(error_document(exc, "Interrupted"))
        print("mavsid: interrupted", file=sys.stderr)
        return 130
    finally:
        warnings.showwarning = _default_showwarning
        signal.signal(signal.SIGTERM, previous)
        if once:  # the interpreter's last collection at exit would walk every live object
            gc.freeze()


def _terminate(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
