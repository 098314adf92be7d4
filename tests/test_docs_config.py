"""The generated reference pages of the documentation (``docs/hooks/reference_pages.py``).

The configuration page must list every option key with its default and a meaning, so a new
option without a description (a docstring clause, a comment, or a ``SUPPLEMENT`` entry) fails
here, before ``mkdocs build`` would publish a blank cell. Needs no mkdocs.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import sys
import typing
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

from svains.frontend.options import FrontendOptions
from svains.navigation.config_io import to_dict, with_settings
from svains.navigation.options import RunConfig
from svains.sim.config import SimConfig

ROOT = Path(__file__).resolve().parents[1]
HOOKS = ROOT / "docs" / "hooks"


def _load(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(name, HOOKS / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def pages() -> ModuleType:
    return _load("reference_pages")


def _keys(root: type, prefix: str = "") -> Iterator[tuple[str, type, str]]:
    """(dotted key, owning dataclass, field name) of every field, sections included."""
    hints = typing.get_type_hints(root)
    for f in dataclasses.fields(root):
        yield f"{prefix}{f.name}", root, f.name
        if dataclasses.is_dataclass(hints[f.name]):
            yield from _keys(hints[f.name], f"{prefix}{f.name}.")


ROOTS = [RunConfig, SimConfig, FrontendOptions]


@pytest.mark.parametrize("root", ROOTS, ids=lambda r: r.__name__)
def test_every_option_key_is_listed_with_a_meaning(pages: ModuleType, root: type) -> None:
    rows = {row.key: row for row in pages.option_rows(root)}
    expected = [key for key, _, _ in _keys(root)]
    assert list(rows) == expected
    undescribed = [row.owner for row in rows.values() if not row.meaning.strip()]
    assert undescribed == [], (
        "option keys without a meaning: describe each in its dataclass (a docstring clause "
        "starting with ``name``, or a comment) or in SUPPLEMENT of docs/hooks/reference_pages.py"
    )


def test_the_documented_roots_are_the_option_trees(pages: ModuleType) -> None:
    assert [tree.root for tree in pages.option_trees()] == ROOTS


def _value_at(values: dict[str, Any], key: str) -> Any:
    """The value (or section dict) at dotted ``key`` of a ``to_dict`` configuration."""
    value: Any = values
    for part in key.split("."):
        value = value[part]
    return value


def test_defaults_are_the_dataclasses_own(pages: ModuleType) -> None:
    values = to_dict(RunConfig())
    for row in pages.option_rows(RunConfig):
        value = _value_at(values, row.key)
        if isinstance(value, dict):
            assert row.default == "(section)"
        else:
            assert row.default == pages._default_text(value), row.key


def test_every_listed_run_key_is_a_set_key(pages: ModuleType) -> None:
    """Each leaf key of the run configuration is accepted by ``--set`` (``with_settings``)."""
    values = to_dict(RunConfig())
    for row in pages.option_rows(RunConfig):
        value = _value_at(values, row.key)
        if not isinstance(value, dict):
            assert with_settings(RunConfig(), {row.key: value}) == RunConfig(), row.key


def test_supplement_is_current_and_not_shadowed(pages: ModuleType) -> None:
    """A ``SUPPLEMENT`` entry names an existing field whose source says nothing better."""
    fields = {f"{cls.__name__}.{name}": (cls, name) for root in ROOTS
              for _, cls, name in _keys(root)}  # fmt: skip
    stale = sorted(set(pages.SUPPLEMENT) - set(fields))
    assert stale == [], f"SUPPLEMENT entries for fields that no longer exist: {stale}"
    shadowed = [
        owner for owner in pages.SUPPLEMENT
        if {"definition", "above"} & set(pages.meaning_sources(*fields[owner]))
    ]  # fmt: skip
    assert shadowed == [], f"SUPPLEMENT entries the source now describes: {shadowed}"


def test_configuration_page_lists_every_key(pages: ModuleType) -> None:
    text = pages.configuration_page()
    for root in ROOTS:
        for key, _, _ in _keys(root):
            assert f"`{key}`" in text, key
    assert "\n| `vision.frame_stride` | int | `1` |" in text


def test_meaning_comes_from_the_source() -> None:
    """A docstring clause, the comment above and a unit comment are each found."""
    module = _load("reference_pages")

    @dataclasses.dataclass(frozen=True)
    class Example:
        """Example options. ``alpha``: the first; ``beta`` the second (one; two)."""

        alpha: float = 1.0
        beta: int = 2
        # The gamma factor.
        gamma: float = 3.0
        delta_m: float = 4.0  # m
        eps: bool = True  # switches eps on

    assert module.field_meaning(Example, "alpha") == "`alpha`: the first."
    assert module.field_meaning(Example, "beta") == "`beta` the second (one; two)."
    assert module.field_meaning(Example, "gamma") == "The gamma factor."
    assert module.field_meaning(Example, "delta_m") == ""  # a unit alone is no meaning
    assert module.field_meaning(Example, "eps") == "switches eps on."


def test_cli_page_lists_every_command(pages: ModuleType) -> None:
    from svains.cli.main import COMMAND_MODULES

    text = pages.cli_page()
    for name in COMMAND_MODULES:
        assert f"\n## svains {name}\n" in text, name
    run = text.split("\n## svains run\n")[1].split("\n## ")[0]
    assert "`--set" in run and "`--method" in run
