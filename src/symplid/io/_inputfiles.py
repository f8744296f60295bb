"""Data files of driven systems: input columns beside the observed ones, or in a file of
their own.

A CSV file ``t,q1,u1`` holds the observed positions and the input u1 at each time. The
input columns are those named ``u1, u2, …`` (the header convention), or the columns the
settings name (``inputs.columns``, read as u1, u2, … in that order). A row whose observed
cells are all empty is an input sample only: a logger's fast input channel beside a slower
sensor, so the inputs may be known on a denser grid than the observations. Every row must
give every input (a missing input value is an error, never filled in). A second file
(``inputs.file``, columns ``t,u1,…``) gives the inputs instead.
"""

from __future__ import annotations

import csv
import io as _io
import math
import os
import re
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from symplid.io._datafiles import check_data_file, parse_csv, read_text
from symplid.model._data import DataError, Observations
from symplid.model._inputs import SampledInputs

__all__ = ["INPUT_COLUMN", "read_driven_csv", "read_input_file"]

#: The header convention of an input column: ``u1``, ``u2``, ….
INPUT_COLUMN = re.compile(r"^u[1-9][0-9]*$")


def _rows(path: Path, text: str) -> list[tuple[int, list[str]]]:
    return [(n, row) for n, row in enumerate(csv.reader(_io.StringIO(text)), start=1)
            if row and any(c.strip() for c in row) and not row[0].lstrip().startswith("#")]


def _input_indices(path: Path, header: list[str], columns: Sequence[str]) -> list[int]:
    names = [c.strip().lower() for c in header]
    if columns:
        missing = [c for c in columns if c.strip().lower() not in names]
        if missing:
            raise DataError(f"{path}: no input column {missing[0]!r} (inputs.columns); the "
                            f"header has {', '.join(header)}")
        return [names.index(c.strip().lower()) for c in columns]
    found = [j for j, n in enumerate(names) if INPUT_COLUMN.match(n)]
    return sorted(found, key=lambda j: int(names[j][1:]))


def _number(cell: str, path: Path, line: int, column: str) -> float:
    text = cell.strip()
    if not text or text.lower() == "nan":
        raise DataError(f"{path}: line {line}, column {column!r}: the input value is missing "
                        "(every row must give every input)")
    try:
        value = float(text)
    except ValueError:
        raise DataError(f"{path}: line {line}, column {column!r}: {text!r} is not a "
                        "number") from None
    if not math.isfinite(value):
        raise DataError(f"{path}: line {line}, column {column!r}: the input must be finite")
    return value


def read_driven_csv(path: str | os.PathLike, columns: Sequence[str] = (),
                    interpolation: str = "linear") -> Observations:
    """Observations whose ``inputs`` are the file's input columns (module docstring).

    Raises
    ------
    DataError
        One line naming the file, and the line and column where it applies: no input column,
        a missing or non-numeric input value, and everything :func:`parse_csv` refuses.
    """
    path = check_data_file(path)
    if path.suffix.lower() != ".csv":
        raise DataError(f"{path}: inputs are read from a CSV file (t, the observed columns, "
                        "u1..)")
    text = read_text(path)
    rows = _rows(path, text)
    if not rows:
        raise DataError(f"{path}: the file is empty (no header and no data)")
    header_line, header = rows[0]
    index = _input_indices(path, header, columns)
    if not index:
        raise DataError(f"{path}: line {header_line}: no input columns (name them u1, u2, … "
                        "or list them in inputs.columns)")
    keep = [j for j in range(len(header)) if j not in index]
    lines = [""] * (rows[-1][0])
    lines[header_line - 1] = ",".join(header[j] for j in keep)
    times, values = [], []
    for line, row in rows[1:]:
        if len(row) != len(header):
            raise DataError(f"{path}: line {line}: {len(row)} fields but the header has "
                            f"{len(header)} columns")
        times.append(_number(row[0], path, line, "t"))
        values.append([_number(row[j], path, line, header[j].strip()) for j in index])
        observed = [row[j] for j in keep]
        if any(c.strip() and c.strip().lower() != "nan" for c in observed[1:]):
            lines[line - 1] = ",".join(observed)
    obs = parse_csv(path, "\n".join(lines) + "\n")
    names = tuple(f"u{k + 1}" for k in range(len(index)))
    signal = SampledInputs(np.asarray(times), np.asarray(values), names, interpolation)
    return replace(obs, inputs=signal)


def read_input_file(path: str | os.PathLike, interpolation: str = "linear",
                    columns: Sequence[str] = ()) -> SampledInputs:
    """The inputs of a file ``t,u1,…`` (``inputs.file``; forecasts' ``--inputs``)."""
    path = check_data_file(path)
    rows = _rows(path, read_text(path))
    if len(rows) < 2:
        raise DataError(f"{path}: an input file needs a header t,u1,… and rows")
    header_line, header = rows[0]
    if header[0].strip().lower() != "t":
        raise DataError(f"{path}: line {header_line}: the first column must be the time 't'")
    index = _input_indices(path, header, columns)
    if not index:
        raise DataError(f"{path}: line {header_line}: no input columns (name them u1, u2, …)")
    times = [_number(row[0], path, line, "t") for line, row in rows[1:]]
    values = [[_number(row[j] if j < len(row) else "", path, line, header[j].strip())
               for j in index] for line, row in rows[1:]]
    names = tuple(f"u{k + 1}" for k in range(len(index)))
    try:
        return SampledInputs(np.asarray(times), np.asarray(values), names, interpolation)
    except DataError as err:
        raise DataError(f"{path}: {err}") from None
