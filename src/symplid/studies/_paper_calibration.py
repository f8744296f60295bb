"""Calibration of the paper's posterior: does its 95 % interval contain the truth as often?

Cell side (:func:`cell_calibration`, called by the paper's ``run_cell``): for every parameter
with a known true value, the posterior's central 95 % interval (2.5 % and 97.5 % quantiles of
all kept draws), whether it contains the truth, and the rank of the truth among
:data:`~._claims_stats.RANK_DRAWS` evenly thinned draws.

Table side (:func:`evaluate_calibration`): over the seeds of one setting and propagator, the
coverage of each parameter's interval with a Wilson interval, and a χ² test that the ranks are
uniform (they are, whatever the data, when the posterior is calibrated — simulation-based
calibration). A setting *restores nominal coverage* when 95 % lies inside every parameter's
Wilson interval.

True values. The coefficients are the system's (Hénon–Heiles, eq. 20 of the paper, in this
library's sign convention: those of U). The observation-noise variance is σ². The data are
simulated without process noise, so the true process-noise variance, 0, is on the boundary of
its support: no central interval can contain it, and it is left out (``process_var``'s
quantiles are kept in the cell records for reference).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from symplid.dynamics._potentials import coefficient_name
from symplid.studies._claims_stats import (
    LEVEL,
    RANK_DRAWS,
    rank_uniformity,
    truth_rank,
    wilson_interval,
)

__all__ = ["BOUNDARY_PARAMS", "RHAT_FAILED", "cell_calibration", "evaluate_calibration",
           "true_values"]

#: Parameters whose true value (0) lies on the boundary of their support: not calibrated.
BOUNDARY_PARAMS = ("process_var",)
_PREFIX = "calibration."


def cell_calibration(
    param_names: Sequence[str],
    draws: np.ndarray,
    truth: Mapping[str, float],
    num_draws: int = RANK_DRAWS,
) -> dict[str, Any]:
    """The calibration record of one fit.

    Parameters
    ----------
    param_names
        The posterior's parameter names, in the order of the last axis of ``draws``.
    draws
        The kept draws, ``(chain, draw, param)``.
    truth
        The true value of each parameter that has one (others are skipped).
    num_draws
        How many evenly thinned draws the truth is ranked among.

    Returns
    -------
    dict
        ``{name: {"truth", "q025", "q975", "covered", "rank"}}`` for the named parameters, plus
        ``{"process_var": {"q025", "q975"}}`` when present, and ``"rank_draws": num_draws``.
    """
    d = np.asarray(draws, dtype=float)
    out: dict[str, Any] = {}
    for i, name in enumerate(param_names):
        values = d[..., i]
        lo, hi = np.quantile(values, [(1 - LEVEL) / 2, (1 + LEVEL) / 2])
        if name in truth:
            t = float(truth[name])
            out[name] = {
                "truth": t,
                "q025": float(lo),
                "q975": float(hi),
                "covered": bool(lo <= t <= hi),
                "rank": truth_rank(values, t, num_draws),
            }
        elif name in BOUNDARY_PARAMS:
            out[name] = {"q025": float(lo), "q975": float(hi)}
    out["rank_draws"] = int(num_draws)
    return out


def true_values(system: Any, model: Any, noise_std: float) -> dict[str, float]:
    """The true value of each parameter of ``model`` that has one, for data of ``system``.

    The coefficients are the system's, mapped by term onto the model's potential (a term the
    system lacks is 0); the observation-noise variance is ``noise_std``² (isotropic noise).
    """
    terms = dict(zip(system.potential.param_names, system.coefficients, strict=True))
    coefficients = model.hamiltonian.coefficients_from(terms)
    names = [coefficient_name(n) for n in model.hamiltonian.param_names]  # as in θ's names
    truth = dict(zip(names, map(float, coefficients), strict=True))
    if "obs_var" in model.param_names:
        truth["obs_var"] = float(noise_std) ** 2
    return truth


def calibrated_params(table: Any) -> list[str]:
    """The parameters with calibration columns in a results table, in column order."""
    names = []
    for col in table.columns:
        if col.startswith(_PREFIX) and col.endswith(".rank"):
            names.append(col[len(_PREFIX) : -len(".rank")])
    return names


def evaluate_calibration(rows: Any, label: str) -> dict[str, Any]:
    """Coverage and rank uniformity over the ok, converged rows of one setting and propagator.

    A row whose ``rhat_max`` exceeds :data:`RHAT_FAILED` is left out and reported apart
    (``"not_converged"``: its count, seeds and R-hat), so that a sampler failure does not
    count as a miss or a hit of the posterior.

    ``rows``: a results table with the ``calibration.<param>.covered`` and ``.rank`` columns
    of :func:`cell_calibration` (flattened by the sweep). Rows without them (cells run before
    calibration was recorded) are counted as ``missing``.
    """
    import pandas as pd

    ok = rows[rows["status"] == "ok"] if "status" in rows else rows
    restarted = _restarted(ok)
    ok, failed = _split_converged(ok)
    num_draws = RANK_DRAWS
    if f"{_PREFIX}rank_draws" in ok and ok[f"{_PREFIX}rank_draws"].notna().any():
        num_draws = int(ok[f"{_PREFIX}rank_draws"].dropna().iloc[0])
    params: dict[str, Any] = {}
    for name in calibrated_params(ok):
        covered = ok[f"{_PREFIX}{name}.covered"]
        have = covered.notna().to_numpy()
        k = int(sum(bool(v) for v in covered[have]))
        n = int(have.sum())
        ci = wilson_interval(k, n)
        ranks = pd.to_numeric(ok[f"{_PREFIX}{name}.rank"], errors="coerce").dropna()
        uniform = rank_uniformity(ranks.to_numpy(), num_draws)
        params[name] = {
            **_shift(ok, name),
            "n": n,
            "covered": k,
            "coverage": k / n if n else None,
            "coverage_ci": list(ci) if ci else None,
            "nominal_inside": None if ci is None else bool(ci[0] <= LEVEL <= ci[1]),
            "below_nominal": ci is not None and ci[1] < LEVEL,
            "rank_counts": uniform["counts"],
            "rank_bins": uniform["bins"],
            "rank_chi2": uniform["chi2"],
            "rank_p_value": uniform["p_value"],
            "ranks": [int(r) for r in ranks],
        }
    judged = [p for p in params.values() if p["nominal_inside"] is not None]
    return {
        "label": label,
        "cells": len(ok),
        "missing": len(ok) - min((p["n"] for p in params.values()), default=0),
        "rank_draws": num_draws,
        "level": LEVEL,
        "params": params,
        "below_nominal": [n for n, p in params.items() if p["below_nominal"]],
        "nominal": bool(judged) and all(p["nominal_inside"] for p in judged),
        "min_coverage": min((p["coverage"] for p in judged), default=None),
        "not_converged": failed,
        "restarted": restarted,
    }


def _restarted(ok: Any) -> dict[str, Any]:
    """The chains the sampler restarted at the end of the burn-in (stuck far below the
    others, :mod:`symplid.sampling._restart`) over the rows: how many, in which
    seeds (none recorded: cells run before the rule)."""
    if "restarted_chains" not in ok:
        return {"chains": 0, "seeds": []}
    import pandas as pd

    count = pd.to_numeric(ok["restarted_chains"], errors="coerce").fillna(0).astype(int)
    seeds = [int(v) for v in ok.loc[count > 0, "seed"]] if "seed" in ok else []
    return {"chains": int(count.sum()), "seeds": seeds}


def _shift(ok: Any, name: str) -> dict[str, Any]:
    """Where the truth lies in the intervals, in posterior sds: per row
    z = (interval midpoint − truth) / (width / 3.92), the width of a normal's central 95 %
    being 3.92 sds; the mean of z over the rows is the posterior's shift, its sd the spread
    (about 1 when the intervals have the right width). ``None`` without the columns (cells
    recorded before the quantiles were kept) or with fewer than two rows."""
    import pandas as pd

    cols = [f"{_PREFIX}{name}.{k}" for k in ("q025", "q975", "truth")]
    if not all(c in ok for c in cols):
        return {"z_mean": None, "z_sd": None}
    lo, hi, truth = (pd.to_numeric(ok[c], errors="coerce").to_numpy(float) for c in cols)
    width = hi - lo
    z = ((lo + hi) / 2 - truth) / (width / (2 * _Z95))
    z = z[np.isfinite(z) & (width > 0)]
    if z.size < 2:
        return {"z_mean": None, "z_sd": None}
    return {"z_mean": float(z.mean()), "z_sd": float(z.std(ddof=1))}


#: The two-sided 95 % normal quantile (a central 95 % interval is 2·1.96 sds wide).
_Z95 = 1.959963984540054


#: A cell whose chains have a larger R-hat did not converge: it is left out of the
#: calibration and reported apart (R-hat > 1.1 is the conventional sign of chains that have
#: not mixed; Gelman et al., BDA3, section 11.5).
RHAT_FAILED = 1.1


def _split_converged(ok: Any) -> tuple[Any, dict[str, Any]]:
    """The rows whose R-hat is at most :data:`RHAT_FAILED` (or not recorded), and the count
    and seeds of the others."""
    if "rhat_max" not in ok:
        return ok, {"n": 0, "seeds": []}
    import pandas as pd

    rhat = pd.to_numeric(ok["rhat_max"], errors="coerce")
    bad = rhat > RHAT_FAILED
    seeds = [int(v) for v in ok.loc[bad, "seed"]] if "seed" in ok else []
    return ok[~bad], {"n": int(bad.sum()), "seeds": seeds,
                      "rhat": [float(v) for v in rhat[bad]]}
