"""Outputs are never overwritten without ``--force`` and never left half-written (issue 12)."""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from _files import tree_digest
from svains.cli.main import app
from svains.datasets import load_dataset
from svains.datasets.asl_writer import AslWriter
from svains.datasets.completion import MARKER, incomplete_reason
from svains.errors import DatasetError, OutputError
from svains.outputs import TMP_PREFIX, atomic_path, atomic_write_text
from svains.sim import SimConfig, simulate

runner = CliRunner()


def _cfg(seed: int = 1) -> SimConfig:
    cfg = SimConfig(duration_s=2.0, seed=seed)
    cfg.camera.render_images = False
    return cfg


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return simulate(_cfg(), tmp_path_factory.mktemp("out") / "ds")



def test_atomic_path_leaves_the_old_file_on_failure(tmp_path: Path) -> None:
    target = atomic_write_text(tmp_path / "a.txt", "old\n")
    with pytest.raises(KeyboardInterrupt), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise KeyboardInterrupt
    assert target.read_text() == "old\n"
    assert [p.name for p in tmp_path.iterdir()] == ["a.txt"]
    atomic_write_text(target, "new\n")
    assert target.read_text() == "new\n" and len(list(tmp_path.iterdir())) == 1


def test_simulate_writes_a_marker_and_refuses_an_existing_data_set(
    dataset: Path, tmp_path: Path
) -> None:
    assert (dataset / "mav0" / MARKER).is_file() and incomplete_reason(dataset / "mav0") is None
    root = shutil.copytree(dataset, tmp_path / "ds")
    before = tree_digest(root)
    with pytest.raises(OutputError, match="already holds a data set"):
        simulate(_cfg(seed=2), root)
    res = runner.invoke(app, ["simulate", "--out", str(root), "--duration", "2", "--no-images",
                              "--seed", "2"])  # fmt: skip
    assert res.exit_code == 2 and "use --force" in res.stderr
    assert tree_digest(root) == before
    res = runner.invoke(app, ["simulate", "--out", str(root), "--duration", "2", "--no-images",
                              "--seed", "2", "--force"])  # fmt: skip
    assert res.exit_code == 0, res.stderr
    assert tree_digest(root) != before and (root / "mav0" / MARKER).is_file()
    assert not [p for p in root.iterdir() if p.name.startswith(TMP_PREFIX)]


def test_interrupted_simulate_leaves_nothing_a_reader_accepts(
    dataset: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def boom(*args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(AslWriter, "write_gps", boom)
    fresh = tmp_path / "fresh"
    with pytest.raises(KeyboardInterrupt):
        simulate(_cfg(), fresh)
    assert not fresh.exists()  # the folder made for it goes too: no mav0/, no staging left
    with pytest.raises(DatasetError):
        load_dataset(fresh)
    # Replacing a data set: the old one stays whole until the new one is complete.
    root = shutil.copytree(dataset, tmp_path / "ds")
    before = tree_digest(root)
    with pytest.raises(KeyboardInterrupt):
        simulate(_cfg(seed=3), root, overwrite=True)
    assert tree_digest(root) == before


def test_reader_warns_on_a_simulated_set_without_marker(
    dataset: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # What a killed simulate (SIGKILL: no cleanup) leaves in its staging folder.
    root = shutil.copytree(dataset, tmp_path / "partial")
    (root / "mav0" / MARKER).unlink()
    with caplog.at_level(logging.WARNING):
        load_dataset(root)
    assert "without the completion marker" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        load_dataset(dataset)
    assert "completion marker" not in caplog.text


@pytest.mark.realdata
def test_real_data_sets_are_not_warned_about(caplog: pytest.LogCaptureFixture) -> None:
    euroc = Path(__file__).resolve().parents[1] / "../shared/data/euroc_v101_micro"
    if not euroc.is_dir():
        pytest.fail(f"real data missing: {euroc} (CI provides ../shared)")
    assert incomplete_reason(euroc / "mav0") is None


def test_run_refuses_a_non_empty_out_and_force_keeps_other_files(
    dataset: Path, tmp_path: Path
) -> None:
    out = tmp_path / "run"
    out.mkdir()
    (out / "notes.txt").write_text("mine\n")
    args = ["run", str(dataset), "--out", str(out), "--init", "groundtruth", "--duration", "1"]
    res = runner.invoke(app, args)
    assert res.exit_code == 2 and "is not empty; use --force" in res.stderr
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    res = runner.invoke(app, [*args, "--force"])
    assert res.exit_code == 0, res.stderr
    assert sorted(p.name for p in out.iterdir()) == [
        "config.yaml", "notes.txt", "pose_covariance.csv", "report.json", "states.csv",
        "trajectory.tum", "trajectory_euroc.csv", "updates.csv",
    ]  # fmt: skip
    assert (out / "notes.txt").read_text() == "mine\n"


def test_interrupted_run_leaves_no_report(
    dataset: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import svains.replay.writers as writers

    def boom(*args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt

    # Interrupted while computing: the output folder is not even created.
    monkeypatch.setattr("svains.evaluation.run.replay", boom)
    out = tmp_path / "run"
    res = runner.invoke(app, ["run", str(dataset), "--out", str(out), "--init", "groundtruth"])
    assert res.exit_code == 130 and not out.exists()
    monkeypatch.undo()
    # Interrupted while writing a replacing run: the previous run is left exactly as it was,
    # and no temporary entry is left beside it or in it.
    res = runner.invoke(app, ["run", str(dataset), "--out", str(out), "--init", "groundtruth",
                              "--duration", "1"])  # fmt: skip
    assert res.exit_code == 0 and (out / "report.json").is_file()
    before = tree_digest(out)
    monkeypatch.setattr(writers, "atomic_write_text", boom)
    res = runner.invoke(app, ["run", str(dataset), "--out", str(out), "--init", "groundtruth",
                              "--duration", "2", "--force"])  # fmt: skip
    assert res.exit_code == 130
    assert tree_digest(out) == before
    assert not [p for p in (*out.iterdir(), *tmp_path.iterdir()) if p.name.startswith(TMP_PREFIX)]
