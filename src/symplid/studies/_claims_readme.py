"""The README's paper-claims section, generated from ``claims.json`` (no number typed by hand).

:func:`readme_block` turns the study's ``claims.json`` content into Markdown; every number in
it is a value of that content passed through one of the formatters below (tested).
:func:`update_readme` replaces the text between :data:`BEGIN` and :data:`END` in a README
(the markers stay) and copies the study's figures beside it, so the block's images resolve::

    symplid study paper-claims --out runs/claims --update-readme README.md

:func:`calibration_block` is a compact alternative for a front page: one row per fit of the
calibration (lowest and median coverage, how many parameters reach the level, the smallest
rank p-value, the largest shift), between :data:`CALIBRATION_BEGIN` and
:data:`CALIBRATION_END`; ``update_readme`` rewrites whichever of the two blocks a file has.
"""

from __future__ import annotations

import math
import os
import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from symplid.studies._paper_study_report import ANSWER_LABELS, calibration_answer

__all__ = [
    "BEGIN",
    "CALIBRATION_BEGIN",
    "CALIBRATION_END",
    "END",
    "FIGURES_DIR",
    "calibration_block",
    "check_readme",
    "readme_block",
    "update_readme",
]

BEGIN = "<!-- claims:begin -->"
END = "<!-- claims:end -->"
#: The markers of the compact calibration table (:func:`calibration_block`).
CALIBRATION_BEGIN = "<!-- calibration:begin -->"
CALIBRATION_END = "<!-- calibration:end -->"
#: Where the figures go, relative to the README.
FIGURES_DIR = "docs/figures/claims"
_FIGURE_TITLES = {
    "hamiltonian": "H error: fractions and paired differences",
    "process_noise": "Process-noise ratio",
    "prediction": "Prediction-horizon ratio",
    "calibration_coverage": "Coverage of the posterior intervals",
    "calibration_ranks": "Rank histograms of the truth",
}


# ----------------------------------------------------------------------------- formatters
def pct(x: float | None) -> str:
    """A fraction as a whole percentage."""
    return "–" if x is None else f"{100 * x:.0f} %"


def num(x: float | None) -> str:
    """Three significant digits."""
    if x is None or not math.isfinite(x):
        return "–"
    return f"{x:.3g}"


def whole(x: float | None) -> str:
    """A count or a duration in whole units, with thousands separators."""
    return "–" if x is None else f"{x:,.0f}"


FORMATTERS = (pct, num, whole)


# ----------------------------------------------------------------------------- the block
def readme_block(claims: Mapping[str, Any], figures: str | None = FIGURES_DIR) -> str:
    """The Markdown between the markers, from ``claims.json``'s content."""
    study = claims["study"]
    level = pct(claims["level"])
    lines = [
        "<!-- generated from claims.json by `symplid study paper-claims --update-readme`; "
        "edits here are overwritten -->",
        "",
        *_setup(study),
        "",
        f"| claim | variant | holds in | {level} interval | verdict | median paired effect "
        f"({level} interval) |",
        "|---|---|---|---|---|---|",
    ]
    for name, claim in claims["claims"].items():
        for e in claim["per_variant"]:
            if not e.get("applies", True):
                lines.append(f"| {_SHORT[name]} | {e['variant']} | – | – | n/a | – |")
                continue
            eff = e["effect"]
            lines.append(
                f"| {_SHORT[name]} | {e['variant']} | {e['holds']} / {e['n']} | "
                f"{pct(_lo(e['fraction_ci']))} – {pct(_hi(e['fraction_ci']))} | "
                f"{e['verdict']} | {num(eff['median'])} ({num(eff['lo'])} – {num(eff['hi'])}) |"
            )
    lines += ["", *_effects(claims), "", *_not_holding(claims), "", *_calibration(claims)]
    if figures and study.get("figures"):
        lines += [""] + [
            f"![{_FIGURE_TITLES.get(k, k)}]({figures}/{Path(p).name})"
            for k, p in study["figures"].items()
        ]
    return "\n".join(lines)


_SHORT = {
    "hamiltonian": "H closer to the truth",
    "process_noise": "process noise smaller",
    "prediction": "longer valid prediction",
}


def _lo(ci: Any) -> float | None:
    return None if ci is None else ci[0]


def _hi(ci: Any) -> float | None:
    return None if ci is None else ci[1]


def _setup(study: Mapping[str, Any]) -> list[str]:
    b = study["budget"]
    names = ", ".join(v["name"] for v in study["variants"])
    return [
        f"**Measured** with budget *{study['budget_name']}* ({whole(b['num_chains'])} DRAM "
        f"chains × {whole(b['num_iterations'])} iterations, {whole(b['burn_in'])} burn-in, "
        f"{whole(b['num_starts'])} MAP starts per cell) over {whole(study['seeds'])} data "
        f"seeds; variants: {names}. {whole(study['cells'])} cells, "
        f"{whole(study['cells_failed'])} failed"
        + (f", {whole(study['cells_pending'])} not run yet (left out of every fraction)"
           if study.get("cells_pending") else "")
        + f", {whole(study['cell_seconds_total'])} s of compute in all."
        + _last_run(study)
        + _estimate(study)
        + _caveat(study)
    ]


def _last_run(study: Mapping[str, Any]) -> str:
    runs = study.get("runs") or []
    if not runs:
        return ""
    r = runs[-1]
    where = f" on {whole(r['workers'])} worker(s)" if r.get("workers") else (
        " on a Dask cluster" if r.get("scheduler") else " on a local cluster")
    speed = f", a speed-up of {num(r['speedup'])}×" if r.get("speedup") else ""
    return (f" The last call that ran cells ran {whole(r['cells_run'])} in "
            f"{whole(r['wall_time_s'])} s{where} ({whole(r['cell_seconds'])} s of cell time"
            f"{speed}).")


def _estimate(study: Mapping[str, Any]) -> str:
    """The estimated cost at the paper's budget (none when the paper's budget was run)."""
    if study["budget_name"] == "paper":
        return ""
    est = study.get("estimate_paper_budget") or {}
    one, two = est.get("1_workers"), est.get("2_workers")
    if not one or not two:
        return ""
    return (f" At the paper's budget these cells are estimated at {whole(one['core_s'])} s "
            f"on one core: {whole(one['wall_s'])} s with one worker, {whole(two['wall_s'])} s "
            "with two (from the measured seconds per iteration of each propagator).")


def _caveat(study: Mapping[str, Any]) -> str:
    if study["budget_name"] == "paper":
        return ""
    return (" **This budget is smaller than the paper's**: the chains are short, so the "
            "posterior quantities (process noise, intervals, ranks) are rough; the numbers "
            "exercise the study, they do not replace the run at the paper's budget.")


def _effects(claims: Mapping[str, Any]) -> list[str]:
    out = ["Paired effects (one number per seed, from the two fits of the same data): "]
    parts = [f"*{_SHORT[n]}*: {c['effect_label']}" for n, c in claims["claims"].items()]
    out[0] += "; ".join(parts) + (
        f". The process-noise claim holds for a seed at a ratio ≥ "
        f"{num(claims['ratio_threshold'])}; a verdict is *holds* (*fails*) when the Wilson "
        f"interval of the fraction lies above (below) {pct(claims['verdict_split'])}."
    )
    return out


def _not_holding(claims: Mapping[str, Any]) -> list[str]:
    bad = [
        (name, e) for name, c in claims["claims"].items() for e in c["per_variant"]
        if e["verdict"] != "holds" and e.get("applies", True)
    ]
    if not bad:
        return ["Every claim holds in every variant measured."]
    out = ["**Where a claim does not hold** (verdict *mixed* or *fails*):", ""]
    for name, e in bad:
        out.append(
            f"- {_SHORT[name]}, {e['variant']}: {e['holds']} / {e['n']} seeds "
            f"({pct(e['fraction'])}), {e['verdict']}."
        )
    return out


def _calibration(claims: Mapping[str, Any]) -> list[str]:
    ans = calibration_answer(claims)
    level = pct(claims["level"])
    groups = [(k, g) for k, g in ans.items() if g is not None]
    if not groups:
        return []
    names = list(groups[0][1]["params"])
    out = [
        f"**Calibration**: how often each parameter's central {level} posterior interval "
        f"contains the truth (Wilson {level} interval), per propagator.",
        "",
        "| parameter | " + " | ".join(g["label"] for _, g in groups) + " |",
        "|---|" + "---|" * len(groups),
    ]
    for name in names:
        row = []
        for _, g in groups:
            p = g["params"].get(name)
            row.append("–" if not p or not p["n"] else
                       f"{pct(p['coverage'])} ({pct(_lo(p['coverage_ci']))} – "
                       f"{pct(_hi(p['coverage_ci']))})")
        out.append(f"| {name} | " + " | ".join(row) + " |")
    out.append("")
    for _, g in groups:
        state = ("nominal coverage" if g["nominal"] else "below nominal coverage"
                 if g["below_nominal"] else "above nominal coverage")
        below = ", ".join(g["below_nominal"]) or "none"
        out.append(f"- {g['label']}: {state}; lowest coverage {pct(g['min_coverage'])}; "
                   f"intervals entirely below {level}: {below}.")
    out += ["", _restores(ans)]
    return out


def _restores(ans: Mapping[str, Any]) -> str:
    """The answer to "does yoshida4 or a smaller dt restore nominal coverage?"."""
    def said(key: str, what: str) -> str:
        g = ans[key]
        if g is None:
            return f"{what} was not run"
        return f"{what} {'gives' if g['nominal'] else 'does not give'} nominal coverage"

    base = ans["baseline"]
    head = ("Leapfrog at the paper's setting " + ("is" if base and base["nominal"] else
            "is not") + " nominally calibrated; ") if base else ""
    more = [said(k, w) for k, w in (("no_process_noise", "leapfrog without process noise"),
                                     ("no_process_noise_yoshida4",
                                      "yoshida4 without process noise"),
                                     ("log_uniform", "leapfrog with the log-uniform Σ prior"),
                                     ("log_uniform_yoshida4",
                                      "yoshida4 with the log-uniform Σ prior"))
            if ans.get(k) is not None]
    return (f"{head}{said('yoshida4', 'yoshida4')} and {said('smaller_dt', 'leapfrog at dt=0.1')}"
            + "".join(f"; {m}" for m in more)
            + " (nominal: every parameter's Wilson interval of the coverage contains the level).")


# ----------------------------------------------------------------------------- compact
def calibration_block(claims: Mapping[str, Any]) -> str:
    """A compact calibration table for a front page: one row per fit of
    :func:`~._paper_study_report.calibration_answer` that was run (leapfrog, RK2 and yoshida4
    at the paper's setting, leapfrog at dt = 0.1, then the deterministic likelihood and the
    log-uniform Σ prior), with the lowest coverage over the parameters (its Wilson interval),
    the median coverage, how many parameters' Wilson intervals contain the level, the
    smallest rank-uniformity p-value and the largest mean shift of a posterior from the truth
    (:func:`~._paper_calibration.evaluate_calibration`'s ``z_mean``)."""
    study = claims["study"]
    level = pct(claims["level"])
    lines = [
        "<!-- generated from claims.json by `symplid study paper-claims --update-readme`; "
        "edits here are overwritten -->",
        f"| fit (budget *{study['budget_name']}*) | seeds (+ not converged) | lowest "
        f"coverage of the {level} intervals (Wilson {level}) | median | {level} inside the "
        "Wilson interval | smallest rank p-value | largest mean shift [posterior sd] |",
        "|---|---|---|---|---|---|---|",
    ]
    for key, g in calibration_answer(claims).items():
        if g is None:
            continue
        params = {n: p for n, p in g["params"].items() if p["coverage"] is not None}
        if not params:
            continue
        low = min(params, key=lambda n: params[n]["coverage"])
        p = params[low]
        inside = sum(bool(q["nominal_inside"]) for q in params.values())
        pvals = [q["rank_p_value"] for q in params.values() if q["rank_p_value"] is not None]
        median = float(np.median([q["coverage"] for q in params.values()]))
        failed = (g.get("not_converged") or {}).get("n", 0)
        seeds = whole(max(q["n"] for q in params.values())) + (
            f" (+ {whole(failed)})" if failed else "")
        lines.append(
            f"| {ANSWER_LABELS[key]} | {seeds} | {low}: {pct(p['coverage'])} "
            f"({pct(_lo(p['coverage_ci']))} – {pct(_hi(p['coverage_ci']))}) | {pct(median)} | "
            f"{inside} of {len(params)} | {num(min(pvals)) if pvals else '–'} | "
            f"{_largest_shift(params)} |"
        )
    return "\n".join(lines)


def _largest_shift(params: Mapping[str, Any]) -> str:
    """The parameter whose posterior is shifted most from the truth (mean z, in sds)."""
    shifts = {n: p["z_mean"] for n, p in params.items() if p.get("z_mean") is not None}
    if not shifts:
        return "–"
    name = max(shifts, key=lambda n: abs(shifts[n]))
    return f"{name}: {num(shifts[name])}"


# ----------------------------------------------------------------------------- the README
def _replace_block(text: str, begin: str, end: str, block: str) -> str | None:
    start, stop = text.find(begin), text.find(end)
    if start < 0 or stop < start:
        return None
    return text[: start + len(begin)] + "\n" + block + "\n" + text[stop:]


def check_readme(readme: str | os.PathLike) -> None:
    """Refuse, before a study runs, a README that :func:`update_readme` could not rewrite:
    missing, unreadable, or with neither pair of markers (one line, a :class:`ValueError`),
    so that a long study does not end in an error after its success line."""
    path = Path(readme)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        why = "no such file" if isinstance(err, FileNotFoundError) else type(err).__name__
        raise ValueError(f"{path}: cannot be read ({why}); --update-readme rewrites an "
                         "existing README") from None
    if all(_replace_block(text, begin, end, "") is None
           for begin, end in ((BEGIN, END), (CALIBRATION_BEGIN, CALIBRATION_END))):
        raise ValueError(f"{path}: no '{BEGIN}' ... '{END}' or '{CALIBRATION_BEGIN}' ... "
                         f"'{CALIBRATION_END}' block to rewrite")


def update_readme(
    readme: str | os.PathLike,
    claims: Mapping[str, Any],
    study_dir: str | os.PathLike | None = None,
) -> str:
    """Rewrite the blocks of ``readme`` between :data:`BEGIN` and :data:`END` (the summary
    of :func:`readme_block`) and between :data:`CALIBRATION_BEGIN` and
    :data:`CALIBRATION_END` (:func:`calibration_block`), whichever it has; returns the text
    written between the markers (both blocks, in that order, when it has both).

    With ``study_dir`` and a summary block, the figures named in
    ``claims["study"]["figures"]`` are copied from it into :data:`FIGURES_DIR` beside the
    README.

    Raises
    ------
    ValueError
        The README has neither pair of markers (or has them out of order).
    """
    path = Path(readme)
    text = path.read_text(encoding="utf-8")
    written = []
    new = _replace_block(text, BEGIN, END, readme_block(claims))
    if new is not None:
        text, summary = new, True
        written.append(readme_block(claims))
    else:
        summary = False
    new = _replace_block(text, CALIBRATION_BEGIN, CALIBRATION_END, calibration_block(claims))
    if new is not None:
        text = new
        written.append(calibration_block(claims))
    if not written:
        raise ValueError(f"{path}: no '{BEGIN}' ... '{END}' or '{CALIBRATION_BEGIN}' ... "
                         f"'{CALIBRATION_END}' block to rewrite")
    if study_dir is not None and summary:
        target = path.parent / FIGURES_DIR
        target.mkdir(parents=True, exist_ok=True)
        for rel in claims["study"].get("figures", {}).values():
            shutil.copyfile(Path(study_dir) / rel, target / Path(rel).name)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)
    return "\n".join(written)
