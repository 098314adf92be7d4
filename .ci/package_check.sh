#!/usr/bin/env bash
# Packaging check: build the sdist and the wheel, check that both hold every module of
# src/svains, install the wheel in a fresh virtual environment (dependencies from the package
# registry, as a user gets them), check that nothing installed is GPL-licensed, and run
# `svains --help` and a 2 s simulation from the installed command. Fails on any error.
#
# PY: the Python that builds (needs `build`, the test extra; default .venv/bin/python) and whose
# base interpreter makes the fresh environment.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
PY=${PY:-$ROOT/.venv/bin/python}
TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT
start=$(date +%s)
step() { echo "package_check: $* ($(( $(date +%s) - start )) s)"; }

step "build the sdist, then the wheel from it"
"$PY" -m build --outdir "$TMP/dist" . >"$TMP/build.log" 2>&1 \
    || { cat "$TMP/build.log"; exit 1; }
wheel=$(ls "$TMP"/dist/svains-*.whl)
sdist=$(ls "$TMP"/dist/svains-*.tar.gz)
echo "  $(basename "$wheel"), $(basename "$sdist")"

step "compare the archives with src/svains"
"$PY" - "$wheel" "$sdist" <<'EOF'
"""Every .py under src/svains is in the wheel (svains/...) and the sdist (src/svains/...), and the
wheel holds no module that is not in the source tree; the version is __version__."""
import ast
import sys
import tarfile
import zipfile
from pathlib import Path

src = Path("src/svains")
modules = {p.relative_to(src.parent).as_posix() for p in src.rglob("*.py")}
wheel = {n for n in zipfile.ZipFile(sys.argv[1]).namelist() if n.endswith(".py")}
with tarfile.open(sys.argv[2]) as tar:
    sdist = {n.split("/", 1)[1] for n in tar.getnames() if n.endswith(".py") and "/src/" in n}
problems = [f"not in the wheel: {m}" for m in sorted(modules - wheel)]
problems += [f"in the wheel, not in src: {m}" for m in sorted(wheel - modules)]
problems += [f"not in the sdist: src/{m}" for m in sorted(modules - {s[4:] for s in sdist})]
init = ast.parse((src / "__init__.py").read_text(encoding="utf-8"))
version = next(
    n.value.value for n in init.body
    if isinstance(n, ast.Assign) and getattr(n.targets[0], "id", "") == "__version__"
)
if f"svains-{version}-" not in Path(sys.argv[1]).name:
    problems.append(f"wheel {Path(sys.argv[1]).name} is not version {version}")
if problems:
    sys.exit("package_check: " + "\n  ".join(["archives differ from src/svains:", *problems]))
print(f"  {len(modules)} modules in both archives, version {version}")
EOF

step "fresh virtual environment, install the wheel"
base=$("$PY" -c 'import sys; print(sys._base_executable)')
"$base" -m venv "$TMP/venv"
"$TMP/venv/bin/python" -m pip install --quiet --disable-pip-version-check "$wheel" \
    >"$TMP/pip.log" 2>&1 || { cat "$TMP/pip.log"; exit 1; }

step "licences of every installed distribution"
"$TMP/venv/bin/python" - <<'EOF'
"""Nothing the wheel pulled in is GPL or AGPL (LGPL is fine): the rule of tests/test_licences.py,
applied to everything installed in this fresh environment."""
import importlib.metadata as md
import re
import sys

GPL_NAME = re.compile(r"\bA?GPL|(?<!lesser )(?<!library )general\s+public\s+licen[cs]e", re.I)
bad = []
for dist in md.distributions():
    meta = dist.metadata
    texts = [meta.get("License-Expression") or "", (meta.get("License") or "").split("\n")[0]]
    texts += [c for c in meta.get_all("Classifier") or [] if c.startswith("License ::")]
    hits = [t for t in texts if GPL_NAME.search(t)]
    if hits:
        bad.append(f"{meta['Name']}: {hits}")
if bad:
    sys.exit("package_check: GPL-licensed distributions installed:\n  " + "\n  ".join(bad))
print(f"  {len(list(md.distributions()))} distributions, none GPL")
EOF

step "run the installed command"
cd "$TMP"  # away from the source tree, so only the installed package can be imported
"$TMP/venv/bin/svains" --help >/dev/null
"$TMP/venv/bin/python" -c 'import svains, sys; sys.exit(0 if "site-packages" in svains.__file__ else 1)'
"$TMP/venv/bin/svains" simulate --duration 2 --out "$TMP/sim" --no-images >"$TMP/sim.log" 2>&1 \
    || { cat "$TMP/sim.log"; exit 1; }
test -f "$TMP/sim/mav0/svains_complete.yaml"
"$TMP/venv/bin/svains" info "$TMP/sim" >/dev/null
step "passed"
