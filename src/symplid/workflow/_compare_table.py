"""The comparison table: one row per candidate of :func:`~symplid.workflow._compare.compare_models`,
best first, its readable text and its files.

The table (a :class:`pandas.DataFrame`, best first) has one row per candidate:

========================  ==================================================================
``rank``                  1 = the largest Laplace log evidence
``order``, ``integrator``  the candidate
``damping``               whether it learns a damping rate γ (:mod:`symplid.dynamics._damping`)
``process_noise``         where its process noise enters (``model.process_noise_per``):
                          ``gap``, ``step``, or ``none`` (no Σ: the deterministic-trajectory
                          likelihood, :mod:`symplid.model._deterministic`)
``gamma``                 its MAP γ (NaN for an undamped candidate)
``num_params``            the size of θ (coefficients, variances, learned initial states)
``log_likelihood``        log L(θ*) at the MAP (Theorem 1, by the UKF)
``log_posterior``         log π(θ*) + log L(θ*), the unnormalised log posterior at the MAP
``log_evidence``          the log evidence (NaN if the Hessian was not finite)
``delta_log_evidence``    log evidence minus the best one (0 for rank 1, negative below)
``probability``           posterior probability of the candidate among those compared,
                          with equal prior probabilities: softmax of the log evidences
``bic``                   −2 log L(θ*) + num_params · log n, n = the number of measured
                          values (a cruder, prior-free score; lower is better)
``process_var``           MAP process-noise variance (the mean when ``noise = "diagonal"``)
``obs_var``               MAP observation-noise variance (the same; NaN for purely
                          multiplicative noise, whose relative variances are in map.json)
``at_bounds``             parameters whose MAP sits on a bound and whose integral in the
                          evidence is rougher for it (comma separated; the "on a bound"
                          flag): every parameter on a bound except the variances that
                          the evidence integrated by quadrature, for which a MAP on the
                          floor is no problem (all of them when the method is "laplace")
``at_floor``              variances (and γ) whose MAP sits on their floor (information only)
``evidence_method``       how the evidence was computed: ``quadrature`` (isotropic noise),
                          ``axis-quadrature`` (more variances), ``laplace``
``log_evidence_laplace``  the plain Laplace approximation, for comparison
``converged``             whether the best MAP start reported convergence
``map_seconds``           wall time of the MAP search, Hessian and evidence (compilation
                          included)
``<coefficient>``         one column per coefficient name met among the candidates (``c[q1]``,
                          ``c[q1^2]``, ...): the candidate's MAP value, blank where it lacks it
========================  ==================================================================

With ``out``, the table is written to ``out/compare.csv`` and ``out/compare.txt`` (the
readable table that :func:`format_table` prints).

"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from symplid.io._files import write_text
from symplid.model._params import POSITIVE_GROUPS
from symplid.workflow._settings import Settings

__all__ = [
    "COLUMNS",
    "CandidateFit",
    "comparison_table",
    "format_table",
    "num_measured",
    "write_comparison",
]

COLUMNS = (
    "rank",
    "order",
    "integrator",
    "damping",
    "process_noise",
    "gamma",
    "num_params",
    "log_likelihood",
    "log_posterior",
    "log_evidence",
    "delta_log_evidence",
    "probability",
    "bic",
    "process_var",
    "obs_var",
    "at_bounds",
    "at_floor",
    "evidence_method",
    "log_evidence_laplace",
    "converged",
    "map_seconds",
    "model",
)
"""The fixed columns of the comparison table, in order; the MAP coefficients follow, one
column per coefficient name."""


@dataclass(frozen=True)
class CandidateFit:
    """One candidate of a comparison: its settings, posterior and MAP (with the Hessian)."""

    order: int
    integrator: str
    settings: Settings
    posterior: Any
    map_result: Any
    log_likelihood: float
    seconds: float
    damping: bool = False
    model: str = "polynomial"
    """The candidate's model: its family's name, or a label (a settings file's name)."""
    process_noise: str = "gap"
    """``model.process_noise_per`` of the candidate (``"none"``: no process noise)."""


def _gamma(fit: CandidateFit) -> float:
    """The MAP damping rate of a damped candidate (NaN otherwise)."""
    names = list(getattr(fit.posterior, "param_names", ()))
    if not fit.damping or "gamma" not in names:
        return math.nan
    return float(np.asarray(fit.map_result.theta)[names.index("gamma")])


def num_measured(fit: CandidateFit) -> int:
    return int(sum(int(np.sum(d.mask)) for d in fit.posterior.datasets))


def _group_mean(fit: CandidateFit, group: str) -> float:
    groups = np.asarray(fit.posterior.param_groups)
    values = np.asarray(fit.map_result.theta)[groups == group]
    return float(np.mean(values)) if values.size else math.nan


def _coefficients(fit: CandidateFit) -> dict[str, float]:
    """``{coefficient name: MAP value}`` of a candidate."""
    names = getattr(fit.posterior, "param_names", None)
    if names is None:
        return {}
    groups = tuple(fit.posterior.param_groups)
    theta = np.asarray(fit.map_result.theta, dtype=float)
    return {str(n): float(v) for n, g, v in zip(names, groups, theta, strict=True)
            if g in ("coefficients", "parameters")}


def _bound_flags(fit: CandidateFit) -> tuple[str, str]:
    """(the "on a bound" flag, the variances on their floor) of a candidate (module
    docstring: a variance integrated by quadrature is not flagged)."""
    r = fit.map_result
    integrated = set(getattr(r, "evidence", {}).get("variances", ()))
    groups = dict(zip(getattr(fit.posterior, "param_names", ()), fit.posterior.param_groups,
                      strict=False))
    floor = [n for n in r.at_bounds if groups.get(n) in POSITIVE_GROUPS]
    flagged = [n for n in r.at_bounds if n not in integrated]
    return ",".join(flagged), ",".join(floor)


def comparison_table(fits: Sequence[CandidateFit]) -> pd.DataFrame:
    """The ranked table of :data:`COLUMNS` and the MAP coefficients (module docstring)."""
    if not fits:
        raise ValueError("no candidates to compare")
    rows, coefficient_rows = [], []
    coefficient_columns: list[str] = []
    for fit in fits:
        r = fit.map_result
        k = int(fit.posterior.num_params)
        n = num_measured(fit)
        coefficients = _coefficients(fit)
        coefficient_columns += [c for c in coefficients if c not in coefficient_columns]
        flagged, floor = _bound_flags(fit)
        rows.append(
            {
                "order": int(fit.order),
                "integrator": fit.integrator,
                "damping": bool(fit.damping),
                "process_noise": str(fit.process_noise),
                "gamma": _gamma(fit),
                "num_params": k,
                "log_likelihood": float(fit.log_likelihood),
                "log_posterior": float(r.log_posterior),
                "log_evidence": float(r.log_evidence),
                "bic": -2.0 * float(fit.log_likelihood) + k * math.log(max(n, 1)),
                "process_var": _group_mean(fit, "process_var"),
                "obs_var": _group_mean(fit, "obs_var"),
                "at_bounds": flagged,
                "at_floor": floor,
                "evidence_method": str(getattr(r, "evidence_method", "laplace")),
                "log_evidence_laplace": float(getattr(r, "log_evidence_laplace",
                                                      r.log_evidence)),
                "converged": bool(r.success),
                "map_seconds": float(fit.seconds),
                "model": fit.model,
            }
        )
        coefficient_rows.append(coefficients)
    # a coefficient named like a fixed column gets "coef:" in front
    extra = [f"coef:{c}" if c in COLUMNS else c for c in coefficient_columns]
    coefs = pd.DataFrame(coefficient_rows, columns=coefficient_columns, dtype=float)
    df = pd.concat([pd.DataFrame(rows), coefs.set_axis(extra, axis=1)], axis=1)
    evidence = df["log_evidence"].to_numpy(dtype=float)
    finite = np.isfinite(evidence)
    best = float(np.max(evidence[finite])) if finite.any() else math.nan
    df["delta_log_evidence"] = evidence - best
    weights = np.where(finite, np.exp(np.where(finite, evidence - best, 0.0)), 0.0)
    total = float(np.sum(weights))
    df["probability"] = weights / total if total > 0 else np.nan
    # Best evidence first; NaN evidences last, ordered among themselves by BIC.
    df["_key"] = np.where(finite, -evidence, np.inf)
    df = df.sort_values(["_key", "bic"], kind="stable").drop(columns="_key")
    df.insert(0, "rank", np.arange(1, len(df) + 1))
    return df.reset_index(drop=True)[[*COLUMNS, *extra]]


def format_table(table: pd.DataFrame, title: str | None = None) -> str:
    """The comparison table as aligned text (what ``compare.txt`` holds)."""
    by_model = any(m != "polynomial" for m in table["model"])
    header = (
        "rank", "model" if by_model else "order", "integrator", "damping", "params", "log L",
        "log post", "log evidence", "Δ log ev", "prob", "BIC", "process var", "obs var",
        "MAP s", "on a bound",
    )
    lines_body = []
    for row in table.itertuples(index=False):
        lines_body.append(
            (
                str(row.rank),
                str(row.model) if by_model else str(row.order),
                str(row.integrator),
                f"γ = {row.gamma:.3g}" if row.damping else "no",
                str(row.num_params),
                _num(row.log_likelihood, 2),
                _num(row.log_posterior, 2),
                _num(row.log_evidence, 2),
                _num(row.delta_log_evidence, 2),
                _prob(row.probability),
                _num(row.bic, 2),
                "none" if row.process_noise == "none" else _sci(row.process_var),
                _sci(row.obs_var),
                f"{row.map_seconds:.1f}",
                (row.at_bounds or "-") + ("" if row.converged else " (not converged)"),
            )
        )
    widths = [max(len(h), *(len(r[j]) for r in lines_body)) for j, h in enumerate(header)]
    left = {1, 2, 3, 14} if by_model else {2, 3, 14}

    def fmt(cells: Sequence[str]) -> str:
        out = [
            c.ljust(w) if j in left else c.rjust(w)
            for j, (c, w) in enumerate(zip(cells, widths, strict=True))
        ]
        return "  ".join(out).rstrip()

    lines = [] if title is None else [title, ""]
    lines.append(fmt(header))
    lines.append("  ".join("-" * w for w in widths))
    lines.extend(fmt(r) for r in lines_body)
    lines += [
        "",
        "Ranked by the log evidence (higher is better; Gaussian in the coefficients, the noise",
        "variances integrated on their log scale, see compare.csv's evidence_method); prob =",
        "posterior probability among these candidates with equal prior weights; BIC = -2 log L",
        "+ params·log n (lower is better). \"on a bound\": parameters on a bound other than the",
        "variances the evidence integrated (compare.csv's at_floor lists those on their floor).",
        "The MAP coefficients of each candidate are in compare.csv.",
    ]
    return "\n".join(lines) + "\n"


def _num(x: float, digits: int) -> str:
    return "nan" if not np.isfinite(x) else f"{x:.{digits}f}"


def _sci(x: float) -> str:
    return "nan" if not np.isfinite(x) else f"{x:.3g}"


def _prob(x: float) -> str:
    if not np.isfinite(x):
        return "nan"
    return "<0.001" if 0 < x < 1e-3 else f"{x:.3f}"


def write_comparison(
    table: pd.DataFrame, out: str | os.PathLike, title: str | None = None
) -> tuple[Path, Path]:
    """Write ``compare.csv`` and ``compare.txt`` into the folder ``out`` (created if needed)."""
    folder = Path(out)
    if folder.exists() and not folder.is_dir():
        raise FileExistsError(f"{folder}: exists and is not a folder")
    folder.mkdir(parents=True, exist_ok=True)
    csv_path, txt_path = folder / "compare.csv", folder / "compare.txt"
    write_text(csv_path, table.to_csv(index=False, float_format="%.10g"))
    write_text(txt_path, format_table(table, title))
    return csv_path, txt_path
