"""The thread limit of the numerical libraries (svains.threads)."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg  # noqa: F401  (loads scipy's own BLAS, limited too)
from threadpoolctl import threadpool_info, threadpool_limits

from svains.errors import ConfigError
from svains.threads import ENV_VAR, limit_threads, threads_from_env


def _blas_threads() -> list[int]:
    return [d["num_threads"] for d in threadpool_info() if d["user_api"] == "blas"]


def test_limit_applies_inside_and_is_restored_after() -> None:
    with threadpool_limits(limits=2):  # a known starting point whatever the machine's default
        before = _blas_threads()
        env_before = os.environ.get("OPENBLAS_NUM_THREADS")
        with limit_threads(1):
            assert _blas_threads() and set(_blas_threads()) == {1}
            assert os.environ["OPENBLAS_NUM_THREADS"] == "1"
            assert os.environ["OPENCV_FOR_THREADS_NUM"] == "1"
            # Numbers are unchanged by the thread count.
            a = np.random.default_rng(0).standard_normal((50, 50))
            assert np.isfinite(np.linalg.inv(a @ a.T + np.eye(50))).all()
        assert _blas_threads() == before
        assert os.environ.get("OPENBLAS_NUM_THREADS") == env_before


def test_zero_leaves_the_libraries_alone() -> None:
    with threadpool_limits(limits=2):
        before = _blas_threads()
        with limit_threads(0):
            assert _blas_threads() == before


def test_none_reads_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(ENV_VAR, "1")
    with threadpool_limits(limits=2), limit_threads(None):
        assert set(_blas_threads()) == {1}
    monkeypatch.setenv(ENV_VAR, "3")
    assert threads_from_env() == 3
    monkeypatch.delenv(ENV_VAR)
    assert threads_from_env() == 1
    monkeypatch.setenv(ENV_VAR, " ")
    assert threads_from_env(default=2) == 2


@pytest.mark.parametrize("raw", ["two", "-1", "1.5"])
def test_bad_environment_value_is_named(monkeypatch: pytest.MonkeyPatch, raw: str) -> None:
    monkeypatch.setenv(ENV_VAR, raw)
    with pytest.raises(ConfigError, match=f"SVAINS_THREADS must be an integer >= 0, got '{raw}'"):
        threads_from_env()


def test_negative_limit_is_refused() -> None:
    with pytest.raises(ConfigError, match="thread limit must be >= 0, got -2"), limit_threads(-2):
        pass


def test_cli_applies_the_limit_for_the_command(
    monkeypatch: pytest.MonkeyPatch, euroc_micro: Path
) -> None:
    """``svains --threads N`` and ``SVAINS_THREADS`` reach ``limit_threads``, entered for the
    command's duration; a negative value is refused by the option's range."""
    from contextlib import contextmanager

    from typer.testing import CliRunner

    import svains.cli.main as cli_main

    seen: list[tuple[str, int | None]] = []

    @contextmanager
    def fake(n: int | None = 1) -> Iterator[None]:
        seen.append(("enter", n))
        yield
        seen.append(("exit", n))

    monkeypatch.setattr(cli_main, "limit_threads", fake)
    runner = CliRunner()
    res = runner.invoke(cli_main.app, ["--threads", "3", "info", str(euroc_micro)])
    assert res.exit_code == 0, res.output
    assert seen == [("enter", 3), ("exit", 3)]
    seen.clear()
    res = runner.invoke(cli_main.app, ["info", str(euroc_micro)], env={ENV_VAR: "2"})
    assert res.exit_code == 0, res.output
    assert seen == [("enter", 2), ("exit", 2)]
    seen.clear()
    res = runner.invoke(cli_main.app, ["info", str(euroc_micro)], env={ENV_VAR: ""})
    assert seen[0] == ("enter", 1)
    res = runner.invoke(
        cli_main.app, ["--threads", "-1", "info", str(euroc_micro)], env={"COLUMNS": "200"}
    )
    assert res.exit_code != 0
    assert "Invalid value for '--threads'" in res.output
    assert "greater than or equal to 0" in res.output


def test_nested_none_keeps_the_outer_limit(monkeypatch: pytest.MonkeyPatch) -> None:
    # The replay enters limit_threads(None) inside ``svains --threads N``: it must keep N.
    monkeypatch.delenv(ENV_VAR, raising=False)
    with threadpool_limits(limits=1), limit_threads(2):
        assert os.environ[ENV_VAR] == "2"
        with limit_threads(None):
            assert set(_blas_threads()) == {2}
        with limit_threads(0):
            assert os.environ[ENV_VAR] == "0"
            with limit_threads(None):  # 0 outside: the libraries keep their threads
                assert set(_blas_threads()) == {2}
        assert os.environ[ENV_VAR] == "2"
    assert ENV_VAR not in os.environ


def test_replay_runs_with_the_limit_and_restores_it(monkeypatch: pytest.MonkeyPatch) -> None:
    from _ins_truth import make_dataset
    from svains.navigation.options import InitOptions, RunOptions
    from svains.replay import replay

    seen: list[list[int]] = []

    def on_output(state: object) -> None:
        if not seen:  # threadpool_info costs ~ms: once is enough
            seen.append(_blas_threads())

    monkeypatch.setenv(ENV_VAR, "1")
    ds = make_dataset(2.0)
    with threadpool_limits(limits=2):
        replay(ds, RunOptions(init=InitOptions(mode="groundtruth")), on_output=on_output)
        assert seen and set(seen[0]) == {1}
        assert set(_blas_threads()) == {2}


def test_more_threads_than_cores_are_capped_with_a_warning(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """``--threads 64`` on 2 cores ran a 3.5 s job in 71 s (a user's probe): capped, warned."""
    import os

    from svains.threads import limit_threads

    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    with caplog.at_level("WARNING", logger="svains.threads"), limit_threads(64):
        assert os.environ["SVAINS_THREADS"] == "2" and os.environ["OMP_NUM_THREADS"] == "2"
    assert "64 threads per numerical library on 2 cores would contend: 2 used" in caplog.text
    caplog.clear()
    with caplog.at_level("WARNING", logger="svains.threads"), limit_threads(2):
        pass
    assert caplog.text == ""
