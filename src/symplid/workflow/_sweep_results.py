"""The results table of a sweep: one row per cell from the cell records, as CSV and Parquet."""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from symplid.workflow._results import read_json
from symplid.workflow._sweep_spec import SweepError, SweepSpec

__all__ = ["CELLS_DIR", "MANIFEST", "load_results", "write_table"]

CELLS_DIR = "cells"
MANIFEST = "sweep.json"
RESULTS_CSV = "results.csv"
RESULTS_PARQUET = "results.parquet"

_BOOKKEEPING = ("cell_id", "status", "elapsed_s", "error", "warnings", "started", "finished")


def load_results(out_dir: str | os.PathLike, spec: SweepSpec | None = None) -> Any:
    """The results table of a sweep folder, from its cell records (pandas DataFrame).

    One row per cell of ``spec`` (default: the cells listed in the folder's ``sweep.json``), in
    the spec's order; a cell without a record has status ``"pending"``. Metric columns that
    would clash with a settings or bookkeeping column are prefixed ``metric_``.
    """
    import pandas as pd

    out = Path(out_dir)
    if spec is not None:
        cells = [(c.id, c.settings) for c in spec.cells]
    else:
        manifest = out / MANIFEST
        if not manifest.exists():
            raise SweepError(str(out), None, f"not a sweep folder (no {MANIFEST})")
        cells = [(c["id"], c["settings"]) for c in read_json(manifest)["cells"]]
    rows = []
    setting_cols: list[str] = []
    metric_cols: list[str] = []
    for cid, settings in cells:
        for k in settings:
            if k not in setting_cols:
                setting_cols.append(k)
        path = out / CELLS_DIR / f"{cid}.json"
        record = read_json(path) if path.exists() else {"status": "pending"}
        row = {"cell_id": cid, **settings}
        row["status"] = record.get("status", "pending")
        for key in ("elapsed_s", "error", "started", "finished"):
            row[key] = record.get(key)
        row["warnings"] = " | ".join(record.get("warnings") or []) or None
        for k, v in _flatten(record.get("metrics") or {}).items():
            name = f"metric_{k}" if k in settings or k in _BOOKKEEPING else k
            if name not in metric_cols:
                metric_cols.append(name)
            row[name] = v
        rows.append(row)
    columns = ["cell_id", *setting_cols, "status", "elapsed_s", *metric_cols, "error", "warnings"]
    columns += ["started", "finished"]
    table = pd.DataFrame(rows, columns=columns)
    return _tidy_types(table)


def _flatten(metrics: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in metrics.items():
        if isinstance(v, Mapping):
            out.update(_flatten(v, f"{prefix}{k}."))
        elif isinstance(v, list):
            out[f"{prefix}{k}"] = json.dumps(v)
        else:
            out[f"{prefix}{k}"] = v
    return out


def _tidy_types(table: Any) -> Any:
    """Object columns of numbers become float; mixed ones become strings (Parquet-safe)."""
    import pandas as pd

    for col in table.columns:
        if table[col].dtype != object:
            continue
        values = table[col].dropna()
        if values.empty:
            continue
        if all(isinstance(v, bool) for v in values):
            continue
        if all(isinstance(v, int | float) and not isinstance(v, bool) for v in values):
            table[col] = pd.to_numeric(table[col], errors="coerce").astype(float)
        elif not all(isinstance(v, str) for v in values):
            table[col] = table[col].map(lambda v: None if v is None else str(v))
    return table


def write_table(table: Any, out: Path) -> None:
    """Write ``results.csv`` and ``results.parquet`` into ``out``, each atomically."""
    for name, write in (
        (RESULTS_CSV, lambda p: table.to_csv(p, index=False)),
        (RESULTS_PARQUET, lambda p: table.to_parquet(p, index=False)),
    ):
        path = out / name
        tmp = path.with_name(f".{name}.tmp")
        write(tmp)
        os.replace(tmp, path)
