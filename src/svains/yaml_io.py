"""YAML as svains reads every file a user writes: PyYAML's safe loader (data only, no tags that
run code), refusing a mapping key given twice. PyYAML keeps the last value of a repeated key
without a word: a ``filter:`` section written twice lost the first one's settings."""

from __future__ import annotations

from typing import Any

import yaml
from yaml.nodes import MappingNode

_MERGE_TAG = "tag:yaml.org,2002:merge"


class RepeatedKeyError(yaml.YAMLError):
    """A mapping key given twice in one mapping."""


class _StrictLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` whose mappings refuse a repeated key."""


def _no_repeated_keys(loader: _StrictLoader, node: MappingNode) -> dict[Any, Any]:
    first_line: dict[Any, int] = {}
    for key_node, _ in node.value:
        if key_node.tag == _MERGE_TAG:  # ``<<: *anchor`` merges may override on purpose
            continue
        key = loader.construct_object(key_node, deep=True)
        try:
            line = first_line.get(key)
        except TypeError:  # an unhashable key: the safe loader refuses it itself
            continue
        if line is not None:
            raise RepeatedKeyError(f"line {key_node.start_mark.line + 1}: the key {key!r} is "
                                   f"given twice in one mapping (first on line {line + 1})")
        first_line[key] = key_node.start_mark.line
    return loader.construct_mapping(node, deep=True)


_StrictLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _no_repeated_keys)


def load_yaml(text: str) -> Any:
    """The data of YAML ``text`` (``yaml.safe_load`` semantics); ``yaml.YAMLError`` for bad
    syntax, a tag, or a mapping key given twice (with both lines)."""
    return yaml.load(text, Loader=_StrictLoader)
