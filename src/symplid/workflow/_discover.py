"""``symplid discover``: which terms of a library the data need, with each term's inclusion
probability, the best subsets with their evidences, and the chosen model fitted fully.

:func:`discover` builds the library's model from the settings (:mod:`._term_library`), its
posterior over one or several trajectories (positions only, a learned initial state, damping:
whatever the settings say), and runs the stepwise search on the evidence of
:mod:`symplid.inference._term_search`. It returns, and writes to ``out``:

* ``terms.csv``: term, inclusion probability, in the chosen subset or not, and its
  coefficient with a 95 % interval (the chosen subset's MAP and Laplace covariance; the
  sampled posterior's 2.5 % and 97.5 % quantiles when the chosen model is fitted);
* ``subsets.csv``: every subset fitted, its log evidence and posterior probability;
* ``summary.json`` (both tables, the search's path and its cost in fits) and ``report.md``;
* ``fit/`` with ``fit=True``: the run folder of the chosen model (a user model of its terms,
  :func:`symplid.workflow._fit.fit`: sampler, ``report`` and ``predict`` work on it).

Example::

    from symplid.workflow._discover import discover
    found = discover(obs, settings, order=3, out="runs/discover")           # polynomial
    found = discover(obs, settings, terms="q1^2, q1^4, cos(q1)", fit=True)  # own terms
    found.table        # term, inclusion_probability, coefficient, lower, upper
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from symplid.inference._term_search import SIZE_PRIORS, SubsetFit, TermSearch, search_terms
from symplid.io import observation_layout
from symplid.io._runfiles import write_json
from symplid.model._data import Observations
from symplid.workflow._compare import resolve_all
from symplid.workflow._fit import build_model, build_posterior, find_map_for, fit
from symplid.workflow._settings import Settings
from symplid.workflow._step_size import choose_step, unchecked_step
from symplid.workflow._term_library import TermLibrary, term_library

__all__ = ["Discovery", "discover", "format_terms", "library_step", "report_text", "subsets_table",
           "terms_table", "write_discovery"]


@dataclass(frozen=True)
class Discovery:
    """What :func:`discover` found (the same content as its folder)."""

    library: TermLibrary
    search: TermSearch
    table: pd.DataFrame  # one row per term
    subsets: pd.DataFrame  # one row per fitted subset, most probable first
    summary: dict[str, Any] = field(default_factory=dict)
    fit: Any = None  # the chosen model's FitOutcome with fit=True

    @property
    def chosen(self) -> tuple[str, ...]:
        """The terms of the most probable subset."""
        return tuple(n for n, k in zip(self.library.names, self.search.best.included,
                                       strict=True) if k)


def _as_list(obs: Observations | Sequence[Observations]) -> list[Observations]:
    if isinstance(obs, Observations):
        return [obs]
    items = list(obs)
    if not items or not all(isinstance(o, Observations) for o in items):
        raise TypeError("obs must be an Observations or a non-empty list of them")
    return items


def library_step(settings: Settings, data: Any) -> Settings:
    """``model.dt = "auto"`` for a term search: the step chosen on the whole library's model
    (:func:`~symplid.workflow._step_size.choose_step`), which every subset then uses.

    The whole library can be a posterior the step search cannot work on: its unneeded
    coefficients sit at the kink of their Laplace prior at 0, where a refit's Hessian need
    not be positive definite (the paper's Hénon–Heiles data and the 9-term cubic). The
    search then says why in one warning, and every subset uses the library's fixed step
    min(smallest gap, :data:`~symplid.workflow._step_size.UNSEARCHED_STEP`), unchecked: a
    term search that ran before ``"auto"`` became the default runs as it did.
    """
    from symplid.inference.map import MapFailedError

    try:
        return choose_step(settings, data, search=find_map_for).settings
    except MapFailedError as err:
        fixed = unchecked_step(settings, data, f"the step could not be chosen on the whole "
                               f"library ({err})")
        warnings.warn(f"{fixed.record['not_searched']}; every subset uses dt = "
                      f"{fixed.record['dt']:g}", UserWarning, stacklevel=2)
        return fixed.settings


def discover(
    obs: Observations | Sequence[Observations],
    settings: Settings,
    terms: str | Sequence[str] | None = None,
    order: int | None = None,
    out: str | Path | None = None,
    *,
    fit_chosen: bool = False,
    size_prior: str = "beta-binomial",
    max_fits: int | None = None,
    subset_starts: int = 1,
    progress: bool = True,
    source: str = "settings",
) -> Discovery:
    """Which terms of the library the data support (module docstring).

    Parameters
    ----------
    obs
        One trajectory or a list of them (sharing the model; see ``initial_state.mode``).
    settings
        Everything but the model's terms: integrator, dt, noise, priors (the coefficients'
        prior is every term's), initial state, damping, MAP starts and seed. ``model.dt =
        "auto"`` (the default) is chosen once, for the whole library's model
        (:func:`~symplid.workflow._step_size.choose_step`), and every subset uses it.
    terms, order
        The library: a list of terms (or comma-separated text), or the polynomial of
        ``order`` in q (default: ``model.order`` of the polynomial family).
    out
        Folder for the files of the module docstring (None: nothing written).
    fit_chosen
        Fit the chosen subset's model fully (``settings``' sampler) into ``out/fit``.
    size_prior, max_fits, subset_starts
        Of :func:`~symplid.inference._term_search.search_terms`.
    progress
        Print one line per fitted subset.
    """
    if size_prior not in SIZE_PRIORS:
        raise ValueError(f"size prior: expected {', '.join(SIZE_PRIORS)}, got {size_prior!r}")
    datasets = _as_list(obs)
    dim = observation_layout(datasets[0]).dim
    library = term_library(settings, dim, terms, order)
    resolved = resolve_all(library.settings, datasets, source)
    data = datasets[0] if len(datasets) == 1 else datasets
    if resolved.model.dt == "auto":  # one step for every subset: the whole library's
        resolved = library_step(resolved, data)
    model = build_model(resolved, datasets[0])
    posterior = build_posterior(resolved, data, model)
    groups = set(posterior.param_groups[: library.size])
    if not groups <= {"coefficients", "parameters"}:  # the layout puts the terms first
        raise RuntimeError(f"the library's coefficients are not θ's first block: {groups}")
    t0 = time.perf_counter()
    search = search_terms(
        posterior, range(library.size), library.names, seed=resolved.map.seed,
        num_starts=resolved.map.num_starts, subset_starts=subset_starts,
        size_prior=size_prior, max_fits=max_fits,
        on_fit=_progress_line(library) if progress else None)
    chosen_fit = None
    if fit_chosen:
        chosen = library.subset_settings(search.best.included)
        chosen = dataclasses.replace(chosen, initial_state=resolved.initial_state,
                                     model=dataclasses.replace(chosen.model,
                                                               dt=resolved.model.dt))
        chosen_fit = fit(data, chosen, out=None if out is None else Path(out) / "fit",
                         progress=progress, source=source)
    table = terms_table(search, chosen_fit)
    subsets = subsets_table(search)
    summary = _summary(library, search, table, subsets, time.perf_counter() - t0, chosen_fit)
    found = Discovery(library, search, table, subsets, summary, chosen_fit)
    if out is not None:
        write_discovery(found, out)
    return found


def _progress_line(library: TermLibrary):
    def show(f: SubsetFit) -> None:
        terms = ", ".join(n for n, k in zip(library.names, f.included, strict=True) if k)
        value = f"{f.log_evidence:.2f}" if math.isfinite(f.log_evidence) else "failed"
        print(f"symplid: log evidence {value:>9} ({f.seconds:.1f} s) for {{{terms}}}",
              flush=True)
    return show


def terms_table(search: TermSearch, chosen_fit: Any = None) -> pd.DataFrame:
    """One row per term: inclusion probability, in the chosen subset, coefficient and its
    95 % interval (Laplace; the sampled quantiles when ``chosen_fit`` has draws)."""
    table = pd.DataFrame(search.coefficients())
    table["interval"] = "laplace"
    draws = None if chosen_fit is None else getattr(chosen_fit, "idata", None)
    if draws is not None:
        posterior = draws.posterior
        for i, row in table.iterrows():
            name = f"c{i + 1}"
            if row["in_best"] and name in posterior:
                values = np.asarray(posterior[name]).ravel()
                table.loc[i, ["lower", "upper"]] = np.quantile(values, [0.025, 0.975])
                table.loc[i, "interval"] = "posterior"
    return table


def subsets_table(search: TermSearch) -> pd.DataFrame:
    """Every fitted subset, most probable first: its terms, size, log evidence, posterior
    probability, whether its fit succeeded and its time."""
    rows = []
    for f, prob in search.ranked():
        rows.append({
            "terms": " + ".join(n for n, k in zip(search.term_names, f.included, strict=True)
                                if k) or "(none)",
            "size": f.size, "log_evidence": f.log_evidence, "probability": prob,
            "success": f.success, "seconds": f.seconds, "note": f.note,
        })
    return pd.DataFrame(rows)


def format_terms(table: pd.DataFrame) -> str:
    """The terms table as Markdown: term, inclusion probability, coefficient [95 %]."""
    lines = ["| term | inclusion probability | coefficient | 95 % interval |",
             "|---|---|---|---|"]
    for _, row in table.iterrows():
        coefficient = (f"{row['coefficient']:.4g}" if row["in_best"] else "0 (left out)")
        interval = (f"[{row['lower']:.4g}, {row['upper']:.4g}]" if row["in_best"] else "")
        lines.append(f"| {row['term']} | {row['inclusion_probability']:.3f} | {coefficient} "
                     f"| {interval} |")
    return "\n".join(lines)


def _summary(library: TermLibrary, search: TermSearch, table: pd.DataFrame,
             subsets: pd.DataFrame, seconds: float, chosen_fit: Any) -> dict[str, Any]:
    return {
        "library": list(library.names),
        "library_kind": library.kind,
        "chosen": [n for n, k in zip(library.names, search.best.included, strict=True) if k],
        "terms": table.to_dict(orient="records"),
        "subsets": subsets.head(10).to_dict(orient="records"),
        "size_prior": search.size_prior,
        "path": list(search.path),
        "stopped": search.stopped,
        "num_fits": search.num_fits,
        "evidence": search.details.get("evidence"),
        "final_evidence": search.details.get("final_evidence"),
        "refined": search.details.get("refined", 0),
        "log_probability_gap": search.log_evidence_gap,
        "seconds": seconds,
        "fit_folder": None if chosen_fit is None else "fit",
    }


def write_discovery(found: Discovery, out: str | Path) -> Path:
    """``terms.csv``, ``subsets.csv``, ``summary.json`` and ``report.md`` in ``out``."""
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    found.table.to_csv(folder / "terms.csv", index=False)
    found.subsets.to_csv(folder / "subsets.csv", index=False)
    write_json(found.summary, folder / "summary.json")
    (folder / "report.md").write_text(report_text(found), encoding="utf-8")
    return folder


def report_text(found: Discovery) -> str:
    """report.md: the chosen terms, the terms table, the best subsets and the search's cost."""
    s, top = found.search, found.subsets.head(5)
    lines = [
        "# Which terms the data need", "",
        f"Library ({found.library.kind}, {found.library.size} terms): "
        + ", ".join(found.library.names) + ".", "",
        f"Chosen: **{' + '.join(found.chosen) or '(none)'}**; the next subset is "
        f"{s.log_evidence_gap:.1f} nats behind (log posterior probability).", "",
        format_terms(found.table), "",
        "## Best subsets", "",
        "| terms | log evidence | probability |", "|---|---|---|",
        *[f"| {r.terms} | {r.log_evidence:.2f} | {r.probability:.3g} |"
          for r in top.itertuples()], "",
        f"Search: {s.num_fits} fits (MAP, Hessian, {s.details.get('evidence', '')} evidence "
        f"each; {s.details.get('refined', 0)} re-ranked by "
        f"{s.details.get('final_evidence') or 'none'}) in {s.seconds:.0f} s; "
        f"path {' → '.join(s.path)}; {s.stopped}; prior over subsets: {s.size_prior}.", "",
    ]
    if found.fit is not None:
        lines += ["The chosen model is fitted fully in `fit/` (its intervals above are the "
                  "sampled posterior's).", ""]
    return "\n".join(lines)
