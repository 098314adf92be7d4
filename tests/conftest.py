"""Shared test fixtures: paths to the real data beside the project.

Every numerical library runs one thread in the tests, as svains runs them by default
(``svains.threads``): two pytest-xdist workers on two cores would otherwise each start a
second BLAS/OpenMP thread and oversubscribe the machine.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS", "OMP_NUM_THREADS",
             "OPENCV_FOR_THREADS_NUM"):  # fmt: skip
    os.environ.setdefault(_var, "1")

from pathlib import Path  # noqa: E402

import pytest  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

threadpool_limits(limits=1)  # libraries loaded before this file (none expected) too

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
