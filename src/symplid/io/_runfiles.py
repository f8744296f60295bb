"""Run files: strict JSON with non-finite floats, netCDF attributes, the summary table.

The readers and writers under :class:`symplid.workflow._results.RunFolder`, kept apart from the
folder's rules (markers, modes) because the sweeps and the paper's study write the same files.

JSON conventions
----------------
NumPy and JAX arrays become (nested) lists, NumPy scalars become numbers, tuples lists, dataclasses
and NamedTuples objects. JSON has no NaN or infinity, so non-finite floats are written as the
strings ``"nan"``, ``"inf"`` and ``"-inf"`` (not ``null``, which would lose which one it was);
:func:`read_json` turns those strings back into floats. The files are strict JSON.

netCDF attributes
-----------------
netCDF attributes are written as they are when they are strings or numbers; anything else (a
list or an array of any shape, a dict, a boolean, None) is written as JSON text by
:func:`netcdf_attrs`, its key listed in one extra attribute, and restored by
:func:`restore_attrs` (lists of numbers as arrays). Lists and arrays take the same path, so an
attribute has one format whether a fresh run wrote it (a list) or a resumed one (an array read
back). :func:`netcdf_bytes` makes the whole file in memory, for
:func:`symplid.io._files.write_bytes`.
"""

from __future__ import annotations

import dataclasses
import io as _io
import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from symplid._jsonfloat import decode, encode_float
from symplid.io._files import RunFolderError, read_with, write_text

__all__ = [
    "RunFolderError",
    "flatten",
    "format_summary",
    "netcdf_attrs",
    "netcdf_bytes",
    "numeric_arrays",
    "read_json",
    "restore_attrs",
    "to_jsonable",
    "write_json",
]


# ----------------------------------------------------------------------------- JSON
def to_jsonable(obj: Any, where: str = "") -> Any:
    """Convert ``obj`` to plain JSON types (see the module docstring for the rules)."""
    if obj is None or isinstance(obj, bool | str):
        return obj
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, int | np.integer):
        return int(obj)
    if isinstance(obj, float | np.floating):
        return encode_float(float(obj))
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    if isinstance(obj, Mapping):
        return {str(k): to_jsonable(v, f"{where}.{k}" if where else str(k)) for k, v in obj.items()}
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {
            f.name: to_jsonable(getattr(obj, f.name), f"{where}.{f.name}")
            for f in dataclasses.fields(obj)
        }
    if isinstance(obj, tuple) and hasattr(obj, "_asdict"):  # NamedTuple
        return to_jsonable(obj._asdict(), where)
    if isinstance(obj, list | tuple | set | frozenset):
        items = sorted(obj, key=str) if isinstance(obj, set | frozenset) else obj
        return [to_jsonable(v, f"{where}[{i}]") for i, v in enumerate(items)]
    if hasattr(obj, "__array__"):  # NumPy and JAX arrays
        array = np.asarray(obj)
        if array.dtype.kind in "biuf":
            if array.dtype.kind == "f" and not np.all(np.isfinite(array)):
                return _nested(array.tolist())
            return array.tolist()
        if array.dtype.kind in "US":
            return array.tolist()
        raise TypeError(f"cannot write {array.dtype} array at {where or 'top level'} as JSON")
    raise TypeError(f"cannot write {type(obj).__name__} at {where or 'top level'} as JSON")


def _nested(value: Any) -> Any:
    if isinstance(value, list):
        return [_nested(v) for v in value]
    return encode_float(value) if isinstance(value, float) else value


def write_json(obj: Any, path: str | os.PathLike) -> Path:
    """Write ``obj`` as strict, indented JSON (atomically); returns the path."""
    path = Path(path)
    text = json.dumps(to_jsonable(obj), indent=2, allow_nan=False)
    return write_text(path, text + "\n")


def read_json(path: str | os.PathLike, remedy: str = "write it again") -> Any:
    """Read JSON written by :func:`write_json`; ``"nan"``/``"inf"``/``"-inf"`` become floats.
    A missing, empty or damaged file is one :class:`RunFolderError` line ending in ``remedy``."""

    def parse(path: Path) -> Any:
        try:
            return decode(json.loads(path.read_text(encoding="utf-8")))
        except json.JSONDecodeError as err:
            raise ValueError(f"not valid JSON: {err}") from None

    return read_with(path, parse, remedy)


def numeric_arrays(value: Any) -> Any:
    """Lists of numbers (rectangular, any depth) become arrays (int or float), also in dicts."""
    if isinstance(value, dict):
        return {k: numeric_arrays(v) for k, v in value.items()}
    if isinstance(value, list) and value:
        try:
            array = np.asarray(value)
        except (TypeError, ValueError):  # ragged
            array = None
        if array is not None and array.dtype.kind in "iuf":
            return array
        return [numeric_arrays(v) for v in value]
    return value


# ----------------------------------------------------------------------------- summary table
def format_summary(summary: Mapping[str, Any]) -> str:
    """A readable text table of a (possibly nested) summary.

    Top-level scalars come first, one per line. Sub-tables whose values are scalars (e.g. one
    per propagator) become the columns of one table, rows being their keys; anything nested
    deeper is flattened with dotted keys.
    """
    summary = to_jsonable(summary)
    scalars = {k: v for k, v in summary.items() if not isinstance(v, dict)}
    groups = {k: flatten(v) for k, v in summary.items() if isinstance(v, dict)}
    lines = []
    width = max([len(k) for k in scalars] + [len(k) for g in groups.values() for k in g] + [1])
    for key, value in scalars.items():
        lines.append(f"{key:<{width}}  {_cell(value)}")
    if groups:
        rows: list[str] = []
        for group in groups.values():
            rows += [k for k in group if k not in rows]
        cells = {name: {k: _cell(v) for k, v in g.items()} for name, g in groups.items()}
        widths = {
            name: max([len(name)] + [len(c) for c in col.values()]) for name, col in cells.items()
        }
        if lines:
            lines.append("")
        lines.append(" " * width + "".join(f"  {name:>{widths[name]}}" for name in groups))
        for row in rows:
            lines.append(
                f"{row:<{width}}"
                + "".join(f"  {cells[n].get(row, '—'):>{widths[n]}}" for n in groups)
            )
    return "\n".join(lines) + "\n"


def flatten(table: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested tables as one level of dotted keys (``{"a": {"b": 1}}`` → ``{"a.b": 1}``)."""
    out: dict[str, Any] = {}
    for key, value in table.items():
        if isinstance(value, Mapping):
            out.update(flatten(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def _cell(value: Any) -> str:
    if value is None:
        return "—"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, list):
        flat = np.ravel(np.asarray(decode(value), dtype=object))
        shown = ", ".join(_cell(v) for v in flat[:6])
        return f"[{shown}{', …' if flat.size > 6 else ''}]"
    return str(value)


_JSON_ATTRS = "symplid_json_attrs"


def netcdf_attrs(attrs: Mapping[str, Any]) -> dict[str, Any]:
    """Attributes netCDF can hold as they are; the rest as JSON text, listed in one attribute."""
    out: dict[str, Any] = {}
    encoded = []
    for key, value in attrs.items():
        if _netcdf_ok(value):
            out[key] = value
        else:
            out[key] = json.dumps(to_jsonable(value, key), allow_nan=False)
            encoded.append(key)
    if encoded:
        out[_JSON_ATTRS] = json.dumps(encoded)
    return out


def _netcdf_ok(value: Any) -> bool:
    if isinstance(value, bool | np.bool_):
        return False
    # lists and arrays alike as JSON text: one format however they came
    return isinstance(value, str | int | float | np.integer | np.floating)


def restore_attrs(attrs: dict[str, Any]) -> dict[str, Any]:
    encoded = attrs.pop(_JSON_ATTRS, None)
    if encoded is None:
        return attrs
    for key in json.loads(encoded):
        if key in attrs:
            attrs[key] = numeric_arrays(decode(json.loads(attrs[key])))
    return attrs


def netcdf_bytes(idata: Any) -> bytes:
    """ArviZ ``InferenceData`` as the bytes of a netCDF-4 file (h5netcdf), made in memory: its
    attributes through :func:`netcdf_attrs`, its groups as ``InferenceData.to_netcdf`` writes
    them, so ``arviz.from_netcdf`` reads it back.

    Integer and boolean variables (the sampler's flags) are zlib-compressed; floating-point
    ones (the draws) are stored as they are: random float64 draws hardly compress (the
    paper's 400,000 draws of 11 parameters: 39 MB raw, 31 MB compressed) and compressing them
    took ten times as long as writing them (1.2 s against 0.1 s per fit)."""
    import xarray as xr

    buffer = _io.BytesIO()
    mode = "w"
    top = dict(getattr(idata, "attrs", None) or {})
    if top:
        xr.Dataset(attrs=netcdf_attrs(top)).to_netcdf(buffer, mode=mode, engine="h5netcdf")
        mode = "a"
    for group in idata.groups():
        dataset = getattr(idata, group).copy()
        dataset.attrs = netcdf_attrs(dict(dataset.attrs))
        encoding = {name: {"zlib": True} for name, v in dataset.variables.items()
                    if v.dtype.kind in "biu"}
        dataset.to_netcdf(buffer, mode=mode, group=group, engine="h5netcdf", encoding=encoding)
        mode = "a"
    return buffer.getvalue()
