"""DRAM's paired stages and its choice of linear algebra: the same chain, decided per run.

Both stages' proposals evaluated in one batched call (``paired_stages``), and LAPACK in place
of the unrolled small-matrix arithmetic or that arithmetic compiled region by region
(``linalg``), change how a step is computed, not what it computes: the chains must equal the
stage-by-stage, unrolled ones to rounding.
"""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

import symplid  # noqa: F401  (float64)
from sampler_targets import Banana
from symplid.inference.samplers._dram import DRAMSettings
from symplid.inference.samplers._registry import resolve_dram
from symplid.model import _kernel as compiled_kernel
from symplid.sampling import RunOptions, draws_array, sample

STATS = ("stage1_accepted", "stage2_attempted", "stage2_accepted", "accepted")


def _run(target, settings, *, num_chains=4, num_draws=1500, init=None):
    return sample(target, "dram", num_draws=num_draws, burn_in=500, num_chains=num_chains,
                  seed=3, init=init if init is not None else target.map_result(),
                  settings=settings, options=RunOptions(progress=False))


def _assert_same_chain(a, b, rtol):
    np.testing.assert_allclose(draws_array(a), draws_array(b), rtol=rtol, atol=rtol * 1e-3)
    for name in STATS:
        np.testing.assert_array_equal(a.sample_stats[name], b.sample_stats[name])


@pytest.mark.parametrize("chains", [1, 4])
def test_paired_stages_give_the_stage_by_stage_chain(chains):
    """Banana target, rejections at both stages: paired and stage-by-stage steps make the same
    moves, draw for draw, to rounding (the unrolled algebra in both: the same operations,
    grouped differently by XLA)."""
    target = Banana()
    staged = _run(target, {"paired_stages": False, "linalg": "unrolled"}, num_chains=chains)
    paired = _run(target, {"paired_stages": True, "linalg": "unrolled"}, num_chains=chains)
    assert 0.1 < float(staged.sample_stats["stage2_attempted"].mean()) < 0.9
    _assert_same_chain(staged, paired, rtol=1e-10)


@pytest.mark.parametrize("algebra", ["lapack", "fused"])
@pytest.mark.parametrize("paired", [False, True])
def test_every_algebra_gives_the_unrolled_chain_to_rounding(algebra, paired):
    """LAPACK calls, or the unrolled arithmetic compiled region by region: the same moves."""
    target = Banana()
    unrolled = _run(target, {"paired_stages": paired, "linalg": "unrolled"})
    other = _run(target, {"paired_stages": paired, "linalg": algebra})
    _assert_same_chain(unrolled, other, rtol=1e-9)


def _posterior_on(backend: str) -> SimpleNamespace:
    return SimpleNamespace(model=SimpleNamespace(likelihood_backend=backend))


@pytest.mark.parametrize(
    ("backend", "chains", "method", "paired", "linalg"),
    [
        ("compiled", 4, "vectorized", True, "fused"),  # 2 × 4 proposals fill the 8 lanes
        ("compiled", 8, "vectorized", True, "fused"),
        ("compiled", 2, "vectorized", False, "fused"),  # a batch of 4 is four single calls
        ("compiled", 4, "sequential", False, "fused"),
        ("compiled", 1, "vectorized", False, "fused"),
        ("jax", 4, "vectorized", False, "unrolled"),  # a batch costs its size in JAX
    ],
)
def test_resolution_follows_the_backend_and_the_chains(backend, chains, method, paired, linalg):
    resolved = resolve_dram(DRAMSettings(), _posterior_on(backend), chains, method)
    assert (resolved.paired_stages, resolved.linalg) == (paired, linalg)


def test_resolution_keeps_what_the_user_set():
    given = DRAMSettings(paired_stages=False, linalg="unrolled")
    assert resolve_dram(given, _posterior_on("compiled"), 4, "vectorized") == given
    no_dr = resolve_dram(DRAMSettings(delayed_rejection=False), _posterior_on("compiled"), 4,
                         "vectorized")
    assert no_dr.paired_stages is False
    plain = resolve_dram(DRAMSettings(), object(), 4, "vectorized")  # no model: defaults
    assert (plain.paired_stages, plain.linalg) == (False, "unrolled")


def test_linalg_is_validated():
    with pytest.raises(ValueError, match="linalg must be one of 'unrolled', 'lapack', 'fused'"):
        DRAMSettings(linalg="cholmod")


@pytest.mark.slow
@pytest.mark.skipif(not compiled_kernel.available(), reason="compiled kernel not built")
def test_papers_posterior_on_the_kernel_pairs_and_keeps_the_chain(hh, hh_model, hh_data,
                                                                   hh_theta):
    """The paper's posterior on the compiled kernel: four vectorised chains are resolved to
    paired stages and the fused regions (recorded in the run's settings), and their chain is the
    stage-by-stage, unrolled one to rounding: the kernel's batch of eight gives each θ the
    numbers it gives it alone."""
    from symplid.model._posterior import Posterior

    posterior = Posterior(hh_model, hh_data, x0=hh.initial_state)
    assert hh_model.likelihood_backend == "compiled"
    scales = np.array([0.02] * 9 + [4e-6, 4e-4])
    init = SimpleNamespace(theta=np.asarray(hh_theta), covariance=np.diag(scales**2))
    settings = {"variance_scale": "natural"}
    auto = _run(posterior, settings, num_draws=300, init=init)
    kernel = json.loads(auto.attrs["settings"])["kernel"]
    assert (kernel["paired_stages"], kernel["linalg"]) == (True, "fused")
    staged = _run(posterior, {**settings, "paired_stages": False, "linalg": "unrolled"},
                  num_draws=300, init=init)
    assert float(staged.sample_stats["stage2_attempted"].mean()) > 0.05
    _assert_same_chain(staged, auto, rtol=1e-7)
