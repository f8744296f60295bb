"""The shift study's report: tables, the fit of the shift against dt², figures.

Reads ``decomposition.json`` (written by :func:`~._shift.run_shift_study`) and writes
``report.md`` and ``figures/``: the shift of c[q1²q2] against dt² with the fitted lines
a + b·dt² (the posterior's shift over the leapfrog rows, and the noise-free fit over its
steps), and one stacked bar chart per row of the four parts of every coefficient's shift in
posterior standard deviations.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from symplid.plotting._style import CYCLE, new_figure, save_figure
from symplid.workflow._results import read_json

__all__ = ["FOCUS", "PARTS", "dt2_fit", "format_report", "plot_parts", "plot_shift_vs_dt2",
           "write_shift_report"]

#: The coefficient the issue follows (the largest shift in posterior sds).
FOCUS = "c[q1^2*q2]"
#: The parts of the decomposition, in the order they are stacked.
PARTS = ("discretisation", "noise_reused", "sigma", "remainder")
_LABELS = {"discretisation": "(a) discretisation", "noise_reused": "(b) noise draws",
           "sigma": "(c) process noise Σ", "remainder": "(d) remainder"}


def dt2_fit(dts: Sequence[float], shifts: Sequence[float]) -> dict[str, float] | None:
    """Least squares of ``shift = a + b·dt²``; with the largest residual (None: < 2 points)."""
    dt2, y = np.asarray(dts, dtype=float) ** 2, np.asarray(shifts, dtype=float)
    if len(y) < 2:
        return None
    design = np.stack([np.ones_like(dt2), dt2], axis=1)
    (a, b), *_ = np.linalg.lstsq(design, y, rcond=None)
    return {"a": float(a), "b": float(b),
            "max_residual": float(np.max(np.abs(design @ np.array([a, b]) - y)))}


def _dt_fits(result: Mapping[str, Any], name: str = FOCUS) -> dict[str, dict[str, Any]]:
    """For each integrator: a + b·dt² over the posterior shifts of its cells (every dt the
    paper-claims study ran) and over its noise-free fits."""
    fits: dict[str, dict[str, Any]] = {}
    totals = result.get("posterior_totals") or {}
    for integrator in dict.fromkeys([*result["discretisation"], *totals]):
        by_dt = result["discretisation"].get(integrator, {})
        posterior = totals.get(integrator, {})
        fits[integrator] = {
            "total": dt2_fit([float(d) for d in posterior],
                             [v[name]["total"] for v in posterior.values()]),
            "total_dts": [float(d) for d in posterior],
            "discretisation": dt2_fit([float(d) for d in by_dt],
                                      [v[name] for v in by_dt.values()]),
        }
    return fits


# ----------------------------------------------------------------------------- tables
def _e3(x: float | None) -> str:
    return "–" if x is None or not np.isfinite(x) else f"{1e3 * x:+.1f}"


def _sd(x: float | None, sd: float | None) -> str:
    return "–" if x is None or sd is None else f"{x / sd:+.2f}"


def _row_label(row: Mapping[str, Any]) -> str:
    return f"{row['integrator']} dt {row['dt']:g}"


def _focus_table(rows: Sequence[Mapping[str, Any]], name: str) -> list[str]:
    lines = ["| row | total | (a) discretisation | (b) noise draws (20 seeds) | "
             "fresh draws ± se | (c) Σ | (d) remainder | posterior sd |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        c = r["coefficients"][name]
        lines.append(f"| {_row_label(r)} | {_e3(c.get('total'))} | {_e3(c['discretisation'])} | "
                     f"{_e3(c['noise_reused'])} | {_e3(c['noise_fresh'])} ± "
                     f"{1e3 * c['noise_fresh_se']:.1f} | {_e3(c['sigma'])} | "
                     f"{_e3(c.get('remainder'))} | {_e3(c.get('posterior_sd'))} |")
    return lines


def _coefficient_table(row: Mapping[str, Any]) -> list[str]:
    lines = ["| coefficient | truth | total | (a) | (b) | fresh ± se | (c) | (d) |",
             "|---|---|---|---|---|---|---|---|"]
    for name, c in row["coefficients"].items():
        sd = c.get("posterior_sd")
        cells = [_sd(c.get(k), sd) for k in ("total", "discretisation", "noise_reused",
                                             "noise_fresh")]
        fresh = cells[3] if sd is None else f"{cells[3]} ± {c['noise_fresh_se'] / sd:.2f}"
        lines.append(f"| {name} | {c['truth']:g} | {cells[0]} | {cells[1]} | {cells[2]} | "
                     f"{fresh} | {_sd(c['sigma'], sd)} | {_sd(c.get('remainder'), sd)} |")
    return lines


def _sigma_table(rows: Sequence[Mapping[str, Any]], name: str) -> list[str]:
    options = list(rows[0]["coefficients"][name]["sigma_options"]) if rows else []
    lines = ["| row | " + " | ".join(f"Σ = {o}" for o in options) + " |",
             "|---|" + "---|" * len(options)]
    for r in rows:
        values = r["coefficients"][name]["sigma_options"]
        lines.append(f"| {_row_label(r)} | " + " | ".join(_e3(values.get(o)) for o in options)
                     + " |")
    return lines


def _discretisation_table(result: Mapping[str, Any], name: str,
                          fits: Mapping[str, Any]) -> list[str]:
    dts = sorted({float(d) for by in result["discretisation"].values() for d in by},
                 reverse=True)
    lines = ["| integrator | " + " | ".join(f"dt {d:g}" for d in dts)
             + " | a + b·dt² (noise-free) | a + b·dt² (posterior) |",
             "|---|" + "---|" * (len(dts) + 2)]
    totals = result.get("posterior_totals") or {}
    for integrator, by_dt in result["discretisation"].items():
        values = {float(d): v[name] for d, v in by_dt.items()}
        posterior = {float(d): v[name]["total"] for d, v in totals.get(integrator, {}).items()}
        cells = [_e3(values.get(d)) + (f" ({_e3(posterior[d])})" if d in posterior else "")
                 for d in dts]
        lines.append(f"| {integrator} | " + " | ".join(cells) + " | "
                     + _fit_text(fits[integrator]["discretisation"]) + " | "
                     + _fit_text(fits[integrator]["total"]) + " |")
    return lines


def _fit_text(fit: Mapping[str, float] | None) -> str:
    if fit is None:
        return "–"
    return (f"({1e3 * fit['a']:+.1f} {1e3 * fit['b']:+.1f}·dt²)e-3, "
            f"max residual {1e3 * fit['max_residual']:.1f}e-3")


def _unconverged(row: Mapping[str, Any]) -> str:
    """The fits whose Newton decrement stayed above the tolerance, counted by kind (they
    are in the averages: the largest decrement says how far from a mode they stopped)."""
    bad = row["fits_not_converged"]
    study = set(row["seeds"])
    kinds = {"noise-free fit": [b for b in bad if b["fit"] == "noise-free"],
             "deterministic MAPs on the study's seeds": [
                 b for b in bad if b["fit"] == "deterministic" and b["seed"] in study],
             f"deterministic MAPs on the {row['fresh']} fresh seeds": [
                 b for b in bad if b["fit"] == "deterministic" and b["seed"] not in study],
             "fixed-Σ MAPs": [b for b in bad if b["fit"].startswith("sigma")]}
    parts = [f"{len(v)} {k} (largest decrement {max(b['decrement'] for b in v):.2g})"
             for k, v in kinds.items() if v]
    return ("fits stopped above the Newton-decrement tolerance, kept in the averages: "
            + (", ".join(parts) if parts else "none"))


def format_report(result: Mapping[str, Any]) -> str:
    """``report.md``'s text."""
    rows, budget = result["rows"], result["budget"]
    fits = _dt_fits(result)
    name = FOCUS
    paper_row = rows[0] if rows else None
    lines = [
        "# The coefficient shift, decomposed",
        "",
        f"Hénon–Heiles, σ {result['setting']['noise_std']}, {result['setting']['num_obs']} "
        f"observations every {result['setting']['obs_interval']:g} s, process noise once per "
        f"gap. Study seeds 0..{budget['seeds'] - 1}, {budget['fresh']} fresh seeds from "
        f"{budget['fresh_seed']}; budget `{budget['name']}`; posterior shifts from "
        f"`{result['cells']}`." if result["cells"] else "no paper-claims cells (no totals).",
        "",
        "Shift = estimate − truth, averaged over the seeds. (a) noise-free least-squares fit; "
        "(b) deterministic-likelihood MAP on the study's seeds, minus (a); fresh: the same on "
        "fresh seeds; (c) MAP with Σ held at each seed's posterior median minus the "
        "deterministic MAP; (d) the posterior's interval midpoint minus (a)+(b)+(c).",
        "",
        f"## {name} by row (×1e-3)",
        "",
        *_focus_table(rows, name),
        "",
        f"## {name}: the process-noise part (c) at other values of Σ (×1e-3)",
        "",
        "`median`: each seed's posterior median of Σ; `map`: each seed's MAP Σ (the search's "
        f"floor when it sits there); `typical`: {budget['sigma_typical']:g} for every seed.",
        "",
        *_sigma_table(rows, name),
        "",
        f"## {name}: the noise-free fit against dt (×1e-3) and the fits a + b·dt²",
        "",
        "Each cell: the noise-free fit's shift, in brackets the posterior's (20 seeds of the "
        "paper-claims study) where it ran that step. a + b·dt² by least squares over the "
        "steps (for yoshida4, a 4th-order method, the form does not apply).",
        "",
        *_discretisation_table(result, name, fits),
        "",
    ]
    if paper_row is not None:
        lines += [f"## Every coefficient, {_row_label(paper_row)} (posterior sds)", "",
                  *_coefficient_table(paper_row), ""]
    lines += ["## Left out, and fits that did not converge", ""]
    for r in rows:
        lines.append(f"* {_row_label(r)}: cells not converged (R-hat > "
                     f"{budget['rhat_failed']}), left out of every average: "
                     f"{r['excluded_seeds'] or 'none'}; " + _unconverged(r) + ".")
    if result.get("pending"):
        lines += ["", "**Partial**: not computed yet: " + "; ".join(result["pending"]) + "."]
    lines += ["", "![shift of c[q1²q2] against dt²](figures/shift_vs_dt2.png)", ""]
    lines += [f"![parts, {_row_label(r)}](figures/parts_{r['integrator']}_{r['dt']:g}.png)"
              for r in rows if "total" in r["coefficients"][name]]
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------- figures
def plot_shift_vs_dt2(result: Mapping[str, Any], path: Path, name: str = FOCUS) -> Path:
    """The shift of ``name`` against dt²: each row's posterior shift (filled) and each
    integrator's noise-free fits (open), with the fitted lines a + b·dt²."""
    fig = new_figure(6.0, 4.2)
    ax = fig.add_subplot()
    fits = _dt_fits(result, name)
    for k, (integrator, by_dt) in enumerate(result["discretisation"].items()):
        color = CYCLE[k % len(CYCLE)]
        posterior = (result.get("posterior_totals") or {}).get(integrator, {})
        grid = np.linspace(0.0, max(float(d) for d in [*by_dt, *posterior]) ** 2, 50)
        dts = [float(d) for d in by_dt]
        ax.plot(np.square(dts), [1e3 * v[name] for v in by_dt.values()], "o", mfc="none",
                color=color, label=f"{integrator}: noise-free fit")
        fit = fits[integrator]["discretisation"]
        if fit:
            ax.plot(grid, 1e3 * (fit["a"] + fit["b"] * grid), ":", color=color)
        if posterior:
            ax.plot([float(d) ** 2 for d in posterior],
                    [1e3 * v[name]["total"] for v in posterior.values()], "s", color=color,
                    label=f"{integrator}: posterior (paper-claims seeds)")
        fit = fits[integrator]["total"]
        if fit:
            ax.plot(grid, 1e3 * (fit["a"] + fit["b"] * grid), "-", color=color, lw=1,
                    label=f"a + b·dt² = ({1e3 * fit['a']:.1f} {1e3 * fit['b']:+.0f}·dt²)e-3")
    ax.axhline(0.0, color="0.5", lw=0.5)
    ax.set_xlabel("dt²")
    ax.set_ylabel(f"shift of {name} (×1e-3)")
    ax.legend(fontsize=7)
    return save_figure(fig, path)


def plot_parts(row: Mapping[str, Any], path: Path) -> Path:
    """One row's parts, stacked per coefficient in posterior sds (negative parts below zero),
    the total marked."""
    names = list(row["coefficients"])
    fig = new_figure(7.5, 3.8)
    ax = fig.add_subplot()
    x = np.arange(len(names))
    up, down = np.zeros(len(names)), np.zeros(len(names))
    for k, part in enumerate(PARTS):
        values = np.array([c[part] / c["posterior_sd"] for c in row["coefficients"].values()])
        bottom = np.where(values >= 0, up, down)
        ax.bar(x, values, 0.7, bottom=bottom, color=CYCLE[k], label=_LABELS[part])
        up, down = up + np.maximum(values, 0), down + np.minimum(values, 0)
    totals = [c["total"] / c["posterior_sd"] for c in row["coefficients"].values()]
    ax.plot(x, totals, "kD", ms=5, label="total")
    ax.axhline(0.0, color="0.4", lw=0.5)
    ax.set_xticks(x, names, rotation=35, fontsize=8)
    ax.set_ylabel("shift (posterior sds)")
    ax.set_title(f"{_row_label(row)}: the coefficient shift in four parts", fontsize=10)
    ax.legend(fontsize=7, ncol=3)
    return save_figure(fig, path)


def write_shift_report(out_dir: str | os.PathLike) -> dict[str, Any]:
    """``report.md`` and ``figures/`` from the folder's ``decomposition.json``; the fits of
    a + b·dt² are added to the returned result."""
    out = Path(out_dir)
    result = read_json(out / "decomposition.json")
    result["dt_fits"] = _dt_fits(result)
    plot_shift_vs_dt2(result, out / "figures" / "shift_vs_dt2.png")
    for row in result["rows"]:
        if all("total" in c for c in row["coefficients"].values()):
            plot_parts(row, out / "figures" / f"parts_{row['integrator']}_{row['dt']:g}.png")
    tmp = out / ".report.md.tmp"
    tmp.write_text(format_report(result), encoding="utf-8")
    os.replace(tmp, out / "report.md")
    return result
