"""A real SYSTEMID flight of real hardware (a Pixhawk 6C quad, ArduCopter 4.6.2, a 20° roll-angle
chirp 1 → 40 Hz): the fitted roll model against the plant's response measured here with plain
``scipy.signal.csd`` and pymavlink, not mavsid's own code.

The log is not part of the project (no licence): it is looked up in ``$MAVSID_REAL_LOGS`` or
``keita/`` below ``helpers.REAL_LOGS``, and the test skips without it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import real_path

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow  # (whole real flights, read twice: by mavsid and by pymavlink)


def real_log(name: str) -> Path:
    """``name`` among the real ArduCopter 4.6.2 logs (``keita/`` below
    ``helpers.REAL_LOGS``); skips the test when it is absent."""
    return real_path("keita", name)


def reference_response(path: Path) -> dict[str, np.ndarray | float]:
    """The roll plant measured against the injection with plain scipy: ``H = S_ry / S_ru``
    (``r`` SIDD.Targ, ``u`` RATE.ROut, ``y`` RATE.R in rad/s, read with pymavlink) over every
    SIDD record, Welch with 512-sample Hann windows; coherence the lower of ``r -> u`` and
    ``r -> y``; and ``B e^{-τs} / (s (T s + 1))`` fitted over the coherent band (γ² >= 0.6)
    by CIFER's cost with ``scipy.optimize.least_squares``."""
    from pymavlink import mavutil
    from scipy import optimize, signal

    mlog = mavutil.mavlink_connection(str(path))
    rows: dict[str, list[tuple[float, ...]]] = {"SIDD": [], "RATE": []}
    while (m := mlog.recv_match(type=["SIDD", "RATE"])) is not None:
        t = m.TimeUS * 1e-6
        rows[m.get_type()].append((t, m.Targ) if m.get_type() == "SIDD" else (t, m.R, m.ROut))
    sidd, rate = np.array(rows["SIDD"]), np.array(rows["RATE"])
    fs = 100.0
    g = np.arange(sidd[0, 0], sidd[-1, 0], 1 / fs)
    r = np.interp(g, sidd[:, 0], sidd[:, 1])
    y = np.radians(np.interp(g, rate[:, 0], rate[:, 1]))
    u = np.interp(g, rate[:, 0], rate[:, 2])
    nper = 512
    f, p_ry = signal.csd(r, y, fs=fs, nperseg=nper)
    _, p_ru = signal.csd(r, u, fs=fs, nperseg=nper)
    coh = np.minimum(signal.coherence(r, y, fs=fs, nperseg=nper)[1],
                     signal.coherence(r, u, fs=fs, nperseg=nper)[1])
    h = p_ry / p_ru
    band = (f >= 1.0) & (f <= 40.0) & (coh >= 0.6)
    # the coherent band: up to the first octave-wide stretch without a coherent point
    fb = f[band]
    cut = np.flatnonzero(fb[1:] / fb[:-1] > 2**0.5)
    top = fb[cut[0]] if cut.size else fb[-1]
    band &= f <= top
    fk, hk, ck = f[band], h[band], coh[band]
    s = 2j * np.pi * fk
    w = np.sqrt((1.58 * (1 - np.exp(-ck))) ** 2 * 20 / fk.size)

    def resid(p: np.ndarray) -> np.ndarray:
        ratio = hk / (p[0] * np.exp(-p[2] * s) / (s * (p[1] * s + 1)))
        return np.concatenate([w * 20 * np.log10(np.abs(ratio)),
                               w * np.sqrt(0.01745) * np.degrees(np.angle(ratio))])

    sol = optimize.least_squares(resid, [400.0, 0.01, 0.01], bounds=([1, 0, 0], [1e5, 0.1, 0.1]))
    return {"freq_hz": fk, "response": hk, "coherence": ck, "B": sol.x[0], "lag_s": sol.x[1],
            "delay_s": sol.x[2], "J": float(np.sum(sol.fun**2))}


@pytest.fixture(scope="module")
def chirp71():  # type: ignore[no-untyped-def]
    path = real_log("00000071.BIN")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, "-m", "mavsid", "fit", str(path), "--axis", "roll",
                           "--json"], capture_output=True, text=True, env=env, check=False)
    assert proc.returncode == 0, proc.stderr
    return reference_response(path), json.loads(proc.stdout)


def test_roll_chirp_transfer_function_matches_the_scipy_reference(chirp71) -> None:  # type: ignore[no-untyped-def]
    ref, out = chirp71
    fr = out["axes"]["roll"]["frequency_response"]
    assert fr["structure"] == "integrator" and fr["J"] <= 100
    assert abs(fr["B"] / ref["B"] - 1) <= 0.10, (fr["B"], ref["B"])
    assert abs(fr["lag_s"] - ref["lag_s"]) <= 0.003, (fr["lag_s"], ref["lag_s"])
    assert abs(fr["delay_s"] - ref["delay_s"]) <= 0.003, (fr["delay_s"], ref["delay_s"])
    lo, hi = fr["band_hz"]
    assert lo <= 1.5 and 12.0 <= hi <= 25.0, fr["band_hz"]


def test_roll_model_response_within_the_goal_of_the_measured_one(chirp71) -> None:  # type: ignore[no-untyped-def]
    """The axis model's response (from ``fit --json``) against the scipy measurement: RMS
    within 1.5 dB and 10° over the reference's coherent band, coherence-weighted."""
    ref, out = chirp71
    fr = out["axes"]["roll"]["frequency_response"]
    f = np.asarray(fr["freq_hz"])
    mag = np.interp(ref["freq_hz"], f, fr["model_magnitude_db"])
    ph = np.interp(ref["freq_hz"], f, fr["model_phase_deg"])
    model = 10 ** (mag / 20) * np.exp(1j * np.radians(ph))
    ratio = ref["response"] / model
    w = (1.58 * (1 - np.exp(-ref["coherence"]))) ** 2
    db = np.sqrt(np.sum(w * (20 * np.log10(np.abs(ratio))) ** 2) / np.sum(w))
    deg = np.sqrt(np.sum(w * np.degrees(np.angle(ratio)) ** 2) / np.sum(w))
    assert db <= 1.5 and deg <= 10.0, (db, deg)
    verdict = out["axes"]["roll"]["verdict"]
    assert verdict["level"] in ("good", "usable"), verdict


def fit_error(name: str) -> str:
    path = real_log(name)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, "-m", "mavsid", "fit", str(path), "-q"],
                          capture_output=True, text=True, env=env, check=False)
    assert proc.returncode == 1, proc.stdout
    return next(line for line in proc.stderr.splitlines() if line.startswith("mavsid: error:"))


@pytest.mark.parametrize("name", ["00000064.BIN", "00000067.BIN"])
def test_a_run_that_excites_nothing_is_refused_in_one_line(name: str) -> None:
    """SID_MAGNITUDE 0.15° on a 20-deg-capable quad: the injection is lost in the noise."""
    line = fit_error(name)
    assert "excites nothing above the noise" in line and "magnitude 0.15°" in line, line
    assert "0.05–5 Hz" in line and "γ²" in line
    assert "on the ground" not in line and "ill-conditioned" not in line


def test_a_run_that_ends_in_a_roll_over_is_refused_in_one_line() -> None:
    line = fit_error("00000060.BIN")
    assert "ends in a roll-over" in line and "at t=" in line, line
    assert "on the ground" not in line and "attitude beyond bound" not in line


def test_a_systemid_stay_without_sids_that_injected_nothing_is_refused_in_one_line() -> None:
    """00000062: 9.6 s in SYSTEMID, SIDD logged with Targ 0 throughout, no SIDS record."""
    line = fit_error("00000062.BIN")
    assert line.endswith("roll: SYSTEMID mode (SID_AXIS 1) 3899.3–3908.8 s injected nothing "
                         "(SIDD.Targ is 0 throughout, SIDS not logged)"), line
