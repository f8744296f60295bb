"""The paper-claims study: the seed paper's three claims, checked over many data seeds.

The paper draws its conclusions from one realisation of the observation noise. This study
repeats its Hénon–Heiles experiment (Section IV) for N data seeds with both propagators,
leapfrog and RK2 (midpoint), pairs the two fits of each seed (same data), and reports for each
claim the fraction of seeds where it holds:

1. **hamiltonian**: the MAP model's energy H(x0) is closer to the truth with leapfrog
   (``hamiltonian_rel_error`` smaller). Paper: 0.1219 against 0.1211 for a true 0.1227.
2. **process_noise**: the process-noise variance is about ten times smaller with leapfrog. The
   ratio RK2 / leapfrog of the posterior medians is reported as a distribution; the claim
   counts as holding for a seed when the ratio is ≥ √10, i.e. nearer to ten than to one on a
   log scale. The fraction with ratio > 1 (smaller at all) is given beside it.
3. **prediction**: the leapfrog MAP model predicts validly for longer
   (``prediction_horizon_s``, the first time |q1 − q1_true| > 0.1 when integrated by leapfrog
   at dt 0.01 from the true initial state; paper: about 150 s against 20 s). A tie (for example
   both models valid over the whole window) does not count as holding.

A seed whose leapfrog or RK2 cell failed, or whose metric is not finite, is left out of that
claim's fraction and counted as ``undecided`` / ``unpaired``.

Settings, one at a time
-----------------------
Besides the paper's setting (dt = 0.25, σ = 0.05), the learning step takes the values 0.1 and
0.5 with σ at 0.05, and the noise σ takes 0.01 and 0.1 with dt at 0.25: five settings, each
with every seed and both propagators (10·N cells). Varying one setting at a time around the
paper's answers "does the claim survive a change of this setting?" directly and costs 5/9 of the
full 3 × 3 grid; interactions between dt and σ are not explored. ``variants=False`` runs the
paper's setting alone (2·N cells).

:func:`evaluate_claims` is a pure function of the results table (tested on a hand-made table);
:func:`run_paper_claims` runs the sweep and writes ``claims.json``, ``report.md`` and one figure
per claim into the sweep folder.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from symplid.experiments.paper import CELL_KEYS, PaperConfig
from symplid.experiments.paper_study_report import (
    RATIO_THRESHOLD,
    format_claims_report,
    plot_claims,
)
from symplid.plotting.sweep import format_value, plain, rows_matching, same_value, setting_groups
from symplid.workflow.results import write_json
from symplid.workflow.sweep import SweepSpec, run_sweep, sweep_spec_from_dict

__all__ = [
    "CLAIMS",
    "FULL_BUDGET",
    "PAPER_SETTING",
    "QUICK_BUDGET",
    "VARIANTS",
    "evaluate_claims",
    "format_claims_report",
    "paper_claims_spec",
    "plot_claims",
    "run_paper_claims",
]

#: The paper's Hénon–Heiles setting (Section IV), in sweep keys.
PAPER_SETTING: dict[str, Any] = {
    "system": "henon-heiles",
    "noise_std": 0.05,
    "num_obs": 20,
    "obs_interval": 5.0,
    "dt": 0.25,
    "order": 3,
}
#: The settings of the study: the paper's, then one setting changed at a time.
VARIANTS: tuple[dict[str, Any], ...] = (
    {},
    {"dt": 0.1},
    {"dt": 0.5},
    {"noise_std": 0.01},
    {"noise_std": 0.1},
)
PROPAGATORS = ("leapfrog", PaperConfig.rk2)
#: The paper's sampler budget per cell: DRAM, 4 chains of 200,000 iterations (100,000 burn-in).
FULL_BUDGET: dict[str, Any] = {
    "num_iterations": 200_000,
    "burn_in": 100_000,
    "num_chains": 4,
    "num_starts": 4,
}
#: A small budget to try the study out (that of ``symplid reproduce --quick``): minutes, not
#: the paper's posterior quality.
QUICK_BUDGET: dict[str, Any] = {
    "num_iterations": 3_000,
    "burn_in": 1_500,
    "num_chains": 2,
    "num_starts": 2,
}

#: The three claims: the metric compared per seed and how the claim reads.
CLAIMS: dict[str, dict[str, str]] = {
    "hamiltonian": {
        "metric": "hamiltonian_rel_error",
        "statement": "the learned H is closer to the true H with leapfrog than with RK2",
        "paper": "true H 0.1227; MAP H 0.1219 (0.7 %) with leapfrog, 0.1211 (1.3 %) with RK2",
    },
    "process_noise": {
        "metric": "process_noise_median",
        "statement": "the process noise is about ten times smaller with leapfrog "
        "(ratio RK2/leapfrog ≥ √10)",
        "paper": "about an order of magnitude smaller with leapfrog",
    },
    "prediction": {
        "metric": "prediction_horizon_s",
        "statement": "the leapfrog MAP model predicts validly for longer than the RK2 one",
        "paper": "about 150 s with leapfrog against about 20 s with RK2",
    },
}
_NOT_SETTINGS = ("seed", "integrator")


# ----------------------------------------------------------------------------- the sweep
def paper_claims_spec(
    seeds: int = 20,
    quick: bool = False,
    variants: bool = True,
    cell_fn: str | None = None,
) -> SweepSpec:
    """The study's sweep: seeds 0..N−1 × both propagators × the settings of :data:`VARIANTS`.

    Parameters
    ----------
    seeds
        Number of data seeds (0, 1, …, seeds − 1).
    quick
        Use :data:`QUICK_BUDGET` instead of the paper's :data:`FULL_BUDGET`.
    variants
        Include the one-at-a-time variants of dt and σ (else the paper's setting only).
    cell_fn
        The cell function (default: the paper experiment's ``run_cell``).
    """
    if isinstance(seeds, bool) or not isinstance(seeds, int | np.integer) or seeds < 1:
        raise ValueError(f"seeds must be a positive integer, got {seeds!r}")
    budget = QUICK_BUDGET if quick else FULL_BUDGET
    sweep: dict[str, Any] = {
        "name": "paper-claims" + (" (quick)" if quick else ""),
        "grid": {"seed": list(range(int(seeds))), "integrator": list(PROPAGATORS)},
        "cells": [dict(v) for v in (VARIANTS if variants else VARIANTS[:1])],
    }
    if cell_fn is not None:
        sweep["cell_fn"] = cell_fn
    return sweep_spec_from_dict(
        {"base": {**PAPER_SETTING, **budget}, "sweep": sweep}, source="paper-claims study"
    )


def run_paper_claims(
    out_dir: str | os.PathLike,
    seeds: int = 20,
    quick: bool = False,
    scheduler: str | Any | None = None,
    workers: int | None = None,
    *,
    variants: bool = True,
    cell_fn: str | Callable[[dict], Mapping[str, Any]] | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Run the paper-claims study (resumable) and write its claims, figures and report.

    Parameters
    ----------
    out_dir
        The study folder: the sweep's files (``cells/``, ``results.csv``, ``results.parquet``,
        ``sweep.json``), plus ``claims.json``, ``report.md`` and ``figures/claim_*.png``.
    seeds, quick, variants
        See :func:`paper_claims_spec`.
    scheduler, workers, cell_fn, progress
        See :func:`symplid.workflow.sweep.run_sweep`.

    Returns
    -------
    dict
        The content of ``claims.json``: :func:`evaluate_claims`'s result plus ``study`` (seeds,
        budget, cells run / skipped / failed, wall time).
    """
    spec = paper_claims_spec(seeds, quick, variants)
    t0 = time.perf_counter()
    table = run_sweep(spec, out_dir, scheduler, workers, cell_fn, progress=progress)
    wall = time.perf_counter() - t0
    claims = evaluate_claims(table, baseline=PAPER_SETTING, baseline_label="paper setting")
    counts = dict(table.attrs.get("sweep", {}))
    claims["study"] = {
        "seeds": int(seeds),
        "quick": bool(quick),
        "variants": bool(variants),
        "budget": QUICK_BUDGET if quick else FULL_BUDGET,
        "paper_setting": PAPER_SETTING,
        "cells": counts.get("cells", len(table)),
        "cells_run": counts.get("ran"),
        "cells_skipped": counts.get("skipped"),
        "cells_failed": int((table["status"] != "ok").sum()),
        "failures": _failures(table),
        "wall_time_s": wall,
        "workers": workers,
        "scheduler": None if scheduler is None else str(scheduler),
    }
    out = Path(out_dir)
    figures = plot_claims(claims, table, out / "figures")
    claims["study"]["figures"] = {k: str(p.relative_to(out)) for k, p in figures.items()}
    write_json(claims, out / "claims.json")
    text = format_claims_report(claims)
    tmp = out / ".report.md.tmp"
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, out / "report.md")
    return claims


def _failures(table: Any) -> list[dict[str, Any]]:
    bad = table[table["status"] != "ok"]
    return [
        {"cell_id": r.cell_id, "seed": int(r.seed), "integrator": r.integrator, "error": r.error}
        for r in bad.itertuples()
    ]


# ----------------------------------------------------------------------------- aggregation
def evaluate_claims(
    table: Any,
    *,
    symplectic: str = "leapfrog",
    reference: str = PROPAGATORS[1],
    by: Sequence[str] | None = None,
    baseline: Mapping[str, Any] | None = None,
    baseline_label: str = "baseline",
) -> dict[str, Any]:
    """For each claim and each setting, the fraction of data seeds where the claim holds.

    A pure function of the results table (no files, no randomness).

    Parameters
    ----------
    table
        A pandas DataFrame with one row per cell: ``seed``, ``integrator``, ``status``, the
        setting columns and the metrics ``hamiltonian_rel_error``, ``process_noise_median``,
        ``prediction_horizon_s`` (see :data:`CLAIMS`). Only rows with status ``"ok"`` count.
    symplectic, reference
        The two propagators compared (``integrator`` values).
    by
        The columns that define a setting (default: every sweep setting column in the table
        other than ``seed`` and ``integrator``). Rows are paired by seed within a setting.
    baseline
        A reference setting; settings are then labelled by what differs from it
        (``"dt=0.1"``), and the baseline itself ``baseline_label``. Without it, labels list the
        columns that vary in the table.

    Returns
    -------
    dict
        ``{"symplectic", "reference", "settings": [...], "claims": {name: {"statement",
        "metric", "paper", "per_setting": [...]}}}``. Each ``per_setting`` entry has ``label``,
        ``n`` (seeds judged), ``holds``, ``fraction`` (holds / n; None when n = 0), ``undecided``
        (seeds with a missing or non-finite value), the medians of the metric for each
        propagator, and for ``process_noise`` the distribution of the ratio (``ratio``:
        median, quartiles, 10 % and 90 % quantiles, geometric mean, min, max) and
        ``fraction_smaller`` (ratio > 1); for ``prediction`` the ``ties``.

    Raises
    ------
    ValueError
        A missing column, or two ok rows for the same setting, seed and propagator.
    """
    import pandas as pd

    need = {"seed", "integrator", "status"}
    missing = sorted(need - set(table.columns))
    if missing:
        raise ValueError(f"the results table has no column {', '.join(missing)}")
    if by is None:
        by = [c for c in table.columns if (c in CELL_KEYS or "." in c) and c not in _NOT_SETTINGS]
    by = list(by)
    for col in by:
        if col not in table.columns:
            raise ValueError(f"the results table has no setting column {col!r}")
    for spec in CLAIMS.values():
        if spec["metric"] not in table.columns:
            raise ValueError(f"the results table has no metric column {spec['metric']!r}")

    ok = table[(table["status"] == "ok") & table["integrator"].isin([symplectic, reference])]
    groups = setting_groups(table, by)
    varying = [c for c in by if table[c].nunique(dropna=False) > 1]
    result: dict[str, Any] = {
        "symplectic": symplectic,
        "reference": reference,
        "ratio_threshold": RATIO_THRESHOLD,
        "settings": [],
        "claims": {name: {**spec, "per_setting": []} for name, spec in CLAIMS.items()},
    }
    for values in groups:
        label = _label(values, varying, baseline, baseline_label)
        rows = rows_matching(ok, values)
        seeds_all = rows_matching(table, values)["seed"].unique()
        dup = rows.duplicated(["seed", "integrator"])
        if dup.any():
            first = rows[dup].iloc[0]
            raise ValueError(
                f"setting {label}: more than one ok row for seed {first['seed']} and "
                f"integrator {first['integrator']!r}"
            )
        sym = rows[rows["integrator"] == symplectic].set_index("seed")
        ref = rows[rows["integrator"] == reference].set_index("seed")
        paired = sorted(set(sym.index) & set(ref.index))
        result["settings"].append(
            {
                "label": label,
                "values": {k: plain(v) for k, v in values.items()},
                "seeds": len(seeds_all),
                "pairs": len(paired),
                "unpaired": len(seeds_all) - len(paired),
            }
        )
        for name, spec in CLAIMS.items():
            metric = spec["metric"]
            a = pd.to_numeric(sym.loc[paired, metric], errors="coerce").to_numpy(float)
            b = pd.to_numeric(ref.loc[paired, metric], errors="coerce").to_numpy(float)
            entry = _judge(name, a, b)
            entry = {"label": label, "unpaired": len(seeds_all) - len(paired), **entry}
            result["claims"][name]["per_setting"].append(entry)
    return result


def _judge(name: str, sym: np.ndarray, ref: np.ndarray) -> dict[str, Any]:
    """One claim over paired seeds: symplectic values ``sym``, reference values ``ref``."""
    finite = np.isfinite(sym) & np.isfinite(ref)
    if name == "process_noise":
        finite &= (sym > 0) & (ref > 0)
    s, r = sym[finite], ref[finite]
    n = int(finite.sum())
    out: dict[str, Any] = {"n": n, "undecided": int((~finite).sum())}
    if name == "hamiltonian":
        holds = s < r
    elif name == "process_noise":
        ratio = r / s
        holds = ratio >= RATIO_THRESHOLD
        out["fraction_smaller"] = _fraction(int((ratio > 1).sum()), n)
        out["ratio"] = _distribution(ratio)
    else:
        holds = s > r
        out["ties"] = int((s == r).sum())
    out["holds"] = int(holds.sum())
    out["fraction"] = _fraction(out["holds"], n)
    out["median_symplectic"] = float(np.median(s)) if n else None
    out["median_reference"] = float(np.median(r)) if n else None
    return out


def _fraction(k: int, n: int) -> float | None:
    return k / n if n else None


def _distribution(x: np.ndarray) -> dict[str, float | None]:
    if x.size == 0:
        return dict.fromkeys(("median", "q10", "q25", "q75", "q90", "geometric_mean", "min", "max"))
    q = np.quantile(x, [0.1, 0.25, 0.5, 0.75, 0.9])
    return {
        "median": float(q[2]),
        "q10": float(q[0]),
        "q25": float(q[1]),
        "q75": float(q[3]),
        "q90": float(q[4]),
        "geometric_mean": float(np.exp(np.mean(np.log(x)))),
        "min": float(x.min()),
        "max": float(x.max()),
    }


def _label(
    values: Mapping[str, Any],
    varying: list[str],
    baseline: Mapping[str, Any] | None,
    baseline_label: str,
) -> str:
    if baseline is not None:
        diff = [
            c for c in values if c in baseline and not same_value(plain(values[c]), baseline[c])
        ]
        diff += [c for c in varying if c not in baseline and c not in diff]
        return ", ".join(f"{c}={format_value(values[c])}" for c in diff) or baseline_label
    return ", ".join(f"{c}={format_value(values[c])}" for c in varying) or "all cells"

