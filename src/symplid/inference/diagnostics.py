"""Convergence diagnostics of sampler output: R-hat, bulk and tail ESS, with warnings.

ArviZ does the statistics (rank-normalised split R-hat and the ESS of Vehtari et al. 2021);
this module decides what to say about them. The thresholds are the usual ones: R-hat above
1.01 or an effective sample size below 400 (100 per chain for four chains) means the draws
are not yet to be trusted.

A fit needs only R-hat and the bulk and tail ESS (:func:`convergence_table`): they are
computed as ArviZ's ``summary`` computes them (Vehtari et al. 2021: split chains,
rank-normalised, the folded draws for R-hat's tail, the 5 % and 95 % indicators for the
tail ESS), the same numbers, without the columns nobody reads there (mean, sd, HDI, MCSE),
and with a faster rank normalisation (one stable sort with ties averaged, and the normal
quantile by ``scipy.special.ndtri``, which ``scipy.stats.norm.ppf`` calls; the folded draws
are ranked from the draws' own sorted order): well under half the time of ``az.summary`` on
the paper's 400,000 draws per parameter.
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from types import ModuleType
from typing import Any

import numpy as np

__all__ = [
    "ESS_THRESHOLD",
    "RHAT_THRESHOLD",
    "ConvergenceWarning",
    "convergence_table",
    "import_arviz",
    "quiet_arviz",
    "summary",
]

RHAT_THRESHOLD = 1.01
ESS_THRESHOLD = 400.0


class ConvergenceWarning(UserWarning):
    """The chains have not converged or mixed enough (R-hat, ESS or divergences)."""


def import_arviz() -> ModuleType:
    """Import ArviZ without its import-time notice about a future refactor."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        import arviz

    return arviz


def _extreme(values: np.ndarray, pick) -> str:
    finite = values[np.isfinite(values)]
    return f"{pick(finite):.4g}" if finite.size else "nan"


def _names(frame, mask) -> str:
    return ", ".join(str(name) for name in frame.index[np.asarray(mask)])


def summary(
    idata: Any,
    var_names: list[str] | None = None,
    *,
    rhat_threshold: float = RHAT_THRESHOLD,
    ess_threshold: float = ESS_THRESHOLD,
    show: bool = True,
    warn: bool = True,
    columns: str = "all",
):
    """Summarise posterior draws and warn when they look unconverged.

    Parameters
    ----------
    idata
        ``arviz.InferenceData`` with a ``posterior`` group (as from
        :func:`symplid.inference.samplers.sample`).
    var_names
        Parameters to summarise; all by default.
    rhat_threshold, ess_threshold
        A :class:`ConvergenceWarning` is issued when R-hat exceeds ``rhat_threshold`` (or
        cannot be computed) or when the bulk or tail ESS is below ``ess_threshold``.
    show
        Print the table (mean, sd, HDI, MCSE, bulk and tail ESS, R-hat) and the sampler's
        acceptance or divergence counts.
    warn
        Issue the warnings.
    columns
        ``"all"``: ``az.summary``'s table; ``"convergence"``: only ``r_hat``, ``ess_bulk`` and
        ``ess_tail`` (:func:`convergence_table`, the same numbers, faster; not with ``show``).

    Returns
    -------
    pandas.DataFrame
        ``az.summary`` at full precision, one row per parameter.
    """
    az = import_arviz()
    if not hasattr(idata, "posterior"):
        raise ValueError("idata has no posterior group; pass the result of symplid.sample")
    if columns not in ("all", "convergence"):
        raise ValueError(f"columns must be 'all' or 'convergence', got {columns!r}")
    with quiet_arviz():  # NaN statistics of short chains: one ConvergenceWarning says it below
        if columns == "convergence" and not show:
            table = convergence_table(idata, var_names)
        else:
            table = az.summary(idata, var_names=var_names, round_to="none")
    notes = _sampler_notes(idata)
    if show:
        import pandas as pd

        with pd.option_context("display.max_columns", None, "display.width", 120):
            print(table.to_string(float_format=lambda v: f"{v:.4g}"))
        for note in notes:
            print(note)
    if warn:
        _warn(table, idata, rhat_threshold, ess_threshold)
    return table


def convergence_table(idata: Any, var_names: list[str] | None = None):
    """``r_hat``, ``ess_bulk`` and ``ess_tail`` of each parameter, as ``az.summary`` has them.

    One row per scalar parameter (a vector one row per element, named ``name[i]`` as ArviZ
    names them); NaN where ArviZ gives NaN (fewer than 4 draws per chain; R-hat with one
    chain). The ESS and the autocovariances are ArviZ's own functions; the rank
    normalisation is done here (see the module's note), with the same ranks and quantiles.
    """
    import pandas as pd

    az = import_arviz()
    try:
        from arviz.stats.diagnostics import _ess, _quantile
    except ImportError:  # pragma: no cover - an ArviZ without them: its own summary
        frame = az.summary(idata, var_names=var_names, round_to="none", kind="diagnostics")
        return frame[["ess_bulk", "ess_tail", "r_hat"]]
    posterior = idata.posterior
    names = list(posterior.data_vars) if var_names is None else list(var_names)
    rows: dict[str, tuple[float, float, float]] = {}
    for name in names:
        values = np.asarray(posterior[name], dtype=float)
        flat = values.reshape(values.shape[0], values.shape[1], -1)
        for k in range(flat.shape[2]):
            index = np.unravel_index(k, values.shape[2:]) if values.ndim > 2 else ()
            label = f"{name}[{', '.join(map(str, index))}]" if index else str(name)
            rows[label] = _convergence(flat[:, :, k], _ess, _quantile)
    return pd.DataFrame.from_dict(rows, orient="index", columns=["ess_bulk", "ess_tail",
                                                                 "r_hat"])


def _convergence(ary: np.ndarray, ess, quantile) -> tuple[float, float, float]:
    """(bulk ESS, tail ESS, R-hat) of one parameter's (chain, draw) array, in the order of
    operations of ArviZ's ``_multichain_statistics``."""
    chains, draws = ary.shape
    if draws < MIN_DRAWS or np.isnan(ary).any():
        return np.nan, np.nan, np.nan
    split = _split_chains(ary)
    order = np.argsort(split.ravel(), kind="stable")
    z_split = _z_scale(split, order)
    q05, q95 = quantile(ary, [0.05, 0.95])
    ess_tail = min(ess(_split_chains(ary <= q05)), ess(_split_chains(ary <= q95)))
    if chains < 2:
        rhat = np.nan
    else:
        folded = _split_chains(np.abs(ary - np.median(ary)))
        # taken in the draws' sorted order, |x − median| falls then rises: two runs, which
        # the stable sort (Timsort) merges in linear time instead of sorting afresh
        flat = folded.ravel()
        folded_order = order[np.argsort(flat[order], kind="stable")]
        rhat = max(_rhat(z_split), _rhat(_z_scale(folded, folded_order)))
    return float(ess(z_split)), float(ess_tail), float(rhat)


def _split_chains(ary: np.ndarray) -> np.ndarray:
    half = ary.shape[1] // 2
    return np.vstack((ary[:, :half], ary[:, -half:]))


def _z_scale(ary: np.ndarray, order: np.ndarray | None = None) -> np.ndarray:
    """Rank-normalised draws: average ranks of ties, (r − 3/8)/(S + 1/4), the normal quantile.

    ``order`` sorts ``ary.ravel()`` when known (any order that sorts it gives the same ranks:
    ties are averaged)."""
    from scipy.special import ndtri

    flat = ary.ravel()
    if order is None:
        order = np.argsort(flat, kind="stable")
    ordered = flat[order]
    first = np.empty(flat.size, dtype=bool)  # where a run of equal values starts
    first[:1] = True
    np.not_equal(ordered[1:], ordered[:-1], out=first[1:])
    starts = np.flatnonzero(first)
    counts = np.diff(np.append(starts, flat.size))
    ranks = np.empty(flat.size)
    ranks[order] = np.repeat(starts + (counts + 1) / 2.0, counts)  # 1-based, ties averaged
    c = 3 / 8
    return ndtri((ranks - c) / (flat.size - 2 * c + 1)).reshape(ary.shape)


def _rhat(ary: np.ndarray) -> float:
    """ArviZ's ``_rhat`` (Gelman–Rubin on already split, normalised chains)."""
    num_samples = ary.shape[1]
    chain_mean = np.mean(ary, axis=1)
    chain_var = np.var(ary, axis=1, ddof=1)
    between = num_samples * np.var(chain_mean, axis=None, ddof=1)
    within = np.mean(chain_var)
    return float(np.sqrt((between / within + num_samples - 1) / num_samples))


def _sampler_notes(idata: Any) -> list[str]:
    if not hasattr(idata, "sample_stats"):
        return []
    stats = idata.sample_stats
    notes = []
    if "stage1_accepted" in stats:
        stage1 = float(stats["stage1_accepted"].mean())
        stage2 = float(stats["stage2_accepted"].mean())
        overall = float(stats["accepted"].mean())
        notes.append(f"DRAM acceptance: stage 1 {stage1:.1%}, stage 2 {stage2:.1%}, "
                     f"overall {overall:.1%}")
    if "diverging" in stats:
        notes.append(f"NUTS divergences: {int(stats['diverging'].sum())} of "
                     f"{stats['diverging'].size} transitions")
    return notes


#: ArviZ computes R-hat and ESS from this many draws per chain on.
MIN_DRAWS = 4


@contextmanager
def quiet_arviz() -> Iterator[None]:
    """Silence NumPy's RuntimeWarnings (degrees of freedom ≤ 0, all-NaN slices) and ArviZ's
    logged shape warnings while statistics of very short chains are computed: their NaNs are
    reported once, in words, by :func:`summary`'s warnings."""
    # ArviZ logs through its own Logger instance (``arviz._log``), not logging.getLogger's.
    logger = getattr(import_arviz(), "_log", None) or logging.getLogger("arviz")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            yield
    finally:
        logger.setLevel(level)


def _warn(table, idata, rhat_threshold: float, ess_threshold: float) -> None:
    draws = int(idata.posterior.sizes.get("draw", 0))
    if draws < MIN_DRAWS:
        warnings.warn(
            f"only {draws} draw(s) per chain: R-hat and ESS need at least {MIN_DRAWS}; "
            "run longer (more iterations after burn-in)",
            ConvergenceWarning,
            stacklevel=3,
        )
        return
    rhat = table["r_hat"].to_numpy(dtype=float)
    bad_rhat = ~(rhat <= rhat_threshold)
    if bad_rhat.any():
        warnings.warn(
            f"R-hat above {rhat_threshold} (or not computable) for: "
            f"{_names(table, bad_rhat)} (max {_extreme(rhat, max)}); the chains disagree, "
            "run longer or check the starting points",
            ConvergenceWarning,
            stacklevel=3,
        )
    for column, label in (("ess_bulk", "bulk"), ("ess_tail", "tail")):
        ess = table[column].to_numpy(dtype=float)
        low = ~(ess >= ess_threshold)
        if low.any():
            warnings.warn(
                f"{label} ESS below {ess_threshold:g} for: {_names(table, low)} "
                f"(min {_extreme(ess, min)}); run longer or thin less",
                ConvergenceWarning,
                stacklevel=3,
            )
    stats = getattr(idata, "sample_stats", None)
    if stats is not None and "diverging" in stats:
        count = int(stats["diverging"].sum())
        if count:
            warnings.warn(
                f"{count} divergent NUTS transition(s): the draws may be biased",
                ConvergenceWarning,
                stacklevel=3,
            )
