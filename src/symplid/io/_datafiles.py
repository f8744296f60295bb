"""Data files: read and write :class:`~symplid.model._data.Observations` as CSV or NPZ.

Column layout (both formats)
----------------------------
``t``, then the positions ``q1 … qd``, then optionally the momenta ``p1 … pd``:

* ``t, q1, …, qd, p1, …, pd`` is the **full** state (the paper's experiment, eq. 7 with
  h = identity);
* ``t, q1, …, qd`` is **positions only** (h picks q).

A NaN (or an empty CSV cell, or ``nan`` / ``NA``) means the component was not measured at that
time; the filter skips it in that update. Times must be finite and strictly increasing, and may
be irregular (the propagator splits each gap into ⌈gap/dt⌉ substeps, eq. 14).

CSV: comma separated, one header line, ``#`` lines are comments, blank lines are ignored.
NPZ: either one 1-D array per column (``t``, ``q1``, …), or ``t`` (alias ``times``) with a
``(n, d_y)`` array ``values`` and an optional string array ``names``; without ``names`` the
columns of ``values`` are read as the full state ``q1 … qd, p1 … pd`` (an even count).

Every problem raises :class:`~symplid.DataError` with a one-line message that starts with
the file name and says where (line, column) and what to do.
"""

from __future__ import annotations

import csv
import difflib
import io as _io
import math
import os
import re
import zipfile
from pathlib import Path
from typing import Literal, NamedTuple

import numpy as np

from symplid.io._files import write_text, write_with
from symplid.model._data import DataError, Observations

__all__ = [
    "TRAJECTORY_COLUMN",
    "Layout",
    "check_data_file",
    "column_names",
    "observation_kind",
    "observation_layout",
    "observations_csv",
    "parse_csv",
    "positions_only",
    "read_observations",
    "read_text",
    "write_observations",
]

Kind = Literal["full", "positions"]

_COLUMN = re.compile(r"^([qp])([1-9][0-9]*)$")
#: The CSV column that labels the rows of several trajectories (:mod:`symplid.io._trajectories`).
TRAJECTORY_COLUMN = "trajectory"
_MISSING = {"", "nan", "na", "n/a", "null", "none"}


class Layout(NamedTuple):
    """What the columns imply: ``kind`` ("full" or "positions") and the number of degrees of
    freedom ``dim`` (d, so the state has 2d components)."""

    kind: Kind
    dim: int


# ----------------------------------------------------------------------------- layout
def column_names(dim: int, kind: Kind = "full") -> tuple[str, ...]:
    """The value columns for ``dim`` degrees of freedom: ``q1..qd`` (+ ``p1..pd`` if full)."""
    if kind not in ("full", "positions"):
        raise ValueError(f"kind must be 'full' or 'positions', got {kind!r}")
    if dim < 1:
        raise ValueError(f"dim must be ≥ 1, got {dim}")
    names = tuple(f"q{i}" for i in range(1, dim + 1))
    if kind == "full":
        names += tuple(f"p{i}" for i in range(1, dim + 1))
    return names


def _layout_from_names(names: tuple[str, ...], where: str) -> Layout:
    """Check value-column names against ``q1..qd[, p1..pd]``; raise DataError naming ``where``."""
    if not names:
        raise DataError(f"{where}: no value columns; expected q1..qd (and optionally p1..pd)")
    seen: dict[str, int] = {}
    parsed: list[tuple[str, int]] = []
    for position, name in enumerate(names):
        if name in seen:
            raise DataError(f"{where}: column {name!r} appears twice")
        seen[name] = position
        match = _COLUMN.match(name)
        if match is None:
            hint = ""
            if name in ("t", "time", "times"):
                hint = "; the time column 't' must come first"
            else:
                close = difflib.get_close_matches(name, ["t", "q1", "q2", "p1", "p2"], n=1)
                if close:
                    hint = f"; did you mean {close[0]!r}?"
            raise DataError(
                f"{where}: unknown column {name!r}{hint} (columns are t, q1..qd, then "
                "optionally p1..pd)"
            )
        parsed.append((match.group(1), int(match.group(2))))
    qs = [i for kind, i in parsed if kind == "q"]
    ps = [i for kind, i in parsed if kind == "p"]
    for i in ps:
        if i not in qs:
            raise DataError(f"{where}: column 'p{i}' has no matching 'q{i}' column")
    if not qs:
        raise DataError(f"{where}: no position columns; expected q1..qd before p1..pd")
    dim = max(qs)
    for i in range(1, dim + 1):
        if i not in qs:
            raise DataError(f"{where}: column 'q{i}' is missing (there is a 'q{dim}')")
    if ps:
        for i in range(1, dim + 1):
            if i not in ps:
                raise DataError(
                    f"{where}: column 'p{i}' is missing: give every p1..p{dim} or no p columns"
                )
    kind: Kind = "full" if ps else "positions"
    expected = column_names(dim, kind)
    if tuple(names) != expected:
        raise DataError(
            f"{where}: columns out of order: expected t,{','.join(expected)}, "
            f"got t,{','.join(names)}"
        )
    return Layout(kind, dim)


def observation_layout(obs: Observations) -> Layout:
    """The layout (kind and d) implied by the observations' column names.

    Without names, ``d_y`` columns are read as the full state (``d_y`` must then be even).
    """
    if obs.names is not None:
        return _layout_from_names(tuple(obs.names), "observations")
    if obs.dim % 2:
        raise DataError(
            f"observations have {obs.dim} unnamed columns, which is not a full state "
            "(q1..qd, p1..pd); give names, e.g. names=('q1', ...)"
        )
    return Layout("full", obs.dim // 2)


def observation_kind(obs: Observations) -> Kind:
    """``"full"`` when the columns are ``q1..qd, p1..pd``, ``"positions"`` when only ``q``."""
    return observation_layout(obs).kind


def positions_only(obs: Observations) -> Observations:
    """The same observations with the momentum columns dropped (rows with no q left are kept
    as all-missing rows so the times are unchanged)."""
    layout = observation_layout(obs)
    values = obs.values[:, : layout.dim]
    return Observations(obs.times, values, column_names(layout.dim, "positions"))


# ----------------------------------------------------------------------------- reading
def read_observations(path: str | os.PathLike) -> Observations:
    """Read a CSV or NPZ data file (chosen by extension) into :class:`Observations`.

    The returned observations carry the column names (``q1, …, p1, …``), so
    :func:`observation_kind` tells whether they are the full state or positions only.

    Raises
    ------
    DataError
        With a one-line message naming the file (and the line and column for CSV) for: a missing
        or empty file, no header or no ``t`` column, text in a number column, times not strictly
        increasing, a ``p`` column without its ``q`` pair, columns out of order, unknown columns,
        no data rows, and anything :class:`Observations` rejects.
    """
    path = check_data_file(path)
    if path.suffix.lower() == ".csv":
        return _read_csv(path)
    return _read_npz(path)


def check_data_file(path: str | os.PathLike) -> Path:
    """A one-line :class:`DataError` unless ``path`` is a non-empty ``.csv``/``.npz`` file."""
    path = Path(path)
    if path.suffix.lower() not in (".csv", ".npz"):
        raise DataError(
            f"{path}: unknown data file type {path.suffix or '(no extension)'!r}; use .csv or .npz"
        )
    if not path.exists():
        raise DataError(f"{path}: no such file")
    if path.is_dir():
        raise DataError(f"{path}: is a directory, not a data file")
    if path.stat().st_size == 0:
        raise DataError(f"{path}: the file is empty")
    return path


def read_text(path: Path) -> str:
    """The text of a CSV file (a one-line error when it is not UTF-8)."""
    try:
        return path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise DataError(f"{path}: not a UTF-8 text file") from None


def _read_csv(path: Path) -> Observations:
    return parse_csv(path, read_text(path))


def parse_csv(path: Path, text: str) -> Observations:
    """Observations from the text of a CSV file (``path`` names it in errors)."""
    rows = [
        (number, row)
        for number, row in enumerate(csv.reader(_io.StringIO(text)), start=1)
        if row and any(cell.strip() for cell in row) and not row[0].lstrip().startswith("#")
    ]
    if not rows:
        raise DataError(f"{path}: the file is empty (no header and no data)")
    header_line, header = rows[0]
    header = [cell.strip() for cell in header]
    if all(_is_number(cell) for cell in header):
        raise DataError(
            f"{path}: line {header_line}: no header line; the first line must name the "
            "columns, e.g. t,q1,q2,p1,p2"
        )
    if len(header) == 1 and any(sep in header[0] for sep in (";", "\t", " ")):
        raise DataError(f"{path}: line {header_line}: columns must be separated by commas")
    names = [cell.lower() for cell in header]
    if TRAJECTORY_COLUMN in names:
        raise DataError(
            f"{path}: line {header_line}: a '{TRAJECTORY_COLUMN}' column labels several "
            "trajectories; read the file with symplid.io.read_trajectories (symplid fit does)"
        )
    if names[0] != "t":
        if "t" in names:
            raise DataError(
                f"{path}: line {header_line}: the first column must be 't', "
                f"found {header[0]!r} ('t' is column {names.index('t') + 1})"
            )
        raise DataError(
            f"{path}: line {header_line}: no 't' column; the first column must be the time 't' "
            f"(found {header[0]!r})"
        )
    layout_names = tuple(names[1:])
    if not layout_names:
        raise DataError(f"{path}: line {header_line}: no value columns after 't'")
    _layout_from_names(layout_names, f"{path}: line {header_line}")
    data_rows = rows[1:]
    if not data_rows:
        raise DataError(f"{path}: has a header but no data rows")
    width = len(names)
    times = np.empty(len(data_rows))
    values = np.empty((len(data_rows), width - 1))
    previous_line = 0
    for k, (line, row) in enumerate(data_rows):
        if len(row) != width:
            raise DataError(
                f"{path}: line {line}: {len(row)} fields but the header has {width} columns"
            )
        for j, cell in enumerate(row):
            column = names[j]
            value = _parse_cell(cell, path, line, column)
            if j == 0:
                if math.isnan(value):
                    raise DataError(f"{path}: line {line}, column 't': the time is missing")
                if math.isinf(value):
                    raise DataError(f"{path}: line {line}, column 't': the time must be finite")
                if k > 0 and value <= times[k - 1]:
                    raise DataError(
                        f"{path}: line {line}: t = {value:g} is not after t = {times[k - 1]:g} "
                        f"on line {previous_line}; times must be strictly increasing"
                    )
                times[k] = value
            else:
                if math.isinf(value):
                    raise DataError(
                        f"{path}: line {line}, column {column!r}: {cell.strip()!r} is infinite; "
                        "leave the cell empty or write nan for a missing value"
                    )
                values[k, j - 1] = value
        previous_line = line
    return _make_observations(path, times, values, layout_names)


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def _parse_cell(cell: str, path: Path, line: int, column: str) -> float:
    text = cell.strip()
    if text.lower() in _MISSING:
        return math.nan
    try:
        return float(text)
    except ValueError:
        raise DataError(
            f"{path}: line {line}, column {column!r}: {text!r} is not a number "
            "(leave the cell empty or write nan for a missing value)"
        ) from None


def _read_npz(path: Path) -> Observations:
    if not zipfile.is_zipfile(path):
        raise DataError(f"{path}: not a valid NPZ file (not a zip archive)")
    try:
        with np.load(path, allow_pickle=False) as archive:
            arrays = {name: archive[name] for name in archive.files}
    except (zipfile.BadZipFile, OSError, EOFError) as err:
        raise DataError(f"{path}: not a valid NPZ file ({err})") from None
    except ValueError as err:  # object arrays need pickle, which is refused
        raise DataError(f"{path}: cannot read without pickle ({err}); store numbers only") from None
    if not arrays:
        raise DataError(f"{path}: the file is empty (no arrays)")
    if "t" not in arrays and "times" in arrays:
        arrays["t"] = arrays.pop("times")
    if "t" not in arrays:
        raise DataError(f"{path}: no 't' array (found {', '.join(sorted(arrays))})")
    times = _numeric(arrays.pop("t"), path, "t", ndim=1)
    if times.size == 0:
        raise DataError(f"{path}: no data rows ('t' is empty)")
    if "values" in arrays:
        values = _numeric(arrays.pop("values"), path, "values", ndim=2)
        names_array = arrays.pop("names", None)
        if arrays:
            raise DataError(
                f"{path}: unknown arrays {', '.join(sorted(arrays))} beside 't', 'values' "
                "and 'names'"
            )
        if names_array is None:
            if values.shape[1] % 2:
                raise DataError(
                    f"{path}: 'values' has {values.shape[1]} columns and no 'names'; without "
                    "names the columns are read as the full state q1..qd, p1..pd, which needs "
                    "an even count"
                )
            names = column_names(values.shape[1] // 2, "full")
        else:
            if names_array.dtype.kind not in "US":
                raise DataError(f"{path}: 'names' must be an array of strings")
            names = tuple(str(n).strip().lower() for n in np.ravel(names_array))
            if len(names) != values.shape[1]:
                raise DataError(
                    f"{path}: {len(names)} names for {values.shape[1]} columns of 'values'"
                )
        if values.shape[0] != times.shape[0]:
            raise DataError(
                f"{path}: 't' has {times.shape[0]} entries but 'values' has {values.shape[0]} rows"
            )
        _layout_from_names(names, str(path))
    else:
        arrays.pop("names", None)
        layout = _layout_from_names(_npz_column_order(arrays, path), str(path))
        names = column_names(layout.dim, layout.kind)
        columns = []
        for name in names:
            column = _numeric(arrays[name], path, name, ndim=1)
            if column.shape[0] != times.shape[0]:
                raise DataError(
                    f"{path}: 't' has {times.shape[0]} entries but {name!r} has {column.shape[0]}"
                )
            columns.append(column)
        values = np.stack(columns, axis=1)
    _check_times(times, path)
    if np.any(np.isinf(values)):
        row, col = np.argwhere(np.isinf(values))[0]
        raise DataError(
            f"{path}: {names[col]!r} at row {row} is infinite; use NaN for a missing value"
        )
    return _make_observations(path, times, values, names)


def _npz_column_order(arrays: dict[str, np.ndarray], path: Path) -> tuple[str, ...]:
    """NPZ arrays have no order: sort q's then p's by index, after checking the names."""
    names = tuple(arrays)
    for name in names:
        if _COLUMN.match(name) is None:
            return names  # let the layout check report the unknown name
    return tuple(sorted(names, key=lambda n: (n[0] != "q", int(n[1:]))))


def _numeric(array: np.ndarray, path: Path, name: str, ndim: int) -> np.ndarray:
    if array.dtype.kind not in "biuf":
        raise DataError(f"{path}: array {name!r} holds {array.dtype} values, not numbers")
    array = np.asarray(array, dtype=float)
    if ndim == 2 and array.ndim == 1:
        array = array[:, None]
    if array.ndim != ndim:
        raise DataError(f"{path}: array {name!r} must be {ndim}-D, got shape {array.shape}")
    return array


def _check_times(times: np.ndarray, path: Path) -> None:
    if not np.all(np.isfinite(times)):
        k = int(np.argmin(np.isfinite(times)))
        raise DataError(f"{path}: t[{k}] = {times[k]}; times must be finite (none missing)")
    if np.any(np.diff(times) <= 0):
        k = int(np.argmax(np.diff(times) <= 0))
        raise DataError(
            f"{path}: t[{k + 1}] = {times[k + 1]:g} is not after t[{k}] = {times[k]:g}; "
            "times must be strictly increasing"
        )


def _make_observations(
    path: Path, times: np.ndarray, values: np.ndarray, names: tuple[str, ...]
) -> Observations:
    try:
        return Observations(times, values, names)
    except DataError as err:
        raise DataError(f"{path}: {err}") from None


# ----------------------------------------------------------------------------- writing
def write_observations(obs: Observations, path: str | os.PathLike) -> Path:
    """Write observations to ``path`` (``.csv`` or ``.npz``), replacing it atomically.

    Columns are ``obs.names`` (checked against the ``q1..qd[, p1..pd]`` layout), or the full
    state names when the observations are unnamed. CSV numbers are written with ``repr`` (they
    read back bit for bit); a missing value is written ``nan``. NPZ stores one array per column.
    Returns the path written.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".csv", ".npz"):
        raise DataError(f"{path}: unknown data file type {path.suffix!r}; use .csv or .npz")
    layout = observation_layout(obs)
    names = column_names(layout.dim, layout.kind)
    if suffix == ".csv":
        return write_text(path, observations_csv(obs))
    columns = {name: np.asarray(obs.values[:, j]) for j, name in enumerate(names)}
    return write_with(path, lambda handle: np.savez(handle, t=np.asarray(obs.times), **columns))


def observations_csv(obs: Observations) -> str:
    """The CSV text :func:`write_observations` writes (``t`` then the layout's columns)."""
    layout = observation_layout(obs)
    lines = [",".join(("t", *column_names(layout.dim, layout.kind)))]
    for t, row in zip(obs.times, obs.values, strict=True):
        lines.append(",".join(_format(x) for x in (t, *row)))
    return "\n".join(lines) + "\n"


def _format(x: float) -> str:
    x = float(x)
    return "nan" if math.isnan(x) else repr(x)
