"""Log a fit, a flight, a fleet's trends or closed-loop responses to rerun, and open a viewer.

==============================  ============================================================
module                          content
==============================  ============================================================
:mod:`mavsid.viz.series`        the timeline, colours, scalar series, 2-D line plots, time
                                views, ``.rrd`` files
:mod:`mavsid.viz.recording`     a fit's recording and its blueprint: flight data, segments,
                                bands, predictions, attitude, fit % and Bode plots, summary
:mod:`mavsid.viz.response`      closed-loop responses: target/actual, steps, spectra
:mod:`mavsid.viz.trends`        a fleet's parameters against flight date, change points
:mod:`mavsid.viz.viewer`        where a recording goes: the viewer process mavsid starts and
                                stops (its whole process group), its ports, a running viewer
==============================  ============================================================

Every name below is defined in one of these modules and re-exported here.
"""

from mavsid.data import decimate
from mavsid.viz.recording import (
    blueprint,
    focus_span,
    log_attitude,
    log_bands,
    log_fit_result,
    log_flight,
    log_flight_windows,
    log_rate_targets,
    log_segments,
    log_summary,
    log_validation,
    rate_targets,
    result_focus,
    save_rrd,
    target_axes,
)
from mavsid.viz.response import log_response, response_blueprint, save_response_rrd
from mavsid.viz.series import APPLICATION_ID, TIMELINE, new_recording, write_errors
from mavsid.viz.trends import save_trends_rrd
from mavsid.viz.viewer import (
    Served,
    free_port,
    open_sink,
    run_viewer,
    serve_command,
    stop_group,
    viewer_command,
    viewer_errors,
    wait_listening,
)

__all__ = [
    "APPLICATION_ID",
    "TIMELINE",
    "Served",
    "blueprint",
    "decimate",
    "focus_span",
    "free_port",
    "log_attitude",
    "log_bands",
    "log_fit_result",
    "log_flight",
    "log_flight_windows",
    "log_rate_targets",
    "log_response",
    "log_segments",
    "log_summary",
    "log_validation",
    "new_recording",
    "open_sink",
    "rate_targets",
    "response_blueprint",
    "result_focus",
    "run_viewer",
    "save_response_rrd",
    "save_rrd",
    "save_trends_rrd",
    "serve_command",
    "stop_group",
    "target_axes",
    "viewer_command",
    "viewer_errors",
    "wait_listening",
    "write_errors",
]
