"""Atomic outputs: a file or folder appears whole under its final name, or not at all.

Everything is written under a temporary name (``.svains-tmp-*``) in the destination's own folder,
then renamed with ``os.replace``, which is atomic within one file system. An interrupted writer
leaves only a ``.svains-tmp-*`` entry that no reader takes for the real output. Standard library
only (and ``errors``), so every layer may use it.

A failure to write (a full disk, a read-only place) is raised as :class:`OutputError` naming the
final path, never the temporary one.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import shutil
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

from svains.errors import OutputError

TMP_PREFIX = ".svains-tmp-"


@contextlib.contextmanager
def atomic_path(path: Path | str) -> Iterator[Path]:
    """Yield a temporary file path beside ``path``; on success rename it to ``path``.

    On an exception (Ctrl-C included) the temporary file is removed and ``path`` is untouched.
    """
    final = Path(path)
    tmp = temporary_name(final.parent, f"{TMP_PREFIX}{final.name}-")
    try:
        # created inside the ``try``: a signal between creating and cleaning up is handled
        os.close(os.open(tmp, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600))
        yield tmp
        os.chmod(tmp, 0o644)  # mkstemp creates 0600; outputs are ordinary files
        os.replace(tmp, final)
    except OSError as exc:
        raise _output_error(final, exc) from exc
    finally:
        tmp.unlink(missing_ok=True)


def _output_error(final: Path, exc: OSError, stage: Path | None = None) -> OutputError:
    """One line naming the output (``final``), never the temporary name the OS saw."""
    where = final
    if stage is not None and exc.filename:
        with contextlib.suppress(ValueError):  # inside the staging folder: its final place
            where = final / Path(str(exc.filename)).relative_to(stage)
    reason = exc.strerror or str(exc)
    code = f" [Errno {exc.errno}]" if exc.errno else ""
    return OutputError(f"cannot write {where}: {reason}{code}")


def atomic_write_text(path: Path | str, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically (temporary file, then rename). Undecodable bytes
    that Python kept of a file name as surrogates (a non-ASCII path under a non-UTF-8 locale)
    are written back as those bytes."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding=encoding, errors="surrogateescape")
    return Path(path)


@contextlib.contextmanager
def staging_dir(parent: Path | str) -> Iterator[Path]:
    """Yield a new empty folder ``parent/.svains-tmp-*``, removed with its content on exit.

    Build an output inside it, then move the finished part to its final name with
    :func:`replace_dir` before leaving the block.
    """
    base = Path(parent)
    base.mkdir(parents=True, exist_ok=True)
    stage = temporary_name(base, TMP_PREFIX)
    try:
        # Named before it exists and made inside the ``try``: a SIGTERM or Ctrl-C landing just
        # after the folder appeared left it behind (mkdtemp returned it to no one).
        os.mkdir(stage, 0o700)
        os.chmod(stage, 0o755)  # an output folder is an ordinary folder, whatever the umask
        yield stage
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def temporary_name(parent: Path, prefix: str) -> Path:
    """A fresh ``parent/prefix<16 hex digits>`` that does not exist yet (a clash of 64 random
    bits with an existing entry makes the creation fail with ``FileExistsError``)."""
    return parent / f"{prefix}{secrets.token_hex(8)}"


def holds_working_dir(path: Path | str) -> bool:
    """Whether ``path`` is the current working folder or one of its ancestors (such a folder
    cannot be swapped for a new one under the running process)."""
    p = Path(path).resolve()
    cwd = Path.cwd().resolve()
    return p == cwd or p in cwd.parents


@contextlib.contextmanager
def replaced_dir(
    dst: Path | str, owned: Callable[[str], bool] | None = None
) -> Iterator[Path]:
    """Yield an empty staging folder beside ``dst``; build the new content in it.

    On a normal exit the staging folder replaces ``dst`` whole (:func:`replace_dir`: the old
    output is gone, never mixed with the new files); the entries of the old ``dst`` that
    ``owned(name)`` says are not the output's (a user's notes) are carried over. On an exception
    (Ctrl-C, a full disk) ``dst`` is untouched and the staging folder removed. ``OSError`` is
    raised as :class:`OutputError` naming the path under ``dst``.
    """
    final = Path(dst)
    if final.is_symlink():
        # the link is the user's (an output on another disk): replace the folder it points to,
        # beside which the staging folder is made, and keep the link (it was swapped for a
        # real folder before, the link itself left hidden in a .svains-tmp-old-* sibling)
        final = final.resolve()
    if holds_working_dir(final):
        raise OutputError(f"cannot replace {final}: it is the current folder or holds it")
    if final.exists() and not final.is_dir():
        raise OutputError(f"cannot write {final}: it exists and is not a folder")
    stage: Path | None = None
    try:
        with staging_dir(final.parent) as stage:
            yield stage
            replace_dir(stage, final, owned)
    except OSError as exc:
        raise _output_error(final, exc, stage) from exc
    except OutputError as exc:
        if stage is None or str(stage) not in str(exc):
            raise
        # A file writer inside (atomic_path) named its staging path: name the final one.
        raise OutputError(str(exc).replace(str(stage), str(final))) from exc


def replace_dir(src: Path, dst: Path, owned: Callable[[str], bool] | None = None) -> None:
    """Move the finished folder ``src`` to ``dst``, replacing any folder already there.

    Two renames: the old ``dst`` is first moved aside (then deleted), so at no instant does
    ``dst`` hold a mix of old and new files; ``src`` and ``dst`` must share a file system. With
    ``owned``, the old entries it says are not the output's (and that ``src`` does not hold) are
    moved into the new ``dst`` before the old one is deleted (interrupted there, they are in the
    ``.svains-tmp-old-*`` sibling, not lost).
    """
    old: Path | None = None
    if dst.exists():
        old = Path(tempfile.mkdtemp(prefix=f"{TMP_PREFIX}old-", dir=dst.parent))
        old.rmdir()
        os.replace(dst, old)
    os.replace(src, dst)
    if old is None:
        return
    if owned is not None:
        for entry in old.iterdir():
            if not owned(entry.name) and not (dst / entry.name).exists():
                os.replace(entry, dst / entry.name)
    shutil.rmtree(old, ignore_errors=True)
