"""Real flights: what mavsid makes of every real log it finds, per log and axis.

    python benchmarks/bench_real.py [DIR ...] [--axis roll] [--json OUT.json]

Real logs from public repositories carry no licence to redistribute, so none is part of the
project: put them in a folder of your own (by default ``$MAVSID_REAL_LOGS``, else
``../cache`` beside the checkout, searched recursively for ``.bin``, ``.log``, ``.tlog`` and
``.ulg``) and this script runs ``mavsid fit --json`` on each, one process per log, and
prints per log and axis:

* the response measured against the SYSTEMID injection and its transfer-function fit
  (structure, B, lag, delay, CIFER cost J, the trusted band) with σ;
* the time-domain model (its B, delay and input lag);
* the model's response against the measured one (RMS dB and degrees over the band);
* the controller emulation check (the rebuilt controller against the logged output) and the
  closed-loop twin against its baseline ("the rate follows its target after the best
  delay"), where the log allows them;
* the verdict, or the one line that refused the log.

It judges nothing: a reader compares these figures with the flight's own measured response
(``python benchmarks/bench_real.py --reference`` adds an independent one: plain
``scipy.signal.csd`` over the SYSTEMID run with the injection as reference, and a least-
squares fit of ``B e^{-τs} / (s (T s + 1))`` to it, none of mavsid's estimation code).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
SUFFIXES = (".bin", ".log", ".tlog", ".ulg")


def _logs(dirs: list[Path]) -> Iterator[Path]:
    for d in dirs:
        if d.is_file():
            yield d
            continue
        for p in sorted(d.rglob("*")):
            if p.is_file() and p.suffix.lower() in SUFFIXES:
                yield p


def _fit(path: Path, axis: str | None) -> tuple[int, dict[str, Any] | None, str, float]:
    cmd = [sys.executable, "-m", "mavsid", "fit", str(path), "--json"]
    if axis:
        cmd += ["--axis", axis]
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600, check=False)
    took = time.perf_counter() - t0
    try:
        doc = json.loads(done.stdout) if done.stdout.strip() else None
    except json.JSONDecodeError:
        doc = None
    err = next((ln for ln in reversed(done.stderr.splitlines()) if ln.startswith("mavsid:")),
               "")
    return done.returncode, doc, err, took


def _g(v: Any, fmt: str = ".3g") -> str:
    return "-" if not isinstance(v, (int, float)) else format(v, fmt)


def _pm(d: Mapping[str, Any], key: str, scale: float = 1.0, fmt: str = ".3g") -> str:
    v = d.get(key)
    s = d.get("sigma", {}).get(key)
    if not isinstance(v, (int, float)):
        return "-"
    out = format(v * scale, fmt)
    return out + (f"±{s * scale:{fmt}}" if isinstance(s, (int, float)) else "")


def _axis_lines(axis: str, a: Mapping[str, Any]) -> list[str]:
    fr = a.get("frequency_response") or {}
    params = a.get("params", {})
    b_td = next((v for k, v in params.items() if k.startswith("B[")), None)
    lines = [f"  {axis}: verdict {a.get('verdict', {}).get('level', '-')}"]
    if fr:
        band = fr.get("band_hz") or [None, None]
        lines.append(
            f"    measured response ({'injection' if fr.get('referenced') else 'input'}-"
            f"referenced): {fr.get('structure', '-')} B {_pm(fr, 'B')}, lag "
            f"{_pm(fr, 'lag_s', 1e3, '.1f')} ms, delay {_pm(fr, 'delay_s', 1e3, '.1f')} ms, "
            f"J {_g(fr.get('J'), '.1f')}, band {_g(band[0])}–{_g(band[1])} Hz")
        mc = fr.get("model_check") or {}
        lines.append(f"    model vs measured: {_g(mc.get('rms_db'), '.2f')} dB / "
                     f"{_g(mc.get('rms_deg'), '.1f')} deg RMS")
    elif a.get("frequency_response_note"):
        lines.append(f"    measured response: {a['frequency_response_note']}")
    delay_ms = (a.get("delay_s") or 0) * 1e3
    lines.append(f"    time-domain model: B {_g(b_td)}, delay {_g(delay_ms, '.1f')}"
                 f" ms, input lag {_g((a.get('input_lag_s') or 0) * 1e3, '.1f')} ms")
    cl = a.get("closed_loop") or {}
    emu = cl.get("emulation") or a.get("emulation") or {}
    if emu:
        fits = {k: (v.get("fit_percent") if isinstance(v, dict) else v)
                for k, v in (emu.get("terms") or {}).items()}
        terms = ", ".join(f"{k} {v:.1f} %" for k, v in fits.items()
                          if isinstance(v, (int, float)))
        lines.append(f"    controller emulation {_g(emu.get('fit_percent'), '.1f')} % "
                     f"({'passed' if emu.get('passed') else 'failed'}"
                     f"{'; ' + terms if terms else ''})"
                     + (f": {emu['reason']}" if emu.get("reason") else ""))
    if cl:
        lines.append(f"    twin {_g(cl.get('fit_percent'), '.1f')} % against baseline "
                     f"{_g(cl.get('baseline_percent'), '.1f')} %")
    elif a.get("closed_loop_note"):
        lines.append(f"    twin: {a['closed_loop_note']}")
    return lines


def _reference(path: Path) -> str:
    """An independent measured response of the first SYSTEMID run: scipy only."""
    import numpy as np
    from pymavlink import mavutil
    from scipy import optimize, signal

    m = mavutil.mavlink_connection(str(path))
    sidd: list[tuple[float, float]] = []
    rate: list[tuple[float, float, float]] = []
    sid_axis = None
    while (msg := m.recv_match(type=["SIDD", "RATE", "SIDS"])) is not None:
        kind = msg.get_type()
        if kind == "SIDS" and sid_axis is None:
            sid_axis = int(msg.Ax)
        elif kind == "SIDD":
            sidd.append((msg.TimeUS * 1e-6, msg.Targ))
        elif kind == "RATE":
            rate.append((msg.TimeUS * 1e-6, msg.R, msg.ROut))
    if not sidd or sid_axis not in (1, 4, 7, 10):
        return "reference: no roll SYSTEMID run"
    s, r = np.array(sidd), np.array(rate)
    fs = 1.0 / float(np.median(np.diff(s[:, 0])))
    grid = np.arange(s[0, 0], s[-1, 0], 1.0 / fs)
    ref = np.interp(grid, s[:, 0], s[:, 1])
    y = np.radians(np.interp(grid, r[:, 0], r[:, 1]))
    u = np.interp(grid, r[:, 0], r[:, 2])
    nper = int(2 ** np.round(np.log2(5 * fs)))
    f, s_ru = signal.csd(ref, u, fs=fs, nperseg=nper)
    _, s_ry = signal.csd(ref, y, fs=fs, nperseg=nper)
    _, s_rr = signal.welch(ref, fs=fs, nperseg=nper)
    _, s_yy = signal.welch(y, fs=fs, nperseg=nper)
    h = s_ry / s_ru
    coh = np.abs(s_ry) ** 2 / (s_rr * s_yy)
    band = (f >= 1.0) & (coh >= 0.6)
    if band.sum() < 4:
        return f"reference: the rate is coherent with the injection at {band.sum()} frequencies"
    w = 2 * np.pi * f[band]

    def resid(p: np.ndarray) -> np.ndarray:
        b, lag, tau = p
        model = b * np.exp(-1j * w * tau) / (1j * w * (1j * w * lag + 1))
        d = np.log(h[band] / model)
        return np.concatenate([d.real * 8.686, np.angle(np.exp(1j * d.imag)) * 57.3 * 0.132])

    got = optimize.least_squares(resid, [400.0, 0.01, 0.01],
                                 bounds=([1.0, 0.0, 0.0], [1e4, 0.1, 0.1]))
    b, lag, tau = got.x
    return (f"reference (scipy csd, {nper}-sample windows, band {f[band][0]:.2g}–"
            f"{f[band][-1]:.3g} Hz): B {b:.0f}, lag {lag * 1e3:.1f} ms, delay {tau * 1e3:.1f} ms")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dirs", nargs="*", type=Path)
    ap.add_argument("--axis", choices=("roll", "pitch", "yaw"))
    ap.add_argument("--reference", action="store_true",
                    help="add an independent scipy-only measured response per roll run")
    ap.add_argument("--json", type=Path, help="write every fit's JSON document here")
    args = ap.parse_args(argv)
    dirs = args.dirs or [Path(os.environ.get("MAVSID_REAL_LOGS", ROOT.parent / "cache"))]
    logs = list(_logs([d for d in dirs if d.exists()]))
    if not logs:
        print(f"no real logs under {', '.join(map(str, dirs))}: nothing to run")
        return 0
    everything: dict[str, Any] = {}
    for path in logs:
        rc, doc, err, took = _fit(path, args.axis)
        print(f"{path.name}  exit {rc}  {took:.1f} s")
        if doc is not None:
            everything[str(path)] = doc
            for axis, a in (doc.get("axes") or {}).items():
                print("\n".join(_axis_lines(axis, a)))
        if err:
            print(f"  {err[:300]}")
        if args.reference and path.suffix.lower() == ".bin":
            try:
                print(f"  {_reference(path)}")
            except Exception as exc:  # a reference that cannot read the log says so
                print(f"  reference: {type(exc).__name__}: {exc}")
    if args.json:
        args.json.write_text(json.dumps(everything, indent=1, default=str), encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
