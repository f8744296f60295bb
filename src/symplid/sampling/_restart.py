"""Chains stuck in a region of negligible mass, restarted at the end of the burn-in.

Chains start overdispersed around the MAP (``init_spread``), so that the convergence
diagnostics can see a chain that has not found the bulk of the posterior. On a rugged
likelihood (a long, nearly chaotic record without process noise) such a chain can settle in
a secondary mode and stay there for the whole run: R-hat then rightly flags the run, yet the
mode's share of the posterior mass is nil and the run is lost. This module decides, once, at
the end of the burn-in (before any draw is kept), which chains are stuck and restarts each
from the **current state** of a randomly chosen good chain: position, log density and
whatever the sampler adapted (DRAM's running covariance and scale, NUTS' step size and mass
matrix), i.e. the whole state.

The rule
--------
Let ``m_c`` be the median log density of chain ``c`` over the last quarter of the burn-in
(:func:`burn_in_window`), ``m* = max_c m_c`` and ``d`` the number of parameters. Chain ``c``
is stuck when

    m* − m_c > Δ(d) = max(10, 5 √(d/2)).

Why this threshold. Within one mode that is close to Gaussian, the log density of a draw is
``const − χ²_d / 2``, whose standard deviation is ``√(d/2)``; a median over many iterations
varies less than one draw. Two chains in the same mode therefore differ by well under
``5 √(d/2)`` (for ``d = 11``: a single draw exceeds it with probability 3·10⁻⁴, a median
over thousands of correlated draws essentially never). A region whose typical log density
is ``Δ`` below the best chain's holds less posterior mass than the best chain's region
unless it is ``e^Δ`` times wider (``e^10 ≈ 22,000``; the 10-nat floor covers small ``d``);
a chain there contributes draws of negligible weight, which no finite run can re-weight,
and restarting it from a good chain loses nothing. Chains that differ by less (two modes of
comparable height, as in a symmetric mixture) are left alone, and R-hat reports them.

The decision is a deterministic function of the run's key and the chains' log densities,
so a resumed run decides as the uninterrupted one would; when no chain is stuck the states
are untouched and the draws are bit-for-bit those of a run without the rule.
"""

from __future__ import annotations

import math
from typing import Any

import jax
import numpy as np

__all__ = [
    "MIN_RESTART_THRESHOLD",
    "BurnInMonitor",
    "burn_in_window",
    "restart_threshold",
    "restarted_message",
]

#: Floor of the threshold Δ(d), in nats (the module docstring).
MIN_RESTART_THRESHOLD = 10.0
_SDS = 5.0  # Δ(d) in standard deviations √(d/2) of a Gaussian mode's log density
_MAX_WINDOW = 1000  # log densities kept per chain (the window is thinned to at most this)
_CHOICE_STREAM = 0x5245_5354  # fold_in of the run key that picks the donors ("REST")


def restart_threshold(num_params: int) -> float:
    """Δ(d) = max(10, 5 √(d/2)) nats: a chain whose median log density is this far below the
    best chain's is stuck (module docstring)."""
    return max(MIN_RESTART_THRESHOLD, _SDS * math.sqrt(num_params / 2.0))


def burn_in_window(burn_in: int) -> tuple[int, int]:
    """``(first, stride)``: the iterations the rule reads, ``first, first + stride, …,
    burn_in`` (1-based), the last quarter of the burn-in thinned to at most 1000 per chain.
    ``first = 0`` when there is no burn-in (then nothing is read and nothing restarted)."""
    if burn_in < 1:
        return 0, 1
    width = max(1, burn_in // 4)
    stride = -(-width // _MAX_WINDOW)
    count = -(-width // stride)
    return burn_in - (count - 1) * stride, stride


class BurnInMonitor:
    """Reads the chains' log densities over the end of the burn-in and, when it ends,
    restarts the stuck ones (module docstring).

    Parameters
    ----------
    num_chains, burn_in
        The run's.
    rng_key
        The run's root key (the donors are drawn from a stream of their own).
    arrays
        What :meth:`arrays` returned at a checkpoint, to continue a resumed run (None:
        a fresh run).
    """

    def __init__(self, num_chains: int, burn_in: int, rng_key: jax.Array,
                 arrays: dict[str, np.ndarray] | None = None) -> None:
        self.burn_in, self.rng_key = int(burn_in), rng_key
        self.first, self.stride = burn_in_window(self.burn_in)
        count = 0 if self.first == 0 else (self.burn_in - self.first) // self.stride + 1
        self.window = np.full((num_chains, count), np.nan)
        self.restarted: np.ndarray | None = None  # (k, 4): chain, donor, median, best median
        arrays = arrays or {}
        if "window" in arrays and np.shape(arrays["window"]) == self.window.shape:
            self.window = np.array(arrays["window"], dtype=np.float64)
        if "restarted" in arrays:
            self.restarted = np.asarray(arrays["restarted"], dtype=np.float64).reshape(-1, 4)

    def resumed_from(self, start: int) -> None:
        """A run resumed at iteration ``start`` past the burn-in without a recorded decision
        (a state from before the rule existed): nothing is left to decide."""
        if self.pending and start >= self.burn_in:
            self.restarted = np.zeros((0, 4))

    @property
    def pending(self) -> bool:
        """Whether the decision is still to be taken (a burn-in to read, not decided yet)."""
        return self.first > 0 and self.restarted is None

    def observe(self, iterations: np.ndarray, lp: np.ndarray) -> None:
        """Keep the log densities ``lp`` (iteration, chain) of ``iterations`` in the window."""
        if not self.pending:
            return
        inside = ((iterations >= self.first) & (iterations <= self.burn_in)
                  & ((iterations - self.first) % self.stride == 0))
        if inside.any():
            columns = (iterations[inside] - self.first) // self.stride
            self.window[:, columns] = np.asarray(lp, dtype=np.float64)[inside].T

    def decide(self, states: Any, num_params: int) -> Any:
        """The states with every stuck chain replaced by a good chain's (module docstring);
        records the decision (:attr:`restarted`)."""
        medians = np.array([_median(row) for row in self.window])
        threshold = restart_threshold(num_params)
        seen = medians[np.isfinite(medians)]
        best = float(seen.max()) if seen.size else np.nan
        behind = np.where(np.isnan(medians), 0.0, best - medians)
        stuck = np.flatnonzero(behind > threshold) if seen.size else np.array([], dtype=int)
        good = np.flatnonzero(np.isfinite(medians) & (best - medians <= threshold))
        rows = []
        key = jax.random.fold_in(self.rng_key, _CHOICE_STREAM)
        for chain in stuck:
            pick = int(jax.random.randint(jax.random.fold_in(key, int(chain)), (), 0,
                                          good.size))
            donor = int(good[pick])
            states = jax.tree.map(lambda leaf, c=int(chain), g=donor: leaf.at[c].set(leaf[g]),
                                  states)
            rows.append((int(chain), donor, float(medians[chain]), float(best)))
        self.restarted = np.array(rows, dtype=np.float64).reshape(-1, 4)
        self.window = self.window[:, :0]
        return states

    def arrays(self) -> dict[str, np.ndarray]:
        """What a checkpoint keeps to continue the monitor (window so far, or the decision)."""
        if self.restarted is not None:
            return {"restarted": self.restarted}
        return {"window": self.window} if self.first > 0 else {}

    def records(self) -> list[dict[str, Any]]:
        """The decision as ``attrs["restarted_chains"]``: one dict per restarted chain
        (``chain``, ``from_chain``, ``lp_median``, ``best_lp_median``); empty when none."""
        if self.restarted is None:
            return []
        return [{"chain": int(c), "from_chain": int(g), "lp_median": float(m),
                 "best_lp_median": float(b)} for c, g, m, b in self.restarted]


def _median(row: np.ndarray) -> float:
    """Median of a chain's window: −∞ when the chain was outside the support (a −∞ log
    density) in it, NaN when nothing of it was seen."""
    if row.size and np.isneginf(row).any():
        return -np.inf
    seen = row[np.isfinite(row)]
    return float(np.median(seen)) if seen.size else np.nan


def restarted_message(records: list[dict[str, Any]], threshold: float) -> str:
    """One line saying which chains were restarted and from which."""
    parts = ", ".join(f"chain {r['chain']} (median log density {r['lp_median']:.1f}) from "
                      f"chain {r['from_chain']}" for r in records)
    best = records[0]["best_lp_median"]
    return (f"restarted at the end of the burn-in, more than {threshold:.1f} nats below the "
            f"best chain's median log density {best:.1f}: {parts} "
            "(sampler.restart_stuck_chains = false keeps them)")
