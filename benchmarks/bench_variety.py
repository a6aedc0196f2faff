"""Variety sweep: mavsid's defaults on simulated flights drawn at random, against the truth.

    python benchmarks/bench_variety.py [--n 30] [--seed 0]

Each flight is drawn from the simulator's whole range: manoeuvre (SYSTEMID mixer chirp, stick
doublet, 3-2-1-1, random stick), axis, vehicle (small quad, heavier X quad, hexacopter, a
light racer on its own rate tuning, a heavy-lift on 120-ms motors) and its motor frame
(quad-X, hexa-X, coaxial Y6 and X8, as ArduPilot mixes them), gyro white noise fed back
through the rate controller (0-6 deg/s), frame vibration (0-5 deg/s), logging rate
(10-400 Hz; 10 Hz logs every message that slowly), a third of the stick flights flown
without a hover before or after (the stick never let go) and log layout (ArduCopter 3.2, 3.3,
3.4-dev, 3.6, 4.x, a 4.x traditional heli, ArduPlane 4.x, an ArduPlane QuadPlane hovering;
PX4 1.11, 1.14; a ground station's MAVLink telemetry, its streams at 50 Hz, or at the
logging rate below 25 Hz; heli and plane fly their own plants).
Each is fitted with the defaults (``pipeline.fit``, the axis flown) and compared with the
simulated plant's truth:

* ``ok``: a model whose control effectiveness is within 10 % of the truth, or within 2.5 of
  the σ it reports;
* ``WRONG``: a model off by more than both, yet called ``good`` (the one outcome that must
  never happen);
* ``poor``: off by more than both, called ``usable`` (its reasons say what it is fit for);
* ``refused``: a typed error or ``not identified``, with its reason;
* ``CRASH``: anything else (must never happen).

With ``--faults``, each flight's log is also damaged as a logger can damage it (drawn apart:
the flights are those of the same ``--seed`` without it): records dropped at random (none,
0.5 %, 2 % or 5 % of each message type's, as an SD card that stalls loses them), a reboot
(the clock restarting at 5 s) in a quarter of them, the last 0-3000 bytes cut off (power
lost mid-write).

It prints one line per flight and the counts. Not a test (a sweep takes minutes); run it
after changing a default, on several ``--seed`` values.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import json
import random
import sys
import tempfile
import time
import warnings
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mavsid import pipeline  # noqa: E402
from mavsid.errors import MavsidError  # noqa: E402
from mavsid.synthetic.faults import Faults  # noqa: E402
from mavsid.synthetic.run import scenario_from_options, simulate  # noqa: E402

RATE = {"roll": "p", "pitch": "q", "yaw": "r"}
SID_AXIS = {"roll": 10, "pitch": 11, "yaw": 12}


def draw(rng: random.Random) -> dict[str, Any]:
    """One flight's settings."""
    s = {
        "manoeuvre": rng.choice(["sysid", "sysid", "doublet", "3211", "random"]),
        "axis": rng.choice(["roll", "pitch", "yaw"]),
        "vehicle": rng.choice(["quad", "heavy-x", "hexa", "racer"]),
        "gyro_noise_dps": rng.choice([0.0, 0.0, 1.0, 3.0, 6.0]),
        "vibration_dps": rng.choice([0.0, 0.0, 2.0, 5.0]),
        "rate_hz": float(rng.choice([10, 25, 50, 100, 200, 400])),
        "layout": rng.choice(["copter-4", "copter-4", "copter-3.6", "copter-3.3",
                              "copter-3.4-dev", "copter-3.2", "heli", "plane", "px4-1.14",
                              "px4-1.11", "tlog"]),
        "seed": rng.randrange(1000),
    }
    if s["manoeuvre"] == "sysid":  # the chirp's top: the default, or a short sweep
        s["f_stop_hz"] = rng.choice([15.0, 15.0, 8.0, 3.0])
    if s["layout"] == "plane" and s["manoeuvre"] == "sysid":  # (ArduPlane has no SYSTEMID)
        s["manoeuvre"] = rng.choice(["doublet", "3211", "random"])
    if s["layout"] in ("heli", "plane"):  # (their own plants: a heli's or a wing's physics)
        s["vehicle"] = s["layout"]
    if s["layout"] == "plane":  # half the ArduPlane logs a QuadPlane hovering (drawn apart)
        vtol = random.Random(f"vtol {s['seed']}")
        if vtol.random() < 0.5:
            s["layout"], s["vehicle"] = "quadplane", vtol.choice(["quad", "heavy-x", "hexa"])
    if s["vehicle"] == "heavy-x" and random.Random(f"lift {s['seed']}").random() < 0.25:
        s["vehicle"] = "heavy-lift"  # a quarter of the heavy quads on 120-ms motors (apart)
    # the motor frame, drawn apart (the draws above stay those of earlier sweeps): a hexa's
    # plant as hexa-X or coaxial Y6, a heavy X's as quad-X or coaxial X8 (ArduCopter 3.2
    # named its frame only by its build: quad-X there)
    frames = {"hexa": ["hexa-x", "y6b"], "heavy-x": ["quad-x", "octaquad-x"]}
    if s["layout"] != "copter-3.2" and s["vehicle"] in frames:
        s["frame"] = random.Random(f"frame {s['seed']}").choice(frames[s["vehicle"]])
    # a third of the stick flights flown without a hover before or after (the pilot never
    # lets go of the stick: no quiet stretch in the log), drawn apart
    if s["manoeuvre"] != "sysid" and random.Random(f"hover {s['seed']}").random() < 1 / 3:
        s["stirred"] = True
    return s


def draw_faults(s: dict[str, Any]) -> dict[str, float]:
    """Damage for the flight ``s`` (see the module's ``--faults``), drawn from its seed apart
    from :func:`draw`: the fraction of records dropped, where a reboot falls (a fraction of
    the flight, 0 for none; a ULog holds one boot: none there), bytes cut off the end."""
    rng = random.Random(f"faults {s['seed']} {s['manoeuvre']} {s['axis']} {s['layout']}")
    reboot = rng.uniform(0.25, 0.75) if rng.random() < 0.25 else 0.0
    return {"drop": rng.choice([0.0, 0.005, 0.02, 0.05]),
            "reboot": 0.0 if s["layout"].startswith("px4") else reboot,
            "cut": rng.choice([0, 0, 100, 3000]), "seed": rng.randrange(1000)}


def run_one(folder: Path, i: int, s: dict[str, Any],
            damage: dict[str, float] | None = None) -> tuple[str, str]:
    """Simulate, fit and judge one flight: (outcome, line)."""
    opts = {k: v for k, v in s.items() if k not in ("layout", "stirred")}
    if s["manoeuvre"] == "sysid":
        opts["sid_axes"] = (SID_AXIS[s["axis"]],)
    suffix = (".ulg" if s["layout"].startswith("px4")
              else ".tlog" if s["layout"] == "tlog" else ".bin")
    log = folder / f"f{i}{suffix}"
    desc = (f"{s['manoeuvre']:7s} {s['axis']:5s} {s['vehicle']:7s} "
            + (f"{s['frame']} " if s.get("frame", "quad-x") != "quad-x" else "")
            + ("no hover " if s.get("stirred") else "")
            +
            f"gyro {s['gyro_noise_dps']:g} vib {s['vibration_dps']:g} {s['rate_hz']:g} Hz "
            f"{s['layout']:14s} seed {s['seed']}"
            + (f" to {s['f_stop_hz']:g} Hz" if "f_stop_hz" in s else "")
            + (f" [drop {damage['drop']:g} reboot {damage['reboot']:.2f} cut "
               f"{damage['cut']:g}]" if damage is not None else ""))
    axis, rate = s["axis"], RATE[s["axis"]]
    try:
        scenario = scenario_from_options(**opts)
        if s.get("stirred"):
            scenario = dataclasses.replace(scenario, hover_before_s=0.0, hover_after_s=0.0)
        faults = None if damage is None else Faults(
            drop_fraction=damage["drop"], truncate_bytes=int(damage["cut"]),
            reboot_at_s=damage["reboot"] * scenario.length_s or None, seed=int(damage["seed"]))
        with contextlib.redirect_stdout(io.StringIO()):
            simulate(scenario, [log], faults,
                     layout=None if s["layout"] == "tlog" else s["layout"])
        truth = json.loads(log.with_suffix(".truth.json").read_text())["axes"][axis]
        try:
            res = pipeline.fit([str(log)], pipeline.PipelineConfig(axes=(axis,)))
        except MavsidError as exc:
            return "refused", f"{desc} :: {str(exc).split(': ', 1)[-1][:110]}"
        f = res.axes[axis]
        level = f.verdict.level if f.verdict else "?"
        if f.model is None or level == "not identified":
            why = f.verdict.reasons[0] if f.verdict and f.verdict.reasons else ""
            return "refused", f"{desc} :: {why[:110]}"
        key = f"B[{rate},u_{axis}]"
        b, se = float(f.model.params[key]), float(f.model.stderr.get(key, float("nan")))
        damping = -float(f.model.params[f"A[{rate},{rate}]"])
        err = b / truth["effectiveness"] - 1.0
        z = abs(b - truth["effectiveness"]) / se if se > 0 else float("inf")
        near = abs(err) <= 0.10 or z <= 2.5
        outcome = "ok" if near else ("WRONG" if level == "good" else "poor")
        v = f.validation
        free = float(v.fit_free_run[v.state_names.index(f.output)])
        cl = f.closed_loop
        twin = (f"twin {cl.fit_percent:6.1f} / baseline {cl.baseline_percent:6.1f}"
                if cl is not None else "twin not run")
        return outcome, (f"{desc} :: {level:7s} B {100 * err:+6.1f} % ({z:4.1f} σ) damping "
                         f"{100 * (damping / truth['damping'] - 1):+6.1f} % free run "
                         f"{free:6.1f} % {twin}")
    except Exception as exc:  # (the sweep reports every failure and goes on)
        return "CRASH", f"{desc} :: {type(exc).__name__}: {exc}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=30, help="flights (30)")
    ap.add_argument("--seed", type=int, default=0, help="draws the flights (0)")
    ap.add_argument("--faults", action="store_true",
                    help="damage each log as a logger can (dropped records, a reboot, a cut end)")
    args = ap.parse_args(argv)
    rng = random.Random(args.seed)
    counts: dict[str, int] = {}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for i in range(args.n):
            s = draw(rng)
            outcome, line = run_one(Path(tmp), i, s, draw_faults(s) if args.faults else None)
            counts[outcome] = counts.get(outcome, 0) + 1
            print(f"{outcome:8s} {line}", flush=True)
    print(f"\n{args.n} flights in {time.perf_counter() - t0:.0f} s: "
          + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
    return 1 if counts.get("WRONG") or counts.get("CRASH") else 0


if __name__ == "__main__":
    sys.exit(main())
