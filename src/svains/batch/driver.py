"""Run a campaign: its unfinished tasks on Dask (or in this process), then :func:`aggregate`.

Without a scheduler address a local cluster is started: one worker process per core, one thread
each, listening on the loopback interface only, no dashboard. With ``scheduler``
(``tcp://HOST:8786``, or ``tls://...`` with Dask's TLS settings from its configuration) the same
tasks go to that cluster; its workers need this version of svains installed and, for real data
sets, the data at the same path. Each result is written by this process as soon as it arrives,
so an interrupted campaign resumes where it stopped.
"""

from __future__ import annotations

import fcntl
import logging
import os
import signal
import subprocess
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from svains.batch.aggregate import CampaignSummary, aggregate
from svains.batch.spec import CampaignSpec, Task
from svains.batch.store import is_finished, write_atomic, write_result
from svains.batch.task import TaskResult, run_group
from svains.errors import ConfigError

if TYPE_CHECKING:
    from dask.distributed import Client

log = logging.getLogger(__name__)

# One BLAS/OpenMP thread per worker process: the workers already fill the cores.
WORKER_ENV: dict[str, str] = {
    "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
    "NUMBA_NUM_THREADS": "1",
}  # fmt: skip


@dataclass(frozen=True)
class CampaignProgress:
    """After each finished run: runs ``done`` (this session) of ``todo``, ``failed`` among
    them, ``skipped`` (finished before), and the ``last`` result."""

    done: int
    todo: int
    failed: int
    skipped: int
    last: TaskResult


ProgressFn = Callable[[CampaignProgress], None]


@contextmanager
def dask_client(scheduler: str | None = None, n_workers: int | None = None,
                timeout_s: float = 30.0) -> Iterator[Client]:  # fmt: skip
    """A client of the cluster at ``scheduler``, or of a new local cluster on 127.0.0.1 with
    ``n_workers`` processes (default: one per core) of one thread each; closed on exit."""
    main = threading.current_thread() is threading.main_thread()
    # A Ctrl-C while Dask is imported can land in a weakref callback, where Python reports the
    # KeyboardInterrupt as ignored and goes on: the campaign then ran to its end (Python 3.13,
    # a test's interrupt 0.3 s after the lock). Until the cluster is up the handler also
    # records it, and the record is checked.
    pressed = threading.Event()

    def _record(signum: int, frame: object) -> None:
        pressed.set()
        raise KeyboardInterrupt

    original = signal.signal(signal.SIGINT, _record) if main else None
    try:
        from dask.distributed import Client, LocalCluster
    except BaseException:
        _restore_sigint(main, original)
        raise
    if not logging.getLogger().isEnabledFor(logging.INFO):
        # distributed installs its own INFO handler on import; a local scheduler would log every
        # connection. Follow the application's level instead.
        logging.getLogger("distributed").setLevel(logging.WARNING)
    if scheduler:
        _restore_sigint(main, original)
        if pressed.is_set():
            raise KeyboardInterrupt
        try:
            client = Client(scheduler, timeout=timeout_s)
        except (OSError, TimeoutError, ValueError) as exc:
            raise ConfigError(f"cannot reach the Dask scheduler at {scheduler!r}: {exc}") from exc
        with client:
            yield client
        return
    # Ctrl-C reaches every process of the terminal's group: workers that took it too would stop
    # on their own, racing the cluster's shutdown (Dask's tracebacks and warnings). SIGINT is
    # ignored while the cluster starts, so its worker processes inherit "ignored" and keep it;
    # a Ctrl-C meanwhile is seen by a sentinel (`sleep`, killed by it) and raised once the
    # cluster is up, inside the block that closes it.
    sentinel = None
    try:
        sentinel = _ctrl_c_sentinel() if main else None
        if main:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        cluster = LocalCluster(
            n_workers=n_workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
            host="127.0.0.1", dashboard_address=None, env=WORKER_ENV,
            # The workers' own logs: only the fatal. What fails in a run is in its result, and
            # a worker stopped mid-run by Ctrl-C would log its lost scheduler.
            silence_logs=logging.CRITICAL,
            # No dashboard; the scheduler's remaining HTTP routes (health, metrics) on a free
            # loopback port instead of the fixed 8787.
            scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
        )  # fmt: skip
    finally:
        _restore_sigint(main, original)
        interrupted = _end_sentinel(sentinel) or pressed.is_set()
    logging.getLogger("distributed").setLevel(logging.WARNING)  # this process: lost workers
    with cluster:
        try:
            if interrupted:
                raise KeyboardInterrupt
            with Client(cluster, timeout=timeout_s) as client:
                yield client
        except BaseException as exc:
            if not isinstance(exc, Exception):  # Ctrl-C, SIGTERM: the user stopped the campaign
                # and the workers killed mid-run are expected, not worth Dask's warnings.
                logging.getLogger("distributed").setLevel(logging.CRITICAL)
            raise


def _restore_sigint(main: bool, original: Any) -> None:
    """Give SIGINT back its handler from before ``dask_client`` (Python's default when it
    had none from Python)."""
    if main:
        signal.signal(signal.SIGINT, original if original is not None
                      else signal.default_int_handler)  # fmt: skip


def _ctrl_c_sentinel() -> subprocess.Popen[bytes] | None:
    """A ``sleep`` in this process group with SIGINT at its default: it ends when a Ctrl-C
    reaches the group (None where no ``sleep`` runs)."""
    try:
        return subprocess.Popen(["sleep", "3600"], stdin=subprocess.DEVNULL,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    except OSError:
        return None


def _end_sentinel(sentinel: subprocess.Popen[bytes] | None) -> bool:
    """Stop ``sentinel``; True when a Ctrl-C had ended it."""
    if sentinel is None:
        return False
    interrupted = sentinel.poll() == -signal.SIGINT
    sentinel.kill()
    sentinel.wait()
    return interrupted


LOCK_NAME = ".svains-batch.lock"


@contextmanager
def campaign_lock(out_dir: Path) -> Iterator[None]:
    """Hold ``out_dir``'s campaign lock (an advisory ``flock`` on ``LOCK_NAME``, released by the
    kernel however the process ends): a second campaign on the same folder would redo the runs
    this one has not written yet. Raises ``ConfigError`` naming the holder's pid when taken."""
    path = out_dir / LOCK_NAME
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
            raise ConfigError(f"{out_dir} is in use by another campaign (pid {holder}); wait "
                              "for it to end, or choose another --out") from None  # fmt: skip
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield
    finally:
        os.close(fd)


def _lost(group: Sequence[Task], exc: BaseException) -> list[TaskResult]:
    # Tasks never raise: this is a lost worker or a cancelled future.
    return [TaskResult(t.task_id, "failed", error=f"{type(exc).__name__}: {exc}") for t in group]


def data_groups(tasks: Sequence[Task]) -> list[list[Task]]:
    """``tasks`` grouped by :meth:`Task.data_key`, in order of first appearance: one Dask task
    per group, so a simulated flight is made once for all the methods and configs run on it."""
    groups: dict[str, list[Task]] = {}
    for task in tasks:
        groups.setdefault(task.data_key(), []).append(task)
    return list(groups.values())


def execute(
    tasks: Sequence[Task], out_dir: Path, client: Client | None,
    on_result: Callable[[TaskResult], None],
) -> None:  # fmt: skip
    """Run ``tasks`` on ``client`` (in this process, in order, when None), writing each result
    into ``out_dir`` as it arrives, then calling ``on_result``."""
    groups = data_groups(tasks)

    def finish(group: Sequence[Task], results: Sequence[TaskResult]) -> None:
        for task, result in zip(group, results, strict=True):
            write_result(out_dir, task, result)
            on_result(result)

    if client is None:
        for group in groups:
            finish(group, run_group(group))
        return
    from dask.distributed import as_completed

    keys = [f"svains-batch-{g[0].task_id}" for g in groups]
    futures = client.map(run_group, groups, key=keys, pure=False)
    by_key = dict(zip(keys, groups, strict=True))
    for future in as_completed(futures):
        group = by_key[future.key]
        try:
            results = future.result()
        except Exception as exc:  # a worker died or the scheduler went away
            results = _lost(group, exc)
        future.release()
        finish(group, results)


def run_campaign(
    spec: CampaignSpec,
    out_dir: Path,
    *,
    scheduler: str | None = None,
    n_workers: int | None = None,
    sequential: bool = False,
    client: Client | None = None,
    progress: ProgressFn | None = None,
    figures: bool = True,
) -> CampaignSummary:
    """Run the spec's unfinished runs into ``out_dir`` on ``client``, or on a cluster reached or
    started by :func:`dask_client` (``scheduler``, ``n_workers``), or in this process when
    ``sequential``; then aggregate every finished run into its tables and figures."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    with campaign_lock(out_dir):
        return _run_locked(spec, out_dir, scheduler, n_workers, sequential, client, progress,
                           figures)  # fmt: skip


def _run_locked(
    spec: CampaignSpec, out_dir: Path, scheduler: str | None, n_workers: int | None,
    sequential: bool, client: Client | None, progress: ProgressFn | None, figures: bool,
) -> CampaignSummary:  # fmt: skip
    write_atomic(out_dir / "spec.yaml", yaml.safe_dump(spec.raw, sort_keys=False))
    tasks = spec.tasks()
    todo = [t for t in tasks if not is_finished(out_dir, t)]
    log.info("campaign %s: %d runs, %d finished before, %d to run", spec.name, len(tasks),
             len(tasks) - len(todo), len(todo))  # fmt: skip
    count = {"done": 0, "failed": 0}

    def on_result(result: TaskResult) -> None:
        count["done"] += 1
        count["failed"] += result.status != "ok"
        log.info("run %d/%d %s: %s", count["done"], len(todo), result.task_id,
                 result.status if result.error is None else result.error)  # fmt: skip
        if progress is not None:
            progress(CampaignProgress(count["done"], len(todo), count["failed"],
                                      len(tasks) - len(todo), result))  # fmt: skip

    if todo and (sequential or client is not None):
        execute(todo, out_dir, client, on_result)
    elif todo:
        with dask_client(scheduler, n_workers) as client:
            execute(todo, out_dir, client, on_result)
    return aggregate(spec, out_dir, figures)
