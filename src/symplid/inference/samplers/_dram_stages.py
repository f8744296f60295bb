"""The delayed-rejection stages of one DRAM step: proposals, their acceptance, and the small
linear algebra they share with the adaptation (:mod:`._dram` has the conventions).

Stage 1 proposes ``y1 = x + L z``; stage 2, tried only when stage 1 rejects,
``y2 = x + √γ L z'``, accepted with the probability of Haario et al. (2006) for a symmetric
second stage (:func:`stage2_log_acceptance`). The stages run one after the other in a loop
with one call site of the log density (:func:`staged`), or both proposals are evaluated in one
batched call and judged alike (:func:`paired_stages`). A :data:`Region` says how each stretch
of arithmetic between log-density calls is compiled: inline, or as one kernel of its own
(:func:`symplid._kernel_region.one_kernel`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

from symplid.filters import _linalg as linalg
from symplid.filters._linalg import MAX_UNROLLED_DIM

Array = jax.Array
LogDensityFn = Callable[[Array], Array]

__all__ = [
    "LAPACK",
    "UNROLLED",
    "Algebra",
    "Region",
    "Stages",
    "finite_or_neg_inf",
    "inline",
    "log1mexp",
    "paired_stages",
    "stage2_log_acceptance",
    "staged",
]


Region = Callable[[Callable[..., Any]], Callable[..., Any]]
"""How a stretch of the step between log-density calls is compiled: inline, or
:func:`~symplid._kernel_region.one_kernel`."""


def inline(fn: Callable[..., Any]) -> Callable[..., Any]:
    """``fn`` itself: the stretch is compiled with the code around it."""
    return fn


class Algebra(NamedTuple):
    """The kernel's small linear algebra: proposal factor, triangular solve, ``L z``."""

    cholesky: Callable[[Array], Array]
    solve_lower: Callable[[Array, Array], Array]
    matmul: Callable[[Array, Array], Array]


#: Unrolled small-matrix arithmetic: XLA:CPU compiles a chunk around it as one kernel.
UNROLLED = Algebra(
    lambda a: linalg.cholesky(a, MAX_UNROLLED_DIM),
    lambda chol, b: linalg.solve_lower(chol, b, MAX_UNROLLED_DIM),
    linalg.matmul,
)
#: LAPACK and ``dot``: fewer, larger operations, for a chunk that XLA cannot compile as one
#: kernel anyway (a log density that is a custom call, such as the compiled likelihood).
LAPACK = Algebra(
    jnp.linalg.cholesky,
    lambda chol, b: jax.scipy.linalg.solve_triangular(chol, b, lower=True),
    jnp.matmul,
)

def log1mexp(a: Array) -> Array:
    """``log(1 − exp(a))`` for ``a ≤ 0``, accurate in both tails.

    Uses ``log(−expm1(a))`` for ``a > −log 2`` and ``log1p(−exp(a))`` otherwise
    (Mächler 2012); ``log1mexp(0) = −∞`` and ``log1mexp(−∞) = 0``.
    """
    a = jnp.minimum(a, 0.0)
    near_zero = a > -math.log(2.0)
    safe_near = jnp.where(near_zero, a, -1.0)
    safe_far = jnp.where(near_zero, -1.0, a)
    return jnp.where(near_zero, jnp.log(-jnp.expm1(safe_near)), jnp.log1p(-jnp.exp(safe_far)))


def finite_or_neg_inf(logdensity: Array) -> Array:
    """``logdensity`` with every non-finite value (NaN, ±∞) as −∞: a rejection."""
    logdensity = jnp.asarray(logdensity)
    return jnp.where(jnp.isfinite(logdensity), logdensity, -jnp.inf)


def _log_alpha1(logdensity_from: Array, logdensity_to: Array) -> Array:
    """``log α1(from, to) = min(0, log π(to) − log π(from))``, −∞ when ``to`` is invalid."""
    diff = jnp.where(jnp.isfinite(logdensity_to), logdensity_to - logdensity_from, -jnp.inf)
    return jnp.minimum(0.0, diff)


def _log_q1(chol: Array, start: Array, end: Array, algebra: Algebra = UNROLLED) -> Array:
    """Log density of the stage-1 proposal ``N(end; start, L Lᵀ)`` up to its constant."""
    white = algebra.solve_lower(chol, end - start)
    return -0.5 * jnp.sum(white**2)


def stage2_log_acceptance(
    x: Array,
    logdensity_x: Array,
    y1: Array,
    logdensity_y1: Array,
    y2: Array,
    logdensity_y2: Array,
    chol: Array,
    algebra: Algebra = UNROLLED,
) -> Array:
    """Log of the second-stage acceptance probability α2(x, y1, y2).

    Parameters
    ----------
    x, logdensity_x
        Current point and its (finite) log density.
    y1, logdensity_y1
        Rejected first-stage proposal and its log density (may be −∞).
    y2, logdensity_y2
        Second-stage proposal and its log density (may be −∞ or NaN).
    chol
        Lower Cholesky factor of the first-stage proposal covariance ``C``.
    algebra
        :data:`UNROLLED` or :data:`LAPACK` (the same numbers to rounding).

    Returns
    -------
    Array
        ``log α2 ≤ 0``; −∞ when ``y2`` has a non-finite log density or when
        ``π(y1) ≥ π(y2)`` (then ``1 − α1(y2, y1) = 0``). Never NaN.
    """
    logdensity_y1 = finite_or_neg_inf(logdensity_y1)
    logdensity_y2 = finite_or_neg_inf(logdensity_y2)
    y2_valid = jnp.isfinite(logdensity_y2)
    safe_y2 = jnp.where(y2_valid, logdensity_y2, logdensity_x)
    numerator = (
        safe_y2
        + _log_q1(chol, y2, y1, algebra)
        + log1mexp(_log_alpha1(safe_y2, logdensity_y1))
    )
    denominator = (
        logdensity_x
        + _log_q1(chol, x, y1, algebra)
        + log1mexp(_log_alpha1(logdensity_x, logdensity_y1))
    )
    log_ratio = numerator - denominator
    log_ratio = jnp.where(jnp.isnan(log_ratio), -jnp.inf, log_ratio)
    return jnp.where(y2_valid, jnp.minimum(0.0, log_ratio), -jnp.inf)


class Stages(NamedTuple):
    """Carry of the delayed-rejection loop (index 0: stage 1, index 1: stage 2)."""

    stage: Array
    accepted: Array
    proposals: Array
    logdensities: Array
    log_alphas: Array


def staged(logdensity: LogDensityFn, x: Array, logdensity_x: Array, chol: Array,
           normals: Array, log_uniforms: Array, stage_scales: Array, num_stages: int,
           algebra: Algebra, region: Region) -> Stages:
    """The stages in a loop with one call site of the log density, so that it is compiled
    once (an expensive filter would otherwise be compiled twice), and stage 2 runs only when
    stage 1 rejects. Stage 1: y1 ~ N(x, C); stage 2: y2 ~ N(x, γ C)."""

    def keep_going(carry: Stages) -> Array:
        return (carry.stage < num_stages) & jnp.logical_not(carry.accepted)

    def propose(s: Array) -> Array:
        return x + stage_scales[s] * algebra.matmul(chol, normals[s])

    def judge(carry: Stages, y: Array, logdensity_y: Array) -> Stages:
        s = carry.stage
        log_alpha = jnp.where(
            s == 0,
            _log_alpha1(logdensity_x, logdensity_y),
            stage2_log_acceptance(x, logdensity_x, carry.proposals[0],
                                  carry.logdensities[0], y, logdensity_y, chol, algebra),
        )
        return Stages(
            stage=s + 1,
            accepted=log_uniforms[s] < log_alpha,
            proposals=carry.proposals.at[s].set(y),
            logdensities=carry.logdensities.at[s].set(logdensity_y),
            log_alphas=carry.log_alphas.at[s].set(log_alpha),
        )

    def one_stage(carry: Stages) -> Stages:
        y = region(propose)(carry.stage)
        return region(judge)(carry, y, logdensity(y))

    start = Stages(
        stage=jnp.asarray(0, dtype=jnp.int32),
        accepted=jnp.asarray(False),
        proposals=jnp.stack([x, x]),
        logdensities=jnp.stack([logdensity_x, logdensity_x]),
        log_alphas=jnp.full((2,), -jnp.inf, dtype=x.dtype),
    )
    return lax.while_loop(keep_going, one_stage, start)


def paired_stages(logdensity: LogDensityFn, x: Array, logdensity_x: Array, chol: Array,
                  normals: Array, log_uniforms: Array, stage_scales: Array, num_stages: int,
                  algebra: Algebra, region: Region) -> Stages:
    """Both proposals drawn and evaluated in one batched call (a batch of two; of 2 × chains
    when the chains are vectorized), then judged as :func:`staged` judges them: stage 2's
    value is used only when stage 1 rejects, so the chain is the same to rounding. For a
    likelihood backend that evaluates a batch for little more than one point
    (``LikelihoodBackend.batch_width``)."""

    def propose() -> Array:
        return jnp.stack([x + stage_scales[s] * algebra.matmul(chol, normals[s])
                          for s in range(2)])

    y = region(propose)()
    values = jax.vmap(logdensity)(y)
    return region(functools.partial(_judge_pair, algebra=algebra))(
        x, logdensity_x, chol, y, values, log_uniforms)


def _judge_pair(x: Array, logdensity_x: Array, chol: Array, y: Array, values: Array,
                log_uniforms: Array, algebra: Algebra) -> Stages:
    """Stage 1 and, where it rejects, stage 2, from both proposals and their values."""
    log_alpha1 = _log_alpha1(logdensity_x, values[0])
    accept1 = log_uniforms[0] < log_alpha1
    log_alpha2 = stage2_log_acceptance(x, logdensity_x, y[0], values[0], y[1], values[1], chol,
                                       algebra)
    accept2 = jnp.logical_not(accept1) & (log_uniforms[1] < log_alpha2)
    return Stages(
        stage=jnp.where(accept1, 1, 2).astype(jnp.int32),
        accepted=accept1 | accept2,
        proposals=jnp.stack([y[0], jnp.where(accept1, x, y[1])]),
        logdensities=jnp.stack([values[0], jnp.where(accept1, logdensity_x, values[1])]),
        log_alphas=jnp.stack([log_alpha1, jnp.where(accept1, -jnp.inf, log_alpha2)]),
    )
