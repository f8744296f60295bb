"""A budget set by the answer: the chains run until their draws are good enough.

Without a fixed number of draws (``sample(num_draws=None)``, ``symplid fit`` with
``sampler.num_iterations = "auto"``) the runner checks the draws between its chunks and
stops when every parameter's bulk and tail ESS reach their targets and its R-hat is at most
its target (:class:`~._options.Targets`: 400, 400, 1.01 by default), or at a cap on the
iterations per chain or on the wall time, whichever comes first. The statistics are the
convergence table's (:func:`~symplid.inference._convergence.parameter_statistics`, equal to
ArviZ's ``summary`` to rounding), computed on the draws after the burn-in only.

The burn-in adapts too. It starts at the sampler's first burn-in
(:attr:`~._registry.SamplerSpec.first_burn_in`: DRAM max(2000, 500 d) iterations of
adaptation, NUTS its 1000 warm-up steps), at the end of which the restart of stuck chains
decides as before. While the chains still disagree at a check (R-hat above its target), the
burn-in is extended to half the iterations done (the paper's ratio, 100,000 of 200,000), and
the draws before it are dropped; it never shrinks.

When the checks come. A check is due at the end of the first chunk at which the iterations
done reach ``growth`` (1.25) times those of the last check (the first burn-in counting as
the first), and at the cap. A check costs time in proportion to the draws, so all the checks
cost at most ``growth/(growth − 1)`` (5) times the last, and a run overshoots the iterations
it needed by at most a quarter and a chunk. The schedule and the decisions depend only on
the draws and on the chunk grid (``chunk_size``), so a run is a deterministic function of
its seed and settings, and a run interrupted and resumed (:mod:`~._resume`) checks and stops
where the uninterrupted one does: what the rule has decided so far travels in the
checkpoint (:meth:`BudgetMonitor.arrays`). Only the wall-time cap depends on the machine; it
is obeyed once the first burn-in is over and some draws are kept.

When the cap will come first. ESS grows in proportion to the draws kept, so each check
projects the iterations per chain the targets need at the rate seen so far: the burn-in plus
the iterations kept times the largest ratio of an ESS target to its ESS
(:meth:`BudgetMonitor.projected_iterations`). From the second check on, when that projection
exceeds the cap by ``SHORTFALL`` (2×), the runner says so once (:class:`TargetsOutOfReach`)
and goes on to the cap: its draws still count, and the user can stop the run and keep them.
The run's record keeps the last projection, which the fit's summary reports when the cap ends
the run. (An early estimate of ESS is noisy; the factor 2 and the second check keep a run
that is merely slow from being told it will fail.)
"""

from __future__ import annotations

from typing import Any

import numpy as np

from symplid.inference._convergence import (
    MIN_DRAWS,
    Workspace,
    normal_scores,
    parameter_statistics,
)
from symplid.sampling._options import Targets

__all__ = ["SHORTFALL", "STOPPED_BY", "BudgetMonitor", "TargetsOutOfReach", "draw_statistics",
           "kept_after_burn_in", "two_figures"]

#: What ended a run (``attrs["stopped_by"]``): the targets, a cap, a fixed budget, a stop.
STOPPED_BY = ("target", "iterations", "wall time", "fixed budget", "interrupted")
_PREFIX = "budget_"
#: How far beyond the cap the projected iterations must be for the runner to say, before the
#: cap, that the targets are out of reach (module docstring).
SHORTFALL = 2.0


def two_figures(x: float) -> int:
    """``x`` rounded to two significant figures: a projection is no more precise."""
    return int(float(f"{x:.2g}"))


class TargetsOutOfReach(UserWarning):
    """Warning: at the rate seen so far, a run without a fixed budget will reach its cap on
    the iterations long before its targets (:mod:`~symplid.sampling._budget`)."""


def draw_statistics(theta: np.ndarray) -> tuple[float, float, float]:
    """(smallest bulk ESS, smallest tail ESS, largest R-hat) over the parameters of draws
    ``(chain, draw, param)``; NaN where a parameter's statistic is NaN (too few draws, one
    chain for R-hat)."""
    chains, draws, num_params = theta.shape
    if draws < MIN_DRAWS:
        return np.nan, np.nan, np.nan
    work, table = Workspace(), normal_scores(2 * chains * (draws // 2))
    stats = np.array([parameter_statistics(theta[:, :, i], table, work)
                      for i in range(num_params)])
    worst = (np.min, np.min, np.max)
    return tuple(float(np.nan if np.isnan(stats[:, j]).any() else pick(stats[:, j]))
                 for j, pick in enumerate(worst))


class BudgetMonitor:
    """The stopping rule of a run without a fixed budget (module docstring).

    Parameters
    ----------
    targets
        The targets and caps.
    burn_in, thin, num_chains
        The run's first burn-in, thinning and chains.
    arrays
        What :meth:`arrays` returned at a checkpoint (None: a fresh run).
    """

    def __init__(self, targets: Targets, burn_in: int, thin: int, num_chains: int,
                 arrays: dict[str, np.ndarray] | None = None) -> None:
        self.targets, self.first_burn_in, self.thin = targets, int(burn_in), int(thin)
        self.num_chains = int(num_chains)
        self.burn_in, self.last_check, self.checks = self.first_burn_in, self.first_burn_in, 0
        self.seconds_before = 0.0
        self.stats: tuple[float, float, float] = (np.nan, np.nan, np.nan)
        self.stopped_by = ""
        self.warned = False
        self.stats_kept = 0  # the iterations per chain the statistics were computed on
        arrays = arrays or {}
        if f"{_PREFIX}burn_in" in arrays:
            self.burn_in = int(np.asarray(arrays[f"{_PREFIX}burn_in"]))
            self.last_check = int(np.asarray(arrays[f"{_PREFIX}last_check"]))
            self.checks = int(np.asarray(arrays[f"{_PREFIX}checks"]))
            self.seconds_before = float(np.asarray(arrays[f"{_PREFIX}seconds"]))
            self.stats = tuple(float(x) for x in np.asarray(arrays[f"{_PREFIX}stats"]))

    def due(self, done: int, final: bool) -> bool:
        """Whether a check is due after ``done`` iterations (``final``: at the cap)."""
        if (done - self.burn_in) // self.thin < MIN_DRAWS or done <= self.last_check:
            return False
        return final or done >= self.targets.growth * self.last_check

    def out_of_time(self, elapsed: float) -> bool:
        """Whether the wall-time cap is reached after ``elapsed`` seconds of this run."""
        cap = self.targets.max_seconds
        return cap is not None and self.seconds_before + elapsed >= cap

    def check(self, theta: np.ndarray, done: int, final: bool = False) -> bool:
        """Check the draws kept since the first burn-in, ``theta`` (chain, draw, param), after
        ``done`` iterations; True when the targets are met. Extends the burn-in when the
        chains disagree (module docstring); at the last check (``final``) the statistics
        recorded are then those of the draws after the extended burn-in, the run's draws."""
        self.stats = draw_statistics(self._after_burn_in(theta))
        self.stats_kept = int(done) - self.burn_in
        self.last_check, self.checks = int(done), self.checks + 1
        bulk, tail, rhat = self.stats
        t = self.targets
        rhat_met = rhat <= t.rhat or (self.num_chains == 1 and np.isnan(rhat))
        if bulk >= t.ess_bulk and tail >= t.ess_tail and rhat_met:
            self.stopped_by = "target"
            return True
        if not rhat_met:  # the chains disagree: the burn-in becomes half the run so far
            half = self.first_burn_in + (done // 2 - self.first_burn_in) // self.thin * self.thin
            if half > self.burn_in:
                self.burn_in = half
                if final:
                    self.stats = draw_statistics(self._after_burn_in(theta))
                    self.stats_kept = int(done) - self.burn_in
        return False

    def projected_iterations(self) -> float:
        """The iterations per chain the ESS targets need at the rate of the last check
        (module docstring): the burn-in (extended, if it was) plus the iterations the ESS was
        computed on times the largest ratio of target to ESS; NaN before a check or without a
        finite ESS."""
        bulk, tail, _ = self.stats
        kept = self.stats_kept
        if not (np.isfinite(bulk) and np.isfinite(tail) and bulk > 0 and tail > 0 and kept > 0):
            return np.nan
        t = self.targets
        return self.burn_in + kept * max(t.ess_bulk / bulk, t.ess_tail / tail, 1.0)

    def out_of_reach(self) -> str | None:
        """Once, from the second check on: the line that says the cap will come long before
        the targets (:class:`TargetsOutOfReach`), or None."""
        projected, cap = self.projected_iterations(), self.targets.max_iterations
        if self.warned or self.checks < 2 or not projected > SHORTFALL * cap:
            return None
        self.warned = True
        bulk, tail, _ = self.stats
        need = two_figures(projected)
        return (f"at the rate of its first {self.last_check:,} iterations per chain (min "
                f"ESS {min(bulk, tail):.0f}), the sampler's targets need about {need:,} "
                f"iterations per chain, beyond its cap of {cap:,}: the run will stop at the cap "
                "before them. It goes on (its draws are kept if you stop it); a larger "
                "sampler.max_iterations would reach them, and another sampler.method may mix "
                "better here")

    def has_draws(self, done: int) -> bool:
        """Whether the run has kept enough draws after ``done`` iterations to be checked (a
        wall-time cap waits for them: the first burn-in is always completed)."""
        return (done - self.first_burn_in) // self.thin >= MIN_DRAWS

    def _after_burn_in(self, theta: np.ndarray) -> np.ndarray:
        return _after(theta, self.burn_in, self.first_burn_in, self.thin)

    def trim(self, draws: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """The draws ``name -> (chain, draw, ...)`` kept since the first burn-in, without
        those the burn-in's extension dropped."""
        return {name: self._after_burn_in(value) for name, value in draws.items()}

    def arrays(self, elapsed: float = 0.0) -> dict[str, np.ndarray]:
        """What a checkpoint keeps to continue the rule (``elapsed``: this run's seconds)."""
        return {f"{_PREFIX}burn_in": np.asarray(self.burn_in),
                f"{_PREFIX}last_check": np.asarray(self.last_check),
                f"{_PREFIX}checks": np.asarray(self.checks),
                f"{_PREFIX}seconds": np.asarray(self.seconds_before + elapsed),
                f"{_PREFIX}stats": np.asarray(self.stats, dtype=np.float64)}

    def record(self) -> dict[str, Any]:
        """The rule's outcome as the draws' attributes keep it (``attrs["budget"]``)."""
        bulk, tail, rhat = self.stats
        return {"stopped_by": self.stopped_by, "burn_in": self.burn_in,
                "first_burn_in": self.first_burn_in, "checks": self.checks,
                "ess_bulk_min": bulk, "ess_tail_min": tail, "rhat_max": rhat,
                "projected_iterations": self.projected_iterations(),
                "targets": self.targets.as_dict()}


def kept_after_burn_in(draws: dict[str, np.ndarray], arrays: dict[str, Any] | None,
                       first_burn_in: int, thin: int) -> dict[str, np.ndarray]:
    """Draws kept since the first burn-in without those the extended burn-in (recorded in a
    checkpoint's ``arrays``) dropped; the draws themselves when nothing was extended."""
    if not arrays or f"{_PREFIX}burn_in" not in arrays:
        return draws
    extended = int(np.asarray(arrays[f"{_PREFIX}burn_in"]))
    return {name: _after(value, extended, int(first_burn_in), int(thin))
            for name, value in draws.items()}


def _after(draws: np.ndarray, burn_in: int, first_burn_in: int, thin: int) -> np.ndarray:
    """``draws`` (chain, draw, ...) kept since ``first_burn_in`` without those before the
    extended ``burn_in``: the one slicing :class:`BudgetMonitor` and a checkpoint share."""
    return draws[:, (burn_in - first_burn_in) // thin:]
