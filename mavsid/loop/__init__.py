"""The loop stage: the vehicle's rate controller rebuilt from its parameters, the identified
plant put inside it (the closed-loop twin), and what the loop does with the logged gains.

Submodules (the names below are also served from here, imported on first use):

- :mod:`mavsid.loop.controllers`: ArduPilot ``AC_PID`` and PX4 rate controllers, and their
  rebuild from a log's parameters;
- :mod:`mavsid.loop.plant`: the identified plant as a discrete linear system;
- :mod:`mavsid.loop.twin`: the closed-loop simulation, the controller replay, the twin's fit
  and its baseline;
- :mod:`mavsid.loop.analysis`: margins, bandwidths and step figures of the loop, on a model
  and on measured responses;
- :mod:`mavsid.loop.limits`: the limits a suggested loop must meet, checked with
  python-control, and a step flown in the twin;
- :mod:`mavsid.loop.tune`: gains for a target phase margin under those limits, ``mavsid
  tune``'s report and its parameter file.

The responses measured on SYSTEMID runs are :func:`mavsid.frequency.measured_responses`; the
text ``mavsid tune`` prints is :func:`mavsid.cli_format.format_tune`.
"""

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # (served lazily below; the type checker sees them here)
    from mavsid.cli_format import (
        format_tune,
    )
    from mavsid.frequency import (
        FrfStructure,
        measured_responses,
        sysid_spans,
    )
    from mavsid.loop.analysis import (
        LoopAnalysis,
        analyse_model,
        analyse_plant,
        closed_figures,
        compare_response,
        controller_polys,
        frd_margins,
        frd_margins_at,
        grid_margins,
        loop_figures,
        loop_statespace,
        margin_db,
        margin_grid,
        margins_of,
        margins_on_frf,
        step_figures,
    )
    from mavsid.loop.controllers import (
        AXES,
        AXIS_RATE,
        PID,
        AxisController,
        PX4RateGains,
        PX4RatePID,
        RateGains,
        RatePID,
        autopilot_of,
        controller_from_params,
        gain_params,
        lowpass_alpha,
        measurement_filter,
        scale_of,
        scaled,
    )
    from mavsid.loop.limits import (
        Limits,
        LoopCheck,
        check_loop,
        limit_rows,
        twin_step,
    )
    from mavsid.loop.plant import (
        LinearPlant,
        Poly,
        as_plant,
        plant_from_model,
        plant_response,
        plant_statespace,
        ss2tf,
    )
    from mavsid.loop.tune import (
        LOOP_MISMATCH_DB,
        LOOP_MISMATCH_DEG,
        MIN_CHIRP_TOP_HZ,
        SUGGESTION_CHECK_DEG,
        TuneAnalysis,
        chirp_top_hz,
        param_file,
        suggest_gains,
        tune,
        tune_analysis,
    )
    from mavsid.loop.twin import (
        BASELINE_MAX_DELAY_S,
        LAGS,
        MEAS_DELAY_TOL,
        MEAS_DELAYS,
        SETTLE_S,
        WARMUP_S,
        ClosedLoopFit,
        LocatedBlock,
        TwinBlock,
        TwinSignals,
        baseline_candidates,
        baseline_fit,
        closed_loop_fit,
        lagged,
        locate_blocks,
        replay_controller,
        simulate_closed_loop,
        twin_messages,
        twin_signals,
    )

#: Names served from the module that defines them, on first use.
_LAZY = {
    **dict.fromkeys((
        'format_tune',
    ), 'cli_format'),
    **dict.fromkeys((
        'FrfStructure', 'measured_responses', 'sysid_spans',
    ), 'frequency'),
    **dict.fromkeys((
        'LoopAnalysis', 'analyse_model', 'analyse_plant', 'closed_figures',
        'compare_response', 'controller_polys', 'frd_margins', 'frd_margins_at',
        'grid_margins', 'loop_figures', 'loop_statespace', 'margin_db', 'margin_grid',
        'margins_of', 'margins_on_frf', 'step_figures',
    ), 'loop.analysis'),
    **dict.fromkeys((
        'AXES', 'AXIS_RATE', 'AxisController', 'PID', 'PX4RateGains', 'PX4RatePID', 'RateGains',
        'RatePID', 'autopilot_of', 'controller_from_params', 'gain_params', 'lowpass_alpha',
        'measurement_filter', 'scale_of', 'scaled',
    ), 'loop.controllers'),
    **dict.fromkeys((
        'Limits', 'LoopCheck', 'check_loop', 'limit_rows', 'twin_step',
    ), 'loop.limits'),
    **dict.fromkeys((
        'LinearPlant', 'Poly', 'as_plant', 'plant_from_model', 'plant_response', 'plant_statespace',
        'ss2tf',
    ), 'loop.plant'),
    **dict.fromkeys((
        'LOOP_MISMATCH_DB', 'LOOP_MISMATCH_DEG', 'MIN_CHIRP_TOP_HZ', 'SUGGESTION_CHECK_DEG',
        'TuneAnalysis', 'chirp_top_hz', 'param_file', 'suggest_gains', 'tune', 'tune_analysis',
    ), 'loop.tune'),
    **dict.fromkeys((
        'BASELINE_MAX_DELAY_S', 'ClosedLoopFit', 'LAGS', 'LocatedBlock', 'MEAS_DELAYS',
        'MEAS_DELAY_TOL', 'SETTLE_S', 'TwinBlock', 'TwinSignals', 'WARMUP_S',
        'baseline_candidates', 'baseline_fit', 'closed_loop_fit', 'lagged', 'locate_blocks',
        'replay_controller', 'simulate_closed_loop',
        'twin_messages', 'twin_signals',
    ), 'loop.twin'),
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f"mavsid.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'mavsid.loop' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


__all__ = [
    "AXES",
    "AXIS_RATE",
    "BASELINE_MAX_DELAY_S",
    "LAGS",
    "LOOP_MISMATCH_DB",
    "LOOP_MISMATCH_DEG",
    "MEAS_DELAYS",
    "MEAS_DELAY_TOL",
    "MIN_CHIRP_TOP_HZ",
    "PID",
    "SETTLE_S",
    "SUGGESTION_CHECK_DEG",
    "WARMUP_S",
    "AxisController",
    "ClosedLoopFit",
    "FrfStructure",
    "Limits",
    "LinearPlant",
    "LocatedBlock",
    "LoopAnalysis",
    "LoopCheck",
    "PX4RateGains",
    "PX4RatePID",
    "Poly",
    "RateGains",
    "RatePID",
    "TuneAnalysis",
    "TwinBlock",
    "TwinSignals",
    "analyse_model",
    "analyse_plant",
    "as_plant",
    "autopilot_of",
    "baseline_candidates",
    "baseline_fit",
    "check_loop",
    "chirp_top_hz",
    "closed_figures",
    "closed_loop_fit",
    "compare_response",
    "controller_from_params",
    "controller_polys",
    "format_tune",
    "frd_margins",
    "frd_margins_at",
    "gain_params",
    "grid_margins",
    "lagged",
    "limit_rows",
    "locate_blocks",
    "loop_figures",
    "loop_statespace",
    "lowpass_alpha",
    "margin_db",
    "margin_grid",
    "margins_of",
    "margins_on_frf",
    "measured_responses",
    "measurement_filter",
    "param_file",
    "plant_from_model",
    "plant_response",
    "plant_statespace",
    "replay_controller",
    "scale_of",
    "scaled",
    "simulate_closed_loop",
    "ss2tf",
    "step_figures",
    "suggest_gains",
    "sysid_spans",
    "tune",
    "tune_analysis",
    "twin_messages",
    "twin_signals",
    "twin_step",
]
