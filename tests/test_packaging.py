"""Packaging metadata: one version source, a changelog entry for it, the supported Pythons, the
extras, and CI running the pieces of issue 24. The build itself is ``.ci/package_check.sh``."""

from __future__ import annotations

import ast
import re
import tomllib
from pathlib import Path
from typing import Any

from packaging.specifiers import SpecifierSet

ROOT = Path(__file__).resolve().parents[1]


def _pyproject() -> dict[str, Any]:
    return tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))


def _version() -> str:
    """``__version__`` of src/svains/__init__.py, read without importing the package."""
    tree = ast.parse((ROOT / "src" / "svains" / "__init__.py").read_text(encoding="utf-8"))
    for node in tree.body:
        if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", "") == "__version__":
            assert isinstance(node.value, ast.Constant)
            return str(node.value.value)
    raise AssertionError("no __version__ in src/svains/__init__.py")


def test_one_version_source() -> None:
    project = _pyproject()["project"]
    assert "version" not in project and "version" in project["dynamic"]
    dynamic = _pyproject()["tool"]["setuptools"]["dynamic"]["version"]
    assert dynamic == {"attr": "svains.__version__"}
    assert re.fullmatch(r"\d+\.\d+\.\d+", _version())


def test_changelog_has_the_version() -> None:
    text = (ROOT / "CHANGELOG.md").read_text(encoding="utf-8")
    assert "keepachangelog.com" in text and "## [Unreleased]" in text
    releases = re.findall(r"^## \[(\d+\.\d+\.\d+)\] - (\d{4}-\d{2}-\d{2})$", text, re.M)
    assert releases and releases[0][0] == _version()


def test_supported_pythons() -> None:
    spec = SpecifierSet(_pyproject()["project"]["requires-python"])
    assert all(v in spec for v in ("3.11.0", "3.12.0", "3.13.0"))
    assert "3.10.0" not in spec


def test_extras() -> None:
    extras = _pyproject()["project"]["optional-dependencies"]
    names = {k: {re.split(r"[\[<>=!~ ]", r)[0] for r in v} for k, v in extras.items()}
    assert {"mkdocs", "mkdocs-material", "mkdocstrings"} <= names["docs"]
    assert {"build", "evo"} <= names["test"]
    core = {re.split(r"[\[<>=!~ ]", r)[0] for r in _pyproject()["project"]["dependencies"]}
    assert "evo" not in core


def test_ci_runs_the_suite_first_then_docs_and_packaging() -> None:
    lines = [ln.strip() for ln in (ROOT / ".ci" / "run").read_text().splitlines()
             if ln.strip() and not ln.lstrip().startswith("#")]  # fmt: skip
    commands = [ln for ln in lines if not ln.startswith(("set ", "cd ", "#!"))]
    assert commands[0] == "make test"
    text = "\n".join(lines)
    assert text.index("make docs") < text.index(".ci/package_check.sh") < text.index(
        "make test-py313"
    )
    makefile = (ROOT / "Makefile").read_text()
    assert "mkdocs build --strict --site-dir site" in makefile
    assert "site/" in (ROOT / ".gitignore").read_text().splitlines()


def test_the_measured_with_constraints_pin_every_dependency_inside_its_range() -> None:
    """``bench/measured-with.txt`` (the versions the figures were last measured with, for
    ``pip install -c``) pins each runtime dependency exactly, to a version pyproject allows."""
    from packaging.requirements import Requirement

    pins = {}
    for line in (ROOT / "bench" / "measured-with.txt").read_text(encoding="utf-8").splitlines():
        if line.strip() and not line.startswith("#"):
            req = Requirement(line)
            (spec,) = req.specifier
            assert spec.operator == "==", line
            pins[req.name.lower().replace("_", "-")] = spec.version
    for dep in _pyproject()["project"]["dependencies"]:
        req = Requirement(dep)
        name = req.name.lower().replace("_", "-")
        assert name in pins, f"{name} not pinned in bench/measured-with.txt"
        assert req.specifier.contains(pins[name], prereleases=True), (name, pins[name])
