"""The shift study: its fits against independent answers, and a tiny run end to end.

* the noise-free leapfrog fit of a harmonic oscillator against the analytic modified
  frequency (leapfrog on H = ½p² + ½ω²q² is exactly the flow of ω̃ with
  cos(ω̃h) = 1 − ω²h²/2, so its fitted ω² has a known dt² bias);
* the conditional mode with nothing fixed against the library's MAP search (another
  optimiser), and with Σ fixed against the optimality condition (zero gradient of the log
  density in the free entries, by JAX, at the point returned);
* a batch of fits against the same fits one at a time;
* ``symplid study shift --budget quick`` end to end on the paper-claims cells.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import jax
import numpy as np
import pytest

import symplid  # noqa: F401  (float64)
from symplid.inference.map import find_map
from symplid.model._data import Observations
from symplid.model._posterior import Posterior
from symplid.studies._shift_fits import ConditionalMode, stack_data
from symplid.studies._shift_report import dt2_fit
from symplid.workflow._fit import build_model
from symplid.workflow._settings import Settings, merge_overrides

CELLS = Path(__file__).resolve().parents[1] / "docs" / "studies" / "paper-claims"


def _oscillator_posterior(values: np.ndarray, times: np.ndarray, dt: float,
                          likelihood: str = "none", names: tuple[str, ...] = ("q1",)):
    """The posterior of a 1-d quadratic potential c[q1]·q + c[q1^2]·q², known state (1, 0)
    at t = 0, learned with leapfrog at ``dt``."""
    obs = Observations(times=times, values=values, names=names)
    settings = merge_overrides(Settings(), {
        "model.order": 2, "model.integrator": "leapfrog", "model.dt": dt,
        "model.noise": "isotropic", "model.standardise": "off",
        "model.process_noise_per": likelihood, "initial_state.x0": [1.0, 0.0],
    })
    model = build_model(settings, obs)
    return Posterior(model, obs, x0=np.array([1.0, 0.0]), t0=0.0)


@pytest.mark.parametrize("dt", [0.5, 0.25, 0.1])
def test_noise_free_leapfrog_fit_has_the_modified_frequency(dt):
    """Exact positions cos(ωt) of H = ½p² + ½ω²q² from (1, 0): the leapfrog model whose
    positions equal them has ω̃ = ω, i.e. a learned ω_f² with cos(ωh) = 1 − ω_f²h²/2, so the
    least-squares fit is c[q1^2] = ω_f²/2 = (1 − cos ωh)/h² (zero residual), below the true
    ω²/2 by ≈ ω⁴h²/24."""
    omega, gap = 1.3, 1.0
    times = gap * np.arange(1, 21)
    posterior = _oscillator_posterior(np.cos(omega * times)[:, None], times, dt)
    start = np.array([0.0, 0.5 * omega**2, 1e-4])
    fit = ConditionalMode(posterior).fit(start, fixed=("obs_var",), prior=False)
    h = gap / math.ceil(gap / dt - 1e-9)
    expected = (1.0 - math.cos(omega * h)) / h**2
    assert fit.converged
    assert fit.theta[0] == pytest.approx(0.0, abs=1e-9)
    assert fit.theta[1] == pytest.approx(expected, rel=1e-8)
    bias = fit.theta[1] - 0.5 * omega**2
    assert bias == pytest.approx(-(omega**4) * h**2 / 24, rel=0.05)  # the dt² law


def _noisy_oscillator(likelihood: str, seed: int = 3):
    rng = np.random.default_rng(seed)
    times = 1.0 * np.arange(1, 16)
    clean = np.stack([np.cos(times), -np.sin(times)], axis=1)
    return _oscillator_posterior(clean + 0.05 * rng.standard_normal(clean.shape), times, 0.1,
                                 likelihood, ("q1", "p1"))


def test_conditional_mode_with_nothing_fixed_is_the_map():
    posterior = _noisy_oscillator("none")
    reference = find_map(posterior, seed=0, num_starts=2, compute_hessian=False, warn=False)
    fit = ConditionalMode(posterior).fit(reference.theta * np.array([1.0, 1.05, 2.0]) + 1e-3)
    assert fit.converged
    np.testing.assert_allclose(fit.theta, reference.theta, rtol=1e-4, atol=1e-6)
    assert fit.log_density == pytest.approx(float(posterior.log_density(reference.theta)),
                                            abs=1e-6)


def test_conditional_mode_with_sigma_fixed_is_stationary_in_the_rest():
    posterior = _noisy_oscillator("gap")
    k = posterior.param_names.index("process_var")
    start = np.array([0.0, 0.5, 1e-3, 2.5e-3])
    fit = ConditionalMode(posterior).fit(start, fixed=("process_var",))
    assert fit.converged
    assert fit.theta[k] == start[k]
    grad = np.asarray(jax.grad(posterior.log_density)(fit.theta))
    free = np.arange(len(start)) != k
    scale = np.array([1.0, 1.0, 1.0, fit.theta[3]])  # the variance: d/d log v
    assert np.max(np.abs(grad * scale)[free]) < 1e-5
    assert abs(grad[k]) > 1e-3  # Σ itself is not at its optimum: it was held


def test_a_batch_of_fits_equals_the_fits_one_by_one():
    posteriors = [_noisy_oscillator("none", seed) for seed in (4, 5, 6)]
    fitter = ConditionalMode(posteriors[0])
    start = np.array([0.0, 0.5, 2.5e-3])
    batch = fitter.fit_many([start] * 3, stack_data(posteriors), [(), ("obs_var",), ()],
                            [True, False, True])
    for fit, p, fixed, prior in zip(batch, posteriors, [(), ("obs_var",), ()],
                                    [True, False, True], strict=True):
        one = fitter.fit(start, p.data, fixed=fixed, prior=prior)
        np.testing.assert_allclose(fit.theta, one.theta, rtol=1e-7, atol=1e-10)


def test_conditional_mode_rejects_unknown_names_and_bad_starts():
    fitter = ConditionalMode(_noisy_oscillator("none"))
    with pytest.raises(ValueError, match="no parameter named"):
        fitter.fit(np.array([0.0, 0.5, 2.5e-3]), fixed=("process_var",))
    with pytest.raises(ValueError, match="not positive"):
        fitter.fit(np.array([0.0, 0.5, -1.0]))


def test_dt2_fit_recovers_a_quadratic_law_and_its_residual():
    dts = [0.5, 0.25, 0.1]
    fit = dt2_fit(dts, [-0.041 - 0.206 * d**2 for d in dts])
    assert fit["a"] == pytest.approx(-0.041) and fit["b"] == pytest.approx(-0.206)
    assert fit["max_residual"] < 1e-12
    assert dt2_fit([0.25], [1.0]) is None


@pytest.mark.slow
def test_shift_study_quick_end_to_end(tmp_path):
    from click.testing import CliRunner

    from symplid.cli import main

    out = tmp_path / "shift"
    result = CliRunner().invoke(main, ["study", "shift", "--out", str(out), "--cells",
                                       str(CELLS), "--budget", "quick"])
    assert result.exit_code == 0, result.output
    decomposition = json.loads((out / "decomposition.json").read_text())
    (row,) = decomposition["rows"]
    assert (row["integrator"], row["dt"], row["seeds"]) == ("leapfrog", 0.25, [0, 1])
    c = row["coefficients"]["c[q1^2*q2]"]
    # the total is the cells' own interval midpoints: recomputed here from the cell records
    cells = [json.loads(p.read_text()) for p in (CELLS / "cells").glob("*.json")]
    mids = [(m["q025"] + m["q975"]) / 2 - 1.0 for cell in cells
            if cell["status"] == "ok" and cell["settings"]["seed"] in (0, 1)
            and cell["settings"]["integrator"] == "leapfrog"
            and cell["settings"]["dt"] == 0.25 and cell["settings"]["noise_std"] == 0.05
            and cell["settings"]["num_obs"] == 20
            and cell["settings"]["model.process_noise_per"] == "gap"
            and cell["settings"].get("priors.process_var", "variances") == "variances"
            for m in [cell["metrics"]["calibration"]["c[q1^2*q2]"]]]
    assert c["total"] == pytest.approx(np.mean(mids), rel=1e-12)
    parts = c["discretisation"] + c["noise_reused"] + c["sigma"] + c["remainder"]
    assert parts == pytest.approx(c["total"], abs=1e-12)
    # the noise-free leapfrog fit at dt 0.5 shifts c[q1²q2] down about four times as at 0.25
    by_dt = decomposition["discretisation"]["leapfrog"]
    assert 3.0 < by_dt["0.5"]["c[q1^2*q2]"] / by_dt["0.25"]["c[q1^2*q2]"] < 5.0
    assert (out / "report.md").is_file() and (out / "figures" / "shift_vs_dt2.png").is_file()
    again = CliRunner().invoke(main, ["study", "shift", "--out", str(out), "--cells", str(CELLS),
                                      "--budget", "quick", "--report-only"])
    assert again.exit_code == 0, again.output


def test_shift_study_report_only_without_a_decomposition_is_one_line(tmp_path):
    from click.testing import CliRunner

    from symplid.cli import main

    result = CliRunner().invoke(main, ["study", "shift", "--out", str(tmp_path),
                                       "--report-only"])
    assert result.exit_code == 2
    assert "parts" in result.output and "Traceback" not in result.output
