"""Regenerate the figures of the documentation: the validation and performance tables.

    python benchmarks/validation_page.py [--shared ../shared/logs] [--runs 3]

Writes ``docs/_generated/validation.rst`` and ``docs/_generated/performance.rst`` (included
by ``docs/validation.rst`` and ``docs/performance.rst``) and the figures table of
``README.md`` (between its ``figures:start`` and ``figures:end`` marks). Every figure in
them is measured by this script, in this run, on this machine; each file says when, with
which command and on what machine. Nothing is carried over from an earlier run.

Validation: every simulated fixture in ``fixtures/`` that has a ``*.truth.json`` is fitted
with ``mavsid fit --json`` and its control effectiveness and damping compared with the
plant the simulator flew; the ArduCopter SITL SYSTEMID flight in ``SHARED/sitl`` (when
present) is fitted and tuned (``mavsid fit --json``, ``mavsid tune --json``), the margins
predicted from the identified plant set against those measured from the chirp.

Performance: whole ``mavsid`` commands timed in fresh processes (median of ``--runs``), and
the readers against their references (pymavlink, pyulog) on the same bytes, in this run.
The references are optional: a row whose reference is not installed is left out.

About a minute on a 2-core machine with the shared logs, a few seconds without them.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GENERATED = ROOT / "docs" / "_generated"
SITL = "sitl/flightA_mixer.BIN"
AXES = ("roll", "pitch", "yaw")


# --------------------------------------------------------------------------- helpers

def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(var, "1")
    return env


def _mavsid(*args: str) -> list[str]:
    return [sys.executable, "-m", "mavsid", *args]


def _json(argv: list[str]) -> dict:
    """Run a ``mavsid ... --json`` command and return its JSON document.

    A command that identified nothing exits 1; what it printed is kept as ``{"exit": 1}``
    when it is not JSON.
    """
    out = subprocess.run(argv, capture_output=True, text=True, env=_env(), cwd=ROOT)
    try:
        return dict(json.loads(out.stdout))
    except ValueError:
        if out.returncode == 0:
            raise RuntimeError(f"{' '.join(argv)}: no JSON on stdout") from None
        return {"exit": out.returncode}


def _wall(argv: Sequence[str], runs: int) -> list[float]:
    """Wall time of ``argv`` in ``runs`` fresh processes (output discarded)."""
    return [t for t, _ in _timed(argv, runs)]


def _timed(argv: Sequence[str], runs: int) -> list[tuple[float, float]]:
    """Wall and CPU time (user + system) of ``argv`` in ``runs`` fresh processes."""
    import resource

    out = []
    for _ in range(runs):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run(list(argv), capture_output=True, env=_env(), cwd=ROOT, check=False)
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        out.append((wall, after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime))
    return out


def _command_time(argv: Sequence[str], runs: int) -> str:
    """Median CPU time (user + system) of fresh processes, with their median wall time."""
    times = _timed(argv, runs)
    return (f"{statistics.median(c for _, c in times):.2f} s CPU, "
            f"{statistics.median(t for t, _ in times):.2f} s wall")


def _child(code: str) -> float:
    """Seconds a snippet reports (``print(seconds)``) from a fresh interpreter."""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=_env(), cwd=ROOT, check=True)
    return float(out.stdout.split()[-1])


def _has(module: str) -> bool:
    out = subprocess.run([sys.executable, "-c", f"import {module}"], capture_output=True,
                         env=_env(), check=False)
    return out.returncode == 0


def _level(verdict: dict) -> str:
    return str(verdict.get("level") or verdict.get("verdict") or "?")


def _pm(value: float | None, sigma: float | None, fmt: str = ".1f") -> str:
    if value is None:
        return "none"
    return f"{value:{fmt}}" + (f" ± {sigma:{fmt}}" if sigma else "")


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """An RST list-table."""
    lines = [".. list-table::", "   :header-rows: 1", "   :widths: auto", ""]
    for row in [header, *rows]:
        lines.append(f"   * - {row[0]}")
        lines.extend(f"     - {cell}" for cell in row[1:])
    return "\n".join(lines) + "\n"


def _param(params: dict, prefix: str) -> str | None:
    return next((k for k in params if k.startswith(prefix)), None)


def _machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        load = f", load {os.getloadavg()[0]:.1f} at the start"
    except OSError:
        load = ""
    import numpy
    return (f"{cpu}, {os.cpu_count()} cores{load}; Python {platform.python_version()}, "
            f"numpy {numpy.__version__}")


def _header(title: str, command: str, machine: str) -> str:
    date = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    return (f".. Generated by benchmarks/validation_page.py: do not edit by hand.\n\n"
            f"*{title}: measured {date} with* ``{command}`` *on {machine}.*\n\n")


# --------------------------------------------------------------------------- validation

def fixture_rows() -> list[list[str]]:
    """Every axis fitted on a simulated fixture, against the simulator's true plant."""
    rows = []
    for truth_path in sorted((ROOT / "fixtures").glob("*.truth.json")):
        stem = truth_path.name.removesuffix(".truth.json")
        logs = [p for p in truth_path.parent.glob(stem + ".*") if p.suffix in
                (".bin", ".ulg", ".log", ".tlog")]
        if not logs:
            continue
        log = sorted(logs, key=lambda p: (p.suffix != ".bin", p.suffix))[0]
        truth = json.loads(truth_path.read_text())
        doc = _json(_mavsid("fit", str(log.relative_to(ROOT)), "--json", "-q"))
        if not doc.get("axes"):
            rows.append([f"``{log.name}``", "every axis", "not identified (exit 1)",
                         *["—"] * 4])
        for axis, fitted in (doc.get("axes") or {}).items():
            true = (truth.get("axes") or {}).get(axis)
            params, stderr = fitted.get("params", {}), fitted.get("stderr", {})
            b_key, a_key = _param(params, "B["), _param(params, "A[")
            if true is None or b_key is None:
                continue
            b, sb = params[b_key], stderr.get(b_key) or 0.0
            b_true = true["effectiveness"]
            damping = -params[a_key] if a_key else float("nan")
            d_true = true["damping"]
            fit = fitted.get("fit_percent", {})
            error = f"{100 * (b / b_true - 1):+.1f} %"
            rows.append([
                f"``{log.name}``", axis, _level(fitted.get("verdict", {})),
                f"{b:.1f} ± {sb:.1f} ({b_true:g})",
                f"{error} ({abs(b - b_true) / sb:.1f} σ)" if sb else error,
                f"{damping:.2f} ({d_true:g})",
                f"{fit.get('free_run', float('nan')):.1f} %",
            ])
    return rows


def sitl_tables(shared: Path) -> tuple[str, str, dict]:
    """The SITL flight's fit per axis and its loop figures, as RST tables."""
    log = str(shared / SITL)
    fit = _json(_mavsid("fit", log, "--json", "-q"))
    tune = _json(_mavsid("tune", log, "--json", "-q"))
    fit_rows, tune_rows, summary = [], [], {}
    for axis in AXES:
        a = (fit.get("axes") or {}).get(axis)
        if a is None:
            continue
        params, stderr = a["params"], a.get("stderr", {})
        b_key = _param(params, "B[")
        pct = a.get("fit_percent", {})
        closed = (a.get("closed_loop") or {}).get("fit_percent")
        fit_rows.append([axis, _level(a.get("verdict", {})), f"{pct.get('free_run', 0):.1f} %",
                         f"{pct.get('0.5s', 0):.1f} %", f"{pct.get('one_step', 0):.1f} %",
                         "—" if closed is None else f"{closed:.1f} %",
                         f"{params[b_key]:.4g} ± {stderr.get(b_key, 0):.2g}" if b_key else "—"])
        summary[axis] = {"free_run": pct.get("free_run"), "closed": closed}
    for axis in AXES:
        t = (tune.get("axes") or {}).get(axis)
        if t is None or not t.get("margins"):
            continue
        m, se, cl = t["margins"], t.get("stderr", {}), t.get("closed_loop", {})
        measured = (t.get("loop_frf_margins") or {}).get("phase_deg")
        predicted = (t.get("loop_predicted_margins") or {}).get("phase_deg")
        agree = t.get("loop_frf_vs_predicted") or {}
        tune_rows.append([
            axis, _pm(m.get("phase_deg"), se.get("phase_margin_deg")) + "°",
            _pm(m.get("gain_db"), se.get("gain_margin_db")) + " dB",
            _pm(m.get("crossover_hz"), se.get("crossover_hz"), ".2f") + " Hz",
            _pm(cl.get("bandwidth_hz"), se.get("bandwidth_hz"), ".2f") + " Hz",
            "—" if measured is None else f"{measured:.1f}° / {predicted:.1f}°",
            "—" if not agree else f"{agree['median_db']:.1f} dB / {agree['median_deg']:.1f}°",
        ])
        summary[axis] = {**summary.get(axis, {}), "pm": m.get("phase_deg"),
                         "pm_sigma": se.get("phase_margin_deg"), "pm_measured": measured}
    fit_table = _table(["axis", "verdict", "free run", "0.5 s ahead", "one step",
                        "closed-loop twin", "control effectiveness B (rad/s² per unit)"],
                       fit_rows)
    tune_table = _table(["axis", "phase margin", "gain margin", "crossover",
                         "closed-loop bandwidth", "phase margin at the mixer: measured / "
                         "predicted", "measured against predicted loop (median)"], tune_rows)
    return fit_table, tune_table, summary


# --------------------------------------------------------------------------- performance

def _prefix(src: Path, mb: float, dst: Path) -> Path:
    with src.open("rb") as f:
        dst.write_bytes(f.read(int(mb * 1e6)))
    return dst


def _read_mavsid(path: Path, messages: Sequence[str] | None) -> float:
    sel = repr(list(messages)) if messages else "None"
    return _child("import time, mavsid.readers as r; t=time.perf_counter(); "
                  f"r.read_log({str(path)!r}, messages={sel}); print(time.perf_counter()-t)")


def _read_pymavlink(path: Path, types: Sequence[str] | None) -> float:
    sel = f"type={list(types)!r}" if types else ""
    return _child("import time; from pymavlink import mavutil; t=time.perf_counter(); "
                  f"m=mavutil.mavlink_connection({str(path)!r})\n"
                  f"while True:\n    msg=m.recv_match({sel})\n    if msg is None: break\n"
                  "    msg.to_dict()\n"
                  "print(time.perf_counter()-t)")


def performance_rows(shared: Path | None, runs: int, tmp: Path) -> tuple[list, dict]:
    rows: list[list[str]] = []
    summary: dict[str, str] = {}
    med = statistics.median

    bare = med(_wall([sys.executable, "-c", "pass"], runs + 2))
    version = med(_wall(_mavsid("--version"), runs + 2))
    rows.append(["``mavsid --version``", f"{version - bare:.2f} s beyond the interpreter",
                 f"a bare interpreter, {bare:.2f} s", "fresh processes"])

    fixture = "fixtures/sysid_roll.bin"
    size = (ROOT / fixture).stat().st_size / 1e3
    t = _command_time(_mavsid("fit", fixture, "-q"), runs)
    rows.append([f"``mavsid fit {fixture}`` ({size:.0f} kB)", t, "—", "fresh processes"])
    summary["fit_fixture"] = t

    if shared is not None:
        log = shared / SITL
        mb = log.stat().st_size / 1e6
        t = _command_time(_mavsid("fit", str(log), "-q"), runs)
        rows.append([f"``mavsid fit`` of the {mb:.0f}-MB SITL ``.bin``", t, "—",
                     "fresh processes"])
        summary["fit_sitl"] = t
        summary["sitl_mb"] = f"{mb:.0f}"
        t = _command_time(_mavsid("fit", str(log), "-q", "--rrd", str(tmp / "f.rrd"),
                                  "--report", str(tmp / "f.html")), runs)
        rows.append(["the same with ``--rrd --report``", t, "—", "fresh processes"])
        summary["fit_sitl_outputs"] = t
        t = _command_time(_mavsid("tune", str(log), "-q"), runs)
        rows.append([f"``mavsid tune`` of the {mb:.0f}-MB SITL ``.bin``", t, "—",
                     "fresh processes"])

        fit_reads = ("ATT", "RATE", "IMU", "RCOU")
        whole = med(_read_mavsid(log, fit_reads) for _ in range(runs))
        rows.append([f"reading ATT/RATE/IMU/RCOU of the {mb:.0f}-MB ``.bin``",
                     f"{whole:.2f} s", "—", "first read in a fresh process"])
        if _has("pymavlink"):
            part = _prefix(log, 20, tmp / "prefix.bin")
            ours = med(_read_mavsid(part, fit_reads) for _ in range(runs))
            ref = _read_pymavlink(part, fit_reads)
            rows.append(["the same, first 20 MB", f"{ours:.3f} s, **{ref / ours:.0f}×**",
                         f"pymavlink ``recv_match(type=...)``, {ref:.1f} s",
                         "first read in a fresh process"])
            summary["dataflash_ratio"] = f"{ref / ours:.0f}×"
        tlog = shared / "sitl" / "flightA_mixer.tlog"
        if tlog.is_file() and _has("pymavlink"):
            part = _prefix(tlog, 4, tmp / "prefix.tlog")
            ours = med(_read_mavsid(part, None) for _ in range(runs))
            ref = _read_pymavlink(part, None)
            rows.append(["reading every message of 4 MB of ``.tlog``",
                         f"{ours:.3f} s, **{ref / ours:.0f}×**",
                         f"pymavlink ``recv_match`` loop, {ref:.1f} s",
                         "first read in a fresh process"])
            summary["tlog_ratio"] = f"{ref / ours:.0f}×"
        ulogs = sorted(p for p in (shared / "public").rglob("*.ulg")
                       if not p.name.startswith("corrupt"))
        if ulogs and _has("pyulog"):
            paths = repr([str(p) for p in ulogs])
            code = ("import time, mavsid.readers as r, pyulog\n"
                    f"paths={paths}\n"
                    "def best(f):\n"
                    "    out=[]\n"
                    "    for _ in range(3):\n"
                    "        t=time.perf_counter(); [f(p) for p in paths]; "
                    "out.append(time.perf_counter()-t)\n"
                    "    return min(out)\n"
                    "a=best(r.read_log); b=best(pyulog.ULog); print(a, b)")
            out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                                 env=_env(), cwd=ROOT, check=True).stdout.split()
            ours, ref = float(out[-2]), float(out[-1])
            total = sum(p.stat().st_size for p in ulogs) / 1e6
            rows.append([f"reading the {len(ulogs)} shared ULogs ({total:.0f} MB)",
                         f"{ours:.3f} s, **{ref / ours:.0f}×**", f"pyulog, {ref:.2f} s",
                         "best of 3 in one process"])
            summary["ulog_ratio"] = f"{ref / ours:.0f}×"
    return rows, summary


# --------------------------------------------------------------------------- output

def _readme_block(summary: dict, perf: dict) -> str:
    rows = []
    if "fit_fixture" in perf:
        rows.append(("`mavsid fit fixtures/sysid_roll.bin`", perf["fit_fixture"],
                     "docs/performance.rst"))
    if "fit_sitl" in perf:
        rows.append((f"`mavsid fit` of the {perf['sitl_mb']}-MB SITL `.bin`", perf["fit_sitl"],
                     "docs/performance.rst"))
        rows.append(("the same with `--rrd --report`", perf["fit_sitl_outputs"],
                     "docs/performance.rst"))
    for key, what in (("dataflash_ratio",
                       "reading 20 MB of a `.bin` (what `fit` reads), against pymavlink"),
                      ("tlog_ratio", "reading 4 MB of a `.tlog`, against pymavlink"),
                      ("ulog_ratio", "reading the shared ULogs, against pyulog")):
        if key in perf:
            rows.append((what, f"{perf[key]} faster", "docs/performance.rst"))
    for axis in ("roll", "yaw"):
        s = summary.get(axis)
        if s and s.get("free_run") is not None:
            rows.append((f"SITL {axis}: free-run fit, closed-loop twin",
                         f"{s['free_run']:.1f} %, {s['closed']:.1f} %", "docs/validation.rst"))
    s = summary.get("roll")
    if s and s.get("pm") is not None:
        measured = "" if s.get("pm_measured") is None else \
            f", {s['pm_measured']:.1f}° measured at the mixer"
        rows.append(("SITL roll phase margin (`mavsid tune`)",
                     f"{s['pm']:.1f} ± {s['pm_sigma']:.1f}° predicted{measured}",
                     "docs/validation.rst"))
    date = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d")
    try:
        load = f" at load {os.getloadavg()[0]:.1f}"
    except OSError:
        load = ""
    lines = ["<!-- figures:start (benchmarks/validation_page.py writes this table) -->",
             f"Measured {date} by `python benchmarks/validation_page.py` on {os.cpu_count()} "
             f"cores{load}:", "",
             "| what | figure | details |", "|---|---|---|"]
    lines += [f"| {w} | {f} | [{d}]({d}) |" for w, f, d in rows]
    lines.append("<!-- figures:end -->")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shared", default=str(ROOT.parent / "shared" / "logs"),
                    help="folder of the shared logs (default ../shared/logs)")
    ap.add_argument("--runs", type=int, default=3, help="fresh processes per timing (3)")
    ap.add_argument("--no-readme", action="store_true", help="leave README.md as it is")
    args = ap.parse_args(argv)
    shared = Path(args.shared)
    shared_ok = (shared / SITL).is_file()
    command = "python benchmarks/validation_page.py" + ("" if shared_ok else " (no shared logs)")
    machine = _machine()
    t0 = time.perf_counter()

    parts = [_header("Validation", command, machine)]
    parts += ["Simulated fixtures against their true plant\n",
              "-------------------------------------------\n\n",
              "Control effectiveness *B* and damping (*−A*) identified by ``mavsid fit`` on "
              "each fixture, against the plant the simulator flew "
              "(``fixtures/*.truth.json``); σ is the standard error ``fit`` reports; free run "
              "on the held-out blocks.\n\n",
              _table(["log", "axis", "verdict", "B ± σ (true)", "error", "damping (true)",
                      "free run"], fixture_rows()), "\n"]
    summary: dict = {}
    if shared_ok:
        fit_table, tune_table, summary = sitl_tables(shared)
        parts += ["ArduCopter SITL SYSTEMID flight\n", "-------------------------------\n\n",
                  f"``mavsid fit`` of ``{SITL}`` (mixer-axis chirps 0.5–20 Hz), fit % on "
                  "held-out blocks:\n\n", fit_table, "\n",
                  "``mavsid tune`` of the same flight: the loop predicted from the "
                  "identified plant and the rate controller rebuilt from the log's "
                  "parameters (± σ from the parameter covariance), and the broken loop "
                  "at the mixer measured from the chirp against its prediction:\n\n",
                  tune_table, "\n"]
    else:
        parts.append(f"The shared logs (``{shared}``) were absent: no real-flight table.\n")
    GENERATED.mkdir(parents=True, exist_ok=True)
    (GENERATED / "validation.rst").write_text("".join(parts), encoding="utf-8")

    with tempfile.TemporaryDirectory() as tmp:
        rows, perf = performance_rows(shared if shared_ok else None, args.runs, Path(tmp))
    text = _header("Performance", command, machine) + _table(
        ["what", "figure", "against", "how"], rows)
    (GENERATED / "performance.rst").write_text(text, encoding="utf-8")

    if not args.no_readme:
        readme = ROOT / "README.md"
        old = readme.read_text(encoding="utf-8")
        start, end = old.find("<!-- figures:start"), old.find("<!-- figures:end -->")
        if start >= 0 and end > start:
            new = old[:start] + _readme_block(summary, perf) + \
                old[end + len("<!-- figures:end -->"):]
            readme.write_text(new, encoding="utf-8")
    print(f"wrote {GENERATED / 'validation.rst'}, {GENERATED / 'performance.rst'}"
          f"{'' if args.no_readme else ', README.md'} in {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
