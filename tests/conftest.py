"""Shared test fixtures: paths to the real data beside the project.

Real data is found at ``../shared/data`` beside the project (``SHARED_DATA``; no variable moves
it). Every test that needs it carries the ``realdata`` marker, so ``pytest -m "not realdata"``
runs without it: the tests that take a real-data fixture (``REALDATA_FIXTURES``, directly or
through another fixture) are marked here at collection, the few that open a shared path
themselves are marked where they are defined. A missing data set fails such a test, never
skips it.

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

from _flights import gps_flight  # noqa: E402

threadpool_limits(limits=1)  # libraries loaded before this file (none expected) too

PROJECT_ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = PROJECT_ROOT.parent / "shared" / "data"
EUROC_MICRO = SHARED_DATA / "euroc_v101_micro"
KITTI_A = SHARED_DATA / "kitti_stereo_a"
KITTI_RAW = SHARED_DATA / "kitti_raw_0926_41s"
TRAJECTORIES = SHARED_DATA / "trajectories"


# Fixtures that hand out a data set of ../shared/data.
REALDATA_FIXTURES = frozenset({"euroc_micro", "kitti_a", "kitti_raw"})


@pytest.hookimpl(tryfirst=True)  # before ``-m`` selects by marker
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark ``realdata`` every test whose fixtures (their whole closure) include a real-data
    fixture."""
    for item in items:
        if REALDATA_FIXTURES.intersection(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.realdata)


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


@pytest.fixture(scope="session")
def village_30s(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The simulator's village, 30 s, seed 0, features only, GPS at 1 Hz throughout (the
    online sensor checks' tests: ``test_course_check.py``, ``test_heading_check.py``)."""
    return gps_flight(tmp_path_factory.mktemp("village_30s") / "data", 30.0, 0)
