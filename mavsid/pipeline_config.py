"""The settings of one pipeline run (:func:`mavsid.pipeline.fit`,
:func:`mavsid.pipeline.validate_logs`), from a TOML file or a dict; channel presets and
mixers from TOML are :mod:`mavsid.autopilot.config`'s.

TOML configuration (every key optional)::

    [pipeline]
    name = "ArduCopter SYSTEMID rate loop"
    preset = "ardupilot-rate"    # channel preset (mavsid.autopilot.presets); default from the log
    presets_file = "my.toml"     # extra presets/mixers (relative to this file)
    rate_hz = 400.0              # alignment grid; default the body-rate channel's rate
    axes = ["roll", "pitch", "yaw"]
    estimator = "ls"             # ls | ridge | l1
    allow_unstable = false       # keep a rate model identified unstable (else bounded refit)

    [segments]
    source = "auto"              # auto | sysid | scan
    block_s = 10.0               # train/validation block length, s
    options = {}                 # passed to the segment finder

    [model]                      # passed to the estimator (e.g. order, delay)

    [validation]
    horizons_s = [0.01, 0.05, 0.1, 0.5, 1.0, 2.0]
    max_lag = 50
    fft_window_s = 4.0

Examples
--------
>>> cfg = config_from_dict({"pipeline": {"axes": ["roll"], "estimator": "ridge"},
...                         "segments": {"block_s": 5.0}})
>>> cfg.axes, cfg.estimator, cfg.block_s
(('roll',), 'ridge', 5.0)
>>> config_from_dict({"pipeline": {"estimator": "magic"}})
Traceback (most recent call last):
...
mavsid.errors.ConfigError: pipeline.estimator: 'magic' is not one of ls, ridge, l1
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from mavsid.axes import AXES
from mavsid.errors import ConfigError, finite_number, whole_number
from mavsid.split import MIN_BLOCK_S
from mavsid.validation import DEFAULT_HORIZONS_S

__all__ = [
    "ESTIMATORS",
    "MODEL_OPTIONS",
    "SEGMENT_SOURCES",
    "PipelineConfig",
    "config_from_dict",
    "load_config",
]

ESTIMATORS = ("ls", "ridge", "l1")
SEGMENT_SOURCES = ("auto", "sysid", "scan")


@dataclass(frozen=True)
class PipelineConfig:
    """Settings of one pipeline run (see the module docstring for the TOML form)."""

    name: str = "default"
    preset: str | None = None
    rate_hz: float | None = None
    axes: tuple[str, ...] = AXES
    estimator: str = "ls"
    segment_source: str = "auto"
    block_s: float = 10.0
    segment_options: Mapping[str, Any] = field(default_factory=dict)
    model_options: Mapping[str, Any] = field(default_factory=dict)
    horizons_s: tuple[float, ...] = DEFAULT_HORIZONS_S
    max_lag: int = 50
    fft_window_s: float = 4.0
    path: str | None = None
    presets: Mapping[str, Any] = field(default_factory=dict)
    mixers: Mapping[str, Any] = field(default_factory=dict)
    #: Keep a rate model identified unstable (default: refuse it and offer the bounded fit).
    allow_unstable: bool = False

    def with_overrides(self, **changes: Any) -> PipelineConfig:
        """A copy with the given fields replaced (``None`` values ignored)."""
        return dataclasses.replace(self, **{k: v for k, v in changes.items() if v is not None})


_KEYS: dict[str, dict[str, str]] = {
    "pipeline": {
        "name": "name",
        "preset": "preset",
        "rate_hz": "rate_hz",
        "axes": "axes",
        "estimator": "estimator",
        "allow_unstable": "allow_unstable",
    },
    "segments": {"source": "segment_source", "block_s": "block_s", "options": "segment_options"},
    "validation": {
        "horizons_s": "horizons_s",
        "max_lag": "max_lag",
        "fft_window_s": "fft_window_s",
    },
}


#: ``[model]`` options a configuration may set (those of
#: :func:`mavsid.estimators.fit_axis` and its estimators): kind and the values it may take.
#: Kinds: ``number`` (finite, in ``[lo, hi]``), ``numbers`` (a list of them, ``numbers+``
#: not empty), ``whole`` (an integer in ``[lo, hi]``), ``bool``, ``names`` (a list of
#: strings) and ``choice`` (one of ``hi``). Bounds keep a run finite: a delay step of 1e-9
#: samples took the machine's memory, a 1e9-s delay search or 10^6 bootstrap draws ran for
#: hours.
MODEL_OPTIONS: dict[str, tuple[str, float, Any]] = {
    "delay": ("number", 0.0, 1000.0),  # samples
    "delays": ("numbers+", 0.0, 1000.0),  # samples
    "delay_step": ("number", 0.01, 1.0),  # samples
    "max_delay_s": ("number", 0.0, 1.0),
    "lags_s": ("numbers", 0.0, 1.0),
    "structure_tol": ("number", 0.0, 1.0),
    "inputs": ("names", 0, None),
    "bias": ("bool", 0, None),
    "continuous": ("bool", 0, None),
    "features": ("names", 0, None),
    "refine": ("choice", 0, ("auto", "oe")),
    "alpha": ("number", 0.0, 1e12),  # or "cv"
    "alphas": ("numbers+", 0.0, 1e12),
    "l1_ratio": ("number", 0.0, 1.0),
    "threshold": ("number", 0.0, 1e12),
    "cv_horizon": ("whole", 1, 100_000),
    "n_bootstrap": ("whole", 0, 10_000),
    "hac": ("bool", 0, None),
    "min_blocks": ("whole", 2, 10_000),
    "max_condition": ("number", 1.0, 1e300),
    "random_state": ("whole", 0, 2**32 - 1),
    "max_iter": ("whole", 1, 10_000),
}


def _model_option(key: str, value: Any) -> None:
    """Raise :class:`ConfigError` when ``[model] key = value`` is not one
    :data:`MODEL_OPTIONS` allows.

    Examples
    --------
    >>> _model_option("lags_s", [0.02, 0.04])
    >>> _model_option("delay_step", 0)
    Traceback (most recent call last):
    mavsid.errors.ConfigError: model.delay_step: 0 is not a finite number in [0.01, 1]
    """
    if key not in MODEL_OPTIONS:
        raise ConfigError(f"unknown key model.{key} (known: {', '.join(MODEL_OPTIONS)})")
    kind, lo, hi = MODEL_OPTIONS[key]
    if key == "alpha" and value == "cv":
        return

    def number(x: Any) -> bool:
        return finite_number(x) and lo <= x <= hi

    if kind == "number":
        ok, want = number(value), f"a finite number in [{lo:g}, {hi:g}]"
    elif kind in ("numbers", "numbers+"):
        ok = (isinstance(value, list) and all(map(number, value))
              and (kind == "numbers" or bool(value)))
        want = (f"a {'non-empty ' * (kind == 'numbers+')}list of finite numbers in "
                f"[{lo:g}, {hi:g}]")
    elif kind == "whole":
        ok = whole_number(value) and lo <= value <= hi
        want = f"a whole number in [{lo:g}, {hi}]"
    elif kind == "choice":
        ok, want = value in hi, f"one of {', '.join(map(repr, hi))}"
    elif kind == "bool":
        ok, want = isinstance(value, bool), "true or false"
    else:  # names
        ok = isinstance(value, list) and all(isinstance(v, str) for v in value)
        want = "a list of strings"
    if not ok:
        raise ConfigError(f"model.{key}: {value!r} is not {want}" + (
            " or 'cv'" if key == "alpha" else ""))


def config_from_dict(data: Mapping[str, Any], path: str | None = None) -> PipelineConfig:
    """Build a :class:`PipelineConfig` from the TOML structure; unknown keys are errors."""
    where = f"{path}: " if path else ""
    values: dict[str, Any] = {"path": path}
    for section, content in data.items():
        if section == "model":
            if not isinstance(content, Mapping):
                raise ConfigError(f"{where}[model] must be a table")
            try:
                for key, value in content.items():
                    _model_option(key, value)
            except ConfigError as exc:
                raise ConfigError(f"{where}{exc}") from None
            values["model_options"] = dict(content)
            continue
        if section not in _KEYS or not isinstance(content, Mapping):
            raise ConfigError(
                f"{where}unknown section [{section}] (known: {', '.join([*_KEYS, 'model'])})"
            )
        for key, value in content.items():
            if key not in _KEYS[section]:
                raise ConfigError(
                    f"{where}unknown key {section}.{key} "
                    f"(known: {', '.join(_KEYS[section])})"
                )
            values[_KEYS[section][key]] = value
    try:
        cfg = _checked(values)
    except ConfigError as exc:
        raise ConfigError(f"{where}{exc}") from None
    return cfg


def _checked(v: dict[str, Any]) -> PipelineConfig:
    def need(cond: bool, key: str, text: str) -> None:
        if not cond:
            raise ConfigError(f"{key}: {text}")

    if "axes" in v:
        axes = v["axes"]
        axes = [axes] if isinstance(axes, str) else axes
        need(
            isinstance(axes, list) and bool(axes) and all(a in AXES for a in axes),
            "pipeline.axes",
            f"{v['axes']!r} is not a list of {', '.join(AXES)}",
        )
        v["axes"] = tuple(axes)
    if "estimator" in v:
        need(
            v["estimator"] in ESTIMATORS,
            "pipeline.estimator",
            f"{v['estimator']!r} is not one of {', '.join(ESTIMATORS)}",
        )
    if "segment_source" in v:
        need(
            v["segment_source"] in SEGMENT_SOURCES,
            "segments.source",
            f"{v['segment_source']!r} is not one of {', '.join(SEGMENT_SOURCES)}",
        )
    def positive(x: Any) -> bool:
        return finite_number(x) and x > 0

    for key, name in (("rate_hz", "pipeline.rate_hz"), ("block_s", "segments.block_s"),
                      ("fft_window_s", "validation.fft_window_s")):
        if key in v:
            x = v[key]
            need(positive(x), name, f"{x!r} is not a positive finite number")
            v[key] = float(x)
    if "block_s" in v:
        need(v["block_s"] >= MIN_BLOCK_S, "segments.block_s",
             f"{v['block_s']!r} s: a training or validation block must hold at least "
             f"{MIN_BLOCK_S} s of flight")
    if "horizons_s" in v:
        h = v["horizons_s"]
        need(
            isinstance(h, list) and all(positive(x) for x in h),
            "validation.horizons_s",
            f"{h!r} is not a list of positive finite numbers",
        )
        v["horizons_s"] = tuple(float(x) for x in h)
    if "max_lag" in v:
        need(whole_number(v["max_lag"]) and v["max_lag"] > 0, "validation.max_lag",
             f"{v['max_lag']!r} is not a positive integer")
    if "allow_unstable" in v:
        need(isinstance(v["allow_unstable"], bool), "pipeline.allow_unstable",
             f"{v['allow_unstable']!r} is not true or false")
    if "segment_options" in v:
        need(isinstance(v["segment_options"], Mapping), "segments.options", "must be a table")
        from mavsid.excitation import ScanOptions

        ScanOptions.from_options(v["segment_options"])  # (its errors name the option)
    for key in ("name", "preset"):
        if key in v:
            need(isinstance(v[key], str), f"pipeline.{key}", f"{v[key]!r} is not a string")
    return PipelineConfig(**v)


def load_config(path: str | os.PathLike[str]) -> PipelineConfig:
    """Read a pipeline TOML file.

    ``pipeline.presets_file`` may name a TOML file of channel presets and mixers
    (:func:`mavsid.autopilot.config.load_presets`; a relative path is taken from the config's
    folder); they are tried before the built-in ones.

    Raises
    ------
    ConfigError
        The file cannot be read, is not TOML, or has unknown keys or bad values.
    """
    from mavsid.autopilot.config import load_presets, read_toml

    data = read_toml(path)
    section = data.get("pipeline")
    extra = section.pop("presets_file", None) if isinstance(section, dict) else None
    cfg = config_from_dict(data, path=os.fspath(path))
    if extra is not None:
        if not isinstance(extra, str):
            raise ConfigError(f"{path}: pipeline.presets_file: {extra!r} is not a path")
        presets, mixers = load_presets(os.path.join(os.path.dirname(os.fspath(path)), extra))
        cfg = dataclasses.replace(cfg, presets=presets, mixers=mixers)
    return cfg
