"""MAP-level sensitivity checks of a fit: the learning step, and the process noise.

Two questions a posterior cannot answer about itself, each answered by one more MAP search
with one setting changed, the shift of every coefficient measured in the fit's posterior
standard deviations (the Laplace sds of its MAP):

* **step size**: the MAP refitted at dt/2 (``model.dt`` halved, everything else equal). The
  integrator's error is O(dt^p); a coefficient that moves by more than :data:`THRESHOLD_SD`
  posterior sds when dt is halved is biased by the learning step: the warning says to use a
  smaller dt or a higher-order symplectic integrator that the model accepts
  (:func:`step_advice`: ``yoshida4`` for a separable H, ``tao4`` for a non-separable one,
  none when the fit's integrator is already of the highest order).
* **process noise**: the MAP of the same settings with the other likelihood: without process
  noise (``model.process_noise_per = "none"``, :mod:`symplid.model._deterministic`) for a fit
  with, with process noise once per gap for a fit without; the shift of each coefficient and
  the log evidence of both (``symplid compare --process-noise`` ranks them the same way). A
  large shift means the answer depends on Σ: the evidence says which model the data prefer.

:func:`sensitivity_checks` runs both and returns a JSON-ready dict; :func:`sensitivity_lines`
turns it into the Markdown of a report. The refits start from the fit's MAP (without its
process variance for the refit without process noise, the homotopy of
:mod:`symplid.inference.map._homotopy`), so each costs a short search and one compilation.

A user's fit runs both right after its MAP (``map.sensitivity = true``, the default;
:func:`symplid.workflow._fit.fit`), saves them as ``diagnostics.json`` in the run folder and
prints :func:`sensitivity_summary`; ``symplid report`` shows them without recomputing. A check
that cannot be made (its refit raised, or its MAP search failed) is recorded as
``{"not_available": reason}`` and never fails the fit; a stop asked for during a refit
(:mod:`symplid._stopping`) is obeyed at its next evaluation.
"""

from __future__ import annotations

import dataclasses
import re
import time
from typing import Any

import numpy as np

from symplid.dynamics._integrators import INTEGRATORS, get_integrator
from symplid.dynamics._nonseparable import TaoIntegrator
from symplid.inference.map import find_map, without_process_var
from symplid.io import as_list
from symplid.workflow._building import build_model, build_posterior
from symplid.workflow._model_builder import model_family
from symplid.workflow._scaling import scaling_for

__all__ = [
    "DYNAMICS_GROUPS",
    "THRESHOLD_SD",
    "fit_posterior",
    "process_noise_check",
    "refit_map",
    "sensitivity_checks",
    "sensitivity_lines",
    "sensitivity_summary",
    "step_advice",
    "step_size_check",
]

THRESHOLD_SD = 0.3
"""A coefficient whose MAP moves by more than this many posterior sds is flagged."""

DYNAMICS_GROUPS = ("coefficients", "parameters", "damping")
"""The parameter groups whose shifts are measured: the dynamics' (a polynomial's
coefficients, a user model's parameters, the damping rate), not the noise variances or x0."""


def refit_map(settings: Any, obs: Any, init: np.ndarray | None = None,
              compute_hessian: bool = True, search: Any = None,
              plan: Any = None, posterior: Any = None) -> tuple[Any, Any]:
    """(MAP result in the data's units, posterior) of ``settings`` on ``obs``, one start.

    The fit runs in standardised coordinates when ``settings`` ask for them (as a fit does,
    :mod:`symplid.workflow._scaling`); ``init`` is a θ in the data's units, or None for the
    default start. Without ``compute_hessian`` the refit has no covariance and no evidence
    (the step-size check needs neither: one compilation and the quadrature saved).
    ``search(settings, posterior)``, given, replaces the one start (without ``init``): the
    fit's whole search (:func:`symplid.workflow._fit.find_map_for`) in the fit's coordinates.
    ``plan``: the fit's :class:`~symplid.workflow._plan.ModelPlan`, whose U or H the refit
    reuses (no second parse of a user's expression); None builds it from ``settings``.
    ``posterior``: the posterior of these very settings in the fit's coordinates, returned by
    an earlier refit; its compiled programs (the search's objective and Hessian, cached on
    it) are reused instead of compiled again.
    """
    scaling = scaling_for(settings, obs)
    if posterior is None:
        posterior = fit_posterior(settings, obs, scaling, plan)
    groups = posterior.param_groups
    start = None
    if init is not None:
        start = np.asarray(init, dtype=float)
        if scaling is not None:
            start = scaling.reparameterisation(groups).to_unconstrained(start)
    if search is not None and start is None:
        result = search(settings if scaling is None else scaling.settings(settings), posterior)
    else:
        result = find_map(posterior, seed=settings.map.seed, num_starts=1, init=start,
                          evidence=settings.map.evidence, warn=False,
                          compute_hessian=compute_hessian)
    if scaling is not None:
        result = scaling.map_result(result, groups, obs)
    return result, posterior


def fit_posterior(settings: Any, obs: Any, scaling: Any, plan: Any) -> Any:
    """The posterior of ``settings`` on ``obs`` in the fit's coordinates (standardised when
    ``scaling`` is given)."""
    fit_settings = settings if scaling is None else scaling.settings(settings)
    fit_obs = obs
    if scaling is not None:
        scaled = [scaling.observations(o) for o in as_list(obs)]
        fit_obs = scaled if isinstance(obs, list) else scaled[0]
    model = (build_model(fit_settings, fit_obs) if plan is None
             else plan.model(fit_settings, fit_obs))
    return build_posterior(fit_settings, fit_obs, model)


def _shifts(names: list[str], groups: list[str], base: Any, other: Any,
            other_names: list[str]) -> dict[str, float]:
    """Each coefficient's change from ``base`` to ``other`` in ``base``'s posterior sds."""
    if base.covariance is None:
        return {}
    sd = np.sqrt(np.maximum(np.diag(np.asarray(base.covariance)), 0.0))
    theta, alt = np.asarray(base.theta), np.asarray(other.theta)
    index = {n: i for i, n in enumerate(other_names)}
    return {n: float((alt[index[n]] - theta[i]) / sd[i])
            for i, (n, g) in enumerate(zip(names, groups, strict=True))
            if g in DYNAMICS_GROUPS and n in index and sd[i] > 0}


def _check(shifts: dict[str, float]) -> list[str]:
    return [n for n, z in shifts.items() if not abs(z) <= THRESHOLD_SD]


def step_size_check(settings: Any, obs: Any, posterior: Any, map_result: Any,
                    plan: Any = None) -> dict:
    """The MAP refitted at dt/2 (started from the fit's): ``dt``, ``dt_refit``, ``shifts``
    (coefficient → change in the fit's posterior sds) and ``flagged`` (above
    :data:`THRESHOLD_SD`). Arguments as :func:`sensitivity_checks`."""
    m = settings.model
    half = dataclasses.replace(settings, model=dataclasses.replace(m, dt=m.dt / 2))
    half_map, half_post = refit_map(half, obs, np.asarray(map_result.theta),
                                    compute_hessian=False, plan=plan)
    _refit_found(half_map)
    shifts = _shifts(list(posterior.param_names), list(posterior.param_groups), map_result,
                     half_map, list(half_post.param_names))
    return {"dt": m.dt, "dt_refit": m.dt / 2, "shifts": shifts, "flagged": _check(shifts),
            "advice": step_advice(settings, obs, plan)}


def step_advice(settings: Any, obs: Any, plan: Any = None) -> str:
    """What to do about a learning step that biases the fit: ``"use a smaller dt or NAME"``,
    NAME the first registered symplectic integrator of a higher order than the fit's that a
    model of these settings accepts (the model is built with it to find out), or ``"use a
    smaller dt"`` when there is none."""
    m = settings.model
    order = get_integrator(m.integrator).order
    for name, entry in INTEGRATORS.items():
        if not entry.symplectic or entry.order <= order:
            continue
        binding = m.binding if isinstance(entry, TaoIntegrator) else 0.0
        other = dataclasses.replace(settings, model=dataclasses.replace(
            m, integrator=name, binding=binding))
        try:
            build_model(other, obs) if plan is None else plan.model(other, obs)
        except ValueError:  # the model refuses this integrator
            continue
        return f"use a smaller dt or {name}"
    return "use a smaller dt"


def process_noise_check(settings: Any, obs: Any, posterior: Any, map_result: Any,
                        plan: Any = None) -> dict:
    """The MAP with the other likelihood (without process noise for a fit with, with for a
    fit without): ``fitted``, ``refit`` (the ``model.process_noise_per`` of each), ``shifts``,
    ``flagged`` and the ``log_evidence`` of both. Arguments as :func:`sensitivity_checks`."""
    m = settings.model
    groups = list(posterior.param_groups)
    deterministic = m.process_noise_per == "none"
    other = "gap" if deterministic else "none"
    alt_settings = dataclasses.replace(settings, model=dataclasses.replace(
        m, process_noise_per=other))
    # without Σ: start from the fit's MAP less its process variance (the homotopy); with Σ:
    # the default start (a large process variance)
    init = None if deterministic else without_process_var(groups, map_result.theta)
    alt_map, alt_post = refit_map(alt_settings, obs, init, plan=plan)
    _refit_found(alt_map)
    shifts = _shifts(list(posterior.param_names), groups, map_result, alt_map,
                     list(alt_post.param_names))
    return {"fitted": m.process_noise_per, "refit": other, "shifts": shifts,
            "flagged": _check(shifts), "log_evidence": float(map_result.log_evidence),
            "log_evidence_refit": float(alt_map.log_evidence)}


def _refit_found(result: Any) -> None:
    """Refuse a refit whose MAP search failed (:mod:`symplid.inference.map._checks`): its
    shifts would measure the search, not the setting."""
    if getattr(result, "failure", ""):
        raise ValueError(f"the refit's MAP search failed (the best point {result.failure})")


def _unavailable(settings: Any, map_result: Any) -> str:
    """Why no check can be made for this fit ("" when they can)."""
    if model_family(settings.model).neural:
        return ("a neural family's MAP is its whole Adam + L-BFGS fit: refitting it twice is "
                "not a cheap check")
    if getattr(map_result, "covariance", None) is None:
        return "the fit's MAP has no Laplace covariance to measure the shifts in"
    return ""


def _safely(check: Any, *args: Any, **kwargs: Any) -> dict:
    """``check(*args)``, or ``{"not_available": reason}`` when it raises (an error, not a
    stop: :class:`~symplid._stopping.StopRequested` is a ``KeyboardInterrupt`` and passes)."""
    try:
        return check(*args, **kwargs)
    except Exception as err:  # a diagnostic never fails the fit it checks
        text = re.sub(r"\s*\([^()]{60,}\)", "", str(err))  # not a whole θ's list of values
        return {"not_available": f"{type(err).__name__}: {text}"}


def sensitivity_checks(settings: Any, obs: Any, posterior: Any, map_result: Any,
                       step_size: dict | None = None, plan: Any = None) -> dict:
    """The step-size and process-noise checks of a fit (module docstring).

    Parameters
    ----------
    settings
        The fit's resolved settings.
    obs
        Its data (one :class:`~symplid.model._data.Observations` or a list), in the data's units.
    posterior, map_result
        The fit's posterior and MAP (with its Laplace covariance), in the data's units.
    step_size
        The step-size check made already (``dt``, ``dt_refit``, ``shifts``: the last halving
        of ``model.dt = "auto"``, :func:`symplid.workflow._step_size.step_check`): used
        instead of a refit at dt/2.
    plan
        The fit's :class:`~symplid.workflow._plan.ModelPlan`: the refits reuse its U or H
        (None: each refit builds its own).

    Returns
    -------
    dict
        ``{"threshold_sd": ..., "step_size": {...}, "process_noise": {...}, "seconds": ...}``:
        the results of :func:`step_size_check` and :func:`process_noise_check`, each
        ``{"not_available": reason}`` where it could not be made (it never raises but for a
        stop, :mod:`symplid._stopping`).
    """
    start = time.perf_counter()
    why = _unavailable(settings, map_result)
    args = (settings, obs, posterior, map_result)
    step = ({**step_size, "flagged": _check(step_size["shifts"])} if step_size is not None
            else {"not_available": why} if why
            else _safely(step_size_check, *args, plan=plan))
    return {"threshold_sd": THRESHOLD_SD,
            "step_size": step,
            "process_noise": ({"not_available": why} if why
                              else _safely(process_noise_check, *args, plan=plan)),
            "seconds": time.perf_counter() - start}


def sensitivity_lines(checks: dict) -> list[str]:
    """The Markdown section of a report for :func:`sensitivity_checks`' result, warnings
    first."""
    step, noise = checks["step_size"], checks["process_noise"]
    limit = checks["threshold_sd"]
    lines = ["## Sensitivity (MAP refits)", ""]
    if step.get("flagged"):
        lines += [f"**Warning**: the learning step biases these parameters: "
                  f"{', '.join(step['flagged'])} (they move by more than {limit:g} posterior "
                  f"sds when dt is halved); {_advice(step)}.", ""]
    name = "without" if noise.get("refit", "none") == "none" else "with"
    if noise.get("flagged"):
        lines += [f"**Note**: these parameters depend on the process noise: "
                  f"{', '.join(noise['flagged'])} (they move by more than {limit:g} posterior "
                  f"sds in the fit {name} process noise); compare the evidences below.", ""]
    for title, check in (("Step-size check", step), ("Process-noise check", noise)):
        if "not_available" in check:
            lines += [f"{title}: not available: {check['not_available']}", ""]
    steps, noises = step.get("shifts", {}), noise.get("shifts", {})
    if steps or noises:
        at = f"dt = {step['dt_refit']:g}" if "dt_refit" in step else "dt/2"
        lines += [f"| parameter | shift at {at} (sds) | shift {name} process noise (sds) |",
                  "|---|---:|---:|"]
        lines += [f"| {n} | {_fmt(steps.get(n))} | {_fmt(noises.get(n))} |"
                  for n in steps | noises]
        lines.append("")
    if "log_evidence_refit" in noise:
        lines += [f"Log evidence: this fit {noise['log_evidence']:.2f}, the fit {name} "
                  f"process noise {noise['log_evidence_refit']:.2f}.", ""]
    return lines


def sensitivity_summary(checks: dict) -> list[str]:
    """One or two lines for the end of ``symplid fit``: what the checks found, and a
    warning line when a parameter moves by more than :data:`THRESHOLD_SD` posterior sds."""
    step, noise = checks["step_size"], checks["process_noise"]
    limit = checks["threshold_sd"]
    name = "without" if noise.get("refit", "none") == "none" else "with"
    parts = [f"step-size check not available ({step['not_available']})" if "not_available"
             in step else f"halving dt moves a parameter by at most {_largest(step)}"]
    if "not_available" in noise:
        parts.append(f"process-noise check not available ({noise['not_available']})")
    else:
        parts.append(f"{name} process noise by at most {_largest(noise)}, log evidence "
                     f"{noise['log_evidence_refit']:.2f} against this fit's "
                     f"{noise['log_evidence']:.2f}")
    lines = [f"sensitivity (MAP refits): {'; '.join(parts)}"]
    if step.get("flagged"):
        lines.append(f"warning: the learning step biases {', '.join(step['flagged'])} (more "
                     f"than {limit:g} posterior sds when dt is halved); {_advice(step)}")
    if noise.get("flagged"):
        lines.append(f"note: {', '.join(noise['flagged'])} move by more than {limit:g} "
                     f"posterior sds {name} process noise; the evidences say which model the "
                     "data prefer (symplid compare --process-noise)")
    return lines


def _advice(step: dict) -> str:
    """The step-size check's advice (a run folder written before it had one: a smaller dt,
    the one advice every model accepts), and, for a step the user set, the step chosen from
    the data (``model.dt = "auto"``, :mod:`symplid.workflow._step_size`)."""
    advice = str(step.get("advice", "use a smaller dt"))
    if step.get("auto"):
        return advice
    return f'{advice}, or let the fit choose it from the data (model.dt = "auto", --dt auto)'


def _largest(check: dict) -> str:
    shifts = check.get("shifts", {})
    if not shifts:
        return "— (no parameter to compare)"
    name = max(shifts, key=lambda n: abs(shifts[n]) if np.isfinite(shifts[n]) else np.inf)
    return f"{abs(shifts[name]):.2f} posterior sds ({name})"


def _fmt(value: float | None) -> str:
    return "—" if value is None else f"{value:+.2f}"
