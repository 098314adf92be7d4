"""Mutation bench (issue 26): do the non-golden tests catch a wrong filter?

Each mutant of ``bench/mutations.yaml`` (name, file, an exact snippet ``find`` that must occur
once, its ``replace``, why it matters, optional ``first`` test files) is applied to a fresh copy
of the repository (its files as git lists them, tracked and untracked-not-ignored: ``src/``,
``tests/`` and whatever the tests read, such as ``docs/``, ``README.md``, ``pyproject.toml``) in
a temporary directory (``tempfile.mkdtemp``; ``../shared`` is linked beside the copy so the
real-data tests find their data). pytest then runs in that copy with ``PYTHONPATH`` at the
copy's ``src``, which comes before the editable install's path entry, so the mutated code is
the one imported (``--canary`` checks it: a mutant raising at import must be killed).

A mutant runs its ``first`` test files, then, if nothing failed, every other non-golden test:
a survivor has run the whole non-golden suite. The goldens (``tests/test_golden.py`` and
``tests/test_navigator.py::test_fed_by_hand_equals_svains_run``, which compares with them)
are excluded. pytest gets ``-x -q -p no:cacheprovider`` and ``--workers N`` (1: no xdist,
else ``-n N``).

Usage::

    python bench/mutations.py                  # all mutants
    python bench/mutations.py --list
    python bench/mutations.py --only pixel_bias_sign --json out.json
    python bench/mutations.py --check          # every snippet found exactly once, nothing run
    python bench/mutations.py --baseline       # the unmutated copy first (must pass)
    python bench/mutations.py --canary         # an import-time error must be killed
    python bench/mutations.py --root SNAPSHOT  # copy a frozen tree instead of the work tree

The copy is taken from the work tree as it is when each mutant starts (other people's
unfinished edits included): for a figure to quote, freeze a snapshot and pass ``--root``.
A mutant whose pytest run exceeds ``--timeout`` counts as killed (by the timeout).

Exit code 0 whatever the kill rate; 2 when the bench itself cannot run (a snippet not found
exactly once, an unknown mutant, a baseline that fails).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
SPEC = Path(__file__).resolve().with_suffix(".yaml")
# Never copied from a tree that is not a git work tree (virtualenvs, caches, build output).
SKIP_DIRS = frozenset({".git", ".venv", ".venv313", "__pycache__", ".pytest_cache", ".ruff_cache",
                       ".hypothesis", "site", "build", "dist", "demo_out", "out"})  # fmt: skip
GOLDEN_ARGS = (
    "--ignore=tests/test_golden.py",
    "--deselect=tests/test_navigator.py::test_fed_by_hand_equals_svains_run",
)
# A mutant still running after this long (one phase) counts as killed by the timeout.
TIMEOUT_S = 1800.0
CANARY = {
    "name": "canary_import_error",
    "file": "src/svains/__init__.py",
    "find": None,  # prepended, see apply_mutation
    "replace": "raise RuntimeError('mutation bench canary: the copy is imported')\n",
    "why": "Checks that the copy's src is imported, not the editable install.",
    "first": ["tests/test_models_imu.py"],
}
_RESULT_LINE = re.compile(r"^(FAILED|ERROR) (\S+)")


class BenchError(Exception):
    """The bench cannot run (bad mutation list, snippet not found, failing baseline)."""


@dataclass(frozen=True)
class Mutant:
    """One semantic mutation: ``find`` (exact, once in ``file``) becomes ``replace``.

    ``variants``: further ``(find, replace)`` pairs for a file being rewritten (the code before
    and after); exactly one of all the pairs must match, exactly once.
    """

    name: str
    file: str
    find: str | None
    replace: str
    why: str
    first: tuple[str, ...] = ()
    variants: tuple[tuple[str, str], ...] = ()


@dataclass
class Result:
    """Outcome of one mutant: killed or not, wall time, the test ids that failed."""

    name: str
    killed: bool
    seconds: float
    killed_by: list[str] = field(default_factory=list)
    phase: str = ""  # "first", "rest" (the test ids were in that run) or "timeout"
    returncode: int = 0
    tests_run: str = ""  # pytest's last summary line(s)


def load_mutants(path: Path = SPEC) -> list[Mutant]:
    """The mutation list from ``path`` (BenchError on a malformed entry or duplicate name)."""
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise BenchError(f"{path}: {' '.join(str(exc).split())}") from exc
    if not isinstance(data, dict) or not isinstance(data.get("mutants"), list):
        raise BenchError(f"{path}: expected a mapping with a 'mutants' list")
    out: list[Mutant] = []
    for i, m in enumerate(data.get("mutants", [])):
        pairs = [(v["find"], v["replace"]) for v in m.get("variants", [])]
        if "find" in m or "replace" in m or not pairs:
            pairs.insert(0, (m.get("find"), m.get("replace")))
        missing = [k for k in ("name", "file", "why") if k not in m]
        if missing or any(not isinstance(f, str) or not isinstance(r, str) for f, r in pairs):
            raise BenchError(f"{path.name}: entry {i} ({m.get('name')}) lacks "
                             f"{', '.join(missing) or 'a find/replace string'}")  # fmt: skip
        out.append(Mutant(m["name"], m["file"], pairs[0][0], pairs[0][1], m["why"],
                          tuple(m.get("first", ())), tuple(pairs[1:])))  # fmt: skip
    names = [m.name for m in out]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise BenchError(f"{path.name}: duplicate mutant names {dup}")
    return out


def mutated_text(m: Mutant, text: str) -> str:
    """``text`` with the mutation applied (BenchError unless ``find`` occurs exactly once)."""
    if m.find is None:
        return m.replace + text
    pairs = [(m.find, m.replace), *m.variants]
    counts = [text.count(f) for f, _ in pairs]
    if sorted(counts)[-1] != 1 or sum(counts) != 1:
        shown = m.find if len(pairs) == 1 else f"any of {len(pairs)} variants, first {m.find!r}"
        raise BenchError(f"mutant {m.name}: snippet found {sum(counts)} times in {m.file} "
                         f"(must be exactly once): {shown!r}")  # fmt: skip
    find, replace = pairs[counts.index(1)]
    out = text.replace(find, replace)
    if out == text:
        raise BenchError(f"mutant {m.name}: the replacement equals the snippet")
    return out


def check_all(mutants: list[Mutant], root: Path = ROOT) -> None:
    """Every snippet occurs exactly once and every ``first`` file exists (BenchError if not)."""
    for m in mutants:
        mutated_text(m, (root / m.file).read_text())
        for f in m.first:
            if not (root / f).is_file():
                raise BenchError(f"mutant {m.name}: first test file {f} does not exist")


def repo_files(root: Path) -> list[str]:
    """The repository's files (relative paths): what git tracks plus untracked files it does
    not ignore, so a new test or a file being written is copied and the virtualenv, caches and
    build output are not. A tree that is not a git work tree (a snapshot) is taken whole, less
    ``SKIP_DIRS``."""
    if (root / ".git").exists():
        cmd = ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"]
        out = subprocess.run(cmd, cwd=root, capture_output=True, check=True).stdout
        return [f for f in out.decode().split("\0") if f and (root / f).is_file()]
    return [str(p.relative_to(root)) for p in root.rglob("*")
            if p.is_file() and not _skipped(p.relative_to(root).parts)]


def _skipped(parts: tuple[str, ...]) -> bool:
    """A path inside a folder a snapshot copy leaves out."""
    return any(d in SKIP_DIRS or d.endswith(".egg-info") for d in parts[:-1])


def make_copy(root: Path = ROOT) -> Path:
    """A fresh copy of the repository at ``root`` (or a snapshot of it, see ``repo_files``):
    ``<tmp>/main``, with ``<tmp>/shared`` linked to the real ``../shared`` (when it exists).
    The compiled caches of ``src`` are copied too (the numba kernels' caches then load; Python
    recompiles a changed file by its time stamp)."""
    base = Path(tempfile.mkdtemp(prefix="svains-mut-"))
    dst = base / "main"
    for rel in repo_files(root):
        (dst / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(root / rel, dst / rel)
    for cache in (root / "src").rglob("__pycache__"):
        target = dst / cache.relative_to(root)
        if target.parent.is_dir():
            shutil.copytree(cache, target, dirs_exist_ok=True)
    shared = next((p for p in (root.parent / "shared", ROOT.parent / "shared") if p.is_dir()),
                  None)  # fmt: skip
    if shared is not None:
        (base / "shared").symlink_to(shared)
    return dst


def apply_mutation(m: Mutant, copy_root: Path) -> None:
    """Write the mutated file into the copy."""
    path = copy_root / m.file
    path.write_text(mutated_text(m, path.read_text()))


def pytest_command(workers: int, paths: list[str], ignore: list[str],
                   deselect: tuple[str, ...] = ()) -> list[str]:  # fmt: skip
    """The pytest command line of one phase (``paths`` to run, ``ignore`` more files,
    ``deselect`` test ids known to fail without any mutation)."""
    cmd = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *GOLDEN_ARGS]
    cmd += ["-p", "no:xdist"] if workers <= 1 else ["-n", str(workers)]
    cmd += [f"--ignore={p}" for p in ignore] + [f"--deselect={d}" for d in deselect]
    return cmd + paths


def failed_ids(output: str) -> list[str]:
    """Test ids (or files, for collection errors) pytest's short summary lists as failed."""
    ids = []
    for line in output.splitlines():
        hit = _RESULT_LINE.match(line.strip())
        if hit and hit.group(2) not in ids:
            ids.append(hit.group(2))
    return ids


def _summary(output: str) -> str:
    lines = [ln.strip() for ln in output.strip().splitlines() if ln.strip()]
    return lines[-1] if lines else ""


def run_phase(copy_root: Path, workers: int, paths: list[str], ignore: list[str],
              timeout_s: float, deselect: tuple[str, ...] = ()) -> tuple[int, str]:  # fmt: skip
    """Run pytest in the copy with its ``src`` first on the path: (return code, output);
    return code -1 on a timeout."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(
        [str(copy_root / "src"), *filter(None, [env.get("PYTHONPATH")])]
    )
    env.pop("PYTEST_ADDOPTS", None)
    env.setdefault("PYTHONHASHSEED", "0")
    try:
        proc = subprocess.run(pytest_command(workers, paths, ignore, deselect), cwd=copy_root,
                              env=env,
                              capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired as exc:
        out = exc.stdout if isinstance(exc.stdout, str) else ""
        return -1, out
    return proc.returncode, proc.stdout + proc.stderr


def _outcome(rc: int, output: str, phase: str) -> tuple[bool, list[str]] | None:
    """(killed, test ids) of a phase; None when every selected test passed (or none ran)."""
    if rc == -1:
        return True, ["(timeout)"]
    if rc in (0, 5):  # passed, or nothing collected (a first-phase file list that is empty)
        return None
    if rc in (1, 2, 3):
        ids = failed_ids(output)
        return True, ids or [f"(pytest exit {rc}: {_summary(output)})"]
    raise BenchError(f"pytest usage error (exit {rc}) in the {phase} phase: {_summary(output)}")


def run_mutant(m: Mutant | None, workers: int = 1, keep: bool = False,
               timeout_s: float = TIMEOUT_S, root: Path = ROOT,
               deselect: tuple[str, ...] = ()) -> Result:  # fmt: skip
    """Apply ``m`` (None: the unmutated baseline) to a fresh copy of ``root`` and run the tests
    there."""
    t0 = time.perf_counter()
    name = "baseline" if m is None else m.name
    copy_root = make_copy(root)
    try:
        if m is not None:
            apply_mutation(m, copy_root)
        first = list(m.first) if m is not None else []
        phases: list[tuple[str, list[str], list[str]]] = []
        if first:
            phases.append(("first", first, []))
        phases.append(("rest", [], first))
        summaries = []
        for phase, paths, ignore in phases:
            rc, out = run_phase(copy_root, workers, paths, ignore, timeout_s, deselect)
            summaries.append(_summary(out))
            got = _outcome(rc, out, phase)
            if got is not None:
                return Result(name, got[0], time.perf_counter() - t0, got[1],
                              "timeout" if rc == -1 else phase, rc, " | ".join(summaries))
        return Result(name, False, time.perf_counter() - t0, [], "", 0, " | ".join(summaries))
    finally:
        if keep:
            print(f"  (copy kept: {copy_root})", flush=True)
        else:
            shutil.rmtree(copy_root.parent, ignore_errors=True)


def print_table(results: list[Result]) -> None:
    """Summary table and kill rate."""
    w = max([len(r.name) for r in results] + [6])
    print(f"\n{'mutant':<{w}}  {'result':<8}  {'seconds':>7}  killed by")
    for r in results:
        state = "killed" if r.killed else "SURVIVED"
        by = ", ".join(r.killed_by[:3]) + (" ..." if len(r.killed_by) > 3 else "")
        print(f"{r.name:<{w}}  {state:<8}  {r.seconds:7.1f}  {by}")
    n = len(results)
    k = sum(r.killed for r in results)
    print(f"\nkilled {k} of {n} mutants: kill rate {100.0 * k / max(n, 1):.1f} %"
          f", {sum(r.seconds for r in results):.0f} s in all")  # fmt: skip
    survivors = [r.name for r in results if not r.killed]
    if survivors:
        print("survivors: " + ", ".join(survivors))


def main(argv: list[str] | None = None) -> int:
    """Command line (see the module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", action="append", default=[], metavar="NAME",
                    help="run this mutant only (repeatable, or comma-separated)")
    ap.add_argument("--list", action="store_true", help="list the mutants and exit")
    ap.add_argument("--check", action="store_true",
                    help="check every snippet occurs exactly once, run nothing")
    ap.add_argument("--workers", type=int, default=1, help="pytest-xdist workers (1: no xdist)")
    ap.add_argument("--json", type=Path, default=None, metavar="PATH", help="write the results")
    ap.add_argument("--baseline", action="store_true",
                    help="first run the unmutated copy (it must pass the non-golden suite)")
    ap.add_argument("--canary", action="store_true",
                    help="run the import-error canary (must be killed: the copy is imported)")
    ap.add_argument("--keep", action="store_true", help="keep the temporary copies")
    ap.add_argument("--timeout", type=float, default=TIMEOUT_S, help="s per pytest run")
    ap.add_argument("--spec", type=Path, default=SPEC, help="the mutation list (YAML)")
    ap.add_argument("--deselect", action="append", default=[], metavar="NODEID",
                    help="a test that fails without any mutation (repeatable; say why)")
    ap.add_argument("--root", type=Path, default=ROOT,
                    help="copy src/tests from this tree (e.g. a snapshot; default: this repo)")
    args = ap.parse_args(argv)
    try:
        mutants = load_mutants(args.spec)
        root = args.root.resolve()
        desel = tuple(args.deselect)
        check_all(mutants, root)
        if args.list:
            for m in mutants:
                print(f"{m.name:<40} {m.file}\n    {' '.join(m.why.split())}")
            print(f"{len(mutants)} mutants")
            return 0
        if args.check:
            print(f"{len(mutants)} mutants: every snippet found exactly once")
            return 0
        only = [n for o in args.only for n in o.split(",") if n]
        if only:
            known = {m.name: m for m in mutants}
            unknown = [n for n in only if n not in known]
            if unknown:
                raise BenchError(f"unknown mutant(s): {', '.join(unknown)} (see --list)")
            mutants = [known[n] for n in only]
        t_start = time.perf_counter()
        extra: list[Result] = []
        if args.baseline:
            print("baseline (no mutation) ...", flush=True)
            b = run_mutant(None, args.workers, args.keep, args.timeout, root, desel)
            print(f"  baseline: {'FAILED' if b.killed else 'passed'} in {b.seconds:.1f} s "
                  f"({b.tests_run})", flush=True)  # fmt: skip
            if b.killed:
                raise BenchError(f"the unmutated copy fails: {', '.join(b.killed_by)}")
            extra.append(b)
        if args.canary:
            c = run_mutant(Mutant(**{**CANARY, "first": tuple(CANARY["first"])}), args.workers,
                           args.keep, args.timeout, root, desel)  # fmt: skip
            print(f"  canary: {'killed' if c.killed else 'SURVIVED'} in {c.seconds:.1f} s "
                  f"by {', '.join(c.killed_by)}", flush=True)  # fmt: skip
            if not c.killed:
                raise BenchError("the import-error canary survived: the copy is not imported")
            extra.append(c)
        results = []
        for i, m in enumerate(mutants, 1):
            print(f"[{i}/{len(mutants)}] {m.name} ({m.file}) ...", flush=True)
            r = run_mutant(m, args.workers, args.keep, args.timeout, root, desel)
            state = "killed" if r.killed else "SURVIVED"
            by = f" by {', '.join(r.killed_by)} ({r.phase})" if r.killed else ""
            print(f"  {state} in {r.seconds:.1f} s{by}; pytest: {r.tests_run}", flush=True)
            results.append(r)
        if results:
            print_table(results)
        wall = time.perf_counter() - t_start
        print(f"wall time {wall:.0f} s, workers {args.workers}")
        if args.json is not None:
            args.json.parent.mkdir(parents=True, exist_ok=True)
            args.json.write_text(json.dumps({
                "mutants": len(results), "killed": sum(r.killed for r in results),
                "wall_s": wall, "workers": args.workers, "root": str(root),
                "deselected": list(desel),
                "results": [asdict(r) for r in results], "checks": [asdict(r) for r in extra],
            }, indent=2) + "\n")  # fmt: skip
    except BenchError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
