"""Sharp edges of the defaults: each case was an error, a traceback or wrong advice before.

A learned initial state with data from t = 0, expression errors that name their real cause,
advice that names only what the model accepts, one prior syntax in every table, and a report
that describes a user's model as written.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from symplid.io import read_observations
from symplid.workflow.settings import Settings, merge_overrides, resolve_for_data


def write_csv(path: Path, times, columns: dict[str, np.ndarray]) -> Path:
    header = ",".join(["t", *columns])
    rows = [",".join([f"{t:.17g}", *(f"{columns[c][k]:.17g}" for c in columns)])
            for k, t in enumerate(times)]
    path.write_text(header + "\n" + "\n".join(rows) + "\n")
    return path


def harmonic(times, noise=0.02, seed=0):
    rng = np.random.default_rng(seed)
    t = np.asarray(times, dtype=float)
    return {"q1": np.cos(t) + noise * rng.normal(size=t.size),
            "p1": -np.sin(t) + noise * rng.normal(size=t.size)}


# ----------------------------------------------------------------------------- t0 at the data
def test_learned_initial_state_with_data_from_t0_just_works(tmp_path):
    """The defaults (t0 = 0) with data whose first time is 0: the state sits at the first
    observation, and the posterior's density is finite there."""
    from symplid.workflow.building import build_model, build_posterior

    t = np.arange(0.0, 12.0)
    obs = read_observations(write_csv(tmp_path / "h.csv", t, harmonic(t)))
    learned = merge_overrides(Settings(), {"initial_state.mode": "learned", "model.order": 2})
    resolved = resolve_for_data(learned, obs)
    assert resolved.initial_state.t0 == "first"
    posterior = build_posterior(resolved, obs, build_model(resolved, obs))
    assert posterior.t0 == [None]
    truth = {"c[q1^2]": 0.5, "process_var": 1e-4, "obs_var[q]": 4e-4, "obs_var[p]": 4e-4,
             "x0[0].q1": 1.0, "x0[0].p1": 0.0}
    theta = np.array([truth.get(n, 0.0) for n in posterior.param_names])
    assert np.isfinite(float(posterior.log_density(theta)))


def test_a_t0_before_the_data_is_kept_and_one_after_is_refused(tmp_path):
    t = np.arange(1.0, 12.0)
    obs = read_observations(write_csv(tmp_path / "h.csv", t, harmonic(t)))
    learned = merge_overrides(Settings(), {"initial_state.mode": "learned", "model.order": 2})
    assert resolve_for_data(learned, obs).initial_state.t0 == 0.0
    late = merge_overrides(learned, {"initial_state.t0": 2.0})
    with pytest.raises(ValueError, match="must be before the first observation time"):
        resolve_for_data(late, obs)


# ----------------------------------------------------------------------------- advice
NONSEPARABLE = "0.5*(1 + a*q1^2)*p1^2 + 0.5*q1^2"


def _resolved(tmp_path, overrides):
    from symplid.workflow.settings import settings_from_dict

    t = np.arange(0.0, 12.0)
    obs = read_observations(write_csv(tmp_path / "h.csv", t, harmonic(t)))
    return resolve_for_data(merge_overrides(settings_from_dict({
        "initial_state": {"mode": "learned"},
        "model": {"parameters": {"a": {"prior": "normal", "loc": 0.0, "scale": 1.0}}}
        if "model.hamiltonian" in overrides else {}}), overrides), obs), obs


@pytest.mark.parametrize(("overrides", "advice"), [
    ({"model.order": 2}, "use a smaller dt or yoshida4"),
    ({"model.order": 2, "model.damping": True}, "use a smaller dt or yoshida4"),
    ({"model.order": 2, "model.integrator": "yoshida4"}, "use a smaller dt"),
    ({"model.hamiltonian": NONSEPARABLE}, "use a smaller dt or tao4"),
    ({"model.hamiltonian": NONSEPARABLE, "model.integrator": "tao4"}, "use a smaller dt"),
])
def test_step_advice_names_only_what_the_model_accepts(tmp_path, overrides, advice):
    """The step-size warning's advice, and the model built with the integrator it names."""
    import dataclasses

    from symplid.workflow.building import build_model
    from symplid.workflow.sensitivity import sensitivity_lines, sensitivity_summary, step_advice

    settings, obs = _resolved(tmp_path, overrides)
    assert step_advice(settings, obs) == advice
    named = advice.rpartition(" or ")[2]
    if " or " in advice:
        build_model(dataclasses.replace(settings, model=dataclasses.replace(
            settings.model, integrator=named)), obs)
    step = {"dt": 0.25, "dt_refit": 0.125, "shifts": {"a": 1.0}, "flagged": ["a"],
            "advice": advice}
    noise = {"not_available": "skipped"}
    text = "\n".join([*sensitivity_lines({"threshold_sd": 0.3, "step_size": step,
                                          "process_noise": noise}),
                      *sensitivity_summary({"threshold_sd": 0.3, "step_size": step,
                                            "process_noise": noise})])
    assert text.count(advice) == 2
    if "yoshida4" not in advice:
        assert "yoshida4" not in text
