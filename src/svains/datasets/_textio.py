"""Text file edges of the ASL layout: ``%YAML:1.0`` sensor files and ``data.csv`` tables.

Floats are written with Python's shortest round-trip ``repr`` so reading back is bit-exact;
timestamps are parsed as Python ints (int64 ns exceed float64's 53-bit mantissa).
"""

from __future__ import annotations

import math
import re
import warnings
from collections.abc import Sequence
from decimal import Decimal
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from svains.errors import CalibrationError, DatasetError
from svains.sensors.units import time_unit_problem
from svains.yaml_io import load_yaml

YAML_DIRECTIVE = "%YAML:1.0"


def format_float(x: float) -> str:
    """Shortest exact text of ``x`` that YAML 1.1 (PyYAML) also reads as a float."""
    x = float(x)
    if math.isnan(x):
        return ".nan"
    if math.isinf(x):
        return ".inf" if x > 0 else "-.inf"
    r = repr(x)
    # PyYAML's float pattern needs a dot in the mantissa ("1e-05" would load as a string).
    if "e" in r and "." not in r.split("e")[0]:
        mant, exp = r.split("e")
        r = f"{mant}.0e{exp}"
    return r


def _yaml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return format_float(float(v))
    if isinstance(v, str):
        return v
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_yaml_value(e) for e in np.asarray(v).tolist()) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to sensor.yaml")


def write_sensor_yaml(path: Path, entries: Sequence[tuple[str, Any]], comment: str = "") -> None:
    """Write a Kalibr/EuRoC style yaml (``%YAML:1.0`` first line).

    ``entries`` keep their order; a 4x4 array under ``T_BS`` is written as the EuRoC
    ``cols/rows/data`` matrix (row-major).
    """
    lines = [YAML_DIRECTIVE]
    if comment:
        lines.append(f"comment: {comment}")
    for key, value in entries:
        if key == "T_BS":
            T = np.asarray(value, dtype=float).reshape(4, 4)
            lines += ["T_BS:", "  cols: 4", "  rows: 4"]
            rows = [", ".join(format_float(e) for e in r) for r in T.tolist()]
            lines.append("  data: [" + ",\n         ".join(rows) + "]")
        else:
            lines.append(f"{key}: {_yaml_value(value)}")
    path.write_text("\n".join(lines) + "\n")


def read_text(path: Path) -> str:
    """A text file's content; DatasetError naming the file if absent or not text (UTF-8)."""
    if not path.is_file():
        raise DatasetError(f"missing file: {path}")
    try:
        # utf-8-sig: a byte-order mark (spreadsheet exports) is not part of the first field.
        return path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise DatasetError(f"{path}: not a text file ({exc.reason} at byte {exc.start})") from exc


def read_sensor_yaml(path: Path) -> dict[str, Any]:
    """Load a ``%YAML:1.0`` file (the directive, which PyYAML rejects, is stripped)."""
    text = read_text(path)
    if text.lstrip().startswith("%YAML"):
        # a blank line in its place keeps the line numbers of errors the file's own
        text = "\n" + text.split("\n", 1)[1] if "\n" in text else ""
    try:
        data = load_yaml(text)
    except yaml.YAMLError as exc:
        raise CalibrationError(f"{path}: invalid YAML: {exc}") from exc
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise CalibrationError(f"{path}: expected a mapping of keys, got {type(data).__name__}")
    return data


def yaml_float(data: dict[str, Any], key: str, path: Path, default: float | None = None) -> float:
    """A float field of a sensor.yaml (CalibrationError naming file and key if absent/invalid)."""
    if key not in data:
        if default is not None:
            return default
        raise CalibrationError(f"{path}: missing field '{key}'")
    try:
        return float(data[key])
    except (TypeError, ValueError, OverflowError) as exc:
        raise CalibrationError(f"{path}: field '{key}' is not a number: {data[key]!r}") from exc


def yaml_vector(data: dict[str, Any], key: str, path: Path, n: int) -> NDArray[np.float64]:
    """A list of ``n`` floats from a sensor.yaml."""
    if key not in data or data[key] is None:
        raise CalibrationError(f"{path}: missing field '{key}'")
    try:
        v = np.asarray([float(e) for e in data[key]], dtype=float)
    except (TypeError, ValueError, OverflowError) as exc:
        raise CalibrationError(f"{path}: field '{key}' must be {n} numbers") from exc
    if v.shape != (n,):
        raise CalibrationError(f"{path}: field '{key}' must have {n} numbers, has {v.size}")
    return v


def yaml_T_BS(data: dict[str, Any], path: Path, required: bool = True) -> NDArray[np.float64]:
    """The 4x4 ``T_BS`` (sensor to body) of a sensor.yaml; identity when absent and optional."""
    node = data.get("T_BS")
    if node is None:
        if required:
            raise CalibrationError(f"{path}: missing field 'T_BS'")
        return np.eye(4)
    values = node.get("data") if isinstance(node, dict) else node
    if isinstance(values, list) and values and all(isinstance(r, list) for r in values):
        # a nested 4x4 list, as Kalibr's camchain writes T_cam_imu (refused as "must be 16
        # numbers": a user's probe)
        values = [e for row in values for e in row]
    try:
        T = np.asarray([float(e) for e in values], dtype=float)
    except (TypeError, ValueError, OverflowError) as exc:
        raise CalibrationError(f"{path}: 'T_BS' data must be 16 numbers") from exc
    if T.size != 16:
        raise CalibrationError(f"{path}: 'T_BS' data must be 16 numbers, has {T.size}")
    return T.reshape(4, 4)


# Rows formatted at a time by ``write_csv``: memory in proportion to a chunk, not the file (a
# simulated hour of features, 9 M rows, built as one string took 10 GB: a user's probe).
CSV_CHUNK_ROWS = 50_000


def write_csv(path: Path, header: str | Sequence[str], blocks: Sequence[NDArray[Any]]) -> None:
    """Write a ``#``-headed CSV from column blocks (1-D or 2-D, same length).

    Integer blocks are written as integers, float blocks with exact ``repr``, string blocks as is;
    ``CSV_CHUNK_ROWS`` rows at a time.
    """
    arrays: list[NDArray[Any]] = []
    n: int | None = None
    for block in blocks:
        arr = np.asarray(block)
        if arr.ndim == 1:
            arr = arr[:, None]
        if n is None:
            n = arr.shape[0]
        elif arr.shape[0] != n:
            raise ValueError(f"{path.name}: column blocks have {n} and {arr.shape[0]} rows")
        arrays.append(arr)
    head = header if isinstance(header, str) else ",".join(header)
    with path.open("w") as f:
        f.write("#" + head + "\n")
        for start in range(0, n or 0, CSV_CHUNK_ROWS):
            cols: list[list[str]] = []
            for arr in arrays:
                part = arr[start : start + CSV_CHUNK_ROWS]
                fmt = repr if part.dtype.kind == "f" else str
                cols += [[fmt(v) for v in part[:, j].tolist()] for j in range(part.shape[1])]
            if cols:
                f.write("\n".join(",".join(row) for row in zip(*cols, strict=True)) + "\n")


def _is_data_line(line: str, first: bool) -> bool:
    """Whether a stripped CSV line is a data row: not blank, not a ``#`` comment, and not, as
    the ``first`` row, a header written without its '#' (pandas' to_csv writes "timestamp,...":
    no row starts with a letter, and the first one that does could be nothing else)."""
    return bool(line) and not line.startswith("#") and not (first and line[0].isalpha())


def read_csv_rows(path: Path, n_cols: int | tuple[int, ...]) -> tuple[list[list[str]], list[int]]:
    """Split a ``#``-headed CSV into rows of ``n_cols`` fields and their 1-based line numbers.

    Blank lines and ``#`` comment lines are skipped, and so is a first line that starts with a
    letter (a header written without its ``#``); a row with another field count raises a
    DatasetError naming the file and line. ``n_cols`` as a tuple allows several layouts (a
    GPS with or without velocity): the first row picks one and every row must follow it.
    """
    allowed = (n_cols,) if isinstance(n_cols, int) else tuple(n_cols)
    rows: list[list[str]] = []
    line_no: list[int] = []
    # Lines split as a text-mode file would (universal newlines), so numbers match editors'.
    lines = read_text(path).replace("\r\n", "\n").replace("\r", "\n").split("\n")
    for k, raw in enumerate(lines, start=1):
        line = raw.strip()
        if not _is_data_line(line, first=not rows):
            continue
        fields = [f.strip() for f in line.split(",")]
        if len(fields) not in allowed:
            expected = " or ".join(str(n) for n in allowed)
            raise DatasetError(
                f"{path}:{k}: malformed row, expected {expected} fields, got {len(fields)}: "
                f"{line[:80]!r}"
            )
        if rows and len(fields) != len(rows[0]):
            raise DatasetError(
                f"{path}:{k}: malformed row, {len(fields)} fields where the rows before have "
                f"{len(rows[0])}: {line[:80]!r}"
            )
        rows.append(fields)
        line_no.append(k)
    return rows, line_no


class DataLines(Sequence[int]):
    """The 1-based line numbers of a CSV's data rows (those ``read_csv_rows`` keeps), found
    only when an error message asks for one: a table read whole by ``read_numeric_table``
    never needs them otherwise."""

    def __init__(self, path: Path, n_rows: int) -> None:
        self.path, self.n_rows = path, n_rows
        self._lines: list[int] | None = None

    def __len__(self) -> int:
        return self.n_rows

    def __getitem__(self, i):  # type: ignore[no-untyped-def,override]
        if self._lines is None:
            lines = read_text(self.path).replace("\r\n", "\n").replace("\r", "\n").split("\n")
            keep: list[int] = []
            for k, raw in enumerate(lines, start=1):
                if _is_data_line(raw.strip(), first=not keep):
                    keep.append(k)
            self._lines = keep
        return self._lines[i]


# Above this size a numeric CSV is parsed by numpy's C reader first (a 600 s simulated flight's
# 106 MB features0: 9.3 s and 0.96 GB as Python lists of strings); any row it cannot read, or a
# value the checks refuse, sends the file through ``read_csv_rows`` for the error's line.
FAST_TABLE_BYTES = 1 << 20


def read_numeric_table(
    path: Path, n_cols: int | tuple[int, ...], strict: bool = True, min_rows: int = 1
) -> tuple[NDArray[np.int64], NDArray[np.float64], Sequence[int]]:
    """A stream's ``data.csv``: integer-ns stamps (N,) (strictly increasing, or with ``strict``
    False non-decreasing), the other columns as float64 (N, n_cols - 1), and the rows' line
    numbers (N); every error names the file and line (see ``read_csv_rows``)."""
    try:
        big = path.stat().st_size > FAST_TABLE_BYTES
    except OSError:
        big = False  # the careful reader names what is wrong with the file
    got = _fast_table(path, n_cols) if big else None
    if got is not None:
        t, a = got
        lines: Sequence[int] = DataLines(path, t.size)
        if t.size >= min_rows and np.all(np.isfinite(a)):
            check_timestamps(path, t, lines, strict)
            return t, a, lines
    rows, line_list = read_csv_rows(path, n_cols)
    t = parse_timestamps(path, rows, line_list, strict=strict)
    from svains.datasets.validate import check_rows

    check_rows(t, path, min_rows)
    return t, parse_floats(path, rows, line_list, slice(1, None)), line_list


def _fast_table(path: Path, n_cols: int | tuple[int, ...]
                ) -> tuple[NDArray[np.int64], NDArray[np.float64]] | None:  # fmt: skip
    """numpy's reading of a plain numeric CSV (``#`` comments, int64 stamps, floats), or None
    when it cannot read it whole (any odd row: the careful reader then names it)."""
    for n in (n_cols,) if isinstance(n_cols, int) else tuple(n_cols):
        dtype = np.dtype([("t", np.int64)] + [(f"c{i}", np.float64) for i in range(n - 1)])
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error")  # "input contained no data": the careful way
                table = np.loadtxt(path, dtype=dtype, delimiter=",", comments="#", ndmin=1,
                                   encoding="utf-8-sig")  # fmt: skip
        except (ValueError, OverflowError, UnicodeDecodeError, UserWarning):
            continue
        values = np.stack([table[f"c{i}"] for i in range(n - 1)], axis=1) if n > 1 else (
            np.zeros((table.size, 0)))
        return np.asarray(table["t"], np.int64), values
    return None


def parse_timestamps(
    path: Path, rows: list[list[str]], line_no: list[int], strict: bool = True
) -> NDArray[np.int64]:
    """Column 0 as int64 ns; ``strict`` demands strictly increasing, else non-decreasing."""
    try:
        t = np.array([int(r[0]) for r in rows], dtype=np.int64)
    except OverflowError:
        raise DatasetError(f"{path}: a timestamp is outside the int64 nanosecond range") from None
    except ValueError:
        for r, k in zip(rows, line_no, strict=True):
            try:
                int(r[0])
            except ValueError:
                raise DatasetError(
                    f"{path}:{k}: malformed timestamp {r[0]!r} (expected integer nanoseconds"
                    f"{_seconds_hint(r[0])})"
                ) from None
        raise
    check_timestamps(path, t, line_no, strict)
    return t


def _seconds_hint(text: str) -> str:
    """A hint for a stamp written as decimal seconds (``1700000000.000000``: a user's
    export), else nothing."""
    if re.fullmatch(r"\d{1,11}\.\d*", text.strip()) is None:
        return ""
    ns = int(Decimal(text.strip()) * 1_000_000_000)  # exact: a float rounds 1.7e18 to 256 ns
    return f"; {text} looks like seconds with decimals: write integer nanoseconds, {ns} here"


def check_timestamps(path: Path, t: NDArray[np.int64], line_no: Sequence[int],
                     strict: bool = True) -> None:  # fmt: skip
    """DatasetError naming the line of the first stamp of ``t`` (N,) that does not increase
    (``strict``; else that decreases), or when they are not nanoseconds (``check_time_unit``)."""
    d = np.diff(t)
    bad = np.flatnonzero(d <= 0) if strict else np.flatnonzero(d < 0)
    if bad.size:
        i = int(bad[0]) + 1
        kind = "duplicate" if d[i - 1] == 0 else "non-increasing"
        raise DatasetError(
            f"{path}:{line_no[i]}: {kind} timestamp {t[i]} after {t[i - 1]} "
            f"(timestamps must be strictly increasing)"
            if strict
            else f"{path}:{line_no[i]}: decreasing timestamp {t[i]} after {t[i - 1]}"
        )
    check_time_unit(path, t, line_no)


# Timestamps must be integer nanoseconds (``sensors.units.time_unit_problem``); a step this many
# median spacings (and at least an hour) past the previous row is a stray row (a corrupted or
# misplaced stamp), not a pause.
STRAY_ROW_SPACINGS = 10_000
STRAY_ROW_MIN_NS = 3600 * 10**9


def check_time_unit(path: Path, t: NDArray[np.int64], line_no: Sequence[int]) -> None:
    """DatasetError naming the file (and line) when the stamps ``t`` (N,) of a sorted stream are
    not nanoseconds or one row lies far outside the others (see the constants)."""
    u = np.unique(t)
    if u.size < 3:
        return
    d = np.diff(u)
    med = float(np.median(d))
    unit = time_unit_problem(med)
    if unit is not None:
        raise DatasetError(f"{path}: {unit} (the ASL layout stamps in integer nanoseconds)")
    far = np.flatnonzero((d > STRAY_ROW_SPACINGS * med) & (d > STRAY_ROW_MIN_NS))
    if far.size:
        k = int(np.searchsorted(t, u[far[0] + 1]))
        raise DatasetError(
            f"{path}:{line_no[k]}: timestamp {u[far[0] + 1]} is {d[far[0]] * 1e-9 / 3600:.3g} h "
            f"after the row before (median spacing {med * 1e-6:.3g} ms): a stray row"
        )


def parse_floats(
    path: Path, rows: list[list[str]], line_no: list[int], cols: slice
) -> NDArray[np.float64]:
    """Columns ``cols`` as float64 (N, K); a bad number or a NaN names its file and line."""
    if not rows:
        raise DatasetError(f"{path}: no data rows (header only)")
    try:
        a = np.array([r[cols] for r in rows], dtype=float)
    except ValueError:
        for r, k in zip(rows, line_no, strict=True):
            for f in r[cols]:
                try:
                    float(f)
                except ValueError:
                    raise DatasetError(f"{path}:{k}: malformed number {f!r}") from None
        raise
    if a.size == 0:
        return a.reshape(len(rows), -1)
    nan_rows = np.flatnonzero(~np.all(np.isfinite(a), axis=1))
    if nan_rows.size:
        k = line_no[int(nan_rows[0])]
        raise DatasetError(f"{path}:{k}: NaN or infinite value ({nan_rows.size} row(s) affected)")
    return a
