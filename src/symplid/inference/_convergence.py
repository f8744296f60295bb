"""The numerics of the convergence table: rank normalisation, batched ESS and split R-hat.

The statistics are those of Vehtari et al. (2021) as ArviZ computes them (its
``_multichain_statistics``, which ``az.summary`` calls): the chains split in halves, the draws
rank-normalised (average ranks of ties, Blom's (r − 3/8)/(S + 1/4), the normal quantile),
the bulk ESS of the normalised split chains, the tail ESS the smaller of those of the
indicators ``x ≤ q05`` and ``x ≤ q95`` (R's type-7 quantiles of all draws), and R-hat the
larger of the rank-normalised split R-hat of the draws and of the folded draws
|x − median|. The arithmetic is ArviZ's, rearranged for speed; the numbers agree to rounding
(relative differences of order 1e-15):

* the normal quantiles of every possible (half-integer) rank are computed once per table,
  and each draw looks its score up;
* the draws are sorted once (an unstable sort: ties are averaged, so any sorting order gives
  the same ranks), and the folded draws are sorted by merging the two monotone runs
  |x − median| forms in that order;
* the three ESS of a parameter are one batched computation: the chains' power spectra are
  averaged before the one inverse FFT per statistic (the transform is linear, and only the
  chains' mean autocovariance is used), the transform is padded for the lags Geyer's
  sequence reaches (all of them again, with ArviZ's padding, for a statistic whose sequence
  runs further), and Geyer's initial positive and monotone sequences are evaluated as
  array operations instead of a loop over lags;
* the large scratch arrays are reused from one parameter to the next (:class:`Workspace`).
"""

from __future__ import annotations

import numpy as np
from scipy.fft import next_fast_len
from scipy.special import ndtri

__all__ = ["MIN_DRAWS", "Workspace", "ess_batch", "normal_scores", "parameter_statistics"]

#: ArviZ computes R-hat and ESS from this many draws per chain on.
MIN_DRAWS = 4
_BLOM = 3 / 8


def normal_scores(size: int) -> np.ndarray:
    """Normal quantiles of the Blom-transformed ranks 1, 1.5, 2, …, ``size``.

    Entry ``2 r − 2`` belongs to (average) rank ``r``; the arithmetic is ArviZ's
    ``_backtransform_ranks`` followed by the standard normal quantile."""
    ranks = np.arange(2, 2 * size + 1) / 2.0
    return ndtri((ranks - _BLOM) / (size - 2 * _BLOM + 1))


class Workspace:
    """Scratch arrays reused from one parameter to the next: allocating the tens of MB a
    parameter of the paper's size needs afresh each time costs a quarter of the time in
    page faults."""

    def __init__(self) -> None:
        self._arrays: dict[str, np.ndarray] = {}

    def get(self, name: str, shape: tuple[int, ...], dtype: type = float) -> np.ndarray:
        """An uninitialised array of this shape and type, the same one on each call."""
        array = self._arrays.get(name)
        if array is None or array.shape != shape or array.dtype != dtype:
            array = self._arrays[name] = np.empty(shape, dtype)
        return array


def _sorted_scores(ordered: np.ndarray, table: np.ndarray, work: Workspace) -> np.ndarray:
    """Rank-normalised values of the sorted values ``ordered``, in that order; ties get
    their average rank."""
    size = ordered.size
    first = work.get("first", (size,), bool)  # where a run of equal values starts
    first[0] = True
    np.not_equal(ordered[1:], ordered[:-1], out=first[1:])
    if first.all():  # no ties: ranks 1, 2, …, size
        return table[::2]
    # a run from 0-based position s to e has the average rank (s + e)/2 + 1, table entry s + e
    starts = np.flatnonzero(first)
    runs = starts.size
    bounds = work.get("bounds", (size + 1,), np.intp)[:runs + 1]  # starts, then the size
    bounds[:-1] = starts
    bounds[-1] = size
    index = np.add(bounds[:-1], bounds[1:], out=work.get("index", (size,), np.intp)[:runs])
    index -= 1
    run_scores = np.take(table, index, out=work.get("run_scores", (size,))[:runs])
    counts = np.subtract(bounds[1:], bounds[:-1], out=index)
    return np.repeat(run_scores, counts)


def _folded_scores(ordered: np.ndarray, order: np.ndarray, median: float,
                   table: np.ndarray, out: np.ndarray, work: Workspace) -> np.ndarray:
    """Rank-normalised |x − median|, into the flat ``out``, from the draws' sorted order:
    there the folded values fall, then rise; reversing the first run makes two rising runs,
    which a stable sort (Timsort) merges in linear time."""
    size = ordered.size
    cut = int(np.searchsorted(ordered, median, side="left"))
    runs = work.get("folded_runs", (size,))  # |x − median|, bit for bit: x − m = −(m − x)
    np.subtract(median, ordered[:cut][::-1], out=runs[:cut])
    np.subtract(ordered[cut:], median, out=runs[cut:])
    merge = np.argsort(runs, kind="stable")
    folded = np.take(runs, merge, out=work.get("folded", (size,)))
    in_runs = work.get("folded_scores", (size,))
    in_runs[merge] = _sorted_scores(folded, table, work)
    out[order[:cut]] = in_runs[:cut][::-1]
    out[order[cut:]] = in_runs[cut:]
    return out


def _type7_quantiles(ordered: np.ndarray, probs: np.ndarray) -> np.ndarray:
    """``scipy.stats.mstats.mquantiles(x, probs, alphap=1, betap=1)`` (R's type 7, as ArviZ
    calls it) of the sorted values, with its arithmetic."""
    n = ordered.size
    m = 1.0 + probs * (1.0 - 1.0 - 1.0)
    aleph = n * probs + m
    k = np.floor(aleph.clip(1, n - 1)).astype(int)
    gamma = (aleph - k).clip(0, 1)
    return (1.0 - gamma) * ordered[k - 1] + gamma * ordered[k]


def _rhat(ary: np.ndarray, work: Workspace) -> float:
    """ArviZ's ``_rhat`` (Gelman–Rubin on already split, normalised chains), with NumPy's
    ``var`` arithmetic in a scratch array."""
    num_samples = ary.shape[1]
    chain_mean = np.mean(ary, axis=1)
    deviations = np.subtract(ary, chain_mean[:, None], out=work.get("deviations", ary.shape))
    np.multiply(deviations, deviations, out=deviations)
    chain_var = deviations.sum(axis=1) / (num_samples - 1)  # np.var(ary, axis=1, ddof=1)
    between = num_samples * np.var(chain_mean, axis=None, ddof=1)
    within = np.mean(chain_var)
    with np.errstate(divide="ignore", invalid="ignore"):  # constant draws: NaN, as ArviZ's
        return float(np.sqrt((between / within + num_samples - 1) / num_samples))


def _split_chains(ary: np.ndarray) -> np.ndarray:
    """The chains' first and last halves as chains (ArviZ stacks all first halves, then all
    second halves; the statistics do not depend on the order of the chains)."""
    chains, draws = ary.shape
    half = draws // 2
    if draws % 2 == 0:
        return np.ascontiguousarray(ary).reshape(2 * chains, half)
    return np.vstack((ary[:, :half], ary[:, -half:]))


def parameter_statistics(ary: np.ndarray, table: np.ndarray | None = None,
                         work: Workspace | None = None) -> tuple[float, float, float]:
    """(bulk ESS, tail ESS, R-hat) of one parameter's (chain, draw) draws, as ArviZ's
    ``summary`` has them: NaN for fewer than :data:`MIN_DRAWS` draws per chain or any NaN
    draw, R-hat NaN for one chain.

    ``table`` is :func:`normal_scores` of the number of split draws and ``work`` the scratch
    arrays (both made here if not given; pass them to share them between parameters)."""
    ary = np.asarray(ary, dtype=float)
    chains, draws = ary.shape
    if draws < MIN_DRAWS or np.isnan(ary).any():
        return np.nan, np.nan, np.nan
    work = Workspace() if work is None else work
    split = _split_chains(ary)
    flat = split.ravel()
    table = normal_scores(flat.size) if table is None else table
    order = np.argsort(flat)  # unstable is fine: ties get their average rank
    ordered = np.take(flat, order, out=work.get("ordered", flat.shape))
    stack = work.get("stack", (3, *split.shape))  # normalised draws, two tail indicators
    stack[0].reshape(-1)[order] = _sorted_scores(ordered, table, work)
    full = ordered if draws % 2 == 0 else np.sort(ary, axis=None)
    q05, q95 = _type7_quantiles(full, np.array([0.05, 0.95]))
    np.less_equal(split, q05, out=stack[1])
    np.less_equal(split, q95, out=stack[2])
    least, most = ordered[0], ordered[-1]  # constant: all draws equal, all on one side
    constant = np.array([least == most, most <= q05 or least > q05, most <= q95 or least > q95])
    bulk, low, high = ess_batch(stack, work, constant)
    tail = high if high < low else low  # min(low, high), NaN as Python's min has it
    if chains < 2:
        return float(bulk), float(tail), np.nan
    median = (full[(full.size - 1) // 2] + full[full.size // 2]) / 2  # np.median's
    z_folded = _folded_scores(ordered, order, median, table,
                              work.get("z_folded", flat.shape), work)
    rhat_bulk = _rhat(stack[0], work)
    rhat = max(rhat_bulk, _rhat(z_folded.reshape(split.shape), work))  # ArviZ's order, NaN too
    return float(bulk), float(tail), float(rhat)


def ess_batch(stack: np.ndarray, work: Workspace | None = None,
              constant: np.ndarray | None = None) -> np.ndarray:
    """ArviZ's ``_ess`` of each (chain, draw) array of ``stack`` (shape (rows, chains,
    draws)): the autocorrelations averaged over chains, Geyer's initial positive and
    monotone sequences, τ bounded below by 1/log10(chains·draws).

    A constant array (max − min below the float resolution, as ArviZ tests it; or where
    ``constant`` says so) has ESS chains·draws, as in ArviZ; the caller handles NaN draws."""
    work = Workspace() if work is None else work
    rows, chains, draws = stack.shape
    if constant is None:
        spread = stack.max(axis=(1, 2)) - stack.min(axis=(1, 2))
        constant = spread < np.finfo(float).resolution
    out = np.full(rows, float(chains * draws))
    varying = np.flatnonzero(~constant)
    if varying.size == 0:
        return out
    lags = min(draws, 2048 + draws // 32)  # first try: enough for τ up to several hundred
    some = stack if varying.size == rows else stack[varying]
    result, done = _ess_lags(some, lags, work)
    if not done.all():  # a sequence ran past them: all lags, with ArviZ's padding
        result[~done], _ = _ess_lags(some[~done], draws, work)
    out[varying] = result
    return out


def _mean_autocov(stack: np.ndarray, lags: int, work: Workspace
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The chains' mean autocovariance at lags 0 … lags − 1 (rows, lags) and the chain
    means (rows, chains); the FFT is padded so that these lags do not wrap around."""
    rows, chains, draws = stack.shape
    length = next_fast_len(2 * draws if lags >= draws else draws + lags, real=True)
    chain_mean = stack.mean(axis=2)
    padded = work.get("padded", (rows, chains, length))
    padded[..., draws:] = 0.0
    np.subtract(stack, chain_mean[..., None], out=padded[..., :draws])
    spectrum = work.get("spectrum", (rows, chains, length // 2 + 1), complex)
    np.fft.rfft(padded, axis=2, out=spectrum)
    parts = spectrum.view(float)  # (re, im, re, im, …): |X|² summed over the chains
    np.square(parts, out=parts)
    summed = parts.sum(axis=1)
    power = summed[:, 0::2] + summed[:, 1::2]
    power /= chains
    acov = np.fft.irfft(power, n=length, axis=1)[:, :lags]
    acov /= draws
    return acov, chain_mean


def _ess_lags(stack: np.ndarray, lags: int, work: Workspace
              ) -> tuple[np.ndarray, np.ndarray]:
    """ESS of each row from the autocovariances up to ``lags``, and whether those lags
    sufficed (Geyer's sequence ended, or reached ArviZ's last lag, within them)."""
    rows, chains, draws = stack.shape
    acov, chain_mean = _mean_autocov(stack, lags, work)
    mean_var = acov[:, 0] * draws / (draws - 1.0)
    var_plus = mean_var * (draws - 1.0) / draws
    if chains > 1:
        var_plus = var_plus + np.var(chain_mean, axis=1, ddof=1)
    rho = 1.0 - (mean_var[:, None] - acov) / var_plus[:, None]
    rho[:, 0] = 1.0
    # ArviZ's loop computes pair j = (lag 2j, lag 2j + 1) for j = 1, 2, … while the previous
    # pair's sum is positive and 2j − 1 < draws − 3; pair 0 is (1, ρ1).
    last_pair = max((draws - 3) // 2, 0)
    pairs = min(last_pair, (lags - 2) // 2)
    pair_sum = rho[:, 0:2 * pairs + 1:2] + rho[:, 1:2 * pairs + 2:2]
    stops = ~(pair_sum > 0)
    ended = stops.any(axis=1)
    iters = np.where(ended, stops.argmax(axis=1), last_pair)
    iters = np.minimum(iters, last_pair)
    done = ended | (last_pair <= pairs)
    iters = np.where(done, iters, 0)
    # the monotone sequence: each pair's sum is the running minimum of the sums so far
    running = np.minimum.accumulate(pair_sum, axis=1)
    kept = np.arange(pairs + 1) < iters[:, None]
    total = np.where(kept, running, 0.0).sum(axis=1)
    at = np.arange(rows)
    even = rho[at, 2 * iters]  # ArviZ's rho_hat_t[max_t + 1]: the last even lag computed
    keep_even = (even > 0) | (pair_sum[at, iters] >= 0) | (iters == 0)
    tau = -1.0 + 2.0 * total + np.where(keep_even, even, 0.0)
    size = chains * draws
    tau = np.maximum(tau, 1 / np.log10(size))
    ess = size / tau
    ess[np.isnan(rho[:, 1]) | np.isnan(tau)] = np.nan
    return ess, done
