"""Regression: every golden case (``tests/_golden_cases.py``) reproduces the trajectory, the
covariance and the fused/rejected counts recorded from the pre-Navigator batch runner."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from _golden_cases import CASES, GOLDEN_DIR, Case, case_params, run_case, summarise
from svains.models.state import P


@pytest.fixture(scope="session")
def golden_tmp(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.getbasetemp()  # shared: the village is simulated once per session


def assert_matches_golden(case: Case, arrays: dict[str, np.ndarray]) -> None:
    ref = np.load(GOLDEN_DIR / f"{case.name}.npz")
    np.testing.assert_array_equal(arrays["t_ns"], ref["t_ns"])
    assert arrays["counts"].tolist() == ref["counts"].tolist()
    # Position to 1e-9 m; every other state component (velocity, attitude, rates, biases)
    # to the same absolute tolerance.
    np.testing.assert_allclose(arrays["x"][:, P], ref["x"][:, P], rtol=0, atol=1e-9)
    np.testing.assert_allclose(arrays["x"], ref["x"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(arrays["P9"], ref["P9"], rtol=1e-7, atol=1e-15)


@pytest.mark.slow
@pytest.mark.parametrize("case", case_params(CASES))
def test_run_entry_reproduces_the_goldens(case: Case, golden_tmp: Path) -> None:
    res = run_case(case, golden_tmp)
    assert_matches_golden(case, summarise(res.t_ns, res.x, res.P9, res.report))


def test_recording_refuses_an_unknown_case(tmp_path: Path) -> None:
    from _golden_cases import record

    with pytest.raises(SystemExit, match="no golden case named nope"):
        record(["euroc_lc", "nope"], tmp_path)
