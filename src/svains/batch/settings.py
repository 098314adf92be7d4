"""Dotted run settings of a campaign spec -> the typed ``RunConfig``: the one adapter.

Keys follow the sections of the run configuration (``section.key``); this module is the only
place that knows how they map onto :class:`~svains.navigation.options.RunConfig`:

| spec key | ``RunOptions`` field |
|---|---|
| ``model`` | ``model`` (``paper`` or ``biased``) |
| ``filter.<f>``, ``noise.<f>``, ``init.<f>``, | field ``<f>`` of ``filter``, ``noise``, ``init``, |
| ``smoother.<f>``, ``faults.<f>``, ``zupt.<f>`` | ``smoother``, ``faults``, ``zupt`` |
| ``fusion.<f>``: ``use_gps``, ``use_mag``, ``use_sonar``, ``use_gps_velocity``, | the top-level |
| ``max_mag_rate_hz``, ``max_sonar_rate_hz`` | field ``<f>`` |
| ``output.period_s`` | ``output_period_s`` |
| ``replay.duration_s`` | ``duration_s`` |
| ``vision.<k>`` | ``vision.<k>`` (fields of ``VisionOptions``) |
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import fields, replace
from typing import Any, get_args

from svains.errors import ConfigError
from svains.navigation.config_io import build
from svains.navigation.options import InitMode, ModelName, RunOptions, VisionOptions

_SECTIONS = ("filter", "noise", "init", "smoother", "faults", "zupt")
_FUSION = ("use_gps", "use_mag", "use_sonar", "use_gps_velocity", "max_mag_rate_hz",
           "max_sonar_rate_hz")  # fmt: skip
_RENAMED = {"output.period_s": "output_period_s", "replay.duration_s": "duration_s"}


def _checked(key: str, value: Any, default: Any) -> Any:
    """``value`` if it has the type of the field's ``default`` (a YAML ``"no"`` for a bool, or a
    string for a number, would otherwise pass silently); ints are accepted for floats."""
    if isinstance(default, bool):
        ok = isinstance(value, bool)
    elif isinstance(default, int | float):
        ok = isinstance(value, int | float) and not isinstance(value, bool)
    elif isinstance(default, str):
        ok = isinstance(value, str)
    else:  # None or a container default: the options' own checks apply
        ok = True
    if not ok:
        raise ConfigError(
            f"setting '{key}' must be a {type(default).__name__}, got {value!r}"
        )
    return float(value) if isinstance(default, float) and not isinstance(value, bool) else value


def run_options_from_settings(settings: Mapping[str, Any]) -> RunOptions:
    """``RunOptions`` from dotted ``settings`` (mapping in the module docstring); an unknown
    key or a value of the wrong type raises :class:`ConfigError` naming the key."""
    base = RunOptions()
    top: dict[str, Any] = {}
    sections: dict[str, dict[str, Any]] = {s: {} for s in _SECTIONS}
    vision: dict[str, Any] = {}
    for key, value in settings.items():
        section, _, name = key.partition(".")
        if key == "model":
            top["model"] = _checked(key, value, base.model)
        elif key in _RENAMED:
            top[_RENAMED[key]] = _checked(key, value, getattr(base, _RENAMED[key]))
        elif section == "fusion" and name in _FUSION:
            top[name] = _checked(key, value, getattr(base, name))
        elif section in _SECTIONS and name in {f.name for f in fields(getattr(base, section))}:
            sections[section][name] = _checked(key, value, getattr(getattr(base, section), name))
        elif section == "vision" and name:
            vision[name] = value
        else:
            raise ConfigError(f"unknown setting '{key}'")
    try:
        vision_options = build(VisionOptions, vision, "vision.")
    except (ConfigError, TypeError) as exc:
        raise ConfigError(f"vision settings: {exc}") from exc
    for key, value, allowed in (
        ("model", top.get("model", base.model), get_args(ModelName)),
        ("init.mode", sections["init"].get("mode", base.init.mode), get_args(InitMode)),
    ):
        if value not in allowed:
            raise ConfigError(f"setting '{key}' must be one of {', '.join(allowed)}, got {value!r}")
    parts = {s: replace(getattr(base, s), **v) for s, v in sections.items() if v}
    return replace(base, **top, **parts, vision=vision_options)
