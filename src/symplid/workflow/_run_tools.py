"""Work on a finished run folder: predictions and the report (``symplid predict``/``report``)."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np

from symplid.inference._diagnostics import ESS_THRESHOLD, RHAT_THRESHOLD, quiet_arviz
from symplid.inference._diagnostics import summary as diagnostics_summary
from symplid.inference.map import MapResult
from symplid.io import as_list
from symplid.io._files import write_with
from symplid.plotting import plot_predictive
from symplid.plotting._style import DPI, write_figure
from symplid.sampling import draws_array
from symplid.sampling._restart import restart_threshold, restarted_message
from symplid.workflow._driven import is_driven, power_balance_lines, predicted_inputs
from symplid.workflow._fit import build_model, build_posterior
from symplid.workflow._model_builder import model_description
from symplid.workflow._results import RunFolder, format_summary
from symplid.workflow._run_figures import ReportFigure, report_figures, trajectory_paths
from symplid.workflow._sensitivity import sensitivity_checks, sensitivity_lines
from symplid.workflow._step_size import step_lines

__all__ = ["predict_run", "report_run", "run_diagnostics", "save_atomically"]

#: The most integrator steps a prediction may take ((t_end − t0)/dt), so that a mistyped
#: horizon (1e9) is a one-line error rather than hours of work or an exhausted memory.
MAX_PREDICTION_STEPS = 10_000_000


def _load(folder: RunFolder, plan: Any = None):
    settings = folder.read_settings()
    obs = folder.read_data()
    model = build_model(settings, obs) if plan is None else plan.model(settings, obs)
    posterior = build_posterior(settings, obs, model)
    return settings, obs, model, posterior


def _draws(folder: RunFolder, wanted: bool, what: str) -> np.ndarray | None:
    if not folder.file(RunFolder.POSTERIOR).exists():
        if wanted:
            warnings.warn(
                f"{folder.path}: posterior.nc is missing (deleted?); {what}", UserWarning,
                stacklevel=3,
            )
        return None
    return draws_array(folder.read_posterior())


def save_atomically(figure: Any, path: Path) -> Path:
    """Write a figure as :func:`symplid.plotting.save_figure` does, made in memory and
    written atomically (:func:`symplid.io._files.write_with`: never a half-written PNG)."""
    return write_with(path, lambda buffer: write_figure(
        figure, buffer, path.suffix.lstrip(".") or "png", DPI))


def _prediction_args(settings, obs, t_end, dt, num_paths) -> tuple[float, float, int, float]:
    """Check the prediction's arguments before anything is computed or written (``t0``: the
    latest start of the trajectories)."""
    p = settings.prediction
    t_end = p.t_end if t_end is None else float(t_end)
    dt = p.dt if dt is None else float(dt)
    num_paths = p.num_paths if num_paths is None else int(num_paths)
    t0 = max(settings.initial_state.start_time(o.times[0]) for o in as_list(obs))
    if not np.isfinite(t_end) or t_end <= t0:
        raise ValueError(f"--t-end must be after the initial time {t0:g}, got {t_end:g}")
    if not np.isfinite(dt) or dt <= 0:
        raise ValueError(f"--dt must be positive, got {dt:g}")
    if num_paths < 0:
        raise ValueError(f"--num-paths must be ≥ 0, got {num_paths}")
    steps = (t_end - t0) / dt
    if steps > MAX_PREDICTION_STEPS:
        raise ValueError(
            f"predicting from t = {t0:g} to {t_end:g} at dt = {dt:g} takes {steps:.3g} steps; "
            f"at most {MAX_PREDICTION_STEPS:,} are allowed (a larger --dt or a nearer --t-end)"
        )
    return t_end, dt, num_paths, t0


def predict_run(
    run: str | Path,
    t_end: float | None = None,
    dt: float | None = None,
    num_paths: int | None = None,
    inputs: Path | None = None,
) -> str:
    """MAP path and posterior predictive band to ``t_end``; writes predictions.npz and a figure.

    A driven run (``model.force``) integrates its inputs along: beyond the data's inputs it
    needs the future ones, ``inputs`` (a CSV ``t,u1,…``), and refuses in one line without
    them (:func:`~symplid.workflow._driven.predicted_inputs`).

    The paths start from the known initial state or, when it was learned, the MAP path from
    the MAP's and each path of the band from its own draw's. ``t_end``, ``dt`` and
    ``num_paths`` default to the run's ``[prediction]`` settings. Several trajectories are
    predicted each from its own initial state: the arrays of trajectory k carry the suffix
    ``_k`` and its figure is ``predictive_k``. Every argument is checked and every path
    computed before the folder is touched, and the files are replaced atomically: a failed
    or interrupted prediction leaves a finished run finished. Returns a one-line description.
    """

    folder = RunFolder(run, "r")
    settings, obs, model, posterior = _load(folder)
    t_end, dt, num_paths, _ = _prediction_args(settings, obs, t_end, dt, num_paths)
    if inputs is not None or is_driven(settings.model):
        obs = predicted_inputs(obs, settings, t_end, inputs)
        posterior = build_posterior(settings, obs, model)
    theta_map = np.asarray(folder.read_map()["theta"], dtype=float)
    draws = _draws(folder, num_paths > 0, "predicting the MAP path only")
    flat = None if draws is None else draws.reshape(-1, draws.shape[-1])
    trajectories = as_list(obs)
    arrays: dict[str, Any] = {}
    figures = []
    for k, one in enumerate(trajectories):
        t0 = settings.initial_state.start_time(one.times[0])
        times, path, band = trajectory_paths(settings, model, posterior, theta_map, flat, k,
                                             t0, t_end, dt, num_paths)
        tag = f"_{k}" if len(trajectories) > 1 else ""
        arrays.update({f"times{tag}": times, f"map_path{tag}": path})
        if band is None:
            continue
        arrays.update({f"band_times{tag}": band.times, f"band_lower{tag}": band.lower,
                       f"band_upper{tag}": band.upper, f"band_median{tag}": band.median,
                       f"sample_paths{tag}": band.paths})
        figures.append((f"predictive{tag}", plot_predictive(
            band, one, map_path=(times, path), t_data_end=float(one.times[-1]),
            time_unit=settings.plots.time_unit)))
    with RunFolder(run, "a") as update:
        update.write_npz("predictions.npz", **arrays)
        for name, figure in figures:
            save_atomically(figure, update.figure_path(name))
    what = "MAP path and posterior band" if figures else "MAP path"
    many = f" for {len(trajectories)} trajectories" if len(trajectories) > 1 else ""
    return f"{folder.file('predictions.npz')}: {what}{many} to t = {t_end:g} (dt = {dt:g})"


def report_run(run: str | Path, plan: Any = None) -> str:
    """Write ``report.md``: the summary, a per-parameter R-hat/ESS table, the sensitivity
    checks of the fit (:func:`run_diagnostics`), and the figures (traces, pairs, U(q) with its
    band, the data against the fit; see :mod:`symplid.workflow._run_figures`).

    Everything is computed before the folder is touched; a failed or interrupted report leaves
    a finished run finished. A run whose ``posterior.nc`` is missing gets a one-line warning
    and a report without the posterior's table and figures. ``plan``: the fit's
    :class:`~symplid.workflow._plan.ModelPlan` (the report right after a fit reuses its U or
    H); None builds the model from the run's settings.
    """

    folder = RunFolder(run, "r")
    settings, obs, model, posterior = _load(folder, plan)
    summary = folder.read_summary() if folder.file("summary.json").exists() else {}
    idata = None
    if folder.file(RunFolder.POSTERIOR).exists():
        idata = folder.read_posterior()
    else:
        _draws(folder, True, "the report has no posterior table or figures")
    figures: list[ReportFigure] = []
    table = None
    if idata is not None:
        theta_map = np.asarray(folder.read_map()["theta"], dtype=float)
        table = convergence_table(idata)
        figures = report_figures(settings, obs, model, posterior, draws_array(idata), theta_map)
    lines = [
        *_report_header(run, settings, obs),
        "```",
        format_summary(summary) if summary else "(no summary)",
        "```",
        "",
    ]
    if table is not None:
        lines += ["## Convergence", "", table, ""]
        lines += _restart_lines(idata)
    if summary.get("learning_step"):
        lines += step_lines(summary["learning_step"])
    if idata is not None:
        lines += power_balance_lines(settings, model, posterior, theta_map)
    checks = run_diagnostics(folder, settings, obs, posterior)
    if checks is not None:
        lines += sensitivity_lines(checks)
    notes = [f"{f.title}: {f.note}" for f in figures if f.note]
    with RunFolder(run, "a") as update:
        for f in figures:
            save_atomically(f.figure, update.figure_path(f.name))
        shown = [(f.title, f"figures/{f.name}.png", f.note) for f in figures]
        shown += [(f"Predictions{_which(p)}", f"figures/{p.name}", "")
                  for p in update.figures() if p.stem.startswith("predictive")]
        for title, path, note in shown:
            lines += [f"![{title}]({path})\n"] + ([f"*{note}*\n"] if note else [])
        if checks is not None and not folder.file(RunFolder.DIAGNOSTICS).exists():
            update.write_json(RunFolder.DIAGNOSTICS, checks)  # computed for an older run
        update.write_report("\n".join(lines))
    extra = f" ({'; '.join(notes)})" if notes else ""
    return f"{folder.file('report.md')}: {len(shown)} figures{extra}"


def run_diagnostics(folder: RunFolder, settings: Any = None, obs: Any = None,
                    posterior: Any = None) -> dict | None:
    """A run's sensitivity checks: ``diagnostics.json`` as its fit saved them, else (a run
    made before fits computed them) computed now when its ``map.sensitivity`` is on (given
    its ``settings``, ``obs`` and ``posterior``), else None."""
    if folder.file(RunFolder.DIAGNOSTICS).exists():
        return folder.read_json(RunFolder.DIAGNOSTICS)
    if settings is None or not settings.map.sensitivity:
        return None
    return sensitivity_checks(settings, obs, posterior, MapResult.from_dict(folder.read_map()))


def _which(path: Path) -> str:
    tail = path.stem.removeprefix("predictive").lstrip("_")
    return f" (trajectory {tail})" if tail else ""


def _report_header(run: str | Path, settings, obs) -> list[str]:
    m = settings.model
    unit = settings.plots.time_unit
    data = "; ".join(
        f"{o.num_times} observations of {o.dim} components, t = {o.times[0]:g}..."
        f"{o.times[-1]:g} {unit}" for o in as_list(obs))
    many = f"{len(as_list(obs))} trajectories: " if isinstance(obs, list) else ""
    return [
        f"# Run {Path(run).name}",
        "",
        f"{many}{data}; {model_description(m)}, {m.integrator} at dt = {m.dt:g}; "
        f"{settings.sampler.method.upper()}, {settings.sampler.num_chains} chains, "
        f"{settings.sampler.budget_words()}.",
        "",
    ]


def _restart_lines(idata: Any) -> list[str]:
    """The chains the sampler restarted at the end of the burn-in, in one paragraph (none:
    no lines)."""
    records = list(idata.attrs.get("restarted_chains", None) or [])
    if not records:
        return []
    threshold = restart_threshold(len(idata.attrs["param_names"]))
    return [f"Chains {restarted_message(records, threshold)}.", ""]


def convergence_table(idata: Any) -> str:
    """A Markdown table: each parameter's posterior mean, sd, R-hat, bulk and tail ESS, and
    a flag where R-hat > 1.01 or an ESS < 400 (the thresholds of
    :mod:`symplid.inference._diagnostics`)."""

    with quiet_arviz():  # ArviZ/NumPy on very short chains: the flags say it
        table = diagnostics_summary(idata, show=False, warn=False)
    rows = [
        "| parameter | mean | sd | R-hat | ESS bulk | ESS tail | |",
        "|---|---:|---:|---:|---:|---:|---|",
    ]
    for name, row in table.iterrows():
        rhat, bulk, tail = (float(row[k]) for k in ("r_hat", "ess_bulk", "ess_tail"))
        ok = rhat <= RHAT_THRESHOLD and min(bulk, tail) >= ESS_THRESHOLD
        rows.append(
            f"| {name} | {row['mean']:.4g} | {row['sd']:.3g} | {rhat:.3f} | {bulk:.0f} | "
            f"{tail:.0f} | {'' if ok else 'not converged'} |"
        )
    return "\n".join(rows)
