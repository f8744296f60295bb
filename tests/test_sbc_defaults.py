"""The SBC study of the defaults (symplid.studies._sbc_defaults): that it fits with every default
but the model file, draws its truths from the priors the fit uses, and makes its data with the
exact flow; its replications themselves are the study (docs/studies/sbc-defaults.md)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

import symplid  # noqa: F401  (float64)
from symplid.studies._sbc_defaults import (
    FLOW_TOLERANCE,
    MODEL,
    draw_truth,
    sbc_defaults_spec,
    settings_for,
    simulate_data,
)
from symplid.studies._sbc_report import groups, sbc_summary
from symplid.workflow import Settings
from symplid.workflow._settings import settings_to_dict


def _flat(table: dict, prefix: str = "") -> dict:
    out = {}
    for key, value in table.items():
        if isinstance(value, dict) and key != "parameters":
            out.update(_flat(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def test_every_setting_but_the_model_file_is_the_default():
    given, default = _flat(settings_to_dict(settings_for(7))), _flat(settings_to_dict(Settings()))
    changed = {k for k in given.keys() | default.keys() if given.get(k) != default.get(k)}
    seeds = {"seed", "map.seed", "sampler.seed"}
    set_keys = [f"{section}.{key}" for section, table in MODEL.items() for key in table]
    assert changed - seeds <= {k for k in changed for s in set_keys if k.startswith(s)}
    assert changed >= seeds  # the replication reseeds the fit
    settings = settings_for(7)
    # the defaults the study is about: the step from the data, the budget from the answer
    assert settings.model.dt == "auto" and settings.sampler.num_iterations == "auto"
    assert settings.sampler.method == "dram" and settings.map.num_starts == 4
    assert settings.model.process_noise_per == "gap"


def test_truths_are_drawn_from_the_fits_priors():
    from scipy import stats

    truths = pd.DataFrame([draw_truth(seed) for seed in range(200)])
    k = MODEL["model"]["parameters"]["k"]
    variances = MODEL["priors"]["variances"]
    x0_sd = MODEL["priors"]["initial_state"]["scale"]
    expected = {
        "k": stats.lognorm(k["sigma"], scale=math.exp(k["mu"])),
        "gamma": stats.halfnorm(scale=MODEL["priors"]["damping"]["scale"]),
        "process_var": stats.lognorm(variances["sigma"], scale=math.exp(variances["mu"])),
        "obs_var": stats.lognorm(variances["sigma"], scale=math.exp(variances["mu"])),
        "x0[0].q1": stats.norm(MODEL["initial_state"]["x0"][0], x0_sd),
        "x0[0].p1": stats.norm(MODEL["initial_state"]["x0"][1], x0_sd),
    }
    assert set(truths.columns) == set(expected)
    for name, law in expected.items():
        assert stats.kstest(truths[name], law.cdf).pvalue > 1e-3, name
    # the entries are drawn independently of one another
    assert abs(np.corrcoef(truths["process_var"], truths["obs_var"])[0, 1]) < 0.25


def test_data_follow_the_exact_damped_flow():
    """Without noise and at small amplitude, sin q = q to 1e-9: the positions are the damped
    linear oscillator's, q(t) = e^{−γt/2}(q0 cos ωt + (p0 + γq0/2)/ω sin ωt), to the flow's
    absolute tolerance (a wrong gap, sign or rate would miss by 1e-6 or more)."""
    q0, p0, k, gamma = 1e-4, -5e-5, 4.0, 0.1
    truth = {"k": k, "gamma": gamma, "process_var": 0.0, "obs_var": 0.0,
             "x0[0].q1": q0, "x0[0].p1": p0}
    obs = simulate_data(truth, {"seed": 0, "num_obs": 25, "obs_interval": 0.8})
    t = obs.times
    omega = math.sqrt(k - gamma**2 / 4)
    exact = np.exp(-gamma * t / 2) * (q0 * np.cos(omega * t)
                                      + (p0 + gamma * q0 / 2) / omega * np.sin(omega * t))
    assert obs.names == ("q1",) and t[0] == pytest.approx(0.8) and len(t) == 25
    assert np.max(np.abs(obs.values[:, 0] - exact)) < 5 * FLOW_TOLERANCE


def test_noise_enters_once_per_gap_and_once_per_observation():
    """With the flow at rest (q = p = 0 is a fixed point), the positions are Σ-noise summed
    over the gaps' velocity kicks plus Γ-noise: their spread grows with Σ and not Γ alone."""
    rest = {"k": 4.0, "gamma": 0.0, "x0[0].q1": 0.0, "x0[0].p1": 0.0}
    cell = {"seed": 3, "num_obs": 400, "obs_interval": 0.8}
    only_obs = simulate_data({**rest, "process_var": 0.0, "obs_var": 1e-4}, cell)
    assert np.var(only_obs.values) == pytest.approx(1e-4, rel=0.2)
    both = simulate_data({**rest, "process_var": 1e-4, "obs_var": 1e-4}, cell)
    assert np.var(both.values) > 1.5e-4


def test_defaults_rows_form_one_group_with_their_budget_outcome():
    rows = pd.DataFrame({"status": ["ok", "ok", "failed"], "rank_draws": 99, "thin_draws": 49,
                         "sbc.k.rank": [3, 90, np.nan], "sbc.k.rank_thin": [1, 45, np.nan],
                         "rhat_max": [1.002, 1.2, np.nan], "ess_min": [700.0, 30.0, np.nan],
                         "reached_target": [1.0, 0.0, np.nan], "dt": [0.025, 0.05, np.nan],
                         "wall_time_s": [40.0, 50.0, np.nan]})
    (sampler, likelihood, ok), = groups(rows)
    assert (sampler, likelihood, len(ok)) == ("dram", "gap", 2)
    summary = sbc_summary(rows)["dram"]["gap"]
    assert summary["reached_target"] == 1 and summary["converged"] == 1
    assert summary["dt"] == pytest.approx({"min": 0.025, "median": 0.0375, "max": 0.05})


def test_spec_has_one_cell_per_replication():
    spec = sbc_defaults_spec(3)
    assert [c.settings["seed"] for c in spec.cells] == [0, 1, 2]
    with pytest.raises(ValueError, match="positive integer"):
        sbc_defaults_spec(0)
