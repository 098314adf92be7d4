"""``RunConfig`` as plain data: YAML round trip and ``section.key=value`` overrides.

Values are type-checked against the dataclass fields (bool, int, float, str, ``Literal``,
``X | None``, tuples, nested sections); every error names the dotted key. Floats are written with
``repr`` by PyYAML, so ``from_yaml(to_yaml(c)) == c`` exactly.
"""

from __future__ import annotations

import dataclasses
import re
import types
import typing
from pathlib import Path
from typing import Any

import yaml

from svains.errors import ConfigError
from svains.navigation.options import RunConfig

# A decimal number with an exponent and no dot, which YAML 1.1 (PyYAML) leaves a string.
_DECIMAL = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+")


def to_dict(config: Any) -> dict[str, Any]:
    """Nested dict of plain YAML types (tuples become lists)."""

    def plain(v: Any) -> Any:
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, (tuple, list)):
            return [plain(e) for e in v]
        return v

    return plain(config)  # type: ignore[no-any-return]


def _coerce(value: Any, tp: Any, key: str) -> Any:
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
                return _coerce(value, a, key)
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
            return tuple(_coerce(v, args[0], f"{key}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(f"{key} must have {len(args)} entries, got {value!r}")
        return tuple(_coerce(v, a, f"{key}[{i}]") for i, (v, a) in enumerate(zip(value, args,
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
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        if key not in names:
            raise ConfigError(f"unknown configuration key '{prefix}{key}'; known in this "
                              f"section: {', '.join(names)}")
        kwargs[key] = _coerce(value, hints[key], f"{prefix}{key}")
    # Cross-field checks (``__post_init__``) raise ConfigError naming their dotted key.
    return cls(**kwargs)


def from_dict(data: dict[str, Any]) -> RunConfig:
    return build(RunConfig, data)  # type: ignore[no-any-return]


def to_yaml(config: RunConfig, path: Path | None = None, header: str = "") -> str:
    """YAML text of ``config`` (written to ``path`` if given); ``header`` lines become comments."""
    comment = "".join(f"# {line}\n" for line in header.splitlines())
    text = comment + yaml.safe_dump(to_dict(config), sort_keys=False)
    if path is not None:
        Path(path).write_text(text, encoding="utf-8")
    return text


def from_yaml(path: Path) -> RunConfig:
    """Read a configuration file (a partial one: missing keys keep their defaults)."""
    try:
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8")) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f"cannot read run configuration {path}: {exc}") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"run configuration {path} is not a mapping")
    return from_dict(data)


def with_settings(config: RunConfig, settings: dict[str, Any]) -> RunConfig:
    """``config`` with ``{"section.key": value}`` overrides applied (values type-checked)."""
    data = to_dict(config)
    for dotted, value in settings.items():
        node = data
        parts = dotted.split(".")
        for i, part in enumerate(parts[:-1]):
            if not isinstance(node.get(part), dict):
                raise ConfigError(f"unknown configuration section '{'.'.join(parts[: i + 1])}' "
                                  f"in '{dotted}'")
            node = node[part]
        if parts[-1] not in node:
            raise ConfigError(f"unknown configuration key '{dotted}'")
        node[parts[-1]] = value
    return from_dict(data)


def parse_setting(item: str) -> tuple[str, Any]:
    """``section.key=value`` -> (key, value parsed as a YAML scalar or list)."""
    if "=" not in item:
        raise ConfigError(f"expected section.key=value, got {item!r}")
    key, text = item.split("=", 1)
    try:
        return key.strip(), yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{key.strip()}: cannot parse {text!r}: {exc}") from exc
