"""Variants of the paper-claims study that run no reference, or to which a claim does not apply.

The deterministic likelihood (``model.process_noise_per = "none"``) and the log-uniform prior
on Σ are fitted for the calibration alone: no RK2 cell, every claim *n/a*. The answers are
counted by hand from small tables; the matching of rows to variants is checked by its
consequence (adding another variant's rows leaves a variant's result unchanged).
"""

from __future__ import annotations

import json

import pandas as pd
import pytest

from symplid.studies._claims_readme import (
    CALIBRATION_BEGIN,
    CALIBRATION_END,
    calibration_block,
    readme_block,
    update_readme,
)
from symplid.studies._claims_stats import rank_uniformity, wilson_interval
from symplid.studies._paper_claims import NOT_APPLICABLE, evaluate_claims
from symplid.studies._paper_study import PAPER_SETTING, VARIANTS, Variant, paper_claims_spec
from symplid.studies._paper_study_report import calibration_answer, format_claims_report

LF, RK, Y4 = "leapfrog", "rk2-midpoint", "yoshida4"
Z95 = 1.959963984540054
NONE = {"model.process_noise_per": "none"}
LOGU = {"priors.process_var": "log-uniform"}


def _row(seed, integrator, h, noise, horizon, covered=(True, True), ranks=(50, 50),
         mid=None, **setting):
    """One ok cell with the claim metrics and the calibration columns of two parameters
    (with ``mid``, a's interval: mid ± 1.96 around a truth 0, so that z = mid)."""
    quantiles = {} if mid is None else {
        "calibration.a.q025": mid - Z95, "calibration.a.q975": mid + Z95,
        "calibration.a.truth": 0.0}
    return {
        **quantiles,
        **PAPER_SETTING, **setting, "seed": seed, "integrator": integrator, "status": "ok",
        "hamiltonian_rel_error": h, "process_noise_median": noise,
        "prediction_horizon_s": horizon, "rhat_max": 1.001,
        "calibration.a.covered": covered[0], "calibration.a.rank": ranks[0],
        "calibration.b.covered": covered[1], "calibration.b.rank": ranks[1],
        "calibration.rank_draws": 99,
    }


PAPER_ROWS = [
    _row(0, LF, 0.01, 1e-6, 150.0), _row(0, RK, 0.02, 1e-5, 20.0),
    _row(1, LF, 0.02, 1e-6, 200.0), _row(1, RK, 0.01, 2e-6, 100.0),
    _row(0, Y4, 0.01, 1e-6, 150.0), _row(1, Y4, 0.01, 1e-6, 150.0, covered=(False, True)),
]
# No process noise: no process-noise metric (NaN), four seeds of leapfrog and yoshida4.
# Leapfrog covers a in 3 of 4 seeds and b in all; yoshida4 covers both in every seed.
NO_NOISE_ROWS = [
    _row(s, LF, 0.01, float("nan"), 150.0, covered=(s != 2, True), ranks=(10 * s, 99 - s),
         mid=0.5 * s, **NONE)
    for s in range(4)
] + [_row(s, Y4, 0.005, float("nan"), 180.0, ranks=(40 + s, 60), **NONE) for s in range(4)]
# The log-uniform prior: two seeds of leapfrog (a missed once).
LOG_UNIFORM_ROWS = [
    _row(0, LF, 0.01, 1e-9, 150.0, covered=(False, True), **LOGU),
    _row(1, LF, 0.01, 1e-9, 150.0, **LOGU),
]


def _variants(*names):
    return [v for v in VARIANTS if v.name in names]


def _table(*groups) -> pd.DataFrame:
    return pd.DataFrame([r for g in groups for r in g])


def test_a_variant_without_reference_judges_no_claim():
    table = _table(PAPER_ROWS, NO_NOISE_ROWS)
    result = evaluate_claims(table, _variants("paper", "no-process-noise"))
    record = result["variants"][1]
    assert record == {"name": "no-process-noise", "reference": None, "seeds": 4, "pairs": 0,
                      "unpaired": 0, "claims": []}
    for claim in result["claims"].values():
        entry = claim["per_variant"][1]
        assert entry["verdict"] == NOT_APPLICABLE == "n/a" and not entry["applies"]
        assert (entry["n"], entry["holds"], entry["fraction"], entry["fraction_ci"]) == (
            0, 0, None, None)
        assert "no reference" in entry["why"] and entry["per_seed"]["seed"] == []
    # calibration: leapfrog and yoshida4, the paper's setting left as it was
    cal = {(g["variant"], g["integrator"]): g for g in result["calibration"]}
    assert set(cal) == {("paper", LF), ("paper", RK), ("paper", Y4),
                        ("no-process-noise", LF), ("no-process-noise", Y4)}
    lf = cal[("no-process-noise", LF)]["params"]
    assert (lf["a"]["covered"], lf["a"]["n"], lf["b"]["covered"]) == (3, 4, 4)
    assert lf["a"]["coverage_ci"] == pytest.approx(wilson_interval(3, 4))
    assert lf["a"]["ranks"] == [0, 10, 20, 30]
    assert lf["a"]["rank_p_value"] == pytest.approx(
        rank_uniformity([0, 10, 20, 30], 99)["p_value"])
    assert cal[("no-process-noise", Y4)]["params"]["a"]["covered"] == 4
    assert cal[("paper", Y4)]["params"]["a"]["covered"] == 1  # seed 1 missed a
    # the paper's claims do not see the deterministic cells
    alone = evaluate_claims(_table(PAPER_ROWS), _variants("paper"))
    assert result["claims"]["hamiltonian"]["per_variant"][0] == \
        alone["claims"]["hamiltonian"]["per_variant"][0]


def test_a_setting_other_cells_lack_matches_them_at_its_default():
    """The paper's cells have no ``priors.process_var`` (NaN once a log-uniform cell sets the
    column): they are the half-normal cells, and the log-uniform ones are not the paper's."""
    with_logu = _table(PAPER_ROWS, LOG_UNIFORM_ROWS)
    assert with_logu["priors.process_var"].isna().sum() == len(PAPER_ROWS)
    both = evaluate_claims(with_logu, _variants("paper", "log-uniform"))
    alone = evaluate_claims(_table(PAPER_ROWS), _variants("paper"))
    for name, claim in both["claims"].items():
        assert claim["per_variant"][0] == alone["claims"][name]["per_variant"][0]
        assert claim["per_variant"][1]["verdict"] == "n/a"
    cal = {(g["variant"], g["integrator"]): g for g in both["calibration"]}
    assert cal[("log-uniform", LF)]["params"]["a"]["covered"] == 1
    assert cal[("paper", LF)]["params"]["a"]["n"] == 2
    assert ("log-uniform", Y4) not in cal  # not run: no entry


def test_a_variant_may_name_the_claims_that_apply():
    table = _table(PAPER_ROWS)
    only_h = Variant("h only", reference=RK, claims=("hamiltonian",))
    result = evaluate_claims(table, [only_h])
    per = {k: c["per_variant"][0] for k, c in result["claims"].items()}
    assert per["hamiltonian"]["applies"] and (per["hamiltonian"]["n"],
                                              per["hamiltonian"]["holds"]) == (2, 1)
    for name in ("process_noise", "prediction"):
        assert per[name]["verdict"] == "n/a" and "metric does not exist" in per[name]["why"]
    assert result["variants"][0]["claims"] == ["hamiltonian"]
    with pytest.raises(ValueError, match="unknown claim"):
        Variant("bad", claims=("speed",))
    assert Variant("cal", reference=None, extra=(Y4,)).propagators() == (LF, Y4)


def test_the_new_variants_run_no_reference_cells():
    spec = paper_claims_spec(seeds=2, budget="quick", variants="no-process-noise,log-uniform")
    new = [c.settings for c in spec.cells if c.settings.get("model.process_noise_per") == "none"
           or c.settings.get("priors.process_var") == "log-uniform"]
    assert sorted((c["integrator"], c["seed"]) for c in new) == sorted(
        [(i, s) for i in (LF, Y4) for s in (0, 1)] * 2)
    assert len(spec.cells) == 2 * 3 + len(new)  # the paper's three propagators, then these
    assert set(paper_claims_spec(2, "quick", "none").ids) <= set(spec.ids)


@pytest.fixture(scope="module")
def claims_json():
    table = _table(PAPER_ROWS, NO_NOISE_ROWS, LOG_UNIFORM_ROWS)
    claims = evaluate_claims(table, _variants("paper", "no-process-noise", "log-uniform"))
    claims["study"] = {
        "seeds": 4, "budget_name": "paper",
        "budget": {"num_iterations": 200000, "burn_in": 100000, "num_chains": 4,
                   "num_starts": 4},
        "variants": [{"name": n} for n in ("paper", "no-process-noise", "log-uniform")],
        "cells": 16, "cells_run": 10, "cells_skipped": 6, "cells_failed": 0, "failures": [],
        "wall_time_s": 600.0, "cell_seconds_total": 1100.0, "workers": 2, "runs": [],
    }
    return json.loads(json.dumps(claims))


def test_report_and_readme_say_n_a(claims_json):
    report = format_claims_report(claims_json)
    assert "| no-process-noise | – | – | – | – | n/a | – | – | – |" in report
    assert "*n/a* in no-process-noise, log-uniform: no reference propagator" in report
    assert "yoshida4 without process noise (deterministic likelihood): nominal coverage" \
        in report
    block = readme_block(claims_json)
    assert "| H closer to the truth | no-process-noise | – | – | n/a | – |" in block
    assert "no-process-noise: 0 / 0" not in block  # not listed as a claim that fails
    answer = calibration_answer(claims_json)
    assert answer["no_process_noise"]["label"] == "no-process-noise, leapfrog"
    assert answer["log_uniform_yoshida4"] is None


def test_calibration_block_counts_by_hand(claims_json, tmp_path):
    block = calibration_block(claims_json)
    rows = {line.split(" | ")[0][2:]: line for line in block.splitlines()[3:]}
    # leapfrog without process noise: a covered 3 of 4 (Wilson 30 – 95 %, which holds 95 %),
    # b 4 of 4; median coverage 87.5 %; the smallest p-value is b's ranks 99, 98, 97, 96;
    # a's z = 0, 0.5, 1, 1.5: mean shift 0.75 (b has no quantiles: no shift)
    lo, hi = wilson_interval(3, 4)
    p_min = min(rank_uniformity([0, 10, 20, 30], 99)["p_value"],
                rank_uniformity([99, 98, 97, 96], 99)["p_value"])
    row = rows["Leapfrog without process noise (deterministic likelihood)"]
    assert row == (f"| Leapfrog without process noise (deterministic likelihood) | 4 | a: 75 % "
                   f"({100 * lo:.0f} % – {100 * hi:.0f} %) | 88 % | 2 of 2 | {p_min:.3g} | "
                   "a: 0.75 |")
    # yoshida4 at the paper's setting: a 1 of 2 (Wilson 9 – 91 %: 95 % outside)
    assert "| a: 50 % (9 % – 91 %) | 75 % | 1 of 2 |" in rows["yoshida4 at the paper's setting"]
    assert "yoshida4 with the log-uniform prior on Σ" not in rows  # not run
    readme = tmp_path / "README.md"
    readme.write_text(f"intro\n{CALIBRATION_BEGIN}\nold\n{CALIBRATION_END}\nend\n")
    assert update_readme(readme, claims_json) == block
    assert readme.read_text() == f"intro\n{CALIBRATION_BEGIN}\n{block}\n{CALIBRATION_END}\nend\n"


def test_shift_and_spread_of_the_truth_in_posterior_sds():
    """z = (midpoint − truth) / (width / 3.92): intervals [0, 3.92], [0, 3.92], [1, 4.92]
    (sd 1) around truths 1.96, 0.96, 0.96 give z = 0, 1, 2: mean 1, spread 1."""
    from symplid.studies._paper_calibration import evaluate_calibration

    z95 = Z95
    rows = pd.DataFrame({
        "status": ["ok"] * 3,
        "calibration.a.q025": [0.0, 0.0, 1.0],
        "calibration.a.q975": [2 * z95, 2 * z95, 1.0 + 2 * z95],
        "calibration.a.truth": [z95, z95 - 1.0, z95 - 1.0],
        "calibration.a.covered": [True, True, True],
        "calibration.a.rank": [50, 20, 5],
    })
    a = evaluate_calibration(rows, "three")["params"]["a"]
    assert (a["z_mean"], a["z_sd"]) == pytest.approx((1.0, 1.0))
    one = evaluate_calibration(rows.iloc[:1], "one")["params"]["a"]
    assert one["z_mean"] is None  # no spread from one seed
    old = evaluate_calibration(rows.drop(columns="calibration.a.q025"), "old")["params"]["a"]
    assert old["z_mean"] is None and old["covered"] == 3
