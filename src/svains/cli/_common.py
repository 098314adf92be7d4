"""What every command shares: one-line errors on stderr, the exit codes, ``--out`` checks.

Exit codes (the same for every command):

- ``0`` success;
- ``1`` bad data or input: a data set, calibration, configuration or trajectory file that cannot
  be used, an output that cannot be written, a run that failed;
- ``2`` usage: the command line itself cannot be carried out, found before any input is read
  (unknown option, invalid option value, an ``--out`` that is a file, is not writable, or is not
  empty without ``--force``).

Errors are written as one ``error: ...`` line on stderr, as plain text: never wrapped, never
parsed as rich markup (so ``[fu, fv, cu, cv]`` survives). An unexpected exception (a bug) is
reported on one line too, with exit code 1; ``svains --verbose`` shows its traceback.
"""

from __future__ import annotations

import codecs
import contextlib
import io
import logging
import math
import os
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Annotated, Any, NoReturn

import typer
from typer.core import TyperGroup

from svains.errors import ConfigError, SvainsError
from svains.outputs import TMP_PREFIX, holds_working_dir, temporary_name

EXIT_OK = 0
EXIT_BAD_INPUT = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130  # the shell's code for SIGINT


def one_line(text: str) -> str:
    """``text`` with its lines joined by single spaces (YAML and OS errors span lines)."""
    return " ".join(part.strip() for part in str(text).splitlines() if part.strip())


def print_error(message: str) -> None:
    """``error: message`` as one plain line on stderr (no markup, no wrapping)."""
    sys.stderr.write(f"error: {one_line(message)}\n")
    sys.stderr.flush()


def fail(exc: BaseException | str, code: int = EXIT_BAD_INPUT) -> NoReturn:
    """Print ``exc`` as a one-line error and exit with ``code`` (default 1, bad input)."""
    print_error(str(exc))
    raise typer.Exit(code)


def usage_error(message: str, option: str | None = None) -> NoReturn:
    """Stop with a usage error (exit 2) naming ``option`` when given."""
    raise typer.BadParameter(message, param_hint=f"'{option}'" if option else None)


# --- option values ---------------------------------------------------------------------------


def one_of(*names: str) -> Callable[[str | None], str | None]:
    """Typer callback: ``None`` or one of ``names`` (else a usage error, exit 2)."""

    def check(value: str | None) -> str | None:
        if value is not None and value not in names:
            raise typer.BadParameter(f"must be {' or '.join(repr(n) for n in names)}, got "
                                     f"{value!r}")  # fmt: skip
        return value

    return check


def positive_finite(value: float | None) -> float | None:
    """Typer callback: ``None`` or a finite number > 0 (rejects 0, negatives, nan and inf)."""
    if value is not None and not (math.isfinite(value) and value > 0):
        raise typer.BadParameter(f"must be a finite number > 0, got {value}")
    return value


def non_negative_finite(value: float | None) -> float | None:
    """Typer callback: ``None`` or a finite number >= 0 (``--start``: seconds into the data)."""
    if value is not None and not (math.isfinite(value) and value >= 0):
        raise typer.BadParameter(f"must be a finite number >= 0, got {value}")
    return value


def stereo_rate(value: float | None) -> float | None:
    """Typer callback: ``None`` or a simulated stereo rate in (0, 20] Hz (a usage error, exit 2,
    like ``--camera-rate 0``)."""
    from svains.sim.config import MAX_CAMERA_RATE_HZ

    if value is not None and not (math.isfinite(value) and 0 < value <= MAX_CAMERA_RATE_HZ):
        raise typer.BadParameter(f"must be in (0, {MAX_CAMERA_RATE_HZ:g}] Hz, got {value}")
    return value


def rotation_choice(value: str | None) -> str | None:
    """Typer callback: ``None`` or one of the vision motion models (a usage error otherwise,
    like ``--method``)."""
    from svains.navigation.options import MOTION_MODELS

    if value is not None and value not in MOTION_MODELS:
        raise typer.BadParameter(f"must be one of {', '.join(MOTION_MODELS)}, got {value!r}")
    return value


# --- outputs ---------------------------------------------------------------------------------


def _nearest_existing(path: Path) -> Path:
    p = path.absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def probe_writable(out: Path, option: str) -> None:
    """Refuse (usage error) an output folder ``out`` in which nothing can be created (tried in
    its nearest existing ancestor: nothing is created on the way)."""
    _probe_writable(_nearest_existing(out), out, option)


def _probe_writable(folder: Path, out: Path, option: str) -> None:
    """Create and remove a temporary entry in ``folder`` (creating it): the permission bits
    alone do not tell (root, read-only mounts, /proc)."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = temporary_name(folder, TMP_PREFIX)
        try:
            os.mkdir(probe)
        finally:
            with contextlib.suppress(FileNotFoundError):
                os.rmdir(probe)
    except OSError as exc:
        usage_error(f"{out} cannot be written: {exc.strerror or exc} ({folder})", option)


def _refuse_unexpanded_home(out: Path, option: str) -> None:
    """A path starting with a literal ``~`` (``--out=~/x``: the shell expands ``~`` only at the
    start of a word) would create a folder named ``~``; refused with the two spellings that
    work (a folder really named ``~`` is still reachable as ``./~``)."""
    if out.parts and out.parts[0] == "~":
        usage_error(f"{out} starts with a '~' the shell did not expand (it does not after "
                    f"'='); write '{option} ~/…' with a space, or $HOME/…", option)  # fmt: skip


def check_out_dir(
    out: Path, force: bool, option: str = "--out", inputs: Sequence[Path] = (),
    replaced_whole: bool = True,
) -> None:
    """Refuse an output folder before any computation: usage error (exit 2) when ``out`` is a
    file, cannot be created or written, or is not empty without ``force``; and, for an output
    that replaces its folder whole (``replaced_whole``), when it is the working folder (or holds
    it) or holds one of ``inputs``."""
    _refuse_unexpanded_home(out, option)
    if out.exists() and not out.is_dir():
        usage_error(f"{out} exists and is not a folder", option)
    base = _nearest_existing(out)
    if not base.is_dir():
        usage_error(f"{out} cannot be created: {base} is not a folder", option)
    if not os.access(base, os.W_OK | os.X_OK):
        usage_error(f"{out} is not writable ({base})", option)
    if out.is_dir() and any(out.iterdir()) and not force:
        usage_error(f"{out} is not empty; use --force to replace it", option)
    if replaced_whole and holds_working_dir(out):
        usage_error(f"{out} is the current folder or holds it; the output replaces its folder "
                    "whole, so choose a new one", option)  # fmt: skip
    resolved = out.resolve()
    for path in inputs if replaced_whole else ():
        p = Path(path).resolve()
        if p.exists() and (p == resolved or resolved in p.parents):
            usage_error(f"{out} holds the input {path}; the output replaces its folder whole, "
                        "so choose another one", option)  # fmt: skip
    _probe_writable(out.absolute().parent, out, option)


def check_out_file(out: Path | None, force: bool, option: str) -> None:
    """Refuse an output file before any computation: a folder, an unwritable place, or an
    existing file without ``force`` (usage error, exit 2)."""
    if out is None:
        return
    _refuse_unexpanded_home(out, option)
    if out.is_dir():
        usage_error(f"{out} is a folder", option)
    base = _nearest_existing(out.parent)
    if not base.is_dir():
        usage_error(f"{out} cannot be created: {base} is not a folder", option)
    if not os.access(base, os.W_OK | os.X_OK):
        usage_error(f"{out} is not writable ({base})", option)
    if out.exists() and not force:
        usage_error(f"{out} exists; use --force to replace it", option)
    _probe_writable(out.absolute().parent, out, option)


# --- the command group -----------------------------------------------------------------------


class Terminated(BaseException):
    """SIGTERM received: unwinds like Ctrl-C (``finally`` blocks run), past ``except Exception``."""


EXIT_TERMINATED = 143  # 128 + SIGTERM, as a shell reports a process it terminated


def _terminated(signum: int, frame: object) -> None:
    raise Terminated


_STRICT_ERRORS = ("strict", "surrogateescape")
_OUTPUT_ERRORS = "svains-output"


def _output_errors(exc: UnicodeError) -> tuple[str | bytes, int]:
    """Codec error handler of the command line's output: a file name's undecodable bytes (kept
    as surrogates) back as those bytes, any other character the locale cannot encode as "?"."""
    if not isinstance(exc, UnicodeEncodeError):
        raise exc
    part = exc.object[exc.start : exc.end]
    if all(0xDC80 <= ord(c) <= 0xDCFF for c in part):
        return bytes(ord(c) - 0xDC00 for c in part), exc.end
    return "?" * len(part), exc.end


codecs.register_error(_OUTPUT_ERRORS, _output_errors)


class OneLineErrorGroup(TyperGroup):
    """Typer group whose every failure ends as one ``error:`` line and a documented exit code.

    Usage errors (click's own and ``typer.BadParameter``) exit 2; :class:`SvainsError` and
    ``OSError`` exit 1; Ctrl-C exits 130; any other exception is a bug, reported on one line
    with exit 1 (its traceback with ``--verbose``).
    """

    def main(  # type: ignore[override]
        self,
        args: Sequence[str] | None = None,
        prog_name: str | None = None,
        complete_var: str | None = None,
        standalone_mode: bool = True,
        **extra: Any,
    ) -> Any:
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, standalone_mode, **extra)
        for stream in (sys.stdout, sys.stderr):
            # A terminal or pipe in a non-UTF-8 locale (LANG=C without Python's UTF-8 mode)
            # cannot encode the tables' "m/s²" or "σ": shown as "?" rather than a crash.
            if isinstance(stream, io.TextIOWrapper) and stream.errors in _STRICT_ERRORS:
                stream.reconfigure(errors=_OUTPUT_ERRORS)
        if threading.current_thread() is threading.main_thread():
            # SIGTERM (kill, timeouts, docker stop, Slurm) as Ctrl-C: staging folders are
            # removed and outputs kept whole (the default handler left .svains-tmp-* behind)
            signal.signal(signal.SIGTERM, _terminated)
        try:
            rv = super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        except typer.TyperException as exc:  # click's ClickException family
            if type(exc).__name__ == "NoArgsIsHelpError":
                exc.show()  # type: ignore[attr-defined]
            else:
                print_error(exc.format_message())
            sys.exit(getattr(exc, "exit_code", EXIT_USAGE))
        except (typer.Abort, KeyboardInterrupt):
            print_error("interrupted")
            sys.exit(EXIT_INTERRUPTED)
        except Terminated:
            print_error("terminated (SIGTERM)")
            sys.exit(EXIT_TERMINATED)
        except (SvainsError, OSError) as exc:
            print_error(str(exc))
            sys.exit(EXIT_BAD_INPUT)
        except Exception as exc:
            if logging.getLogger().isEnabledFor(logging.DEBUG):
                raise
            print_error(
                f"unexpected {type(exc).__name__}: {exc} (a bug in svains; "
                "run with --verbose for the traceback)"
            )
            sys.exit(EXIT_BAD_INPUT)
        if rv == EXIT_INTERRUPTED:  # typer returns Ctrl-C as this code, having said nothing
            print_error("interrupted")
        sys.exit(rv if isinstance(rv, int) else EXIT_OK)


# Options that ``run`` and ``compare`` share, spelled once.
SonarOption = Annotated[
    bool | None, typer.Option("--sonar/--no-sonar", help="Fuse sonar.")
]


def parse_outage(text: str, option: str = "--gps-outage") -> tuple[float, float]:
    """``option`` (``--gps-outage``, ``--stop``) ``START:DURATION`` (seconds) -> (start,
    duration): ConfigError unless both are finite, START >= 0 and DURATION > 0."""
    try:
        a, b = text.split(":")
        start, length = float(a), float(b)
    except ValueError as exc:
        raise ConfigError(f"{option} expects START:DURATION in seconds, got {text!r}") from exc
    if not (math.isfinite(start) and math.isfinite(length) and start >= 0 and length > 0):
        raise ConfigError(f"{option} expects START >= 0 and DURATION > 0 (finite seconds), "
                          f"got {text!r}")  # fmt: skip
    return start, length


def _windows(option: str) -> Callable[[list[str] | None], list[str] | None]:
    def check(values: list[str] | None) -> list[str] | None:
        for text in values or []:
            try:
                parse_outage(text, option)
            except ConfigError as exc:
                raise typer.BadParameter(str(exc).removeprefix(f"{option} ")) from None
        return values

    return check


# Typer callbacks: each value read by ``parse_outage`` (else a usage error, exit 2, naming the
# option)
gps_outages = _windows("--gps-outage")
stop_windows = _windows("--stop")


# the --rotation help of run, compare and demo
ROTATION_HELP = ("Vision motion model: clone (default; the one that holds with frames seconds "
                 "apart: imu lost the filter at 3-5 s on EuRoC), imu, linear (paper eq. 18) or "
                 "exp.")

TopicOption = Annotated[
    list[str] | None,
    typer.Option("--topic", help="ROLE=TOPIC: a bag's topic for a role (imu, left, right, gps, "
                 "gt) when auto-detection is ambiguous; repeatable (config key replay.topics)."),
]
GpsOutageOption = Annotated[
    list[str] | None,
    typer.Option("--gps-outage", help="START:DURATION \\[s from the first IMU sample fed] "
                 "without GPS; repeatable.", callback=gps_outages),
]
GpsUntilOption = Annotated[
    float | None, typer.Option("--gps-until", help="No GPS after S seconds.",
                               callback=non_negative_finite),
]
