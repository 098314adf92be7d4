"""Threads of the numerical libraries (BLAS, OpenMP, OpenCV): one per library by default.

Why: the filter's matrices are small (25-37 sigma points, a few hundred measurements) and the
front end works on one 752x480 pair at a time. OpenBLAS's threads cost more in wake-ups than
they save on such sizes, and on a loaded machine they oversubscribe the cores (issue 11: a 20 s
`3d` run from images, 2.5x real time with one BLAS thread, 1.8x with the default two). Measured
on a loaded 2-core machine, three interleaved pairs: one thread per library took 10-13 % less
wall time than the libraries' defaults, the filter side 23-24 % less. One process per core
scales better than threads inside one process.

``SVAINS_THREADS`` (environment) or ``svains --threads N`` changes the limit: a positive N
allows N threads per library; 0 leaves every library at its own default. The command line
applies it for the whole command; ``svains.replay.replay`` enters ``limit_threads(None)`` once
around its loop, and other library users enter ``limit_threads()`` once around a run (entering
and leaving costs about 0.6 ms: not per frame). Inside a block ``SVAINS_THREADS`` holds the
block's limit, so a nested ``limit_threads(None)`` (the replay under ``svains --threads N``)
keeps the outer one.
"""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager

from svains.errors import ConfigError

log = logging.getLogger(__name__)

ENV_VAR = "SVAINS_THREADS"
DEFAULT_THREADS = 1
# Read by OpenBLAS, MKL, BLIS, OpenMP and OpenCV when they are loaded: covers the libraries
# imported after the limit is set (threadpoolctl only sees those already loaded).
_LIBRARY_ENV = (
    "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS", "OMP_NUM_THREADS",
    "OPENCV_FOR_THREADS_NUM",
)  # fmt: skip


def threads_from_env(default: int = DEFAULT_THREADS) -> int:
    """The limit from ``SVAINS_THREADS`` (an integer >= 0), ``default`` when unset or empty."""
    raw = os.environ.get(ENV_VAR, "").strip()
    if not raw:
        return default
    try:
        n = int(raw)
    except ValueError:
        raise ConfigError(f"{ENV_VAR} must be an integer >= 0, got {raw!r}") from None
    if n < 0:
        raise ConfigError(f"{ENV_VAR} must be an integer >= 0, got {raw!r}")
    return n


@contextmanager
def limit_threads(n: int | None = DEFAULT_THREADS) -> Iterator[None]:
    """Allow at most ``n`` threads per numerical library inside the block; restored on exit.

    ``None`` takes the limit from ``SVAINS_THREADS`` (default 1); 0 changes nothing. Libraries
    already loaded are limited through threadpoolctl (BLAS, OpenMP) and ``cv2.setNumThreads``;
    the ones loaded inside the block read the limit from their environment variables when they
    load, and keep it after the block.
    """
    n = threads_from_env() if n is None else int(n)
    if n < 0:
        raise ConfigError(f"thread limit must be >= 0, got {n}")
    cores = os.cpu_count() or 1
    if n > cores:
        # more threads than cores only contend: 64 per library on 2 cores ran a 3.5 s job in
        # 71 s and loaded a shared machine to 690 (a user's probe)
        log.warning("%d threads per numerical library on %d cores would contend: %d used", n,
                    cores, cores)  # fmt: skip
        n = cores
    saved_env = {k: os.environ.get(k) for k in (ENV_VAR, *_LIBRARY_ENV)}
    os.environ[ENV_VAR] = str(n)
    if n == 0:
        try:
            yield
        finally:
            _restore_env(saved_env)
        return
    from threadpoolctl import threadpool_limits

    os.environ.update({k: str(n) for k in _LIBRARY_ENV})
    # Only touch OpenCV if something already imported it (the front end): importing it here
    # would cost every command its load time, and the layering keeps cv2 in frontend/.
    cv2 = sys.modules.get("cv2")
    cv2_saved = cv2.getNumThreads() if cv2 is not None else None
    if cv2 is not None:
        cv2.setNumThreads(n)
    try:
        with threadpool_limits(limits=n):
            log.debug("numerical libraries limited to %d thread(s)", n)
            yield
    finally:
        if cv2 is not None and cv2_saved is not None:
            cv2.setNumThreads(cv2_saved)
        _restore_env(saved_env)


def _restore_env(saved: dict[str, str | None]) -> None:
    for k, v in saved.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v
