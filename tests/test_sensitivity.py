"""The report's sensitivity checks (symplid.workflow._sensitivity).

The step-size check on the paper's Hénon–Heiles data (20 full-state observations 5 s apart):
leapfrog's bias of the cubic couplings grows like dt² (about −0.21·dt² for c[q1²q2]); at
dt = 0.5 halving the step moves it by ~0.04, more than a posterior sd, so the check must warn;
at dt = 0.05 the move is a hundred times smaller and it must stay quiet.
"""

from __future__ import annotations

import numpy as np
import pytest

import symplid
from symplid.workflow._sensitivity import (
    THRESHOLD_SD,
    process_noise_check,
    refit_map,
    sensitivity_lines,
    step_size_check,
)
from symplid.workflow._settings import Settings, merge_overrides


@pytest.fixture(scope="module")
def paper():
    system = symplid.get_system("henon-heiles")
    return system, symplid.simulate(system, seed=0)


def _settings(system, dt: float, **extra) -> Settings:
    return merge_overrides(Settings(), {
        "initial_state.x0": list(system.initial_state), "map.num_starts": 1,
        "model.dt": dt, **extra})


def _fitted(system, data, dt: float, **extra):
    settings = _settings(system, dt, **extra)
    result, posterior = refit_map(settings, data)
    return settings, posterior, result


@pytest.mark.slow
def test_step_size_warning_fires_at_dt_half_and_not_at_dt_005(paper):
    system, data = paper
    settings, posterior, result = _fitted(system, data, 0.5)
    coarse = step_size_check(settings, data, posterior, result)
    assert "c[q1^2*q2]" in coarse["flagged"], coarse
    assert abs(coarse["shifts"]["c[q1^2*q2]"]) > THRESHOLD_SD
    settings, posterior, result = _fitted(system, data, 0.05)
    fine = step_size_check(settings, data, posterior, result)
    assert fine["flagged"] == [], fine
    # the bias is O(dt²): a hundred times smaller step change, far smaller shifts
    assert max(abs(z) for z in fine["shifts"].values()) < 0.1
    assert "Warning" in "\n".join(sensitivity_lines({
        "threshold_sd": THRESHOLD_SD, "step_size": coarse,
        "process_noise": {"refit": "none", "shifts": {}, "flagged": [], "log_evidence": 0.0,
                          "log_evidence_refit": 0.0}}))


@pytest.mark.slow
def test_process_noise_check_on_the_double_well():
    """Data without process noise: the fit without Σ moves no coefficient by much and its
    evidence is not lower (the filter's MAP has Σ on its floor)."""
    system = symplid.get_system("double-well")
    data = symplid.simulate(system, seed=0)
    settings, posterior, result = _fitted(system, data, 0.25, **{"model.noise": "isotropic",
                                                                 "model.order": 4})
    check = process_noise_check(settings, data, posterior, result)
    assert check["refit"] == "none" and check["fitted"] == "gap"
    assert set(check["shifts"]) == {"c[q1]", "c[q1^2]", "c[q1^3]", "c[q1^4]"}
    assert check["flagged"] == [], check
    assert check["log_evidence_refit"] > check["log_evidence"] - 1.0
    assert np.isfinite(check["log_evidence_refit"])
