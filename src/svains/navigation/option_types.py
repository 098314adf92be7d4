"""Option values against their dataclass field types: the one type check of the run
configuration, for files and ``--set`` (``config_io``) and for options built in Python
(``check_types``, called by each section's ``__post_init__``). Every error names the dotted key."""

from __future__ import annotations

import dataclasses
import functools
import re
import types
import typing
from typing import Any

from svains.errors import ConfigError

# A decimal number with an exponent and no dot, which YAML 1.1 (PyYAML) leaves a string.
_DECIMAL = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+")


def coerce(value: Any, tp: Any, key: str) -> Any:
    """``value`` checked (and converted: int -> float, list -> tuple) against type ``tp``."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for a in args:
            if a is type(None):
                continue
            try:
                return coerce(value, a, key)
            except ConfigError as exc:
                errors.append(str(exc))
        raise ConfigError(errors[0] if errors else f"{key}: bad value {value!r}")
    if origin is typing.Literal:
        if value not in args:
            raise ConfigError(f"{key} must be one of {list(args)}, got {value!r}")
        return value
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{key} must be a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(coerce(v, args[0], f"{key}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(f"{key} must have {len(args)} entries, got {value!r}")
        return tuple(coerce(v, a, f"{key}[{i}]") for i, (v, a) in enumerate(zip(value, args,
                                                                                  strict=True)))
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(f"{key} is a section (a mapping), got {value!r}")
        return build(tp, value, f"{key}.")
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{key} must be true or false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{key} must be an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, str) and _DECIMAL.fullmatch(value.strip()):
            value = float(value)  # YAML 1.1 reads 1e-9 (no dot) as a string
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{key} must be a number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{key} must be a string, got {value!r}")
        return value
    raise ConfigError(f"{key}: unsupported option type {tp!r}")


def build(cls: type, data: dict[str, Any], prefix: str = "") -> Any:
    """Dataclass ``cls`` from a (partial) mapping; unknown keys and wrong types raise
    ``ConfigError`` naming the dotted key."""
    hints = hints_of(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        if key not in names:
            raise ConfigError(f"unknown configuration key '{prefix}{key}'; known in this "
                              f"section: {', '.join(names)}")
        kwargs[key] = coerce(value, hints[key], f"{prefix}{key}")
    # Cross-field checks (``__post_init__``) raise ConfigError naming their dotted key.
    return cls(**kwargs)


@functools.cache
def hints_of(cls: type) -> dict[str, Any]:
    """The resolved field types of dataclass ``cls`` (cached: options are built often)."""
    return typing.get_type_hints(cls)


def check_types(obj: Any, prefix: str) -> None:
    """``ConfigError`` naming the dotted key when a field of the options dataclass ``obj`` (and
    of its sections) holds a value of another type than its annotation (a string where a
    number goes: ``RunConfig(output_period_s="0.1")``). Values are checked, not converted: an
    int stays where a float goes."""
    hints = hints_of(type(obj))
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            check_types(value, f"{prefix}{f.name}.")
        else:
            coerce(value, hints[f.name], f"{prefix}{f.name}")
