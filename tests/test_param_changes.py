"""Parameters set in flight: the simulator's retune, the writers' records of it (checked
with pymavlink and pyulog), the readers' ``RawLog.param_changes``."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from mavsid.synthetic.controller import AttitudeController, ControllerParams
from mavsid.synthetic.run import scenario_from_options, simulate

#: the retune flown: roll P and D raised half-way through a minute of random roll sticks
AT_S = 30.0


def retuned_scenario(seed: int = 4):
    sc = scenario_from_options(manoeuvre="random", axis="roll", duration_s=60.0, seed=seed)
    return replace(sc, retune=(AT_S, replace(sc.controller, rll_p=0.2, rll_d=0.005)))


@pytest.fixture(scope="module")
def retuned(tmp_path_factory):
    folder = tmp_path_factory.mktemp("retune")
    sc = retuned_scenario()
    paths = [folder / "f.bin", folder / "f.ulg", folder / "f.tlog"]
    simulate(sc, paths)
    return sc, paths


def test_set_params_changes_the_gains_and_keeps_the_state() -> None:
    c = AttitudeController(ControllerParams())
    for _ in range(50):
        c.update(np.array([0.1, 0.0, 0.0]), np.zeros(3), np.zeros(3))
    integrator = c.pids[0].integrator
    target = c.att_target.copy()
    c.set_params(ControllerParams(rll_p=0.2))
    assert c.pids[0].g.p == 0.2 and c.pids[0].integrator == integrator
    assert np.array_equal(c.att_target, target)
    with pytest.raises(Exception, match="loop rate"):
        c.set_params(ControllerParams(loop_hz=200.0))


def test_a_retune_outside_the_flight_is_refused() -> None:
    from mavsid.errors import ConfigError

    sc = scenario_from_options(manoeuvre="hover", duration_s=10.0)
    with pytest.raises(ConfigError, match="retune at 20"):
        replace(sc, retune=(20.0, sc.controller))


def test_the_writers_record_the_retune(retuned) -> None:
    from pymavlink import mavutil
    from pyulog import ULog

    sc, (binary, ulog, _) = retuned
    t_change = sc.boot_s + AT_S
    log = mavutil.mavlink_connection(str(binary))
    parm = []
    while (m := log.recv_match(type="PARM")) is not None:
        parm.append((m.TimeUS * 1e-6, m.Name, m.Value))
    log.close()
    later = {(n, round(v, 6)) for t, n, v in parm if t > sc.boot_s}
    assert later == {("ATC_RAT_RLL_P", 0.2), ("ATC_RAT_RLL_D", 0.005)}
    assert [t for t, _, _ in parm if t > sc.boot_s] == pytest.approx([t_change] * 2)
    u = ULog(str(ulog))
    assert {(n, round(v, 6)) for _, n, v in u.changed_parameters} == {
        ("MC_ROLLRATE_P", 0.2), ("MC_ROLLRATE_D", 0.005)}
    assert [t * 1e-6 for t, _, _ in u.changed_parameters] == pytest.approx([t_change] * 2)


def test_the_tlog_reader_gives_the_retune(retuned) -> None:
    from pymavlink import mavutil

    from mavsid.readers import read_log

    sc, (_, _, tlog) = retuned
    raw = read_log(tlog)
    got = [(c.name, round(c.value, 6)) for c in raw.param_changes]
    assert sorted(got) == [("ATC_RAT_RLL_D", 0.005), ("ATC_RAT_RLL_P", 0.2)]
    # pymavlink: the PARAM_VALUE messages after the first of each name; the reader's
    # times on the vehicle's clock
    log = mavutil.mavlink_connection(str(tlog))
    seen, later = set(), []
    while (m := log.recv_match(type="PARAM_VALUE")) is not None:
        if m.param_id in seen:
            later.append((m.param_id, round(m.param_value, 6)))
        seen.add(m.param_id)
    log.close()
    assert sorted(later) == sorted(got)
    assert all(c.time_s == pytest.approx(sc.boot_s + AT_S, abs=0.1) for c in raw.param_changes)


def _pymavlink_changes(path) -> list[tuple[float, str, float]]:
    """PARM records that change a value, by pymavlink: each after the first of its name."""
    from pymavlink import mavutil

    log = mavutil.mavlink_connection(str(path))
    last: dict[str, float] = {}
    out = []
    while (m := log.recv_match(type="PARM")) is not None:
        if m.Name in last and last[m.Name] != m.Value:
            out.append((m.TimeUS * 1e-6, m.Name, m.Value))
        last[m.Name] = m.Value
    log.close()
    return out


def _pyulog_changes(path, messages=None) -> list[tuple[float, str, float]]:
    """pyulog's changed parameters that change a value (its list keeps repeats too)."""
    from pyulog import ULog

    u = ULog(str(path), messages)
    last = {k: float(v) for k, v in u.initial_parameters.items()}
    out = []
    for t, name, value in u.changed_parameters:
        if name in last and last[name] != float(value):
            out.append((t * 1e-6, name, float(value)))
        last[name] = float(value)
    return out


def _ours(raw) -> list[tuple[float, str, float]]:
    return [(c.time_s, c.name, c.value) for c in raw.param_changes]


def _same(a: list[tuple[float, str, float]], b: list[tuple[float, str, float]]) -> bool:
    return ([n for _, n, _ in a] == [n for _, n, _ in b]
            and np.allclose([(t, v) for t, _, v in a], [(t, v) for t, _, v in b],
                            rtol=0, atol=1e-6))


def test_the_dataflash_and_ulog_readers_give_the_retune(retuned) -> None:
    from mavsid.readers import read_log

    _, (binary, ulog, _) = retuned
    got = _ours(read_log(binary, messages=["RATE"]))
    assert _same(got, _pymavlink_changes(binary)) and len(got) == 2
    got = _ours(read_log(ulog))
    assert _same(got, _pyulog_changes(ulog)) and len(got) == 2


@pytest.mark.parametrize("messages", [None, ["vehicle_status"]])
def test_ulog_changes_match_pyulog_on_a_public_log(messages) -> None:
    from helpers import shared_path

    from mavsid.readers import read_log

    path = shared_path("public", "PX4__pyulog", "sample.ulg")
    got = _ours(read_log(path, messages=messages))
    # (the time of a change: the latest record before it of the topics read, as pyulog's)
    assert _same(got, _pyulog_changes(path, messages)) and len(got) >= 3


def test_real_dataflash_changes_match_pymavlink() -> None:
    from helpers import real_path

    from mavsid.readers import read_log

    path = real_path("keita", "00000064.BIN")
    got = _ours(read_log(path, messages=["RATE"]))
    assert _same(got, _pymavlink_changes(path)) and got  # (STAT_* in flight)
