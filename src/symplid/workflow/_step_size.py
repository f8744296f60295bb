"""``model.dt = "auto"``: the learning step chosen from the data by step doubling.

The integrator Ψ of eq. (14) makes the MAP depend on the learning step: an integrator of
order p moves it by about C·dt^p. A fit at a given dt cannot see this bias; halving the step
shows it (Richardson): θ̂(dt) − θ̂(dt/2) ≈ C·dt^p·(1 − 2^−p). The search chooses **the largest
step whose halving moves no dynamics parameter** (:data:`~symplid.workflow._sensitivity.
DYNAMICS_GROUPS`) **by more than** :data:`THRESHOLD_SD` **posterior sds at the MAP**, never
above the first candidate:

1. the first candidate (:func:`first_candidate`) is the data's smallest gap (a step above it
   would be cut to the gap anyway, ⌈gap/dt⌉ = 1) — or, on irregular times, a quarter of the
   median gap where that is larger (:data:`MEDIAN_FRACTION`), so that one close pair of
   observations does not set the step of every gap (measured: a pair 0.0045 apart among
   gaps of median 0.48 put 600 substeps into the longest gap, where the check passes at
   0.15); the gaps shorter than the step are integrated in one step of their own length,
   and the halving check below decides as for any candidate. That step is then halved
   until it resolves the fastest motion the data show (:func:`resolving_step`: rate × dt
   ≤ :data:`RESOLVE`, the rate read from the MAP's data starts without a filter). The
   halving check cannot see a step that is too long for the motion: a Morse oscillator
   sampled 3.5 times a period was searched at its gap, 0.8, where leapfrog is unstable at
   the true parameters (ω·dt from 2.1 to 3.8 along the path), so every start found a slow
   motion instead, and dt/2 warm-started from there agreed with it. Its MAP is the fit's
   whole search (``map.num_starts`` starts and the Laplace sds). If that search fails, the
   step is halved and searched again (up to :data:`MAX_FIRST_TRIES` times);
2. the MAP at dt/2 is found from the MAP at dt (one warm start, no Hessian) and each
   parameter's move is measured in the sds of the last Laplace covariance;
3. a move above the threshold: the integrator's order p predicts how many halvings bring it
   under (the move shrinks by 2^p per halving), and the search jumps there (at most
   :data:`MAX_JUMP` halvings at once, from the nearest MAP found);
4. a move under the threshold measured in another step's sds: the Laplace sds at this dt are
   computed and the move measured again in them; under: this dt is chosen.

Each candidate costs one warm-started MAP refit (:func:`map_at_step`, the one function the
search calls for a MAP at another step). The choice and its check are a JSON-ready record
(:func:`choose_step`) that ``fit`` saves in ``summary.json`` (``learning_step``), prints in its
line (:func:`step_line`) and the report shows (:func:`step_lines`). The search never runs
after it has found its step: the fit then starts from the MAP at the chosen step.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from symplid.dynamics._integrators import get_integrator
from symplid.io import as_list
from symplid.workflow._model_builder import model_family
from symplid.workflow._scaling import scaling_for
from symplid.workflow._sensitivity import DYNAMICS_GROUPS, fit_posterior, refit_map

__all__ = [
    "MAX_FIRST_TRIES",
    "MAX_HALVINGS",
    "MAX_JUMP",
    "MEDIAN_FRACTION",
    "RESOLVE",
    "THRESHOLD_SD",
    "UNSEARCHED_STEP",
    "StepChoice",
    "choose_step",
    "first_candidate",
    "map_at_step",
    "resolving_step",
    "smallest_gap",
    "step_check",
    "step_line",
    "step_lines",
    "unchecked_step",
]

THRESHOLD_SD = 0.1
"""The largest move of a dynamics parameter, in posterior sds, that halving the chosen step
may cause."""

MAX_HALVINGS = 8
"""The chosen step is at least the first candidate / 2^MAX_HALVINGS; a search that reaches it
keeps it and says that the check did not pass."""

MEDIAN_FRACTION = 4
"""On irregular times the first candidate is at least the median gap over this."""

MAX_JUMP = 3
"""The most halvings the order's prediction may skip at once."""

RESOLVE = 1.0
"""The first candidate is halved until the fastest rate the data show times the step is at
most this (:func:`resolving_step`): an oscillation of angular frequency ω gets at least 2π
steps a period, inside leapfrog's stability limit ω·dt < 2 with a margin of two."""

MAX_FIRST_TRIES = 3
"""How many steps (each half the last) the first, whole MAP search is tried at."""

UNSEARCHED_STEP = 0.25
"""The step of a family whose MAP is too costly to refit (a neural one): the library's fixed
step before ``"auto"`` became the default, at most the data's smallest gap, unchecked."""


@dataclass
class StepChoice:
    """The outcome of :func:`choose_step`: the settings at the chosen step, the MAP there (in
    the data's units, to start the fit from), the record saved with the run and the posterior
    at the chosen step in the fit's coordinates (the fit runs on it: the programs the search
    compiled at that step, its objective and Hessian, are not compiled again)."""

    settings: Any
    theta: np.ndarray | None
    record: dict[str, Any] = field(default_factory=dict)
    posterior: Any = None


def _gaps(obs: Any, t0: float | str) -> np.ndarray:
    """The positive times between consecutive observations (and between ``t0`` and the
    first, for a numeric ``t0``) over every trajectory."""
    gaps = []
    for o in as_list(obs):
        times = np.asarray(o.times, dtype=float)
        if not isinstance(t0, str):
            times = np.concatenate([[float(t0)], times])
        diffs = np.diff(times)
        gaps.append(diffs[diffs > 0])
    positive = np.concatenate(gaps)
    if positive.size == 0:
        raise ValueError("the data have no two distinct observation times to choose dt from")
    return positive


def smallest_gap(obs: Any, t0: float | str = "first") -> float:
    """The smallest positive time between consecutive observations (and between ``t0`` and
    the first, for a numeric ``t0``) over every trajectory."""
    return float(np.min(_gaps(obs, t0)))


def first_candidate(obs: Any, t0: float | str = "first") -> float:
    """The search's first (and largest) step: the smallest gap, or the median gap over
    :data:`MEDIAN_FRACTION` where that is larger (irregular times; module docstring)."""
    gaps = _gaps(obs, t0)
    return float(max(np.min(gaps), np.median(gaps) / MEDIAN_FRACTION))


def resolving_step(settings: Any, obs: Any, gap: float, plan: Any = None
                   ) -> tuple[float, float]:
    """(the first candidate ``gap`` halved until it resolves the fastest motion the data
    show, that rate): while rate × dt > :data:`RESOLVE`, dt is halved (at most
    :data:`MAX_HALVINGS` times); the rate is :func:`~symplid.inference.map.fastest_rate` of the
    data start (NaN, and ``gap`` itself, when the data start cannot be read)."""
    from symplid.inference.map import fastest_rate

    at = dataclasses.replace(settings, model=dataclasses.replace(settings.model, dt=float(gap)))
    rate = fastest_rate(fit_posterior(at, obs, scaling_for(at, obs), plan))
    dt = gap
    for _ in range(MAX_HALVINGS):
        if not rate * dt > RESOLVE:
            break
        dt /= 2
    return dt, rate


def map_at_step(settings: Any, obs: Any, dt: float, init: np.ndarray | None = None,
                hessian: bool = False, search: Callable | None = None,
                plan: Any = None, posterior: Any = None) -> tuple[Any, Any]:
    """(MAP in the data's units, posterior) of ``settings`` at learning step ``dt``: from
    ``init`` (θ in the data's units, one start: a warm start from the MAP at another step),
    or, without ``init``, by ``search(settings, posterior)`` (the fit's whole search). The
    Laplace covariance only with ``hessian`` (or from ``search``); the evidence is always
    Laplace's (the search reads the sds only: no quadrature, which the fit computes once, at
    the chosen step). ``plan``: the fit's
    :class:`~symplid.workflow._plan.ModelPlan`, whose U or H every refit reuses. ``posterior``:
    the one an earlier call at this ``dt`` returned (its compiled programs are reused)."""
    at = dataclasses.replace(settings, model=dataclasses.replace(settings.model, dt=float(dt)),
                             map=dataclasses.replace(settings.map, evidence="laplace"))
    return refit_map(at, obs, init, compute_hessian=hessian,
                     search=search if init is None else None, plan=plan, posterior=posterior)


def _sds(result: Any) -> np.ndarray:
    return np.sqrt(np.maximum(np.diag(np.asarray(result.covariance)), 0.0))


def _moves(names: list[str], groups: list[str], base: np.ndarray, half: np.ndarray,
           sds: np.ndarray) -> dict[str, float]:
    """Each dynamics parameter's move from ``base`` (at dt) to ``half`` (at dt/2), in sds."""
    return {n: float((half[i] - base[i]) / sds[i])
            for i, (n, g) in enumerate(zip(names, groups, strict=True))
            if g in DYNAMICS_GROUPS and sds[i] > 0}


def _largest(moves: dict[str, float]) -> float:
    values = [abs(z) if np.isfinite(z) else np.inf for z in moves.values()]
    return max(values, default=0.0)


def _halvings(largest: float, order: int) -> int:
    """Halvings that bring a move of ``largest`` sds under the threshold, predicted from the
    integrator's order (each halving divides the move by 2^order); 1 to :data:`MAX_JUMP`."""
    if not np.isfinite(largest):
        return 1
    need = math.ceil(math.log2(largest / THRESHOLD_SD) / order)
    return int(min(max(need, 1), MAX_JUMP))


@dataclass
class _Search:
    """The state of one search: the MAPs found (dt → θ), the last Laplace sds and where they
    were computed, the candidates' record and the refits made."""

    settings: Any
    obs: Any
    names: list[str]
    groups: list[str]
    order: int
    sds: np.ndarray
    sds_dt: float
    maps: dict[float, np.ndarray]
    candidates: list[tuple[float, float, bool]] = field(default_factory=list)
    refits: int = 0
    plan: Any = None
    posteriors: dict[float, Any] = field(default_factory=dict)

    def refit(self, dt: float, init: np.ndarray, hessian: bool = False) -> Any:
        """The MAP at ``dt`` from ``init`` (data units), on the posterior kept for ``dt``.

        A refit without the Hessian that failed is judged again with it, from where it
        stopped: a line search that can gain nothing more at the optimum (the objective's
        rounding-level roughness) is convergence when the Newton decrement says so, as for
        the fit's own MAP (:func:`~symplid.inference.map._search.judge_with_hessian`)."""
        result, self.posteriors[dt] = map_at_step(self.settings, self.obs, dt, init,
                                                  hessian=hessian, plan=self.plan,
                                                  posterior=self.posteriors.get(dt))
        if getattr(result, "failure", "") and not hessian:
            result, _ = map_at_step(self.settings, self.obs, dt, result.theta, hessian=True,
                                    plan=self.plan, posterior=self.posteriors[dt])
        _found(result, dt)
        self.refits += 1
        self.maps[dt] = np.asarray(result.theta, dtype=float)
        return result

    def theta_at(self, dt: float) -> np.ndarray:
        """The MAP at ``dt``, refitted from the MAP found at the nearest step if not known."""
        if dt not in self.maps:
            nearest = min(self.maps, key=lambda s: abs(math.log(s / dt)))
            self.refit(dt, self.maps[nearest])
        return self.maps[dt]

    def laplace_at(self, dt: float) -> None:
        """The Laplace sds at ``dt`` (one refit from its MAP, with the Hessian)."""
        result = self.refit(dt, self.theta_at(dt), hessian=True)
        self.sds, self.sds_dt = _sds(result), dt

    def check(self, dt: float) -> dict[str, float]:
        """The moves from the MAP at ``dt`` to the MAP at dt/2, in the current sds."""
        moves = _moves(self.names, self.groups, self.theta_at(dt), self.theta_at(dt / 2),
                       self.sds)
        self.candidates.append((dt, _largest(moves), self.sds_dt == dt))
        return moves


def _found(result: Any, dt: float) -> None:
    """Refuse a refit whose MAP search failed: the fit stops in one line, as for its own MAP."""
    if getattr(result, "failure", ""):
        from symplid.inference.map import MapFailedError, failure_message

        raise MapFailedError(f'model.dt = "auto": at dt = {dt:g}, '
                             f"{failure_message(result.failure, 'settings')}")


def _first_search(settings: Any, obs: Any, gap: float, search: Callable | None,
                  status: Callable[[str], None] | None,
                  plan: Any = None) -> tuple[float, Any, Any, int]:
    """The fit's whole MAP search at the first candidate, at half of it if it fails, ...: (dt,
    MAP in the data's units, posterior, tries). Raises the last failure's MapFailedError."""
    from symplid.inference.map import MapFailedError, failure_message

    dt, result, posterior = gap, None, None
    for tries in range(1, MAX_FIRST_TRIES + 1):
        if status is not None:
            status(f'model.dt = "auto": the MAP at dt = {dt:g} (the first candidate step)...')
        result, posterior = map_at_step(settings, obs, dt, search=search, plan=plan)
        if not getattr(result, "failure", "") and result.covariance is not None:
            return dt, result, posterior, tries
        dt /= 2
    raise MapFailedError(failure_message(result.failure or "has no Laplace covariance",
                                         "settings"))


def choose_step(settings: Any, obs: Any, search: Callable | None = None,
                status: Callable[[str], None] | None = None, plan: Any = None) -> StepChoice:
    """The learning step of ``model.dt = "auto"`` (module docstring) for resolved
    ``settings`` on ``obs`` (one :class:`~symplid.model._data.Observations` or a list).

    Parameters
    ----------
    settings
        The fit's settings, resolved for the data, ``model.dt = "auto"``.
    obs
        The data, in the data's units.
    search
        ``search(settings, posterior)`` → MapResult: the fit's whole MAP search
        (:func:`~symplid.workflow._fit.find_map_for`); None: one start at the default.
    status
        Receives one line before each phase.
    plan
        The fit's :class:`~symplid.workflow._plan.ModelPlan`: every refit reuses its U or H
        (no second parse of a user's expression); None: each builds its own.

    Returns
    -------
    StepChoice
        The settings with the chosen ``model.dt``, the MAP there and the record:
        ``dt``, ``smallest_gap``, ``first_candidate``, ``integrator``, ``order``,
        ``threshold_sd``, ``shifts`` (each dynamics parameter's move when the chosen step is
        halved, in its Laplace sds),
        ``largest_shift_sd``, ``passed``, ``tried`` (each step tried and its largest move, in
        words), ``refits`` and ``seconds``.
    """
    start = time.perf_counter()
    if model_family(settings.model).neural:
        return unchecked_step(settings, obs, "a neural family's MAP is its whole Adam + L-BFGS "
                              "fit, too costly to refit")
    gap, rate = resolving_step(settings, obs, first_candidate(obs, settings.initial_state.t0),
                               plan)
    base = {**_base(settings, smallest_gap(obs, settings.initial_state.t0)),
            "first_candidate": gap, "fastest_rate": rate if math.isfinite(rate) else None}
    order = base["order"]
    dt, first, posterior, tries = _first_search(settings, obs, gap, search, status, plan)
    state = _Search(settings, obs, list(posterior.param_names), list(posterior.param_groups),
                    order, _sds(first), dt, {dt: np.asarray(first.theta, dtype=float)},
                    plan=plan, posteriors={dt: posterior})
    if status is not None:
        status(f'model.dt = "auto": halving the step until no parameter moves by more than '
               f"{THRESHOLD_SD:g} posterior sds...")
    moves, passed, smallest = {}, False, gap / 2**MAX_HALVINGS
    while dt >= smallest:
        moves = state.check(dt)
        largest = _largest(moves)
        if largest <= THRESHOLD_SD and state.sds_dt != dt:
            state.laplace_at(dt)  # measure the move in this step's own sds
            moves = state.check(dt)
            largest = _largest(moves)
        if largest <= THRESHOLD_SD:
            passed = True
            break
        dt = max(dt / 2 ** _halvings(largest, order), smallest)
        if dt == smallest and any(c[0] == dt for c in state.candidates):
            break
    dt = min(dt, *(c[0] for c in state.candidates))
    tried = ", ".join(f"{c:.4g}: {z:.3g}" + (" (its own sds)" if own else "")
                      for c, z, own in state.candidates)
    record = {**base, "dt": dt, "shifts": moves, "largest_shift_sd": _largest(moves),
              "passed": passed, "tried": tried, "refits": state.refits + tries,
              "seconds": time.perf_counter() - start}
    chosen = dataclasses.replace(settings, model=dataclasses.replace(settings.model, dt=dt))
    return StepChoice(chosen, state.theta_at(dt), record, state.posteriors.get(dt))


def _base(settings: Any, gap: float) -> dict[str, Any]:
    """The record's entries that do not depend on the search."""
    return {"smallest_gap": gap, "integrator": settings.model.integrator,
            "order": int(get_integrator(settings.model.integrator).order),
            "threshold_sd": THRESHOLD_SD}


def unchecked_step(settings: Any, obs: Any, why: str) -> StepChoice:
    """The step of ``model.dt = "auto"`` where the search cannot run (``why``): min(the data's
    smallest gap, :data:`UNSEARCHED_STEP`), unchecked; no MAP. Its line says why and that a
    given ``model.dt`` is chosen instead."""
    gap = smallest_gap(obs, settings.initial_state.t0)
    dt = min(gap, UNSEARCHED_STEP)
    chosen = dataclasses.replace(settings, model=dataclasses.replace(settings.model, dt=dt))
    why = (f"{why}: the step is min(the data's smallest gap, {UNSEARCHED_STEP:g}), unchecked; "
           "give model.dt to choose it")
    record = {**_base(settings, gap), "dt": dt, "shifts": {}, "largest_shift_sd": None,
              "passed": False, "not_searched": why, "tried": "", "refits": 0, "seconds": 0.0}
    return StepChoice(chosen, None, record)


def step_line(record: dict[str, Any]) -> str:
    """The words of the fit's line for a chosen step."""
    if "not_searched" in record:
        return f"dt = {record['dt']:.4g} (auto: {record['not_searched']})"
    verdict = "≤" if record["passed"] else ">"
    return (f"dt = {record['dt']:.4g} (auto, {record['integrator']}: halving it moves a "
            f"parameter by {record['largest_shift_sd']:.2f} {verdict} {record['threshold_sd']:g}"
            f" posterior sds; {record['refits']} MAP refits)")


def step_lines(record: dict[str, Any]) -> list[str]:
    """The Markdown section of a report for a step chosen by ``model.dt = "auto"``."""
    lines = ["## Learning step (model.dt = \"auto\")", ""]
    if "not_searched" in record:
        return [*lines, f"dt = {record['dt']:.4g}: {record['not_searched']}.", ""]
    if not record["passed"]:
        lines += [f"**Warning**: no step down to {record['dt']:.4g} passed the check: the "
                  "learning step may still bias the parameters; use a higher-order integrator "
                  "(yoshida4).", ""]
    lines += [f"dt = {record['dt']:.4g} ({record['integrator']}, order {record['order']}; the "
              f"data's smallest gap is {record['smallest_gap']:.4g}): the largest step tried "
              f"whose halving moves no dynamics parameter by more than "
              f"{record['threshold_sd']:g} posterior sds at the MAP; {record['refits']} MAP "
              f"refits, {record['seconds']:.0f} s.", "",
              f"Steps tried (dt: the largest move at dt/2, in sds): {record['tried']}.", ""]
    return lines


def step_check(record: dict[str, Any]) -> dict[str, Any] | None:
    """The step-size check of :mod:`symplid.workflow._sensitivity` that the search has made
    already (the chosen step halved), in that check's form; None when it has none."""
    if not record.get("shifts"):
        return None
    return {"dt": record["dt"], "dt_refit": record["dt"] / 2, "shifts": record["shifts"],
            "auto": True}
