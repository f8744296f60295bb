"""Several trajectories of one system: several data files, or a ``trajectory`` column.

The trajectories share the model's parameters θ and each has its own initial state
(:class:`symplid.model._posterior.Posterior` with a list of observations). They come either as
several files with the same columns, or as one CSV file with a ``trajectory`` column (in any
place but the first, which is ``t``) whose value labels each row::

    t,q1,p1,trajectory
    0.5,0.88,-0.47,a
    1.0,0.54,-0.84,a
    0.5,0.12,0.99,b

Rows of one label form one trajectory (times strictly increasing within it), in the order the
labels first appear. Errors name the file and the line, as for one trajectory
(:mod:`symplid.io._datafiles`). A run folder stores several trajectories as one ``data.csv``
with a ``trajectory`` column numbered 0, 1, … (the index ``k`` of ``x0[k]`` in θ).
"""

from __future__ import annotations

import csv
import os
from collections.abc import Sequence
from pathlib import Path

from symplid.io._datafiles import (
    TRAJECTORY_COLUMN,
    check_data_file,
    observations_csv,
    parse_csv,
    read_observations,
    read_text,
    write_observations,
)
from symplid.io._files import write_text
from symplid.model._data import DataError, Observations

__all__ = ["as_list", "num_trajectories", "read_trajectories", "write_trajectories"]


def read_trajectories(paths: Sequence[str | os.PathLike]) -> Observations | list[Observations]:
    """The trajectories in ``paths``: one :class:`Observations` when there is one, else a list.

    Each file holds one trajectory, or several when it is a CSV file with a ``trajectory``
    column. All must have the same columns (the same system, observed the same way).
    """
    if not paths:
        raise DataError("no data file given")
    found: list[tuple[str, Observations]] = []
    for path in paths:
        found += [(f"{path}{where}", obs) for where, obs in _read_file(Path(path))]
    first_where, first = found[0]
    for where, obs in found[1:]:
        if tuple(obs.names or ()) != tuple(first.names or ()):
            raise DataError(
                f"{where}: columns {', '.join(obs.names or ())} differ from those of "
                f"{first_where} ({', '.join(first.names or ())}); trajectories of one system "
                "must be observed the same way"
            )
    trajectories = [obs for _, obs in found]
    return trajectories[0] if len(trajectories) == 1 else trajectories


def _read_file(path: Path) -> list[tuple[str, Observations]]:
    path = check_data_file(path)
    if path.suffix.lower() != ".csv":
        return [("", read_observations(path))]
    text = read_text(path)
    lines = text.splitlines()
    header = _header(lines)
    if header is None or TRAJECTORY_COLUMN not in header[1]:
        return [("", parse_csv(path, text))]
    number, names = header
    column = names.index(TRAJECTORY_COLUMN)
    if column == 0:
        raise DataError(f"{path}: line {number}: the first column must be 't'; put "
                        f"'{TRAJECTORY_COLUMN}' after it")
    labels: dict[str, list[int]] = {}
    for k in range(number, len(lines)):
        cells = next(csv.reader([lines[k]]), [])
        if not cells or not any(c.strip() for c in cells) or cells[0].lstrip().startswith("#"):
            continue
        label = cells[column].strip() if column < len(cells) else ""
        if not label:
            raise DataError(f"{path}: line {k + 1}: no {TRAJECTORY_COLUMN} label")
        labels.setdefault(label, []).append(k)
    out = []
    for label, rows in labels.items():
        # Other trajectories' rows become blank lines, so errors keep the file's line numbers.
        keep = set(rows) | {number - 1}
        own = [_without(lines[k], column) if k in keep else "" for k in range(len(lines))]
        out.append((f" (trajectory {label})", parse_csv(path, "\n".join(own) + "\n")))
    return out


def _header(lines: list[str]) -> tuple[int, list[str]] | None:
    """(1-based line number, lower-case cells) of the first line that is not blank or a comment."""
    for k, line in enumerate(lines):
        cells = next(csv.reader([line]), [])
        if cells and any(c.strip() for c in cells) and not cells[0].lstrip().startswith("#"):
            return k + 1, [c.strip().lower() for c in cells]
    return None


def _without(line: str, column: int) -> str:
    cells = next(csv.reader([line]), [])
    return ",".join(c for j, c in enumerate(cells) if j != column)


def write_trajectories(data: Observations | Sequence[Observations],
                       path: str | os.PathLike) -> Path:
    """Write one trajectory as :func:`~symplid.io._datafiles.write_observations` does, or
    several as one CSV file with a ``trajectory`` column numbered 0, 1, … (atomically)."""
    if isinstance(data, Observations):
        return write_observations(data, path)
    path = Path(path)
    if path.suffix.lower() != ".csv":
        raise DataError(f"{path}: several trajectories are written as CSV")
    blocks = []
    for k, obs in enumerate(data):
        head, *rows = observations_csv(obs).splitlines()
        blocks += [f"{head},{TRAJECTORY_COLUMN}"] if k == 0 else []
        blocks += [f"{row},{k}" for row in rows]
    return write_text(path, "\n".join(blocks) + "\n")


def num_trajectories(data: Observations | Sequence[Observations]) -> int:
    """1 for one :class:`Observations`, else the length of the list."""
    return 1 if isinstance(data, Observations) else len(data)


def as_list(data: Observations | Sequence[Observations]) -> list[Observations]:
    """The trajectories as a list (one :class:`Observations` becomes a list of one)."""
    return [data] if isinstance(data, Observations) else list(data)
