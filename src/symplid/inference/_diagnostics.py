"""Convergence diagnostics of sampler output: R-hat, bulk and tail ESS, with warnings.

ArviZ does the statistics (rank-normalised split R-hat and the ESS of Vehtari et al. 2021);
this module decides what to say about them. The thresholds are the usual ones: R-hat above
1.01 or an effective sample size below 400 (100 per chain for four chains) means the draws
are not yet to be trusted.

A fit needs only R-hat and the bulk and tail ESS (:func:`convergence_table`): they are
computed as ArviZ's ``summary`` computes them (Vehtari et al. 2021: split chains,
rank-normalised, the folded draws for R-hat's tail, the 5 % and 95 % indicators for the
tail ESS), the same numbers to rounding, without the columns nobody reads there (mean, sd,
HDI, MCSE), and several times faster (``symplid.inference._convergence``: one sort per
parameter, the normal scores looked up, the three ESS of a parameter in one batched FFT,
Geyer's sequences as array operations).
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import sys
import threading
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from types import ModuleType
from typing import Any

import numpy as np

from symplid.inference._convergence import (
    MIN_DRAWS,
    Workspace,
    normal_scores,
    parameter_statistics,
)

__all__ = [
    "ESS_THRESHOLD",
    "RHAT_THRESHOLD",
    "ConvergenceWarning",
    "convergence_table",
    "import_arviz",
    "prefetch_arviz",
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


def prefetch_arviz() -> None:
    """Start importing ArviZ in a daemon thread, so that its seconds (xarray, pandas,
    matplotlib) pass while the caller computes: a fit needs it only when its draws are made
    ``InferenceData``, and most of a MAP search runs compiled code, which leaves the
    interpreter free. :func:`import_arviz` then finds it imported, or waits for the import
    under way. Does nothing when ArviZ is imported already. Its import-time notice (a
    ``FutureWarning`` of some versions) is ignored by a filter, not by ``catch_warnings``,
    which is not safe beside another thread.
    """
    if "arviz" in sys.modules:
        return
    warnings.filterwarnings("ignore", category=FutureWarning, module=r"arviz(\.|$)")
    threading.Thread(target=_import_quietly, name="symplid-import-arviz", daemon=True).start()


def _import_quietly() -> None:
    with contextlib.suppress(Exception):  # import_arviz raises it again where it is needed
        importlib.import_module("arviz")


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
        :func:`symplid.sampling.sample`).
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
    names them); NaN where ArviZ gives NaN (fewer than 4 draws per chain, a NaN draw; R-hat
    with one chain). The numbers are ArviZ's to rounding, computed faster (see
    ``symplid.inference._convergence``).
    """
    import pandas as pd

    posterior = idata.posterior
    names = list(posterior.data_vars) if var_names is None else list(var_names)
    rows: dict[str, tuple[float, float, float]] = {}
    tables: dict[int, np.ndarray] = {}  # the normal scores, shared by equal-sized parameters
    work = Workspace()
    for name in names:
        values = np.asarray(posterior[name], dtype=float)
        flat = values.reshape(values.shape[0], values.shape[1], -1)
        size = flat.shape[0] * 2 * (flat.shape[1] // 2)
        if flat.shape[1] >= MIN_DRAWS and size not in tables:
            tables[size] = normal_scores(size)
        for k in range(flat.shape[2]):
            index = np.unravel_index(k, values.shape[2:]) if values.ndim > 2 else ()
            label = f"{name}[{', '.join(map(str, index))}]" if index else str(name)
            rows[label] = parameter_statistics(flat[:, :, k], tables.get(size), work)
    return pd.DataFrame.from_dict(rows, orient="index", columns=["ess_bulk", "ess_tail",
                                                                 "r_hat"])


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
