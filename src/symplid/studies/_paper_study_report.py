"""Figures and ``report.md`` of the paper-claims study (:mod:`._paper_study`).

Both read ``claims.json``'s content alone (no results table), so they can be redrawn from it.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from symplid.plotting import COLORS, save_figure
from symplid.plotting._sweep import strip_plot

__all__ = [
    "ANSWER_LABELS",
    "CALIBRATION_VARIANTS",
    "calibration_answer",
    "format_claims_report",
    "plot_claims",
]

#: The variants whose calibration is drawn and tabulated (all are in ``claims.json``).
CALIBRATION_VARIANTS = ("paper", "dt=0.1", "dt=0.5", "no-process-noise", "log-uniform")
#: The calibration entries of :func:`calibration_answer`, as the report names them.
ANSWER_LABELS = {
    "baseline": "Leapfrog at the paper's setting",
    "reference": "RK2 at the paper's setting",
    "yoshida4": "yoshida4 at the paper's setting",
    "smaller_dt": "Leapfrog at dt = 0.1",
    "no_process_noise": "Leapfrog without process noise (deterministic likelihood)",
    "no_process_noise_yoshida4": "yoshida4 without process noise (deterministic likelihood)",
    "log_uniform": "Leapfrog with the log-uniform prior on Σ",
    "log_uniform_yoshida4": "yoshida4 with the log-uniform prior on Σ",
}
#: Entries the report names even when they were not run (the others appear once run).
_ALWAYS_ANSWERED = ("baseline", "reference", "yoshida4", "smaller_dt")
_TITLES = {
    "hamiltonian": "Claim 1: the learned Hamiltonian",
    "process_noise": "Claim 2: the process noise",
    "prediction": "Claim 3: valid predictions",
}
_PALETTE = ("#1f5fa8", "#c0392b", "#7b3fa0", "#d98a00", "#16867f", "#6b6b6b", "#2ca02c")


# ----------------------------------------------------------------------------- figures
def plot_claims(claims: Mapping[str, Any], folder: str | os.PathLike) -> dict[str, Path]:
    """One PNG per claim (fractions with Wilson intervals; per-seed effects with the bootstrap
    interval of their median, per variant) and two calibration PNGs (coverage per parameter,
    rank histograms). Returns the paths by name."""
    folder = Path(folder)
    paths = {name: _plot_claim(name, claim, claims, folder)
             for name, claim in claims["claims"].items()}
    groups = _calibration_groups(claims)
    if groups:
        paths["calibration_coverage"] = _plot_coverage(groups, claims["level"], folder)
        paths["calibration_ranks"] = _plot_ranks(groups, folder)
    return paths


def _bars(value: float, lo: float, hi: float) -> list[list[float]]:
    """Error-bar lengths below and above ``value``; zero where the interval does not reach past
    it (a percentile-bootstrap interval of a median of few values need not contain it)."""
    return [[max(0.0, value - lo)], [max(0.0, hi - value)]]


def _plot_claim(name: str, claim: Mapping[str, Any], claims: Mapping[str, Any],
                folder: Path) -> Path:
    from matplotlib.figure import Figure

    entries = [e for e in claim["per_variant"] if e.get("applies", True)]  # n/a: not drawn
    x = np.arange(len(entries))
    labels = [e["variant"] for e in entries]
    fig = Figure(figsize=(max(8.0, 1.1 * len(entries) + 4), 4.2), layout="constrained")
    left, right = fig.subplots(1, 2, width_ratios=(1, 1.4))
    for i, e in enumerate(entries):
        if e["fraction_ci"] is None:
            continue
        lo, hi = e["fraction_ci"]
        left.errorbar(i, e["fraction"], _bars(e["fraction"], lo, hi),
                      fmt="o", color=COLORS["leapfrog"], capsize=3)
        left.annotate(f"{e['holds']}/{e['n']}", (i, hi), textcoords="offset points",
                      xytext=(0, 4), ha="center", fontsize=7)
    left.axhline(claims["verdict_split"], color="#888888", lw=0.8, ls=":")
    left.set_ylim(0, 1.1)
    left.set_ylabel(f"fraction of seeds where it holds ({100 * claims['level']:.0f} % Wilson)")
    rng = np.random.default_rng(0)  # jitter of the points only
    for i, e in enumerate(entries):
        values = np.asarray(e["per_seed"]["effect"], float)
        strip_plot(right, i, values, "#555555", rng)
        eff = e["effect"]
        if eff["lo"] is not None:
            right.errorbar(i + 0.3, eff["median"], _bars(eff["median"], eff["lo"], eff["hi"]),
                           fmt="s", color="black", ms=4, capsize=3)
    if claim["effect"] == "ratio":
        right.set_yscale("log")
        right.axhline(1.0, color="black", lw=0.8, ls=":")
        if name == "process_noise":
            right.axhline(claims["ratio_threshold"], color="#888888", lw=0.8, ls="-.")
    else:
        right.axhline(0.0, color="black", lw=0.8, ls=":")
    right.set_ylabel(claim["effect_label"])
    for ax in (left, right):
        ax.set_xticks(x, labels, fontsize=7, rotation=30, ha="right")
        ax.grid(axis="y", alpha=0.3)
    fig.suptitle(claim["statement"], fontsize=9)
    return save_figure(fig, folder / f"claim_{name}.png")


def _calibration_groups(claims: Mapping[str, Any]) -> list[Mapping[str, Any]]:
    return [g for g in claims.get("calibration", [])
            if g["variant"] in CALIBRATION_VARIANTS and g["params"]]


def _plot_coverage(groups: list, level: float, folder: Path) -> Path:
    from matplotlib.figure import Figure

    names = list(groups[0]["params"])
    fig = Figure(figsize=(max(7.0, 0.9 * len(names) + 2), 4.0), layout="constrained")
    ax = fig.add_subplot()
    width = 0.8 / len(groups)
    for k, g in enumerate(groups):
        for i, name in enumerate(names):
            p = g["params"].get(name)
            if not p or p["coverage_ci"] is None:
                continue
            lo, hi = p["coverage_ci"]
            xi = i - 0.4 + width * (k + 0.5)
            ax.errorbar(xi, p["coverage"], _bars(p["coverage"], lo, hi),
                        fmt="o", ms=3, capsize=2, color=_PALETTE[k % len(_PALETTE)],
                        label=g["label"] if i == 0 else None)
    ax.axhline(level, color="black", lw=0.8, ls="--")
    ax.set_xticks(range(len(names)), names, fontsize=8, rotation=30, ha="right")
    ax.set_ylabel(f"coverage of the central {100 * level:.0f} % interval")
    ax.set_ylim(0, 1.05)
    ax.legend(fontsize=7, loc="lower left")
    ax.grid(axis="y", alpha=0.3)
    return save_figure(fig, folder / "calibration_coverage.png")


def _plot_ranks(groups: list, folder: Path) -> Path:
    from matplotlib.figure import Figure

    names = list(groups[0]["params"])
    fig = Figure(figsize=(1.5 * len(names) + 1, 1.3 * len(groups) + 0.8), layout="constrained")
    axes = fig.subplots(len(groups), len(names), squeeze=False, sharey=True)
    for k, g in enumerate(groups):
        for i, name in enumerate(names):
            ax = axes[k, i]
            p = g["params"].get(name)
            if p and p["n"]:
                counts = np.asarray(p["rank_counts"], float)
                ax.bar(np.arange(counts.size), counts, width=0.9,
                       color=_PALETTE[k % len(_PALETTE)])
                ax.axhline(p["n"] / counts.size, color="black", lw=0.8, ls="--")
                pv = p["rank_p_value"]
                ax.set_title(f"p={pv:.2g}" if pv is not None else "", fontsize=7)
            ax.set_xticks([])
            if k == len(groups) - 1:
                ax.set_xlabel(name, fontsize=7)
            if i == 0:
                ax.set_ylabel(g["label"], fontsize=7)
    fig.suptitle("rank of the truth among the thinned draws (uniform when calibrated)",
                 fontsize=9)
    return save_figure(fig, folder / "calibration_ranks.png")


# ----------------------------------------------------------------------------- report
def calibration_answer(claims: Mapping[str, Any]) -> dict[str, Any]:
    """Does yoshida4, or leapfrog at a smaller dt, restore nominal coverage? From the data.

    Returns ``{"baseline", "reference", "yoshida4", "smaller_dt", "no_process_noise",
    "no_process_noise_yoshida4", "log_uniform", "log_uniform_yoshida4"}``, each the
    calibration entry (or ``None`` when not run) of leapfrog, the reference (RK2) and
    yoshida4 at the paper's setting, of leapfrog at dt = 0.1, and of leapfrog and yoshida4
    with the deterministic likelihood and with the log-uniform prior on Σ.
    """
    def find(variant: str, integrator: str) -> Mapping[str, Any] | None:
        for g in claims.get("calibration", []):
            if g["variant"] == variant and g["integrator"] == integrator and g["params"]:
                return g
        return None

    reference = claims["claims"]["hamiltonian"]["per_variant"][0]["reference"]
    sym = claims["symplectic"]
    return {"baseline": find("paper", sym),
            "reference": find("paper", reference),
            "yoshida4": find("paper", "yoshida4"),
            "smaller_dt": find("dt=0.1", sym),
            "no_process_noise": find("no-process-noise", sym),
            "no_process_noise_yoshida4": find("no-process-noise", "yoshida4"),
            "log_uniform": find("log-uniform", sym),
            "log_uniform_yoshida4": find("log-uniform", "yoshida4")}


def format_claims_report(claims: Mapping[str, Any]) -> str:
    """``report.md``: what was run, one table per claim, the calibration, the figures."""
    study = claims.get("study", {})
    lines = ["# The paper's claims over many data seeds", ""]
    if study:
        lines += _study_lines(study)
    lines += [
        "A claim holds for a seed when the leapfrog fit beats the reference fit of the same "
        f"data. Intervals: Wilson {100 * claims['level']:.0f} % for fractions, percentile "
        f"bootstrap {100 * claims['level']:.0f} % for the median paired effect. Verdict: "
        f"*holds* / *fails* when the fraction's interval lies above / below "
        f"{claims['verdict_split']:g}, else *mixed*.",
        "",
    ]
    for name, claim in claims["claims"].items():
        lines += _claim_lines(name, claim, study)
    lines += _calibration_lines(claims, study)
    failures = study.get("failures") or []
    if failures:
        lines += ["## Failed cells", "", "| cell | seed | integrator | error |",
                  "|---|---|---|---|"]
        for f in failures:
            error = str(f["error"] or "").splitlines()[0][:120] if f["error"] else "pending"
            lines.append(f"| {f['cell_id']} | {f['seed']} | {f['integrator']} | {error} |")
        lines.append("")
    return "\n".join(lines)


def _study_lines(study: Mapping[str, Any]) -> list[str]:
    b = study["budget"]
    names = ", ".join(v["name"] for v in study["variants"])
    runs = study.get("runs") or []
    last = runs[-1] if runs else {}
    speed = last.get("speedup")
    return [
        f"Hénon–Heiles; {study['seeds']} data seeds; variants: {names}.",
        f"Sampler budget per cell ({study['budget_name']}): {b['num_chains']} DRAM chains of "
        f"{b['num_iterations']:,} iterations ({b['burn_in']:,} burn-in), {b['num_starts']} "
        "MAP starts.",
        f"Cells: {study['cells']} ({study['cells_run']} run now, {study['cells_skipped']} "
        f"already done, {study['cells_failed']} failed"
        + (f", {study['cells_pending']} not run yet" if study.get("cells_pending") else "")
        + "). Wall time of this call: "
        f"{study['wall_time_s']:.0f} s; the cells' own times sum to "
        f"{study['cell_seconds_total']:.0f} s"
        + (f". The last call that ran cells ran {last['cells_run']} in "
           f"{last['wall_time_s']:.0f} s: speed-up {speed:.2f}× on "
           f"{last['workers'] or 'all'} worker(s)." if speed else "."),
        "",
    ]


def _claim_lines(name: str, claim: Mapping[str, Any], study: Mapping[str, Any]) -> list[str]:
    lines = [f"## {_TITLES[name]}", "", f"Claim: {claim['statement']}.  ",
             f"Paper (one data set): {claim['paper']}.  ",
             f"Paired effect per seed: {claim['effect_label']} ({claim['effect']}).", "",
             "| variant | reference | seeds | holds | fraction (95 % CI) | verdict "
             "| median effect (95 % CI) | median leapfrog | median reference |",
             "|---|---|---|---|---|---|---|---|---|"]
    for e in claim["per_variant"]:
        if not e.get("applies", True):
            lines.append(f"| {e['variant']} | {e['reference'] or '–'} | – | – | – | n/a "
                         "| – | – | – |")
            continue
        eff = e["effect"]
        lines.append(
            f"| {e['variant']} | {e['reference']} | {e['n']} | {e['holds']} | "
            f"{_pct(e['fraction'])} ({_range(e['fraction_ci'], _pct)}) | {e['verdict']} | "
            f"{_num(eff['median'])} ({_num(eff['lo'])} – {_num(eff['hi'])}) | "
            f"{_num(e['median_symplectic'])} | {_num(e['median_reference'])} |"
        )
    left_out = sum(e["undecided"] + e["unpaired"] for e in claim["per_variant"])
    if left_out:
        lines += ["", f"{left_out} seed(s) left out (a failed cell or a non-finite value)."]
    lines += _not_applicable_lines(claim)
    figure = study.get("figures", {}).get(name)
    if figure:
        lines += ["", f"![{_TITLES[name]}]({figure})"]
    return [*lines, ""]


def _calibration_lines(claims: Mapping[str, Any], study: Mapping[str, Any]) -> list[str]:
    groups = _calibration_groups(claims)
    if not groups:
        return []
    names = list(groups[0]["params"])
    lines = ["## Calibration", "",
             "Coverage of each parameter's central 95 % posterior interval over the seeds "
             "(Wilson 95 % interval), and the χ² p-value of the truth's rank among the thinned "
             "draws being uniform. The process-noise variance is left out: its true value, 0, "
             "is on the boundary of its support.", "",
             *_parameter_table(groups, names, _coverage_cell)]
    lines += _shift_lines(groups, names)
    failed = [(g["label"], g.get("not_converged") or {}) for g in groups]
    failed = [(label, f) for label, f in failed if f.get("n")]
    if failed:
        lines += ["", "Not converged (R-hat > 1.1), left out of this table: "
                  + "; ".join(f"{label}: seed(s) {', '.join(map(str, f['seeds']))} (R-hat "
                              f"{', '.join(f'{r:.2f}' for r in f['rhat'])})"
                              for label, f in failed) + "."]
    restarted = [(g["label"], g["restarted"]) for g in groups if (g.get("restarted") or {})
                 .get("chains")]
    if restarted:
        lines += ["", "Chains restarted at the end of the burn-in (stuck far below the others, "
                  "before any draw was kept): " + "; ".join(
                      f"{label}: {r['chains']} in seed(s) {', '.join(map(str, r['seeds']))}"
                      for label, r in restarted) + "."]
    lines += ["", *_answer_lines(claims), ""]
    for key in ("calibration_coverage", "calibration_ranks"):
        if key in study.get("figures", {}):
            lines += [f"![{key}]({study['figures'][key]})", ""]
    return lines


def _shift_lines(groups: list, names: list[str]) -> list[str]:
    """The mean and spread of z = (interval midpoint − truth) / posterior sd per parameter:
    a miss in coverage comes from a shift (mean ≠ 0) or a width (spread ≠ 1)."""
    if not any(p.get("z_mean") is not None for g in groups for p in g["params"].values()):
        return []
    lines = ["", "Where the truth lies: mean (spread) over the seeds of z = (interval midpoint "
             "− truth) / (interval width / 3.92), in posterior sds. A calibrated posterior "
             "has mean ≈ 0 and spread ≈ 1; a mean far from 0 with a spread near or below 1 "
             "is a shift of the posterior, not a too narrow one.", "",
             *_parameter_table(groups, names, _shift_cell)]
    return lines


def _parameter_table(groups: list, names: list[str], cell: Any) -> list[str]:
    """A Markdown table: one row per parameter, one column per group, ``cell(p)`` of the
    group's entry for the parameter (``{}`` where it has none)."""
    lines = ["| parameter | " + " | ".join(g["label"] for g in groups) + " |",
             "|---|" + "---|" * len(groups)]
    for name in names:
        cells = [cell(g["params"].get(name) or {}) for g in groups]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return lines


def _coverage_cell(p: Mapping[str, Any]) -> str:
    if not p.get("n"):
        return "–"
    return (f"{_pct(p['coverage'])} ({_range(p['coverage_ci'], _pct)}), "
            f"p={_num(p['rank_p_value'])}")


def _shift_cell(p: Mapping[str, Any]) -> str:
    return "–" if p.get("z_mean") is None else f"{p['z_mean']:+.2f} ({p['z_sd']:.2f})"


def _answer_lines(claims: Mapping[str, Any]) -> list[str]:
    ans = calibration_answer(claims)
    out = []
    for key, what in ANSWER_LABELS.items():
        g = ans[key]
        if g is None:
            if key in _ALWAYS_ANSWERED:
                out.append(f"{what}: not run.  ")
            continue
        below = ", ".join(g["below_nominal"]) or "none"
        state = ("nominal coverage" if g["nominal"] else
                 "below nominal coverage" if g["below_nominal"] else "above nominal coverage")
        out.append(f"{what}: {state} (lowest coverage {_pct(g['min_coverage'])}; parameters "
                   f"whose interval lies below 95 %: {below}).  ")
    return out


def _not_applicable_lines(claim: Mapping[str, Any]) -> list[str]:
    """Why a claim reads *n/a* in some variants (one line per reason)."""
    reasons: dict[str, list[str]] = {}
    for e in claim["per_variant"]:
        if not e.get("applies", True):
            reasons.setdefault(e.get("why", "it does not apply"), []).append(e["variant"])
    if not reasons:
        return []
    return ["", *(f"*n/a* in {', '.join(names)}: {why}." for why, names in reasons.items())]


def _pct(x: float | None) -> str:
    return "–" if x is None else f"{100 * x:.0f} %"


def _range(ci: Any, fmt: Any) -> str:
    return "–" if ci is None else f"{fmt(ci[0])} – {fmt(ci[1])}"


def _num(x: float | None) -> str:
    if x is None or not math.isfinite(x):
        return "–"
    return f"{x:.3g}"
