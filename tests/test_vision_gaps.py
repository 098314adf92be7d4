"""``vision_gap_report``: the report keys that say when vision stopped."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from svains.navigation.vision_gaps import vision_gap_report

S = 1_000_000_000


def test_vision_that_stops_early_is_reported_as_a_gap() -> None:
    # 20 s run; frames fused at 2 Hz over the first 4.5 s only (the images-cover-4.7-s
    # case): one gap from 4.5 s to the end.
    fused = np.arange(0, 5 * S, S // 2)[:10]
    rep = vision_gap_report(fused, 0, 20 * S, max_gap_s=2.0)
    assert rep["vision_gaps"] == [{"start_s": 4.5, "duration_s": 15.5}]
    assert rep["vision_longest_gap_s"] == pytest.approx(15.5)
    assert rep["vision_gap_fraction"] == pytest.approx(15.5 / 20)
    assert rep["vision_fused_frames"] == 10 and rep["vision_degraded"] is False


def test_regular_vision_has_no_gap_and_none_at_all_is_degraded() -> None:
    fused = np.arange(S, 30 * S, S // 2)
    rep = vision_gap_report(fused, S, 29 * S + S // 2)
    assert rep["vision_gaps"] == [] and rep["vision_gap_fraction"] == 0.0
    assert rep["vision_longest_gap_s"] == pytest.approx(0.5)
    none = vision_gap_report(np.zeros(0, np.int64), 0, 10 * S)
    assert none["vision_degraded"] is True and none["vision_gap_fraction"] == 1.0
    assert none["vision_gaps"] == [{"start_s": 0.0, "duration_s": 10.0}]


def test_a_gap_in_the_middle_and_times_outside_the_run() -> None:
    fused = np.array([-5, 0, 1, 2, 8, 9, 10, 50], dtype=np.int64) * S
    rep = vision_gap_report(fused, 0, 10 * S, max_gap_s=3.0)
    assert rep["vision_gaps"] == [{"start_s": 2.0, "duration_s": 6.0}]
    assert rep["vision_fused_frames"] == 6
    with pytest.raises(ValueError, match="before it starts"):
        vision_gap_report(fused, 10 * S, 0)


def test_the_gap_limit_follows_the_streams_longer_spacings() -> None:
    from svains.navigation.vision_gaps import vision_gap_limit_s

    assert vision_gap_limit_s([], 2.0) == 2.0
    assert vision_gap_limit_s([S // 5] * 31, 2.0) == 2.0  # 5 Hz: the floor
    assert vision_gap_limit_s([5 * S] * 31, 2.0) == pytest.approx(12.5)  # every 25th frame
    # Alternating 0.2 s / 5 s (a user's probe): the same limit with 15 or 16 long spacings in
    # the window (the median flipped between 0.2 and 2.6 s: 2 s, then 6.5 s)
    for n_long in (15, 16):
        spacings = [S // 5] * (31 - n_long) + [5 * S] * n_long
        assert vision_gap_limit_s(spacings, 2.0) == pytest.approx(12.5)


def test_a_run_mostly_without_vision_says_so_at_its_end(tmp_path: Path) -> None:
    """A run that fused a few frames and rode the IMU for the rest ended with no word (a
    probe: 90 % of a run without vision); its table gives the gaps and a warning follows."""
    from typer.testing import CliRunner

    from svains.cli.main import app
    from svains.sim import SimConfig, simulate

    cfg = SimConfig(duration_s=6.0, seed=1)
    cfg.camera.render_images = False
    root = simulate(cfg, tmp_path / "ds")
    path = root / "mav0" / "features0" / "data.csv"
    lines = path.read_text().splitlines()
    t0 = int(lines[1].split(",")[0])
    kept = [ln for ln in lines[1:] if int(ln.split(",")[0]) - t0 < 2_100_000_000]
    path.write_text("\n".join([lines[0], *kept]) + "\n")
    res = CliRunner().invoke(app, ["run", str(root), "--method", "3d", "--init", "groundtruth",
                                   "--out", str(tmp_path / "o")])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "vision gaps" in res.output
    said = re.search(r"3d went without vision for (\d+) % of the run", res.output)
    assert said is not None and 50 <= int(said.group(1)) <= 70, res.output
    argv = ["run", str(root), "--method", "3d", "--init", "groundtruth", "--out",
            str(tmp_path / "o2"), "--duration", "2.5"]  # fmt: skip
    full = CliRunner().invoke(app, argv)
    assert full.exit_code == 0 and "without vision" not in full.output, full.output
