"""What ``symplid fit`` and ``symplid simulate`` do for the command line: read the data, fit or
resume into a run folder, and say the result in one line (the commands themselves, click's
options and the one-line errors are :mod:`symplid.cli`; the values of the options are read by
:mod:`~._commandline`). Nothing here prints: the lines are returned, and the fit's status lines
go to the ``status`` callable the command line passes in.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

from symplid.workflow._commandline import UserError, converged, floats, settings_from_options

__all__ = [
    "diagnostics_lines",
    "fit_result_line",
    "report_after_fit",
    "run_fit",
    "simulate_to_file",
]


def fit_result_line(out: Path, outcome: Any, seconds: float) -> str:
    """The one line ``symplid fit`` prints: MAP, evidence, convergence, or "interrupted"."""
    s = outcome.summary
    extra = ""
    if "rhat_max" in s:
        extra = "; " + _convergence_words(s["rhat_max"], s["ess_min"],
                                          outcome.settings.sampler.num_chains)
        extra += _stopped_words(s)
        if not outcome.interrupted and not converged(s) and s.get("stopped_by") != "target":
            extra += " (not converged: see the warnings; run longer)"
    if s.get("restarted_chains"):
        extra += (f"; {s['restarted_chains']} chain(s) stuck far below the others restarted at "
                  "the end of the burn-in (see the warning)")
    head = f"{out}: "
    if outcome.interrupted:
        total = outcome.settings.sampler.iterations_cap
        head += (f"interrupted after {s['iterations_done']:,} of {total:,} iterations, draws "
                 "kept (continue with --resume); ")
    if s.get("map_optima", 1) > 1:
        extra += (f"; the {outcome.settings.map.num_starts} MAP starts ended in "
                  f"{s['map_optima']} different optima (spread {s['map_optima_spread']:.2f} "
                  "nats; the best is used)")
    if s.get("map_refound"):
        from symplid.workflow._mode_watch import refound_line

        extra += f"; {refound_line(s['map_refound'])}"
    if s.get("learning_step"):
        from symplid.workflow._step_size import step_line

        head += f"{step_line(s['learning_step'])}; "
    return (
        f"{head}MAP log posterior {s['map_log_posterior']:.2f}, log evidence "
        f"{s['log_evidence']:.2f} ({s['evidence_method']}; Laplace "
        f"{s['log_evidence_laplace']:.2f}){extra}; {seconds:.0f} s"
    )


def diagnostics_lines(out: Path, outcome: Any = None) -> list[str]:
    """The lines ``symplid fit`` and ``symplid report`` show for the run's sensitivity checks
    (:func:`~symplid.workflow._sensitivity.sensitivity_summary`; none when the run has none):
    the fit's ``outcome``'s, else the run folder's ``diagnostics.json``. An unreadable
    ``diagnostics.json`` is one line, never an error."""
    from symplid.workflow._results import RunFolder
    from symplid.workflow._sensitivity import sensitivity_summary

    checks = getattr(outcome, "diagnostics", None)
    try:
        if checks is None and (Path(out) / RunFolder.DIAGNOSTICS).exists():
            checks = RunFolder(out, "r", allow_incomplete=True).read_json(RunFolder.DIAGNOSTICS)
        return [] if checks is None else [f"{out}: {line}" for line in
                                          sensitivity_summary(checks)]
    except Exception as err:
        return [f"{out}: the sensitivity checks cannot be shown ({type(err).__name__}: {err})"]


def report_after_fit(out: Path, plan: Any = None) -> str:
    """``symplid report`` at the end of a fit; the fit is finished whatever happens here, so
    a failure is one warning line rather than an error. ``plan``: the fit's
    :class:`~symplid.workflow._plan.ModelPlan` (``FitOutcome.plan``), reused by the report."""
    from symplid.workflow._run_tools import report_run

    try:
        return report_run(out, plan)
    except Exception as err:
        return (f"{out}: the run is finished, but writing its report failed "
                f"({type(err).__name__}: {err}); try 'symplid report {out}'")


def _stopped_words(summary: dict[str, Any]) -> str:
    """What ended the sampling, in words (nothing for a fixed budget or an interruption)."""
    stopped, iterations = summary.get("stopped_by"), summary.get("iterations", 0)
    if stopped == "target":
        t = summary.get("targets", {})
        return (f"; target reached after {iterations:,} iterations per chain (ESS ≥ "
                f"{t.get('ess_bulk', 0):g}, R-hat ≤ {t.get('rhat', 0):g}; burn-in "
                f"{summary.get('burn_in', 0):,})")
    if stopped in ("iterations", "wall time"):
        from symplid.sampling._budget import two_figures

        projected = summary.get("projected_iterations")
        need = ("" if projected is None else
                f"; at the rate seen they need about {two_figures(projected):,}")
        return (f"; cap reached ({stopped}) after {iterations:,} iterations per chain, before "
                f"the targets{need} (raise sampler.max_iterations or sampler.max_seconds, or "
                "try another sampler.method)")
    return ""


def _convergence_words(rhat: float, ess: float, chains: int) -> str:
    if not math.isfinite(ess):
        return "R-hat and ESS not computable (too few draws)"
    if not math.isfinite(rhat):
        why = " with one chain" if chains == 1 else ""
        return f"R-hat not computable{why}, min ESS {ess:.0f}"
    return f"max R-hat {rhat:.3f}, min ESS {ess:.0f}"


def simulate_to_file(system: str, out: Path, t_end: float | None, num_obs: int | None,
                     times: str | None, noise_std: float | None, seed: int, observation: str,
                     x0: str | None, missing: float, observation_noise: str = "additive",
                     rel_std: float = 0.05) -> str:
    """``symplid simulate``: write noisy observations of a named system; returns its line."""
    import numpy as np

    from symplid.dynamics._systems import get_system
    from symplid.io import write_observations
    from symplid.model._data import Observations
    from symplid.model._simulate import simulate as run

    sys_ = get_system(system)
    grid = floats(times, "--times")
    if grid is None and (t_end is not None or num_obs is not None):
        n = num_obs or sys_.num_obs
        end = t_end if t_end is not None else sys_.obs_interval * n
        if end <= 0:
            raise UserError(f"--t-end must be positive, got {end}")
        grid = list(end / n * np.arange(1, n + 1))
    start = floats(x0, "--x0")
    obs = run(sys_, times=grid, noise_std=noise_std, seed=seed, x0=start,
              observation=observation, observation_noise=observation_noise, rel_std=rel_std)
    if missing > 0:
        rng = np.random.default_rng(seed + 1)
        values = np.array(obs.values)
        values[rng.random(values.shape) < missing] = np.nan
        obs = Observations(obs.times, values, obs.names)
    path = write_observations(obs, out)
    shown = ", ".join(f"{v:g}" for v in (start or sys_.initial_state))
    return f"{path}: {obs.num_times} times × {obs.dim} components of {sys_.name} (x0 = {shown})"


def run_fit(paths: tuple[Path, ...], out: Path, config: Path | None, overrides: dict[str, Any],
            sets: tuple[str, ...], holdout: tuple[float | None, float | None], overwrite: bool,
            resume: bool, no_progress: bool,
            status: Callable[[str], None] | None = None) -> tuple[Any, Any]:
    """``symplid fit``: a new run from the data files, or ``--resume`` of an interrupted one.
    Returns the outcome and the held-out observations (or None). ``status`` receives the fit's
    status lines (what it is doing; none with ``no_progress``)."""
    from symplid.sampling import SamplingInterrupted

    with warnings.catch_warnings():
        # The fit's own line says that (and where) the sampler was stopped: the sampler's
        # warning would be a second line.
        warnings.simplefilter("ignore", SamplingInterrupted)
        return _run_fit(paths, out, config, overrides, sets, holdout, overwrite, resume,
                        no_progress, None if no_progress else status)


def _run_fit(paths, out, config, overrides, sets, holdout, overwrite, resume, no_progress,
             status):
    from symplid.workflow._fit import fit

    given = config is not None or bool(sets) or any(v is not None for v in overrides.values())
    if resume and out is None:
        raise UserError("--resume continues the run in --out RUN: give --out")
    if resume:
        if overwrite:
            raise UserError("--resume continues the run in --out; --overwrite would replace it")
        return _resume(paths, out, config, overrides, sets, holdout, given, no_progress, status)
    if not paths:
        raise UserError("give the DATA file(s) to fit (or --resume an interrupted run)")
    if out is None:
        raise UserError("give the run folder to write: --out RUN")
    settings, source = settings_from_options(config, overrides, sets)
    obs, heldout = _read_fit_data(paths, holdout, settings)
    outcome = fit(obs, settings, out=out, progress=not no_progress, source=source,
                  overwrite=overwrite, warn=True, status=status)
    return outcome, heldout


def _read_fit_data(paths: tuple[Path, ...], holdout: tuple[float | None, float | None],
                   settings: Any = None):
    from symplid.io import read_trajectories
    from symplid.workflow._driven import is_driven, read_driven, refuse_forecast

    if settings is not None and is_driven(settings.model):  # the inputs with the data
        if holdout != (None, None):  # refused before the fit, not after it
            refuse_forecast(settings, "--holdout (scored by a forecast from the end of the "
                            "data)")
        obs = read_driven(paths, settings)
    else:
        obs = read_trajectories(paths)
    if holdout == (None, None):
        return obs, None
    from symplid.workflow._forecasting import split_holdout

    if isinstance(obs, list):
        raise UserError("--holdout scores a forecast of one trajectory; give one")
    return split_holdout(obs, *holdout)


def _resume(paths, out, config, overrides, sets, holdout, given, no_progress, status):
    from symplid.workflow._resume import resume_fit
    from symplid.workflow._settings import resolve_for_data

    heldout = None
    if paths:
        obs, heldout = _read_fit_data(paths, holdout)
    elif holdout != (None, None):
        raise UserError("--holdout with --resume needs the DATA file(s) again")

    def expected(run_settings: Any, run_obs: Any) -> Any:
        if paths and not _same_data(obs, run_obs):
            raise UserError(f"{out}: the DATA given are not the data of the run; --resume "
                            "continues the run with its own data (give none, or the same)")
        if not given:
            return None
        asked, source = settings_from_options(config, dict(overrides), sets, base=run_settings)
        return resolve_for_data(asked, run_obs, source)

    outcome = resume_fit(out, progress=not no_progress, warn=True, status=status,
                         expected=expected)
    return outcome, heldout


def _same_data(a: Any, b: Any) -> bool:
    import numpy as np

    a, b = (list(x) if isinstance(x, list | tuple) else [x] for x in (a, b))
    return len(a) == len(b) and all(
        np.array_equal(x.times, y.times) and np.array_equal(x.values, y.values, equal_nan=True)
        for x, y in zip(a, b, strict=True))
