"""Which terms of a library do the data need? A stepwise search on the evidence, and the
inclusion probability of each term by Bayesian model averaging over the subsets it visits.

A library is a model whose potential (or Hamiltonian) is a sum of terms, each with its own
coefficient: the polynomial of eq. (13), or a user's list of terms such as ``q1^2``,
``cos(q1)``. A subset S of the terms is the model with the other coefficients fixed at zero.
Its evidence p(Y | S) (eqs 8–9; :func:`~symplid.inference.map.find_map`'s
``log_evidence``: Gaussian in the coefficients, the noise variances integrated by
quadrature) rewards the fit and charges each coefficient the data do not need an Occam
factor of about log(prior width / posterior width) nats.

The search
----------
Exhaustive search costs 2^m fits (512 for the paper's cubic library); the posterior over
subsets of a physical potential is, in practice, concentrated on one subset and its
neighbours. :func:`search_terms` therefore runs a **stepwise search**:

1. fit the whole library (the MAP search from its data start, ``num_starts`` starts);
2. **backward**: fit the subsets with one term of the current subset removed, the weakest
   coefficient first (smallest |θ_j| / sd_j at the current MAP), each started from the
   current MAP with that coefficient at zero and from the same point with the variances of
   the default start (the higher MAP is kept: the variances can have two modes,
   :mod:`symplid.inference.map._evidence` step 3); move to the first whose score is higher
   than the current one's, and repeat;
3. **forward**: when no removal helps, fit every subset with one more term (the coefficient
   starting at zero); move to the best if it is higher and return to 2;
4. stop when no single removal or addition raises the evidence (or ``max_fits`` is reached).

Every subset is fitted once (fits are kept by subset). At the end, every subset one flip
away from the chosen one has been fitted, which is what the inclusion probabilities need
most: the evidence of the chosen subset with and without each term. Trying the weakest
term first, a removal that helps is usually the first tried, so the cost is about one fit
per term removed, plus the k + (m − k) − 1 fits of the final check: 14 for the paper's
9-term library and its 4 true terms (on each of 40 data sets), where fitting every removal
at each step (and moving to the best) took 39–43, most of them subsets without a term the
motion needs, the slowest to fit. Each fit reuses the same compiled programs
(:class:`~symplid.model._masked.MaskedPosterior`), so after the first only the optimiser's
and the evidence's evaluations are paid.

The evidence
------------
The search compares ~40 subsets and asks of most of them only whether they are far behind
the best. It scores each by the **log-Laplace** evidence (``evidence="log-laplace"``:
Gaussian in the coefficients and the log-variances at their joint mode; one Hessian, no
quadrature grid), then recomputes by the quadrature over the log-variances
(``final_evidence="quadrature"``, :mod:`symplid.inference.map._evidence`) the evidence of
every visited subset within ``refine_within`` (6) nats of the best score. On the paper's
Hénon–Heiles data (seed 0; the process variance on its floor, its log-scale posterior
skewed) the log-Laplace evidence of the true subset and three of its neighbours was
0.85–1.7 nats below the quadrature, at about a tenth of the cost (2.5–6 s instead of
35–63 s each, on a shared machine). Subsets left unrefined keep their log-Laplace value:
at least 6 nats behind, their weight stays below about e⁻⁴ even if the quadrature would
put them two nats higher. :attr:`SubsetFit.screening_log_evidence` keeps the search's
value of a refined subset.

Inclusion probabilities
-----------------------
Over the visited subsets V, with a prior p(S) over subsets,

    P(S | Y) = p(Y | S) p(S) / Σ_{S'∈V} p(Y | S') p(S'),   P(j | Y) = Σ_{S∋j} P(S | Y).

``size_prior="beta-binomial"`` (the default) gives p(S) = 1 / ((m+1)·C(m, |S|)): every model
size is equally likely a priori, which corrects for the number of subsets of each size
(Scott and Berger, 2010); ``"uniform"`` gives every subset 2^−m (each term in with
probability ½, independently). Subsets the search did not visit are taken to have negligible
weight: this is an approximation, good when the evidence falls by several nats away from the
chosen subset, which :attr:`TermSearch.log_evidence_gap` reports.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.special import gammaln, logsumexp

from symplid.inference.map import default_start, find_map, homotopy_start
from symplid.model._masked import MaskedPosterior

SIZE_PRIORS = ("beta-binomial", "uniform")
"""Choices of :func:`search_terms`'s ``size_prior`` (module docstring)."""


@dataclass(frozen=True)
class SubsetFit:
    """One fitted subset: which terms it has, its MAP and its evidence."""

    included: tuple[bool, ...]
    log_evidence: float  # −inf when the subset could not be fitted
    log_posterior: float
    theta: np.ndarray  # the library's θ, the excluded coefficients at zero
    covariance: np.ndarray | None  # the Laplace covariance at the MAP
    success: bool
    seconds: float
    note: str = ""  # why a fit failed
    evidence_method: str = ""  # MapResult.evidence_method of log_evidence
    screening_log_evidence: float = math.nan  # the search's evidence, where refined

    @property
    def size(self) -> int:
        """The number of terms in the subset."""
        return int(sum(self.included))


@dataclass(frozen=True)
class TermSearch:
    """The outcome of :func:`search_terms`."""

    term_names: tuple[str, ...]
    terms: tuple[int, ...]  # the positions of the terms' coefficients in θ
    param_names: tuple[str, ...]
    fits: tuple[SubsetFit, ...]  # in the order fitted
    size_prior: str
    path: tuple[str, ...]  # the moves made ("start", "-q1", "+q2^3", ...)
    seconds: float
    stopped: str  # "converged" or "max_fits"
    details: dict[str, Any] = field(default_factory=dict)

    @property
    def num_fits(self) -> int:
        """Fits made (the search's cost; each is a MAP search, Hessian and evidence)."""
        return len(self.fits)

    def log_model_posterior(self) -> np.ndarray:
        """log P(S | Y) of every visited subset, in the order of :attr:`fits`."""
        m = len(self.terms)
        scores = np.array([f.log_evidence + log_size_prior(f.size, m, self.size_prior)
                           if f.success and np.isfinite(f.log_evidence) else -np.inf
                           for f in self.fits])
        if not np.any(np.isfinite(scores)):
            return np.full(scores.shape, np.nan)
        return scores - logsumexp(scores)

    def inclusion(self) -> np.ndarray:
        """P(term j | Y) for every term (module docstring)."""
        weights = np.exp(self.log_model_posterior())
        members = np.array([f.included for f in self.fits], dtype=float)
        return weights @ members

    def ranked(self) -> list[tuple[SubsetFit, float]]:
        """(fit, posterior probability) of every visited subset, most probable first."""
        probs = np.exp(self.log_model_posterior())
        order = np.argsort(-np.nan_to_num(probs, nan=-1.0), kind="stable")
        return [(self.fits[i], float(probs[i])) for i in order]

    @property
    def best(self) -> SubsetFit:
        """The most probable visited subset."""
        return self.ranked()[0][0]

    @property
    def log_evidence_gap(self) -> float:
        """log P(best) − log P(second best): how far ahead the chosen subset is."""
        ranked = self.ranked()
        if len(ranked) < 2 or not ranked[1][1] > 0:
            return math.inf
        return math.log(ranked[0][1]) - math.log(ranked[1][1])

    def coefficients(self, level: float = 0.95) -> list[dict[str, Any]]:
        """Each term: its inclusion probability, and in the best subset its MAP coefficient
        with a ``level`` interval from the Laplace covariance (zero when excluded)."""
        z = float(_normal_quantile(0.5 + 0.5 * level))
        best, inclusion = self.best, self.inclusion()
        rows = []
        for j, (name, pos) in enumerate(zip(self.term_names, self.terms, strict=True)):
            value = float(best.theta[pos]) if best.included[j] else 0.0
            sd = (math.sqrt(max(float(best.covariance[pos, pos]), 0.0))
                  if best.included[j] and best.covariance is not None else 0.0)
            rows.append({"term": name, "parameter": self.param_names[pos],
                         "inclusion_probability": float(inclusion[j]),
                         "in_best": bool(best.included[j]), "coefficient": value,
                         "lower": value - z * sd, "upper": value + z * sd})
        return rows


def _normal_quantile(p: float) -> float:
    from scipy.stats import norm

    return float(norm.ppf(p))


def log_size_prior(size: int, m: int, size_prior: str) -> float:
    """log p(S) of a subset of ``size`` terms out of ``m`` (module docstring)."""
    if size_prior == "uniform":
        return -m * math.log(2.0)
    if size_prior == "beta-binomial":
        log_choose = gammaln(m + 1) - gammaln(size + 1) - gammaln(m - size + 1)
        return -math.log(m + 1) - float(log_choose)
    raise ValueError(f"size_prior must be one of {', '.join(SIZE_PRIORS)}, got {size_prior!r}")


class _Fitter:
    """Fits subsets on one :class:`MaskedPosterior`, each once."""

    def __init__(self, view: MaskedPosterior, seed: int, num_starts: int, evidence: str,
                 on_fit: Callable[[SubsetFit], None] | None) -> None:
        self.view, self.seed, self.num_starts, self.on_fit = view, seed, num_starts, on_fit
        self.evidence = evidence
        self.fits: dict[tuple[bool, ...], SubsetFit] = {}

    def add(self, fit: SubsetFit) -> SubsetFit:
        self.fits[fit.included] = fit
        if self.on_fit is not None:
            self.on_fit(fit)
        return fit

    def fit(self, included: tuple[bool, ...], start: np.ndarray) -> SubsetFit:
        """The subset's MAP and evidence from ``start`` (its excluded coefficients set to
        zero) and from ``start`` with the variances raised (module docstring). A search that
        fails from there is run again with two more starts, from where it ended or, where
        the warm start cannot be evaluated (the motion escapes without the term), from the
        default start."""
        if included in self.fits:
            return self.fits[included]
        t0 = time.perf_counter()
        self.view.select(included)
        init = self._higher(self.view.embed(start))
        fit = self._attempt(included, init, self.num_starts)
        if not fit.success:
            again = fit.theta if math.isfinite(fit.log_posterior) else None
            fit = self._attempt(included, again, self.num_starts + 2)
        return self.add(dataclasses.replace(fit, seconds=time.perf_counter() - t0))

    def _higher(self, warm: np.ndarray) -> np.ndarray:
        """The higher of the MAPs reached from ``warm`` and from ``warm`` with the variances
        of the default start (no Hessian); ``warm`` itself when neither can be evaluated."""
        ends = []
        for init in (warm, homotopy_start(self.view, warm, default_start(self.view))):
            try:
                with np.errstate(over="ignore"):
                    ends.append(find_map(self.view, seed=self.seed, num_starts=1, init=init,
                                         compute_hessian=False, warn=False))
            except ValueError:  # not finite at that start
                continue
        finite = [r for r in ends if math.isfinite(r.log_posterior)]
        return np.asarray(max(finite, key=lambda r: r.log_posterior).theta) if finite else warm

    def refine(self, fit: SubsetFit, evidence: str) -> SubsetFit:
        """``fit`` with its evidence recomputed by ``evidence`` (the final ranking); the
        screening value is kept in :attr:`SubsetFit.screening_log_evidence`."""
        t0 = time.perf_counter()
        self.view.select(fit.included)
        try:
            with np.errstate(over="ignore"):
                result = find_map(self.view, seed=self.seed, num_starts=1, init=fit.theta,
                                  evidence=evidence, warn=False)
        except ValueError:
            return fit
        new = _from_result(fit.included, self.view.embed(result.theta), result,
                           fit.seconds + time.perf_counter() - t0)
        if not new.success:
            return fit
        new = dataclasses.replace(new, screening_log_evidence=fit.log_evidence)
        self.fits[fit.included] = new
        return new

    def _attempt(self, included: tuple[bool, ...], init: np.ndarray | None,
                 num_starts: int) -> SubsetFit:
        try:
            # A subset far from the data can end where a variance's scan from its bound
            # climbs far above the "optimum" (exp overflows): its evidence is then NaN,
            # which marks the fit failed; the overflow itself is no news.
            with np.errstate(over="ignore"):
                result = find_map(self.view, seed=self.seed, num_starts=num_starts,
                                  init=init, evidence=self.evidence, warn=False)
        except ValueError as err:  # not finite at the start
            return SubsetFit(included, -math.inf, -math.inf, self.view.embed(
                np.zeros(self.view.num_params) if init is None else init), None, False, 0.0,
                str(err).split(";")[0])
        return _from_result(included, self.view.embed(result.theta), result, 0.0)


def _from_result(included: tuple[bool, ...], theta: np.ndarray, result: Any,
                 seconds: float) -> SubsetFit:
    evidence = float(result.log_evidence)
    ok = bool(result.success) and math.isfinite(evidence)
    return SubsetFit(included, evidence if ok else -math.inf, float(result.log_posterior),
                     np.asarray(theta, dtype=float), result.covariance, ok, seconds,
                     "" if ok else (result.failure or "no finite evidence"),
                     evidence_method=str(result.evidence_method))


def search_terms(
    posterior: Any,
    terms: Sequence[int],
    term_names: Sequence[str] | None = None,
    *,
    seed: int = 0,
    num_starts: int = 4,
    subset_starts: int = 1,
    size_prior: str = "beta-binomial",
    max_fits: int | None = None,
    on_fit: Callable[[SubsetFit], None] | None = None,
    evidence: str = "log-laplace",
    final_evidence: str | None = "quadrature",
    refine_within: float = 6.0,
) -> TermSearch:
    """The stepwise search of the module docstring over the coefficients at ``terms``.

    (Over eighty lines: the documentation of its parameters, and the one stepwise loop of the
    module docstring, kept whole so that it reads against it.)

    Parameters
    ----------
    posterior
        A :class:`~symplid.model._posterior.Posterior` whose model holds the whole library.
    terms
        The positions in θ of the library's coefficients.
    term_names
        A name for each term (default: the parameters' names).
    seed, num_starts
        The MAP search of the whole library (step 1).
    subset_starts
        Starts of every further fit (the first is the warm start of the module docstring).
    size_prior
        The prior over subsets: ``"beta-binomial"`` or ``"uniform"`` (module docstring).
    max_fits
        Stop after this many fits (None: until the search converges).
    on_fit
        Called with each :class:`SubsetFit` as it is made (progress).
    evidence
        The evidence of the search (a ``find_map`` evidence; "The evidence" in the module
        docstring).
    final_evidence, refine_within
        The evidence of the final ranking, recomputed for every visited subset whose score
        is within ``refine_within`` nats of the best (None: keep the search's).
    """
    t0 = time.perf_counter()
    log_size_prior(0, 1, size_prior)  # checks the choice
    terms = tuple(int(t) for t in terms)
    names = tuple(term_names) if term_names is not None else tuple(
        posterior.param_names[t] for t in terms)
    if len(names) != len(terms):
        raise ValueError(f"term_names: expected {len(terms)} names, got {len(names)}")
    view = MaskedPosterior(posterior, terms)
    fitter = _Fitter(view, seed, subset_starts, evidence, on_fit)
    full = (True,) * len(terms)
    start = time.perf_counter()
    result = find_map(posterior, seed=seed, num_starts=num_starts, evidence=evidence,
                      warn=False)
    current = fitter.add(_from_result(full, np.asarray(result.theta), result,
                                      time.perf_counter() - start))
    path, stopped = ["start"], "converged"
    budget = math.inf if max_fits is None else int(max_fits)
    m = len(terms)

    def score(fit: SubsetFit) -> float:
        return (fit.log_evidence + log_size_prior(fit.size, m, size_prior)
                if fit.success else -math.inf)

    while True:
        moved = False
        for sign in ("-", "+"):
            flips = [j for j in range(m) if current.included[j] == (sign == "-")]
            if sign == "-":  # the weakest coefficient first (step 2)
                flips.sort(key=lambda j: _strength(current, terms[j]))
            candidates = []
            for j in flips:
                if len(fitter.fits) >= budget and _flip(current.included, j) not in fitter.fits:
                    stopped = "max_fits"
                    continue
                candidates.append((j, fitter.fit(_flip(current.included, j), current.theta)))
                if sign == "-" and score(candidates[-1][1]) > score(current):
                    break  # the first removal that helps
            if candidates:
                j, best = max(candidates, key=lambda c: score(c[1]))
                if score(best) > score(current):
                    current, moved = best, True
                    path.append(f"{sign}{names[j]}")
                    break  # after a move, try removals first again
        if not moved:
            break
    num_searched = len(fitter.fits)
    refined = _refine(fitter, score, final_evidence, refine_within)
    fits = tuple(fitter.fits.values())
    return TermSearch(
        term_names=names, terms=terms, param_names=tuple(posterior.param_names), fits=fits,
        size_prior=size_prior, path=tuple(path), seconds=time.perf_counter() - t0,
        stopped=stopped,
        details={"full_library_map_seconds": fits[0].seconds, "num_starts": int(num_starts),
                 "subset_starts": int(subset_starts), "evidence": evidence,
                 "final_evidence": final_evidence, "search_fits": num_searched,
                 "refined": refined},
    )


def _refine(fitter: _Fitter, score: Callable[[SubsetFit], float], evidence: str | None,
            within: float) -> int:
    """Recompute by ``evidence`` the evidence of every fit within ``within`` nats of the best
    score ("The evidence" in the module docstring); the number recomputed."""
    if evidence is None or evidence == fitter.evidence:
        return 0
    scores = {key: score(f) for key, f in fitter.fits.items()}
    top = max(scores.values())
    if not math.isfinite(top):
        return 0
    chosen = [key for key, value in scores.items() if value >= top - within]
    for key in chosen:
        fitter.refine(fitter.fits[key], evidence)
    return len(chosen)


def _strength(fit: SubsetFit, position: int) -> float:
    """|θ_j| / sd_j of a coefficient at the fit's MAP (Laplace covariance; ∞ without one)."""
    if fit.covariance is None:
        return math.inf
    sd = math.sqrt(max(float(fit.covariance[position, position]), 0.0))
    return abs(float(fit.theta[position])) / sd if sd > 0 else math.inf


def _flip(included: tuple[bool, ...], j: int) -> tuple[bool, ...]:
    return tuple((not v) if i == j else v for i, v in enumerate(included))


__all__ = ["SIZE_PRIORS", "SubsetFit", "TermSearch", "log_size_prior", "search_terms"]
