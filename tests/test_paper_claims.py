"""The paper-claims study's statistics, claim evaluation, calibration and README block.

Each statistic is checked against an independent answer: Wilson intervals against SciPy and
closed forms, the bootstrap against a degenerate case and the median's asymptotic normal
interval, the rank statistic on a conjugate normal model whose exact posterior is known (ranks
uniform) and on a posterior made too narrow (ranks not uniform). The claims and the README
block are computed from small hand-made tables whose answers are counted by hand.
"""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pandas as pd
import pytest

from symplid.studies._claims_readme import (
    BEGIN,
    END,
    FORMATTERS,
    readme_block,
    update_readme,
)
from symplid.studies._claims_stats import (
    bootstrap_median,
    rank_uniformity,
    thin_evenly,
    truth_rank,
    wilson_interval,
)
from symplid.studies._paper_calibration import cell_calibration, evaluate_calibration
from symplid.studies._paper_claims import RATIO_THRESHOLD, evaluate_claims, verdict
from symplid.studies._paper_study import (
    PAPER_SETTING,
    VARIANTS,
    estimate_cost,
    paper_claims_spec,
    parse_budget,
    select_variants,
)
from symplid.studies._paper_study_report import calibration_answer, format_claims_report
from symplid.workflow._sweep_results import _flatten

Z = 1.959963984540054


# ----------------------------------------------------------------------------- statistics
@pytest.mark.parametrize(("k", "n"), [(0, 10), (3, 10), (10, 10), (17, 20), (1, 3), (40, 97)])
def test_wilson_interval_matches_scipy(k, n):
    from scipy.stats import binomtest

    ref = binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
    assert wilson_interval(k, n) == pytest.approx((ref.low, ref.high), abs=1e-12)


def test_wilson_interval_closed_forms_and_errors():
    lo, hi = wilson_interval(0, 10)
    assert lo == 0.0 and hi == pytest.approx(Z**2 / (10 + Z**2))
    lo, hi = wilson_interval(5, 10)  # symmetric about 1/2
    half = Z / (10 + Z**2) * math.sqrt(10 / 4 + Z**2 / 4)
    assert (lo, hi) == pytest.approx((0.5 - half, 0.5 + half))
    assert wilson_interval(0, 0) is None
    with pytest.raises(ValueError, match="0 ≤ k ≤ n"):
        wilson_interval(4, 3)
    for n in range(1, 41):  # the interval holds k / n itself, ends included exactly
        assert wilson_interval(0, n)[0] == 0.0 and wilson_interval(n, n)[1] == 1.0
        for k in range(n + 1):
            lo, hi = wilson_interval(k, n)
            assert 0.0 <= lo <= k / n <= hi <= 1.0


def test_bootstrap_median_known_cases():
    const = bootstrap_median([2.5] * 7)
    assert (const["median"], const["lo"], const["hi"]) == (2.5, 2.5, 2.5)
    one = bootstrap_median([1.0, np.nan])
    assert one["median"] == 1.0 and one["lo"] is None and one["n"] == 1
    # large normal sample: the interval of the median is about median ± z·√(π/2)·σ/√n
    x = np.random.default_rng(3).normal(0.0, 2.0, size=801)
    b = bootstrap_median(x, seed=1)
    half = Z * math.sqrt(math.pi / 2) * 2.0 / math.sqrt(x.size)
    assert b["median"] == pytest.approx(np.median(x))
    assert b["hi"] - b["lo"] == pytest.approx(2 * half, rel=0.25)
    assert b["lo"] < 0.0 < b["hi"]
    assert bootstrap_median(x, seed=1) == b  # seeded: reproducible
    assert bootstrap_median(x, seed=2) != b


def test_thin_evenly_spreads_over_chains():
    draws = np.arange(4 * 1000, dtype=float).reshape(4, 1000)
    thinned = thin_evenly(draws, 8)
    assert thinned.size == 8 and thinned[0] == 0 and thinned[-1] == 3999
    assert sorted(set((thinned // 1000).astype(int))) == [0, 1, 2, 3]
    assert truth_rank(draws, 2000.5, 8) == int(np.sum(thinned < 2000.5))


def _conjugate_records(scale: float, reps: int = 400, seed: int = 0) -> pd.DataFrame:
    """θ ~ N(0, 1), three observations y ~ N(θ, 1): the posterior is N(Σy / 4, 1/4). Draws
    come from that posterior with its sd multiplied by ``scale`` (1: exact)."""
    rng = np.random.default_rng(seed)
    rows = []
    for _ in range(reps):
        theta = rng.normal(size=2)  # two independent parameters
        y = theta[:, None] + rng.normal(size=(2, 3))
        mean, sd = y.sum(axis=1) / 4, 0.5 * scale
        draws = mean + sd * rng.normal(size=(2, 500, 2))  # (chain, draw, param)
        record = cell_calibration(["a", "b"], draws, {"a": theta[0], "b": theta[1]})
        rows.append({"status": "ok", **_flatten({"calibration": record})})
    return pd.DataFrame(rows)


def test_ranks_uniform_when_the_posterior_is_exact():
    cal = evaluate_calibration(_conjugate_records(1.0), "exact")
    for p in cal["params"].values():
        assert p["n"] == 400 and p["rank_bins"] == 10
        assert p["rank_p_value"] > 0.01
        assert p["coverage_ci"][0] <= 0.95 <= p["coverage_ci"][1]
    assert cal["nominal"] and cal["below_nominal"] == []


def test_ranks_not_uniform_when_the_posterior_is_too_narrow():
    cal = evaluate_calibration(_conjugate_records(0.5), "too narrow")
    for p in cal["params"].values():
        assert p["rank_p_value"] < 1e-6
        counts = p["rank_counts"]
        assert counts[0] + counts[-1] > 3 * (p["n"] / p["rank_bins"])  # U-shaped
        assert p["coverage_ci"][1] < 0.95
    assert not cal["nominal"] and cal["below_nominal"] == ["a", "b"]


def test_non_converged_cells_are_reported_apart():
    """A cell with R-hat > 1.1 leaves the calibration (its ranks are not counted) and is
    listed with its seed and R-hat; cells without an R-hat column are all kept."""
    rows = _conjugate_records(1.0, reps=60)
    rows["seed"] = range(60)
    rows["rhat_max"] = 1.002
    rows.loc[[3, 17], "rhat_max"] = [2.58, 1.8]
    cal = evaluate_calibration(rows, "with failures")
    assert all(p["n"] == 58 for p in cal["params"].values())
    assert cal["not_converged"] == {"n": 2, "seeds": [3, 17], "rhat": [2.58, 1.8]}
    kept = evaluate_calibration(rows.drop(columns="rhat_max"), "no R-hat")
    assert kept["not_converged"]["n"] == 0 and kept["params"]["a"]["n"] == 60
    assert cal["restarted"] == {"chains": 0, "seeds": []}  # cells from before the rule


def test_restarted_chains_are_counted_with_their_seeds():
    rows = _conjugate_records(1.0, reps=20)
    rows["seed"] = range(20)
    rows["restarted_chains"] = 0
    rows.loc[[4, 9], "restarted_chains"] = [1, 2]
    cal = evaluate_calibration(rows, "restarts")
    assert cal["restarted"] == {"chains": 3, "seeds": [4, 9]}
    assert all(p["n"] == 20 for p in cal["params"].values())  # they stay in the table


def test_rank_uniformity_bins_and_range():
    u = rank_uniformity(np.arange(100), 99)
    assert u["bins"] == 10 and u["counts"] == [10] * 10 and u["p_value"] == pytest.approx(1.0)
    assert rank_uniformity(np.arange(20) * 5, 99)["bins"] == 4
    with pytest.raises(ValueError, match=r"ranks must lie in 0\.\.99"):
        rank_uniformity([100], 99)


# ----------------------------------------------------------------------------- claims
LF, RK, HEUN = "leapfrog", "rk2-midpoint", "rk2-heun"


def _row(seed, integrator, h, noise, horizon, status="ok", **setting):
    return {
        **PAPER_SETTING,
        **setting,
        "seed": seed,
        "integrator": integrator,
        "status": status,
        "hamiltonian_rel_error": h,
        "process_noise_median": noise,
        "prediction_horizon_s": horizon,
    }


@pytest.fixture(scope="module")
def claims_table():
    """The paper's setting (4 seeds), dt = 0.1 (2 seeds, one RK2 cell failed) and RK2 Heun
    (2 seeds, sharing the paper's leapfrog cells); every answer below is counted by hand."""
    nan = math.nan
    rows = [
        # paper: H errors (lf < rk2 for seeds 0, 2; seed 3 undecided), noise ratios
        # 10, 2, 50, 5; horizons: lf longer for 0 and 3, a tie for 1, shorter for 2
        _row(0, LF, 0.01, 1e-6, 150.0),
        _row(0, RK, 0.02, 1e-5, 20.0),
        _row(1, LF, 0.02, 1e-6, 200.0),
        _row(1, RK, 0.01, 2e-6, 200.0),
        _row(2, LF, 0.05, 2e-6, 30.0),
        _row(2, RK, 0.06, 1e-4, 40.0),
        _row(3, LF, 0.01, 1e-6, 200.0),
        _row(3, RK, nan, 5e-6, 25.0),
        _row(0, "yoshida4", 0.0, 1.0, 0.0),  # not compared: calibration only
        _row(0, HEUN, 0.03, 3e-6, 10.0),
        _row(1, HEUN, 0.01, 1e-6, 250.0),
        _row(0, LF, 0.03, 1e-6, 100.0, dt=0.1),
        _row(0, RK, 0.04, 1e-4, 10.0, dt=0.1),
        _row(1, LF, 0.01, 1e-6, 100.0, dt=0.1),
        _row(1, RK, nan, nan, nan, status="failed", dt=0.1),
    ]
    return pd.DataFrame(rows)


def _variants(*names):
    return [v for v in VARIANTS if v.name in names]


def test_claims_on_a_hand_made_table(claims_table):
    result = evaluate_claims(claims_table, _variants("paper", "dt=0.1", "rk2-heun"))
    assert [v["name"] for v in result["variants"]] == ["paper", "dt=0.1", "rk2-heun"]
    assert [v["pairs"] for v in result["variants"]] == [4, 1, 2]
    assert [v["unpaired"] for v in result["variants"]] == [0, 1, 2]  # no Heun fit of 2, 3
    h, pn, pr = (result["claims"][k]["per_variant"] for k in ("hamiltonian", "process_noise",
                                                                "prediction"))
    assert (h[0]["n"], h[0]["holds"], h[0]["undecided"]) == (3, 2, 1)
    assert h[0]["fraction_ci"] == pytest.approx(wilson_interval(2, 3))
    assert h[0]["effect"]["median"] == pytest.approx(-0.01)  # of −0.01, +0.01, −0.01
    assert h[0]["per_seed"]["seed"] == [0, 1, 2]
    assert (h[1]["n"], h[1]["holds"], h[1]["unpaired"]) == (1, 1, 1)
    assert (h[2]["n"], h[2]["holds"]) == (2, 1)  # Heun: seed 0 holds, seed 1 does not

    assert RATIO_THRESHOLD == 5.0
    assert (pn[0]["n"], pn[0]["holds"], pn[0]["smaller"]) == (4, 3, 4)  # 10, 2, 50, 5
    assert pn[0]["effect"]["median"] == pytest.approx(7.5)
    # the bootstrap medians of four ratios lie between the smallest and the largest
    assert 2.0 - 1e-9 <= pn[0]["effect"]["lo"] < 7.5 < pn[0]["effect"]["hi"] <= 50.0 + 1e-9
    assert pn[2]["per_seed"]["effect"] == pytest.approx([3.0, 1.0])  # Heun: 3e-6/1e-6, 1

    assert (pr[0]["n"], pr[0]["holds"], pr[0]["ties"]) == (4, 2, 1)
    assert pr[0]["per_seed"]["effect"] == pytest.approx([7.5, 1.0, 0.75, 8.0])
    assert pr[0]["effect"]["median"] == pytest.approx(np.median([7.5, 1.0, 0.75, 8.0]))
    assert pr[0]["verdict"] == verdict(wilson_interval(2, 4)) == "mixed"
    assert evaluate_claims(claims_table, _variants("paper")) == evaluate_claims(
        claims_table, _variants("paper"))  # the bootstrap is seeded


def test_verdicts_and_errors(claims_table):
    assert verdict(wilson_interval(20, 20)) == "holds"
    assert verdict(wilson_interval(0, 20)) == "fails"
    assert verdict(wilson_interval(10, 20)) == "mixed"
    assert verdict(None) == "undecided"
    with pytest.raises(ValueError, match="more than one ok row for seed 0"):
        evaluate_claims(pd.concat([claims_table, claims_table.iloc[:1]]), _variants("paper"))
    with pytest.raises(ValueError, match="no column prediction_horizon_s"):
        evaluate_claims(claims_table.drop(columns="prediction_horizon_s"), _variants("paper"))
    # a table without the process-noise column was run per gap: the per-step variant is empty
    old = claims_table.drop(columns="model.process_noise_per")
    result = evaluate_claims(old, _variants("paper", "noise-per-step"))
    assert [v["pairs"] for v in result["variants"]] == [4, 0]


# ----------------------------------------------------------------------------- the spec
def test_variants_one_setting_at_a_time():
    spec = paper_claims_spec(seeds=2, budget="quick", variants="all")
    per_seed = 2 * len(VARIANTS) - 1 + 1  # Heun shares leapfrog; yoshida4 at the paper's
    assert len(spec.cells) == 2 * per_seed and len(set(spec.ids)) == len(spec.cells)
    for cell in (c.settings for c in spec.cells):
        changed = {k for k, v in PAPER_SETTING.items() if cell[k] != v}
        assert len(changed) <= 1
        assert cell["num_iterations"] == 3000
    found = {(c.settings["integrator"], c.settings["dt"]) for c in spec.cells}
    assert ("yoshida4", 0.25) in found and ("yoshida4", 0.1) not in found
    # a run with the variants reuses every cell of a run without them (same settings, same id)
    assert set(paper_claims_spec(2, "quick", "none").ids) <= set(spec.ids)
    none = paper_claims_spec(seeds=3, budget=500, variants="none")
    assert len(none.cells) == 9 and {c.settings["burn_in"] for c in none.cells} == {250}
    some = select_variants("dt=0.1,rk2-heun")
    assert [v.name for v in some] == ["paper", "dt=0.1", "rk2-heun"]
    with pytest.raises(ValueError, match=r"unknown variant 'dt=0\.2'"):
        select_variants("dt=0.2")
    with pytest.raises(ValueError, match="budget must be"):
        parse_budget("fast")
    assert parse_budget("paper")[1]["num_iterations"] == 200_000
    cost1, cost2 = estimate_cost(none, 1), estimate_cost(none, 2)
    assert cost1["core_s"] == cost2["core_s"] and cost2["wall_s"] < 0.6 * cost1["wall_s"]


# ----------------------------------------------------------------------------- README
def _calibration_table(seed: int) -> pd.DataFrame:
    frame = _conjugate_records(1.0, reps=20, seed=seed)
    return frame.drop(columns="status")


@pytest.fixture(scope="module")
def claims_json(claims_table):
    table = claims_table.copy()
    cal = pd.concat([_calibration_table(s) for s in range(2)], ignore_index=True)
    ok = table.index[table["status"] == "ok"]
    table = table.join(cal.iloc[: len(ok)].set_axis(ok))  # the failed cell has none
    claims = evaluate_claims(table, _variants("paper", "dt=0.1", "rk2-heun"))
    claims["study"] = {
        "seeds": 4, "budget_name": "quick",
        "budget": {"num_iterations": 3000, "burn_in": 1500, "num_chains": 2, "num_starts": 2},
        "variants": [{"name": n} for n in ("paper", "dt=0.1", "rk2-heun")],
        "cells": 15, "cells_run": 15, "cells_skipped": 0, "cells_failed": 1, "failures": [],
        "wall_time_s": 123.4, "cell_seconds_total": 230.2, "workers": 2,
        "runs": [{"started": "x", "wall_time_s": 123.4, "cells_run": 15, "cell_seconds": 230.2,
                  "speedup": 1.87, "workers": 2, "scheduler": None}],
        "figures": {"hamiltonian": "figures/claim_hamiltonian.png"},
    }
    return json.loads(json.dumps(claims))  # as read back from claims.json


def _numbers_of(value, out: set[str]) -> set[str]:
    if isinstance(value, dict):
        for k, v in value.items():
            _numbers_of(k, out)  # parameter names such as q1^2
            _numbers_of(v, out)
    elif isinstance(value, list):
        for v in value:
            _numbers_of(v, out)
    elif isinstance(value, bool) or value is None:
        pass
    elif isinstance(value, int | float):
        out.update(re.findall(_NUMBER, " ".join(f(value) for f in FORMATTERS)))
    elif isinstance(value, str):
        out.update(re.findall(_NUMBER, value))
    return out


_NUMBER = r"\d[\d,]*(?:\.\d+)?(?:e[-+]?\d+)?"


def test_readme_block_numbers_come_from_the_json(claims_json, tmp_path):
    block = readme_block(claims_json)
    assert block == readme_block(json.loads(json.dumps(claims_json)))  # deterministic
    allowed = _numbers_of(claims_json, set())
    found = re.findall(_NUMBER, block)
    assert found and set(found) <= allowed, set(found) - allowed
    assert "Where a claim does not hold" in block and "mixed" in block
    changed = json.loads(json.dumps(claims_json))
    changed["study"]["runs"][-1]["wall_time_s"] = 4567.0
    assert "4,567 s" in readme_block(changed) and "4,567" not in block

    readme = tmp_path / "README.md"
    readme.write_text(f"# title\n\nbefore\n{BEGIN}\nold text 99\n{END}\nafter\n")
    update_readme(readme, claims_json)
    text = readme.read_text()
    assert text.startswith("# title\n\nbefore\n") and text.endswith(f"{END}\nafter\n")
    assert "old text" not in text and block in text
    update_readme(readme, claims_json)
    assert readme.read_text() == text  # idempotent
    readme.write_text("no markers\n")
    with pytest.raises(ValueError, match="no '<!-- claims:begin -->'"):
        update_readme(readme, claims_json)


def test_readme_block_estimates_the_papers_budget_only_for_a_smaller_one(claims_json):
    quick = json.loads(json.dumps(claims_json))
    quick["study"]["estimate_paper_budget"] = {
        "1_workers": {"core_s": 4172.0, "wall_s": 4172.0},
        "2_workers": {"core_s": 4172.0, "wall_s": 2086.0},
    }
    block = readme_block(quick)
    assert "estimated at 4,172 s" in block and "smaller than the paper's" in block
    measured = json.loads(json.dumps(quick))
    measured["study"]["budget_name"] = "paper"  # measured at the paper's budget: no estimate
    block = readme_block(measured)
    assert "estimated" not in block and "smaller than the paper's" not in block


def test_report_and_calibration_answer(claims_json):
    answer = calibration_answer(claims_json)
    assert answer["baseline"]["label"] == "paper, leapfrog"
    assert answer["smaller_dt"]["label"] == "dt=0.1, leapfrog"
    assert answer["yoshida4"]["params"]["a"]["n"] == 1
    report = format_claims_report(claims_json)
    assert "## Claim 3: valid predictions" in report and "## Calibration" in report
    assert "| paper | rk2-midpoint | 4 | 2 |" in report


@pytest.mark.parametrize(
    ("option", "message"),
    [
        (["--variants", "dt=0.3"], "unknown variant 'dt=0.3'"),
        (["--budget", "lots"], "budget must be 'paper', 'quick' or a number of iterations"),
    ],
)
def test_cli_mistakes_are_one_line(tmp_path, option, message):
    from click.testing import CliRunner

    from symplid.cli import main

    args = ["study", "paper-claims", "--out", str(tmp_path / "s"), "--seeds", "2", *option]
    result = CliRunner().invoke(main, args, catch_exceptions=False)
    assert result.exit_code == 2, result.output
    assert message in result.output and "Traceback" not in result.output
    assert not (tmp_path / "s").exists()  # nothing run, nothing written


# ----------------------------------------------------------------------------- one program
def test_dram_chunk_takes_the_data_as_an_argument():
    """A DataStep gives the closure step's draws bit for bit, and its compiled chunk is the
    same program for other data (so the next seed of a sweep loads it from the cache)."""
    import jax
    import jax.numpy as jnp

    from symplid.inference.samplers import dram
    from symplid.sampling import RunOptions
    from symplid.sampling._chunk import DataStep, _compile_chunk
    from symplid.sampling._run import run_chains

    settings = dram.DRAMSettings()

    def log_density(data, theta):
        return -0.5 * jnp.sum((theta - data) ** 2)

    def step_fn(data, key, state):
        return dram.build_kernel(lambda t: log_density(data, t), settings)(key, state)

    def record(state, info):
        return {"theta": state.position}

    a, b = jnp.array([0.5, -1.0]), jnp.array([3.0, 2.0])
    init = jax.vmap(lambda p: dram.init(p, lambda t: log_density(a, t), jnp.eye(2), settings))
    states = init(jnp.array([[0.0, 0.0], [1.0, 1.0]]))
    key = jax.random.key(4)
    closure = dram.build_kernel(lambda t: log_density(a, t), settings)
    quiet = RunOptions(progress=False)
    run_a = run_chains(DataStep(step_fn, a), states, key, 60, record=record, options=quiet)
    run_c = run_chains(closure, states, key, 60, record=record, options=quiet)
    np.testing.assert_array_equal(run_a.draws["theta"], run_c.draws["theta"])

    def program(data):
        chunk = _compile_chunk(DataStep(step_fn, data), record, 10, True)
        return chunk.func.lower(states, jax.random.split(key, 2), jnp.int64(0), jnp.int64(10),
                                data=chunk.keywords["data"]).as_text()

    assert program(a) == program(b)
