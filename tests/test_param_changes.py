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
    assert sorted(later) == sorted(got)
    assert all(c.time_s == pytest.approx(sc.boot_s + AT_S, abs=0.1) for c in raw.param_changes)
