"""Figures and ``report.md`` of the paper-claims study (:mod:`.paper_study`)."""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from symplid.plotting import COLORS, save_figure
from symplid.plotting.sweep import rows_matching, strip_plot

__all__ = ["format_claims_report", "plot_claims"]

RATIO_THRESHOLD = math.sqrt(10.0)


# ----------------------------------------------------------------------------- figures
def plot_claims(
    claims: Mapping[str, Any], table: Any, folder: str | os.PathLike
) -> dict[str, Path]:
    """One PNG per claim in ``folder``: the per-seed values for each setting, with the
    fraction of seeds where the claim holds under each setting. Returns the paths by claim."""
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    folder = Path(folder)
    sym, ref = claims["symplectic"], claims["reference"]
    settings = claims["settings"]
    labels = [s["label"] for s in settings]
    ok = table[table["status"] == "ok"]
    paths = {}
    for name, claim in claims["claims"].items():
        metric = claim["metric"]
        fig = Figure(figsize=(max(6.0, 1.6 * len(settings) + 2), 4.2), layout="constrained")
        ax = fig.add_subplot()
        rng = np.random.default_rng(0)  # jitter of the points only
        for i, s in enumerate(settings):
            rows = rows_matching(ok, s["values"])
            if name == "process_noise":
                a = rows[rows["integrator"] == sym].set_index("seed")[metric]
                b = rows[rows["integrator"] == ref].set_index("seed")[metric]
                common = sorted(set(a.index) & set(b.index))
                ratio = (b.loc[common] / a.loc[common]).to_numpy(float)
                ratio = ratio[np.isfinite(ratio) & (ratio > 0)]
                strip_plot(ax, i, ratio, "#555555", rng)
            else:
                for j, (integ, color) in enumerate(
                    ((sym, COLORS["leapfrog"]), (ref, COLORS["rk2"]))
                ):
                    v = rows[rows["integrator"] == integ][metric].to_numpy(float)
                    strip_plot(ax, i + (j - 0.5) * 0.36, v[np.isfinite(v)], color, rng, width=0.3)
        entries = claim["per_setting"]
        ax.set_xticks(
            range(len(settings)),
            [
                f"{lab}\n{e['holds']}/{e['n']} hold" if e["n"] else f"{lab}\nno pairs"
                for lab, e in zip(labels, entries, strict=True)
            ],
            fontsize=8,
        )
        if name == "process_noise":
            ax.set_yscale("log")
            ax.axhline(1.0, color="black", lw=0.8, ls=":", label="equal")
            ax.axhline(RATIO_THRESHOLD, color="#888888", lw=0.8, ls="-.", label="√10 (threshold)")
            ax.axhline(10.0, color="black", lw=0.8, ls="--", label="paper: about 10×")
            ax.set_ylabel(f"process-noise ratio {ref} / {sym}")
            ax.legend(fontsize=8, loc="best")
        else:
            if name == "hamiltonian":
                ax.set_yscale("log")
                ax.set_ylabel("relative error of the MAP H(x0)")
            else:
                ax.set_ylabel("valid prediction horizon (s)")
            handles = [
                Line2D([], [], marker="o", ls="", color=COLORS["leapfrog"], label=sym),
                Line2D([], [], marker="o", ls="", color=COLORS["rk2"], label=ref),
            ]
            ax.legend(handles=handles, fontsize=8, loc="best")
        ax.set_title(claim["statement"], fontsize=9)
        ax.grid(axis="y", alpha=0.3)
        paths[name] = save_figure(fig, folder / f"claim_{name}.png")
    return paths


# ----------------------------------------------------------------------------- report
def format_claims_report(claims: Mapping[str, Any]) -> str:
    """``report.md``: what was run, one table per claim, the figures, and the failures."""
    study = claims.get("study", {})
    sym, ref = claims["symplectic"], claims["reference"]
    lines = ["# The paper's claims over many data seeds", ""]
    if study:
        budget = study["budget"]
        lines += [
            f"Hénon–Heiles, the paper's setting and one setting changed at a time; "
            f"{study['seeds']} data seeds; {sym} against {ref}, paired by seed (same data).",
            f"Sampler budget per cell: {budget['num_chains']} DRAM chains of "
            f"{budget['num_iterations']:,} iterations ({budget['burn_in']:,} burn-in), "
            f"{budget['num_starts']} MAP starts" + (" (quick)." if study["quick"] else "."),
            f"Cells: {study['cells']} ({study['cells_run']} run now, {study['cells_skipped']} "
            f"already done, {study['cells_failed']} failed). Wall time of this call: "
            f"{study['wall_time_s']:.0f} s.",
            "",
        ]
    lines += [
        "A claim holds for a seed when the leapfrog fit beats the RK2 fit of the same data. "
        "Fractions are over the seeds where both fits finished with finite values.",
        "",
    ]
    for name, claim in claims["claims"].items():
        lines += [f"## {_TITLES[name]}", "", f"Claim: {claim['statement']}.  ", ""]
        lines += [f"Paper (one data set): {claim['paper']}.", ""]
        if name == "process_noise":
            lines += [
                "| setting | seeds | ratio ≥ √10 | fraction | ratio > 1 | median ratio "
                "| 10–90 % of ratio | geometric mean |",
                "|---|---|---|---|---|---|---|---|",
            ]
            for e in claim["per_setting"]:
                r = e["ratio"]
                lines.append(
                    f"| {e['label']} | {e['n']} | {e['holds']} | {_pct(e['fraction'])} | "
                    f"{_pct(e['fraction_smaller'])} | {_num(r['median'])} | "
                    f"{_num(r['q10'])} – {_num(r['q90'])} | {_num(r['geometric_mean'])} |"
                )
        else:
            unit = " (s)" if name == "prediction" else ""
            extra = " ties |" if name == "prediction" else ""
            lines += [
                f"| setting | seeds | holds | fraction | median {sym}{unit} | "
                f"median {ref}{unit} |{extra}",
                "|---|---|---|---|---|---|" + ("---|" if extra else ""),
            ]
            for e in claim["per_setting"]:
                tail = f" {e['ties']} |" if extra else ""
                lines.append(
                    f"| {e['label']} | {e['n']} | {e['holds']} | {_pct(e['fraction'])} | "
                    f"{_num(e['median_symplectic'])} | {_num(e['median_reference'])} |{tail}"
                )
        undecided = sum(e["undecided"] + e["unpaired"] for e in claim["per_setting"])
        if undecided:
            lines += ["", f"{undecided} seed(s) left out (a failed cell or a non-finite value)."]
        figure = study.get("figures", {}).get(name)
        if figure:
            lines += ["", f"![{_TITLES[name]}]({figure})"]
        lines.append("")
    failures = study.get("failures") or []
    if failures:
        lines += [
            "## Failed cells",
            "",
            "| cell | seed | integrator | error |",
            "|---|---|---|---|",
        ]
        for f in failures:
            error = str(f["error"] or "").splitlines()[0][:120] if f["error"] else "pending"
            lines.append(f"| {f['cell_id']} | {f['seed']} | {f['integrator']} | {error} |")
        lines.append("")
    return "\n".join(lines)


_TITLES = {
    "hamiltonian": "Claim 1: the learned Hamiltonian",
    "process_noise": "Claim 2: the process noise",
    "prediction": "Claim 3: valid predictions",
}


def _pct(x: float | None) -> str:
    return "–" if x is None else f"{100 * x:.0f} %"


def _num(x: float | None) -> str:
    if x is None or not math.isfinite(x):
        return "–"
    return f"{x:.3g}"
