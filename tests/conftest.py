"""Shared test fixtures: paths to the real data beside the project."""

from __future__ import annotations

from pathlib import Path

import pytest

PROJECT_ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = PROJECT_ROOT.parent / "shared" / "data"
EUROC_MICRO = SHARED_DATA / "euroc_v101_micro"
KITTI_A = SHARED_DATA / "kitti_stereo_a"
KITTI_RAW = SHARED_DATA / "kitti_raw_0926_41s"
TRAJECTORIES = SHARED_DATA / "trajectories"


@pytest.fixture(scope="session")
def euroc_micro() -> Path:
    if not EUROC_MICRO.is_dir():
        pytest.fail(f"real data missing: {EUROC_MICRO} (CI provides ../shared)")
    return EUROC_MICRO


@pytest.fixture(scope="session")
def kitti_a() -> Path:
    if not KITTI_A.is_dir():
        pytest.fail(f"real data missing: {KITTI_A} (CI provides ../shared)")
    return KITTI_A


@pytest.fixture(scope="session")
def kitti_raw() -> Path:
    if not KITTI_RAW.is_dir():
        pytest.fail(f"real data missing: {KITTI_RAW} (CI provides ../shared)")
    return KITTI_RAW
