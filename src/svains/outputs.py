"""Atomic outputs: a file or folder appears whole under its final name, or not at all.

Everything is written under a temporary name (``.svains-tmp-*``) in the destination's own folder,
then renamed with ``os.replace``, which is atomic within one file system. An interrupted writer
leaves only a ``.svains-tmp-*`` entry that no reader takes for the real output. Standard library
only, so every layer may use it (like ``errors``).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

TMP_PREFIX = ".svains-tmp-"


@contextlib.contextmanager
def atomic_path(path: Path | str) -> Iterator[Path]:
    """Yield a temporary file path beside ``path``; on success rename it to ``path``.

    On an exception (Ctrl-C included) the temporary file is removed and ``path`` is untouched.
    """
    final = Path(path)
    fd, tmp_name = tempfile.mkstemp(prefix=f"{TMP_PREFIX}{final.name}-", dir=final.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        os.chmod(tmp, 0o644)  # mkstemp creates 0600; outputs are ordinary files
        os.replace(tmp, final)
    finally:
        tmp.unlink(missing_ok=True)


def atomic_write_text(path: Path | str, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically (temporary file, then rename)."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding=encoding)
    return Path(path)


@contextlib.contextmanager
def staging_dir(parent: Path | str) -> Iterator[Path]:
    """Yield a new empty folder ``parent/.svains-tmp-*``, removed with its content on exit.

    Build an output inside it, then move the finished part to its final name with
    :func:`replace_dir` before leaving the block.
    """
    base = Path(parent)
    base.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=TMP_PREFIX, dir=base))
    try:
        yield stage
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def replace_dir(src: Path, dst: Path) -> None:
    """Move the finished folder ``src`` to ``dst``, replacing any folder already there.

    Two renames: the old ``dst`` is first moved aside (then deleted), so at no instant does
    ``dst`` hold a mix of old and new files; ``src`` and ``dst`` must share a file system.
    """
    old: Path | None = None
    if dst.exists():
        old = Path(tempfile.mkdtemp(prefix=f"{TMP_PREFIX}old-", dir=dst.parent))
        old.rmdir()
        os.replace(dst, old)
    os.replace(src, dst)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
