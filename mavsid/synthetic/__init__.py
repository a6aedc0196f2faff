"""Known plants flown by an ArduPilot-like controller, written as real-format logs.

Ground truth for tests and the demo: :func:`~mavsid.synthetic.flight.fly` simulates a
:class:`~mavsid.synthetic.flight.Scenario`; :func:`simulate` also writes the logs
(DataFlash ``.bin``, MAVLink ``.tlog``, PX4 ULog ``.ulg``) and the ``.truth.json`` sidecar.
"""

from mavsid.synthetic.controller import ControllerParams
from mavsid.synthetic.faults import Faults
from mavsid.synthetic.flight import Flight, LogRates, Scenario, fly
from mavsid.synthetic.plant import PlantParams
from mavsid.synthetic.run import SimulationResult, simulate, truth_path
from mavsid.synthetic.sysid import SysIdSettings, chirp

__all__ = [
    "ControllerParams",
    "Faults",
    "Flight",
    "LogRates",
    "PlantParams",
    "Scenario",
    "SimulationResult",
    "SysIdSettings",
    "chirp",
    "fly",
    "simulate",
    "truth_path",
]
