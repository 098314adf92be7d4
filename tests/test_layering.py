"""Imports flow one way (geometry/sensors <- filter <- models <- frontend <- navigation (the
estimator, ``svains.Navigator``) <- datasets/sim <- replay <- evaluation <- batch <- cli), heavy
dependencies stay in their layer, and the library never prints. So the estimator cannot reach a
data set: only the replay driver, the evaluation, the campaigns and the command line do.

Every import of every module under ``src/svains`` is read with ``ast`` (function-level lazy
imports included), so a violation fails here whatever its style.
"""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src" / "svains"

# Layer rank of each sub-package: a module may import its own layer and the layers below.
LAYERS: dict[str, int] = {
    "geometry": 0, "sensors": 0, "filter": 1, "models": 2, "frontend": 3, "navigation": 4,
    "datasets": 5, "sim": 5, "replay": 6, "evaluation": 7, "batch": 8, "cli": 9,
}  # fmt: skip
# Top-level modules every layer may use.
SHARED = {"errors", "outputs", "threads", "yaml_io"}

# (importing module or package, imported svains module) -> why it is allowed. Keep it short.
LAYER_EXCEPTIONS: dict[tuple[str, str], str] = {
    ("frontend/run.py", "svains.datasets.types"): "the front end's own data-set runner "
    "(``svains frontend``), not used by the estimator",
    ("models/vision_lc.py", "svains.frontend.types"): "the LC measurement model takes the front "
    "end's Egomotion dataclass (plain data, no OpenCV) as its measurement",
}

# Third-party packages confined to some places: package -> allowed modules/packages.
CONFINED: dict[str, dict[str, str]] = {
    "cv2": {
        "frontend": "the front end proper is the OpenCV layer",
        "sim/render.py": "the renderer's per-face perspective warps",
        "sim/raster.py": "the renderer's image pyramid (split out of render.py)",
        "sim/fisheye.py": "the fisheye image's remap from a wide pinhole render",
        "datasets/_image_io.py": "PNG decoding and encoding, imported lazily",
    },
    "typer": {"cli": "the command line"},
    "rich": {"cli": "terminal tables and progress bars"},
    # GPL-3, test-only (the ``test`` extra): the oracle of tests/test_metrics_vs_evo.py. svains
    # computes ATE/RPE itself, so no module under src may import evo.
    "evo": {},
    "matplotlib": {"evaluation": "the paper's figures", "batch/figures.py": "campaign figures"},
    "rosbags": {
        "datasets/rosbag.py": "reading ROS1/ROS2 bags",
        "datasets/rosbag_writer.py": "writing ROS1/ROS2 bags",
    },
    "rerun": {"evaluation/viewer.py": "the optional viewer (svains[viz])"},
    "dask": {"batch": "campaigns on a Dask cluster"},
    "distributed": {"batch": "campaigns on a Dask cluster"},
}


def _sources() -> list[tuple[str, str]]:
    """(path relative to ``src/svains`` in POSIX form, text) of every module."""
    return [
        (p.relative_to(SRC).as_posix(), p.read_text(encoding="utf-8"))
        for p in sorted(SRC.rglob("*.py"))
    ]


def _imports(rel: str, text: str) -> list[tuple[str, int]]:
    """Absolute module names imported anywhere in a module (relative imports resolved)."""
    package = ["svains", *rel.split("/")[:-1]]
    out: list[tuple[str, int]] = []
    for node in ast.walk(ast.parse(text, rel)):
        if isinstance(node, ast.Import):
            out.extend((a.name, node.lineno) for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                name = ".".join([*base, node.module] if node.module else base)
            else:
                name = node.module or ""
            out.append((name, node.lineno))
            # ``from svains import evaluation`` imports the sub-package itself.
            if name == "svains":
                out.extend((f"svains.{a.name}", node.lineno) for a in node.names)
    return out


def _matches(rel: str, key: str) -> bool:
    return rel == key or rel.startswith(key + "/")


def layer_violations(sources: list[tuple[str, str]]) -> list[str]:
    """One line per import that goes up the layer order or to a confined package."""
    bad: list[str] = []
    for rel, text in sources:
        pkg = rel.split("/")[0] if "/" in rel else None
        for name, line in _imports(rel, text):
            top = name.split(".")[0]
            where = f"{rel}:{line} imports {name}"
            if top == "svains" and pkg in LAYERS:
                parts = name.split(".")
                target = parts[1] if len(parts) > 1 else ""
                if target in SHARED or target not in LAYERS or LAYERS[target] <= LAYERS[pkg]:
                    continue
                if any(
                    _matches(rel, who) and (name == what or name.startswith(what + "."))
                    for who, what in LAYER_EXCEPTIONS
                ):
                    continue
                bad.append(f"{where} (layer {pkg} is below {target})")
            elif top in CONFINED and not any(_matches(rel, k) for k in CONFINED[top]):
                places = ", ".join(CONFINED[top]) or "the tests (imported nowhere in src)"
                bad.append(f"{where} ({top} is confined to {places})")
    return bad


def test_every_package_has_a_layer() -> None:
    packages = {p.name for p in SRC.iterdir() if p.is_dir() and (p / "__init__.py").is_file()}
    assert packages == set(LAYERS), "a new package needs its place in LAYERS"


def test_the_estimator_never_imports_data_sets() -> None:
    """filter/, models/ and navigation/ (the Navigator) import nothing from datasets/, sim/,
    replay/, evaluation/ or cli/ (lazy imports included)."""
    edge = (["svains", "datasets"], ["svains", "sim"], ["svains", "replay"],
            ["svains", "evaluation"], ["svains", "cli"])  # fmt: skip
    offenders = [
        f"{rel}:{line} {name}"
        for rel, text in _sources()
        if rel.split("/")[0] in ("filter", "models", "navigation", "sensors")
        for name, line in _imports(rel, text)
        if name.split(".")[:2] in edge
    ]
    assert offenders == []
    bad = layer_violations([("navigation/fake.py", "from svains.datasets.types import Dataset\n")])
    assert len(bad) == 1 and "layer navigation is below datasets" in bad[0]


def test_imports_follow_the_layer_order() -> None:
    assert layer_violations(_sources()) == []


def test_the_checker_catches_lazy_relative_and_package_imports() -> None:
    fake = (
        "def g():\n    from svains.evaluation.metrics import ate\n"
        "from ..evaluation import run\nfrom svains import cli\nimport cv2\n"
        "from svains.errors import ConfigError\nfrom svains.models.state import PAPER\n"
    )
    bad = layer_violations([("navigation/fake.py", fake)])
    assert len(bad) == 4, bad
    assert any("svains.evaluation.metrics" in b for b in bad)
    assert any(":3 imports svains.evaluation " in b for b in bad)  # the relative import
    assert any("svains.cli" in b for b in bad) and any("cv2 is confined" in b for b in bad)
    # The listed exceptions apply to their own module only.
    line = "from svains.frontend.types import Egomotion\n"
    assert layer_violations([("models/vision_lc.py", line)]) == []
    assert len(layer_violations([("models/imu.py", line)])) == 1


def test_evo_is_confined_to_the_tests() -> None:
    """evo (GPL-3) is the tests' oracle only: an import of it anywhere in src is a violation,
    the evaluation layer included."""
    lazy = "def f():\n    from evo.tools import file_interface\n"
    bad = layer_violations([("evaluation/metrics.py", "import evo.core.metrics\n"),
                            ("cli/evaluate.py", lazy)])  # fmt: skip
    assert len(bad) == 2 and all("evo is confined to the tests" in b for b in bad), bad


def test_library_never_prints_or_exits() -> None:
    bad = []
    for rel, text in _sources():
        if rel.startswith("cli/"):
            continue
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.Call):
                f = node.func
                if (isinstance(f, ast.Name) and f.id in ("print", "exit", "quit")) or (
                    isinstance(f, ast.Attribute) and f.attr == "exit"
                    and isinstance(f.value, ast.Name) and f.value.id == "sys"
                ):  # fmt: skip
                    bad.append(f"{rel}:{node.lineno}")
    assert bad == []
