"""svains is MIT: nothing a plain ``pip install .`` pulls in may be GPL or AGPL (LGPL is fine).

The distributions are the transitive closure of svains's ``Requires-Dist`` without extras,
resolved against the installed environment with ``importlib.metadata`` (each requirement's
extras and environment markers followed). A licence is read from the ``License-Expression``
(SPDX), the ``Classifier: License ::`` lines and the ``License`` field (its first line: some
packages put their whole licence text there, whose later lines may cite bundled GPL pieces).
evo (GPL-3) is why this exists: it is the test-only oracle of the metrics (``test`` extra).
"""

from __future__ import annotations

import ast
import email.message
import importlib.metadata as md
import re
import tomllib
from pathlib import Path
from typing import Any

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = ROOT / "pyproject.toml"

# Distributions whose GPL mention was reviewed and accepted (e.g. dual licensed, MIT chosen):
# canonical name -> why. Keep it empty unless a person decided.
REVIEWED: dict[str, str] = {}

# "GPL", "AGPL", "GPLv3", "GNU (Affero) General Public License"; not "LGPL" or the "Lesser" /
# "Library" General Public License.
_GPL_NAME = re.compile(r"\bA?GPL|(?<!lesser )(?<!library )general\s+public\s+licen[cs]e", re.I)
# SPDX identifiers of the GPL family (GPL-2.0-only, GPL-3.0-or-later, AGPL-3.0, GPL-2.0+ ...).
_GPL_SPDX = re.compile(r"^A?GPL-", re.I)


def default_requirements() -> list[str]:
    """svains's own requirements without extras. From the checkout's ``pyproject.toml`` (what
    ``pip install .`` writes into ``Requires-Dist``: an editable install's metadata is as old as
    its last ``pip install``), else from the installed metadata."""
    if PYPROJECT.is_file():
        return list(tomllib.loads(PYPROJECT.read_text(encoding="utf-8"))["project"]["dependencies"])
    return [
        r for r in md.requires("svains") or []
        if (m := Requirement(r).marker) is None or m.evaluate({"extra": ""})
    ]  # fmt: skip


def closure(requirements: list[str]) -> tuple[dict[str, md.Distribution], list[str]]:
    """Installed distributions (canonical name -> distribution) reached from ``requirements``
    through ``Requires-Dist`` (with the extras asked for, markers evaluated here), and the
    requirements that are not installed."""
    found: dict[str, md.Distribution] = {}
    extras_of: dict[str, set[str]] = {}
    missing: list[str] = []
    todo = [Requirement(r) for r in requirements]
    while todo:
        req = todo.pop()
        name = canonicalize_name(req.name)
        asked = set(req.extras)
        if name in found and asked <= extras_of[name]:
            continue
        try:
            dist = found.get(name) or md.distribution(req.name)
        except md.PackageNotFoundError:
            missing.append(str(req))
            continue
        found[name] = dist
        extras_of[name] = extras_of.get(name, set()) | asked
        envs = [{"extra": e} for e in ("", *sorted(extras_of[name]))]
        for r in dist.requires or []:
            sub = Requirement(r)
            if sub.marker is None or any(sub.marker.evaluate(env) for env in envs):
                todo.append(sub)
    return found, missing


def gpl_reasons(meta: Any) -> list[str]:
    """Why a distribution's metadata (``License``, ``License-Expression``, ``Classifier``)
    names a GPL or AGPL licence; empty when it does not (LGPL is not GPL here)."""
    out = []
    expression = meta.get("License-Expression") or ""
    ids = [tok for tok in re.findall(r"[A-Za-z0-9.+-]+", expression) if _GPL_SPDX.match(tok)]
    if ids:
        out.append(f"License-Expression: {expression}")
    for c in meta.get_all("Classifier") or []:
        if c.startswith("License ::") and _GPL_NAME.search(c):
            out.append(f"Classifier: {c}")
    lines = [ln.strip() for ln in (meta.get("License") or "").splitlines() if ln.strip()]
    if lines and _GPL_NAME.search(lines[0]):
        out.append(f"License: {lines[0][:80]}")
    return out


def _fake_meta(license_: str = "", expression: str = "", classifiers: tuple[str, ...] = ()
               ) -> email.message.Message:  # fmt: skip
    m = email.message.Message()
    if license_:
        m["License"] = license_
    if expression:
        m["License-Expression"] = expression
    for c in classifiers:
        m["Classifier"] = c
    return m


def test_the_default_install_has_no_gpl_dependency() -> None:
    dists, missing = closure(default_requirements())
    assert missing == [], f"not installed, so their licences cannot be checked: {missing}"
    assert {"numpy", "scipy", "matplotlib", "distributed"} <= set(dists)  # extras followed too
    offenders = {
        name: why for name, d in sorted(dists.items())
        if name not in REVIEWED and (why := gpl_reasons(d.metadata))
    }  # fmt: skip
    assert offenders == {}, f"GPL/AGPL in the default install of MIT svains: {offenders}"


def test_evo_back_in_the_dependencies_would_fail() -> None:
    dists, missing = closure([*default_requirements(), "evo>=1.28,<2"])
    assert missing == [] and "evo" in dists
    assert gpl_reasons(dists["evo"].metadata)


def test_svains_itself_is_mit() -> None:
    project = tomllib.loads(PYPROJECT.read_text(encoding="utf-8"))["project"]
    assert project["license"] == "MIT"
    assert not any(canonicalize_name(Requirement(r).name) == "evo" for r in project["dependencies"])


def test_the_licence_reader_tells_gpl_from_lgpl_and_others() -> None:
    OSI = "License :: OSI Approved :: "
    gpl = [
        _fake_meta(expression="GPL-3.0-or-later"),
        _fake_meta(expression="MIT AND (AGPL-3.0-only)"),
        _fake_meta(expression="MIT OR GPL-2.0+"),  # strict: a person decides (REVIEWED)
        _fake_meta(classifiers=(f"{OSI}GNU General Public License v3 (GPLv3)",)),
        _fake_meta(classifiers=(f"{OSI}GNU Affero General Public License v3",)),
        _fake_meta(license_="GPLv2+"),
        _fake_meta(license_="GNU GENERAL PUBLIC LICENSE\n   Version 3, 29 June 2007\n..."),
    ]
    fine = [
        _fake_meta(expression="LGPL-2.1-or-later"),
        _fake_meta(expression="Apache-2.0 WITH LLVM-exception AND BSD-2-Clause"),
        _fake_meta(classifiers=(
            f"{OSI}GNU Lesser General Public License v3 (LGPLv3)",
            f"{OSI}GNU Library or Lesser General Public License (LGPL)",
            f"{OSI}BSD License",
        )),
        _fake_meta(license_="LGPL"),
        # A whole BSD text whose later lines describe a bundled GPL runtime (as scipy's does).
        _fake_meta(license_="Copyright (c) 2001 SciPy\n...\nlibgfortran: GNU General Public "
                   "License v3 with GCC Runtime Library exception"),
        _fake_meta(),
    ]  # fmt: skip
    assert all(gpl_reasons(m) for m in gpl)
    assert not any(gpl_reasons(m) for m in fine)


def test_the_library_never_imports_evo() -> None:
    bad = []
    for path in sorted((ROOT / "src" / "svains").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names = [node.module or ""]
            if any(n == "evo" or n.startswith("evo.") for n in names):
                bad.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert bad == []
