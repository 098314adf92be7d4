"""``bench/mutations.yaml`` stays applicable: every mutant's snippet occurs exactly once in its
file and its first test files exist (a refactor that moves a snippet would otherwise leave the
mutation bench broken until someone runs it: ``gps_latency_shift_sign`` was, 2026-12-05)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

BENCH = Path(__file__).resolve().parents[1] / "bench" / "mutations.py"


def _bench() -> ModuleType:
    spec = importlib.util.spec_from_file_location("mutations_bench", BENCH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look themselves up there
    spec.loader.exec_module(module)
    return module


def test_every_mutant_applies_exactly_once() -> None:
    bench = _bench()
    mutants = bench.load_mutants()
    assert len(mutants) >= 100
    bench.check_all(mutants)  # raises BenchError naming the stale mutant


def test_a_stale_snippet_is_named() -> None:
    bench = _bench()
    m = bench.load_mutants()[0]
    stale = bench.Mutant(m.name, m.file, m.find + "# moved", m.replace, m.why, m.first, ())
    try:
        bench.check_all([stale])
    except bench.BenchError as exc:
        assert m.name in str(exc) and "found 0 times" in str(exc)
    else:
        raise AssertionError("a snippet found nowhere passed")
