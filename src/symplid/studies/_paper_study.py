"""The paper-claims study: the seed paper's three claims and its calibration over many seeds.

The paper draws its conclusions from one realisation of the observation noise. This study
repeats its Hénon–Heiles experiment (Section IV) for N data seeds with leapfrog and RK2
(midpoint), pairs the two fits of each seed (same data), and reports per claim and setting the
fraction of seeds where it holds, with a Wilson 95 % interval, and the paired median effect
with a bootstrap 95 % interval (:mod:`._paper_claims`):

1. **hamiltonian**: the MAP model's H(x0) is closer to the truth with leapfrog (paper: 0.1219
   against 0.1211 for a true 0.1227). Effect: the difference of relative errors, leapfrog −
   RK2 (negative favours leapfrog).
2. **process_noise**: the process-noise variance (posterior median) is at least
   :data:`~._paper_claims.RATIO_THRESHOLD` (5) times smaller with leapfrog (paper: about ten
   times). Effect: the ratio RK2 / leapfrog.
3. **prediction**: the leapfrog MAP model predicts validly for longer (the first time
   |q1 − q1_true| > 0.1, leapfrog at dt 0.01 from the true initial state; paper: about 150 s
   against 20 s). A tie does not count. Effect: the ratio leapfrog / RK2.

**Calibration** (:mod:`._paper_calibration`): every fit records, for each coefficient and the
observation-noise variance, whether its central 95 % interval contains the truth and the rank
of the truth among 99 thinned draws. yoshida4 is fitted at the paper's setting besides the two
propagators, and the dt = 0.1 variant gives leapfrog at a smaller step: together they say
whether a more accurate propagator restores nominal coverage.

Variants, one setting at a time
-------------------------------
:data:`VARIANTS` is the list: the paper's setting (dt 0.25, σ 0.05, 20 observations, process
noise per gap, RK2 midpoint), then one change each: dt ∈ {0.1, 0.5}, σ ∈ {0.01, 0.1},
observations ∈ {10, 40}, process noise per integration step, RK2 Heun as the reference. A
variant is data: the cell keys it changes, the reference propagator, and the extra propagators
fitted for calibration alone. Cells shared by two variants (leapfrog under "RK2 Heun" is the
paper's leapfrog) are run once.

Two variants are fitted for the calibration alone, leapfrog and yoshida4 each, with no
reference (``reference=None``: no RK2 cell is run, and every claim reads *n/a* there, since
each compares leapfrog with the reference on the same data): ``no-process-noise``, the
deterministic-trajectory likelihood (``model.process_noise_per = "none"``; its MAP search
starts from the filter's MAP, :func:`symplid.workflow._fit.find_map_for`), and ``log-uniform``,
the log-uniform prior on the process variance (``priors.process_var``). They answer whether
the intervals reach their nominal coverage once Σ no longer shifts the coefficients. A variant
with a reference may also name the claims that apply (``claims``).

:func:`run_paper_claims` runs the sweep (resumable: a rerun skips finished cells) and writes
``claims.json``, ``report.md`` and the figures into the sweep folder.
"""

from __future__ import annotations

import datetime
import os
import platform
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from symplid.studies._paper import EXPERIMENT, PaperConfig
from symplid.studies._paper_claims import CLAIMS, evaluate_claims
from symplid.studies._paper_study_report import format_claims_report, plot_claims
from symplid.workflow._results import read_json, write_json
from symplid.workflow._sweep import SweepSpec, run_sweep, sweep_spec_from_dict
from symplid.workflow._sweep_results import CELLS_DIR, load_results

__all__ = [
    "BUDGETS",
    "CLAIMS",
    "FULL_BUDGET",
    "PAPER_SETTING",
    "QUICK_BUDGET",
    "VARIANTS",
    "Variant",
    "estimate_cost",
    "evaluate_claims",
    "paper_claims_spec",
    "parse_budget",
    "run_paper_claims",
    "select_variants",
]

SYMPLECTIC = "leapfrog"
#: The status of a cell not run yet (:func:`~symplid.workflow._sweep_results.load_results`).
PENDING = "pending"
REFERENCE = PaperConfig.rk2

#: The paper's Hénon–Heiles setting (Section IV), in sweep keys.
PAPER_SETTING: dict[str, Any] = {
    "system": "henon-heiles",
    "noise_std": 0.05,
    "num_obs": 20,
    "obs_interval": 5.0,
    "dt": 0.25,
    "order": 3,
    "model.process_noise_per": "gap",
}


@dataclass(frozen=True)
class Variant:
    """One setting of the study: what changes from :data:`PAPER_SETTING`, and who is fitted.

    ``keys`` are cell keys (short or dotted); ``reference`` is the propagator leapfrog is
    compared with, or ``None`` for a variant fitted for the calibration alone (no reference
    cells are run and no claim is judged: each reads *n/a*); ``extra`` are propagators
    fitted for the calibration alone; ``claims`` names the claims of :data:`CLAIMS` that
    apply (``None``: all of them, when there is a reference).
    """

    name: str
    keys: Mapping[str, Any] = field(default_factory=dict)
    reference: str | None = REFERENCE
    extra: tuple[str, ...] = ()
    description: str = ""
    claims: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        unknown = sorted(set(self.claims or ()) - set(CLAIMS))
        if unknown:
            raise ValueError(f"variant {self.name}: unknown claim(s) {', '.join(unknown)}")

    def setting(self) -> dict[str, Any]:
        """The variant's full setting (without the propagator)."""
        return {**PAPER_SETTING, **self.keys}

    def propagators(self) -> tuple[str, ...]:
        """The propagators fitted: leapfrog, the reference (if any), the extras."""
        reference = () if self.reference is None else (self.reference,)
        return (SYMPLECTIC, *reference, *self.extra)

    def applicable_claims(self) -> tuple[str, ...]:
        """The claims judged in this variant (none without a reference)."""
        if self.reference is None:
            return ()
        return tuple(CLAIMS) if self.claims is None else tuple(self.claims)


#: The paper's setting first, then one setting changed at a time.
VARIANTS: tuple[Variant, ...] = (
    Variant("paper", extra=("yoshida4",), description="the paper's setting"),
    Variant("dt=0.1", {"dt": 0.1}, description="learning step 0.1"),
    Variant("dt=0.5", {"dt": 0.5}, description="learning step 0.5"),
    Variant("noise=0.01", {"noise_std": 0.01}, description="noise σ 0.01"),
    Variant("noise=0.1", {"noise_std": 0.1}, description="noise σ 0.1"),
    Variant("obs=10", {"num_obs": 10}, description="10 observations"),
    Variant("obs=40", {"num_obs": 40}, description="40 observations"),
    Variant(
        "noise-per-step",
        {"model.process_noise_per": "step"},
        description="process noise per integration step",
    ),
    Variant("rk2-heun", reference="rk2-heun", description="RK2 Heun as the reference"),
    Variant(
        "no-process-noise",
        {"model.process_noise_per": "none"},
        reference=None,
        extra=("yoshida4",),
        description="the deterministic-trajectory likelihood (no process noise), "
        "calibration only",
    ),
    Variant(
        "log-uniform",
        {"priors.process_var": "log-uniform"},
        reference=None,
        extra=("yoshida4",),
        description="a log-uniform prior on the process variance, calibration only",
    ),
)

#: The paper's sampler budget per cell: DRAM, 4 chains of 200,000 iterations (100,000 burn-in).
FULL_BUDGET: dict[str, Any] = {
    "num_iterations": 200_000,
    "burn_in": 100_000,
    "num_chains": 4,
    "num_starts": 4,
}
#: A small budget to try the study out (that of ``symplid reproduce --quick``).
QUICK_BUDGET: dict[str, Any] = {
    "num_iterations": 3_000,
    "burn_in": 1_500,
    "num_chains": 2,
    "num_starts": 2,
}
BUDGETS = {"paper": FULL_BUDGET, "quick": QUICK_BUDGET}
#: Sampler seconds per 1,000 iterations of one chain at the paper's setting (medians over the
#: study's own cells at the paper's budget, two workers on two cores, four vectorised chains
#: with paired stages on the compiled kernel), for the cost estimate and the order of the cells
#: (the longest first, so that workers finish together).
SECONDS_PER_KILO_ITER = {"leapfrog": 0.034, "rk2-midpoint": 0.042, "rk2-heun": 0.042,
                         "yoshida4": 0.092}
CELL_OVERHEAD_S = 10.0  # MAP, diagnostics, predictions (cell time minus sampler time)
#: Cost of process noise per integration step relative to per gap (a sigma-point Cholesky
#: at every step; 0.128 against 0.034 s per 1,000 iterations for leapfrog in the same study).
PER_STEP_FACTOR = 3.8


def parse_budget(budget: str | int) -> tuple[str, dict[str, Any]]:
    """``"paper"``, ``"quick"`` or a number of iterations per chain (half burn-in, the paper's
    chains and starts). Returns the label and the sweep keys."""
    if isinstance(budget, str) and budget in BUDGETS:
        return budget, dict(BUDGETS[budget])
    try:
        n = int(str(budget).replace("_", "").replace(",", ""))
    except ValueError:
        n = 0
    if n < 2:
        raise ValueError(
            f"budget must be 'paper', 'quick' or a number of iterations ≥ 2, got {budget!r}"
        )
    return str(n), {**FULL_BUDGET, "num_iterations": n, "burn_in": n // 2}


def select_variants(names: str | Sequence[str] | bool | None = "all") -> tuple[Variant, ...]:
    """``"all"``, ``"none"`` (the paper's setting alone) or variant names (comma-separated or
    a list); the paper's setting is always included, first."""
    if names is True or names is None or names == "all":
        return VARIANTS
    if names is False or names == "none":
        return VARIANTS[:1]
    wanted = [n.strip() for n in (names.split(",") if isinstance(names, str) else names)]
    known = {v.name: v for v in VARIANTS}
    unknown = [n for n in wanted if n and n not in known]
    if unknown:
        raise ValueError(
            f"unknown variant {', '.join(map(repr, unknown))}; the variants are "
            f"{', '.join(known)} (or 'all', 'none')"
        )
    return tuple(v for v in VARIANTS if v.name == "paper" or v.name in wanted)


def _entries(variants: Sequence[Variant]) -> list[dict[str, Any]]:
    """The distinct (setting, propagator) entries of the variants, the costliest first."""
    seen: dict[str, dict[str, Any]] = {}
    for v in variants:
        for integ in v.propagators():
            entry = {**v.keys, "integrator": integ}
            seen.setdefault(repr(sorted(entry.items())), entry)
    return sorted(seen.values(), key=lambda e: -_relative_cost(e))


def _relative_cost(entry: Mapping[str, Any]) -> float:
    s = {**PAPER_SETTING, **entry}
    rate = SECONDS_PER_KILO_ITER.get(str(s["integrator"]), 0.08)
    if s.get("model.process_noise_per") == "step":
        rate *= PER_STEP_FACTOR
    return rate * (PAPER_SETTING["dt"] / s["dt"]) * (s["num_obs"] / PAPER_SETTING["num_obs"])


def paper_claims_spec(
    seeds: int = 20,
    budget: str | int = "paper",
    variants: str | Sequence[str] | bool | None = "all",
    cell_fn: str | None = None,
) -> SweepSpec:
    """The study's sweep: seeds 0..N−1 × the (setting, propagator) entries of the variants."""
    if isinstance(seeds, bool) or not isinstance(seeds, int | np.integer) or seeds < 1:
        raise ValueError(f"seeds must be a positive integer, got {seeds!r}")
    label, keys = parse_budget(budget)
    sweep: dict[str, Any] = {
        "name": "paper-claims" + ("" if label == "paper" else f" ({label})"),
        "grid": {"seed": list(range(int(seeds)))},
        "cells": _entries(select_variants(variants)),
    }
    if cell_fn is not None:
        sweep["cell_fn"] = cell_fn
    return sweep_spec_from_dict(
        {"base": {**PAPER_SETTING, **keys}, "sweep": sweep}, source="paper-claims study",
        experiment=EXPERIMENT,
    )


def estimate_cost(spec: SweepSpec, workers: int = 1) -> dict[str, float]:
    """Estimated seconds of the study: the sum over cells of one core's time, and the wall
    time on ``workers`` cores (longest cells first, greedy)."""
    times = []
    for c in spec.cells:
        s = c.settings
        chains_kilo = s["num_chains"] * s["num_iterations"] / 1000.0
        times.append(CELL_OVERHEAD_S + chains_kilo * _relative_cost(s))
    loads = [0.0] * max(1, int(workers))
    for t in sorted(times, reverse=True):
        loads[loads.index(min(loads))] += t
    return {"cells": len(times), "core_s": float(sum(times)), "wall_s": float(max(loads))}


def run_paper_claims(
    out_dir: str | os.PathLike,
    seeds: int = 20,
    budget: str | int = "paper",
    scheduler: str | Any | None = None,
    workers: int | None = None,
    *,
    variants: str | Sequence[str] | bool | None = "all",
    cell_fn: str | Callable[[dict], Mapping[str, Any]] | None = None,
    progress: bool = True,
    report_only: bool = False,
) -> dict[str, Any]:
    """Run the paper-claims study (resumable) and write its claims, figures and report.

    Parameters
    ----------
    out_dir
        The study folder: the sweep's files (``cells/``, ``results.csv``, ...), plus
        ``claims.json``, ``report.md`` and ``figures/claim_*.png``, ``figures/calibration_*``.
    seeds, budget, variants
        See :func:`paper_claims_spec`.
    scheduler, workers, cell_fn, progress
        See :func:`symplid.workflow._sweep.run_sweep`.
    report_only
        Run nothing: judge the cells the folder already holds (an interrupted or partly run
        study); the cells not run yet are counted as pending and left out of every fraction.

    Returns
    -------
    dict
        The content of ``claims.json``: :func:`~._paper_claims.evaluate_claims`'s result plus
        ``study`` (seeds, budget, variants, cells run / skipped / failed, wall and cell times,
        versions).
    """
    chosen = select_variants(variants)
    label, keys = parse_budget(budget)
    spec = paper_claims_spec(seeds, budget, [v.name for v in chosen], cell_fn=None)
    out = Path(out_dir)
    started = datetime.datetime.now(datetime.UTC).isoformat(timespec="microseconds")
    t0 = time.perf_counter()
    if report_only:
        if not (out / CELLS_DIR).is_dir():
            raise FileNotFoundError(f"{out}: no cells to report on (run the study there first)")
        table = load_results(out_dir, spec)
    else:
        table = run_sweep(spec, out_dir, scheduler, workers, cell_fn, progress=progress,
                          figures=False, experiment=EXPERIMENT)
    wall = time.perf_counter() - t0
    claims = evaluate_claims(table, chosen, symplectic=SYMPLECTIC)
    claims["study"] = _study_record(table, seeds, label, keys, chosen, wall, workers, scheduler)
    claims["study"]["runs"] = _runs(out / "claims.json", table, started, wall, workers,
                                    scheduler)
    figures = plot_claims(claims, out / "figures")
    claims["study"]["figures"] = {k: str(p.relative_to(out)) for k, p in figures.items()}
    write_json(claims, out / "claims.json")
    tmp = out / ".report.md.tmp"
    tmp.write_text(format_claims_report(claims), encoding="utf-8")
    os.replace(tmp, out / "report.md")
    return claims


def _study_record(table: Any, seeds: int, label: str, keys: dict[str, Any],
                  chosen: Sequence[Variant], wall: float, workers: int | None,
                  scheduler: Any) -> dict[str, Any]:
    """``claims.json``'s ``study``: what was run, how long it took, with which versions."""
    counts = dict(table.attrs.get("sweep", {}))
    names = [v.name for v in chosen]
    return {
        "seeds": int(seeds),
        "budget_name": label,
        "budget": keys,
        "paper_setting": PAPER_SETTING,
        "variants": [_describe(v) for v in chosen],
        "cells": counts.get("cells", len(table)),
        # (--report-only runs nothing: every finished cell counts as already done)
        "cells_run": counts.get("ran", 0),
        "cells_skipped": counts.get("skipped", int((table["status"] != PENDING).sum())),
        "cells_failed": int((~table["status"].isin(["ok", PENDING])).sum()),
        "cells_pending": int((table["status"] == PENDING).sum()),
        "failures": _failures(table),
        "wall_time_s": wall,
        **_cell_times(table),
        "workers": workers,
        "scheduler": None if scheduler is None else str(scheduler),
        "estimate_paper_budget": {
            f"{w}_workers": estimate_cost(paper_claims_spec(seeds, "paper", names), w)
            for w in (1, 2)
        },
        "cost_model": {"seconds_per_kilo_iteration": SECONDS_PER_KILO_ITER,
                       "cell_overhead_s": CELL_OVERHEAD_S, "per_step_factor": PER_STEP_FACTOR},
        "versions": _versions(),
    }


def _describe(v: Variant) -> dict[str, Any]:
    return {"name": v.name, "keys": dict(v.keys), "reference": v.reference,
            "extra": list(v.extra), "description": v.description}


def _cell_times(table: Any) -> dict[str, Any]:
    """Seconds per cell by propagator (median of ``elapsed_s``) and their sum."""
    ok = table[table["status"] == "ok"]
    per = {
        str(k): float(np.median(g["elapsed_s"].astype(float)))
        for k, g in ok.groupby("integrator")
    }
    return {"cell_seconds_total": float(ok["elapsed_s"].astype(float).sum()),
            "cell_seconds_median": per}


def _runs(path: Path, table: Any, started: str, wall: float, workers: int | None,
          scheduler: Any) -> list[dict[str, Any]]:
    """The calls that ran cells, oldest first: the earlier ones from ``claims.json``, then
    this one (when it ran any) with its wall time, the seconds of the cells it ran, and the
    parallel speed-up (those seconds over the wall time)."""
    runs: list[dict[str, Any]] = []
    if path.exists():
        try:
            old = read_json(path).get("study", {})
        except Exception:  # an unreadable old file: start the history again
            old = {}
        runs = list(old.get("runs") or [])
        if not runs and old.get("cells_run"):  # a claims.json from before the history
            runs = [{"started": None, "wall_time_s": old.get("wall_time_s"),
                     "cells_run": old["cells_run"], "cell_seconds": old.get("cell_seconds_total"),
                     "speedup": old.get("speedup"), "workers": old.get("workers"),
                     "scheduler": old.get("scheduler")}]
    now = table[table["started"].fillna("") >= started] if "started" in table else table[:0]
    if len(now):
        seconds = float(now["elapsed_s"].astype(float).sum())
        runs.append({
            "started": started, "wall_time_s": wall, "cells_run": len(now),
            "cell_seconds": seconds, "speedup": seconds / wall if wall > 0 else None,
            "workers": workers, "scheduler": None if scheduler is None else str(scheduler),
        })
    return runs


def _versions() -> dict[str, str]:
    import jax
    import scipy

    import symplid

    return {"symplid": symplid.__version__, "jax": jax.__version__, "numpy": np.__version__,
            "scipy": scipy.__version__, "python": platform.python_version()}


def _failures(table: Any) -> list[dict[str, Any]]:
    bad = table[~table["status"].isin(["ok", PENDING])]
    return [
        {"cell_id": r.cell_id, "seed": int(r.seed), "integrator": r.integrator, "error": r.error}
        for r in bad.itertuples()
    ]
