"""A budget set by the answer: the runner stops when the draws meet their targets, or at a cap.

Compared with independent computations: ArviZ's ``summary`` on the returned (or saved) draws
for the targets; a fixed-budget run with the same iterations and burn-in for the draws
themselves; the uninterrupted run for a resumed one.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from click.testing import CliRunner

from sampler_targets import Gaussian2D, TwoModes
from symplid.cli import main
from symplid.inference._diagnostics import import_arviz
from symplid.sampling import RunOptions, Targets, draws_array, sample
from symplid.sampling._budget import (
    SHORTFALL,
    BudgetMonitor,
    TargetsOutOfReach,
    draw_statistics,
)
from symplid.sampling._resume import checkpoint_arrays, resume_sampling
from symplid.sampling._run import SamplingInterrupted
from symplid.workflow._results import RunFolder

az = import_arviz()
QUIET = RunOptions(progress=False, chunk_size=500)


def _arviz_worst(idata) -> tuple[float, float, float]:
    table = az.summary(idata, kind="diagnostics", round_to="none")
    return (float(table["ess_bulk"].min()), float(table["ess_tail"].min()),
            float(table["r_hat"].max()))


def test_draw_statistics_are_arvizs():
    rng = np.random.default_rng(1)
    theta = np.cumsum(rng.normal(size=(3, 401, 2)), axis=1) * 0.05 + rng.normal(size=(3, 401, 2))
    idata = az.from_dict(posterior={"a": theta[..., 0], "b": theta[..., 1]})
    np.testing.assert_allclose(draw_statistics(theta), _arviz_worst(idata), rtol=1e-10)


@pytest.mark.parametrize("method", ["dram", "nuts"])
def test_without_a_budget_the_run_stops_when_the_targets_are_met(method):
    target = Gaussian2D()
    idata = sample(target, method, num_chains=4, seed=2, init=target.map_result(),
                   options=QUIET)
    assert idata.attrs["stopped_by"] == "target"
    bulk, tail, rhat = _arviz_worst(idata)  # ArviZ on the draws returned
    assert bulk >= 400 and tail >= 400 and rhat <= 1.01
    record = json.loads(idata.attrs["budget"])
    assert record["ess_bulk_min"] == pytest.approx(bulk, rel=1e-6)
    # Far fewer than the cap: the run stopped at the first checks that met the targets.
    assert idata.attrs["iterations"] < 20_000
    kept = idata.posterior.sizes["draw"]
    assert kept == idata.attrs["iterations"] - record["burn_in"]


def test_the_draws_are_those_of_the_fixed_budget_it_ended_with():
    target = Gaussian2D()
    adaptive = sample(target, "dram", num_chains=4, seed=2, init=target.map_result(),
                      options=QUIET)
    record = json.loads(adaptive.attrs["budget"])
    burn_in = record["burn_in"]
    fixed = sample(target, "dram", num_draws=adaptive.attrs["iterations"] - burn_in,
                   num_chains=4, seed=2, init=target.map_result(), burn_in=burn_in,
                   options=QUIET)
    np.testing.assert_array_equal(draws_array(adaptive), draws_array(fixed))
    assert fixed.attrs["stopped_by"] == "fixed budget" and "budget" not in fixed.attrs


def test_a_tiny_cap_ends_the_run_and_says_so():
    target = Gaussian2D()
    targets = Targets(ess_bulk=1e6, max_iterations=3000)
    idata = sample(target, "dram", num_chains=2, seed=0, init=target.map_result(),
                   options=dataclasses.replace(QUIET, targets=targets))
    assert idata.attrs["stopped_by"] == "iterations" and idata.attrs["iterations"] == 3000
    assert json.loads(idata.attrs["budget"])["checks"] >= 1
    timed = sample(target, "dram", num_chains=2, seed=0, init=target.map_result(),
                   options=dataclasses.replace(QUIET, targets=Targets(max_seconds=1e-6)))
    assert timed.attrs["stopped_by"] == "wall time"
    assert timed.attrs["iterations"] < 200_000


def test_the_burn_in_is_extended_while_the_chains_disagree():
    # Two chains in each of two equally high, separate modes: R-hat never falls.
    target = TwoModes(gap=0.0)
    starts = np.zeros((4, 2))
    starts[2:] = TwoModes.far
    targets = Targets(max_iterations=12_000)
    idata = sample(target, "dram", num_chains=4, seed=1, init=target.map_result(),
                   options=dataclasses.replace(QUIET, initial_positions=starts,
                                               targets=targets))
    record = json.loads(idata.attrs["budget"])
    assert idata.attrs["stopped_by"] == "iterations" and record["rhat_max"] > 1.01
    assert record["burn_in"] > record["first_burn_in"] == 2000
    assert record["burn_in"] <= 12_000 // 2  # never more than half the run
    assert idata.posterior.sizes["draw"] == 12_000 - record["burn_in"]


def test_the_checks_come_on_a_geometric_grid():
    monitor = BudgetMonitor(Targets(growth=1.25), burn_in=2000, thin=1, num_chains=4)
    assert not monitor.due(2000, False) and not monitor.due(2400, False)
    assert monitor.due(2500, False) and monitor.due(2004, True) and not monitor.due(2003, True)
    monitor.last_check = 8000
    assert not monitor.due(9999, False) and monitor.due(10_000, False)


def _ar1(rho: float, chains: int, n: int, seed: int) -> np.ndarray:
    """``chains`` stationary AR(1) chains of ``n`` draws and two parameters, coefficient rho."""
    rng = np.random.default_rng(seed)
    e = rng.normal(size=(chains, n, 2))
    x = np.empty_like(e)
    x[:, 0] = e[:, 0] / np.sqrt(1 - rho**2)
    for i in range(1, n):
        x[:, i] = rho * x[:, i - 1] + e[:, i]
    return x


@pytest.mark.parametrize("rho", [0.98, 0.995])
@pytest.mark.parametrize("seed", [0, 1])
def test_the_projection_is_the_iterations_an_ar1_chain_needs(rho, seed):
    # An AR(1) chain's ESS per draw is (1 − ρ)/(1 + ρ) (its integrated autocorrelation time),
    # so four chains reach an ESS of 400 after 400 (1 + ρ) / (4 (1 − ρ)) draws each.
    monitor = BudgetMonitor(Targets(), burn_in=1000, thin=1, num_chains=4)
    monitor.check(_ar1(rho, 4, 6000, seed), 7000)
    exact = 1000 + 400 * (1 + rho) / (4 * (1 - rho))
    assert 0.75 < monitor.projected_iterations() / exact < 1.4


def test_the_cap_is_said_to_come_first_once_from_the_second_check():
    slow = _ar1(0.995, 4, 6000, 0)  # needs about 41,000 iterations per chain
    short = BudgetMonitor(Targets(max_iterations=15_000), burn_in=1000, thin=1, num_chains=4)
    short.check(slow[:, :4000], 5000)
    assert short.projected_iterations() > SHORTFALL * 15_000
    assert short.out_of_reach() is None  # one check: too early to say
    short.check(slow, 7000)
    line = short.out_of_reach()
    assert line is not None and "beyond its cap of 15,000" in line
    assert short.out_of_reach() is None  # said once
    roomy = BudgetMonitor(Targets(max_iterations=100_000), burn_in=1000, thin=1, num_chains=4)
    for done in (5000, 7000):
        roomy.check(slow[:, : done - 1000], done)
    assert roomy.projected_iterations() < SHORTFALL * 100_000 and roomy.out_of_reach() is None


def test_a_run_that_cannot_reach_its_targets_says_so_before_its_cap():
    target = Gaussian2D()
    targets = Targets(ess_bulk=1e6, max_iterations=8000)
    with pytest.warns(TargetsOutOfReach, match="beyond its cap of 8,000"):
        idata = sample(target, "dram", num_chains=2, seed=0, init=target.map_result(),
                       options=dataclasses.replace(QUIET, targets=targets))
    record = json.loads(idata.attrs["budget"])
    assert idata.attrs["stopped_by"] == "iterations"
    assert record["projected_iterations"] > SHORTFALL * 8000


@pytest.mark.parametrize("method", ["dram", "nuts"])
def test_a_resumed_run_without_a_budget_equals_the_uninterrupted_one(method, tmp_path):
    target = Gaussian2D()
    init = target.map_result()
    full = sample(target, method, num_chains=2, seed=4, init=init, options=QUIET)
    stop = 2500 if method == "dram" else 1500  # at the first check

    def stop_at(report):
        if report.iterations_done == stop:
            raise KeyboardInterrupt

    with pytest.warns(SamplingInterrupted):
        part, checkpoint = sample(target, method, num_chains=2, seed=4, init=init,
                                  options=dataclasses.replace(QUIET, callback=stop_at,
                                                              return_state=True))
    assert part.attrs["stopped_by"] == "interrupted"
    np.savez(tmp_path / "state.npz", **checkpoint_arrays(checkpoint))
    with np.load(tmp_path / "state.npz") as stored:
        resumed = resume_sampling(target, part, dict(stored), options=QUIET)
    assert resumed.attrs["stopped_by"] == full.attrs["stopped_by"] == "target"
    assert resumed.attrs["iterations"] == full.attrs["iterations"]
    np.testing.assert_array_equal(draws_array(resumed), draws_array(full))


# ---------------------------------------------------------------------------- command line
FIT = ["--order", "2", "--x0", "1,0", "--chains", "4", "--no-progress", "--no-report",
       "--set", "map.num_starts=1", "--set", "map.sensitivity=false",
       "--set", "sampler.chunk_size=500"]
FIT += ["--dt", "0.25"]  # a fixed step: the step search is test_step_size.py's


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def test_fit_without_a_budget_stops_at_the_targets(data_csv, tmp_path):
    out = tmp_path / "run"
    result = run("fit", data_csv, "--out", out, *FIT)
    assert result.exit_code == 0, result.output
    assert "target reached" in result.output and "not converged" not in result.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stopped_by"] == "target" and summary["iterations"] < 200_000
    bulk, tail, rhat = _arviz_worst(RunFolder(out, "r").read_posterior())  # the saved draws
    assert bulk >= 400 and tail >= 400 and rhat <= 1.01


def test_fit_with_a_tiny_cap_says_the_cap_ended_it(data_csv, tmp_path):
    out = tmp_path / "run"
    result = run("fit", data_csv, "--out", out, *FIT, "--set", "sampler.max_iterations=3000",
                 "--set", "sampler.target_ess=100000")
    assert result.exit_code == 0, result.output
    assert "cap reached (iterations) after 3,000 iterations" in result.output
    assert "at the rate seen they need about" in result.output
    assert json.loads((out / "summary.json").read_text())["stopped_by"] == "iterations"


def test_fit_resume_of_a_run_without_a_budget(data_csv, tmp_path, monkeypatch):
    import symplid.workflow._fit as fit_module

    whole, out = tmp_path / "whole", tmp_path / "run"
    assert run("fit", data_csv, "--out", whole, *FIT).exit_code == 0

    def stop_at(report):
        if report.iterations_done == 4000:
            raise KeyboardInterrupt

    def stopped(*args, options, **kwargs):
        return sample(*args, options=dataclasses.replace(options, callback=stop_at), **kwargs)

    monkeypatch.setattr(fit_module, "sample", stopped)
    assert run("fit", data_csv, "--out", out, *FIT).exit_code == 130
    monkeypatch.undo()
    resumed = run("fit", data_csv, "--out", out, "--resume", *FIT)
    assert resumed.exit_code == 0, resumed.output
    assert "target reached" in resumed.output
    mine, reference = (RunFolder(p, "r").read_posterior() for p in (out, whole))
    assert mine.attrs["iterations"] == reference.attrs["iterations"]
    np.testing.assert_array_equal(draws_array(mine), draws_array(reference))


def test_a_cap_below_the_first_burn_in_is_refused_in_one_line(data_csv, tmp_path):
    result = run("fit", data_csv, "--out", tmp_path / "run", *FIT,
                 "--set", "sampler.max_iterations=1000")
    assert result.exit_code == 2
    (line,) = result.output.strip().splitlines()
    assert "sampler.max_iterations (1,000) must be greater than the first burn-in" in line
