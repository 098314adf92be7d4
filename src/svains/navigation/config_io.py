"""``RunConfig`` as plain data: YAML round trip and ``section.key=value`` overrides.

Values are type-checked against the dataclass fields (bool, int, float, str, ``Literal``,
``X | None``, tuples, nested sections); every error names the dotted key. Floats are written with
``repr`` by PyYAML, so ``from_yaml(to_yaml(c)) == c`` exactly.
"""

from __future__ import annotations

import dataclasses
import difflib
from pathlib import Path
from typing import Any

import yaml

from svains.errors import ConfigError
from svains.navigation.option_types import build
from svains.navigation.options import RunConfig
from svains.yaml_io import load_yaml


def to_dict(config: Any) -> dict[str, Any]:
    """Nested dict of plain YAML types (tuples become lists)."""

    def plain(v: Any) -> Any:
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, (tuple, list)):
            return [plain(e) for e in v]
        return v

    return plain(config)  # type: ignore[no-any-return]


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
        data = load_yaml(Path(path).read_text(encoding="utf-8")) or {}
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
            # the nearest names, as a --config file's key lists its section's (a probe)
            near = difflib.get_close_matches(parts[-1], list(node), n=3, cutoff=0.6)
            section = ".".join(parts[:-1])
            hint = ("; did you mean " + " or ".join(
                f"'{section + '.' if section else ''}{k}'" for k in near) + "?") if near else ""
            raise ConfigError(f"unknown configuration key '{dotted}'{hint}")
        node[parts[-1]] = value
    return from_dict(data)


def parse_setting(item: str) -> tuple[str, Any]:
    """``section.key=value`` -> (key, value parsed as a YAML scalar or list)."""
    if "=" not in item:
        raise ConfigError(f"expected section.key=value, got {item!r}")
    key, text = item.split("=", 1)
    try:
        return key.strip(), load_yaml(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{key.strip()}: cannot parse {text!r}: {exc}") from exc
