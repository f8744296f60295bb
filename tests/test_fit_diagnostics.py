"""The sensitivity checks a fit runs after its MAP (symplid.workflow._sensitivity, fit.py).

A default ``symplid fit`` saves them in ``diagnostics.json``, prints them and shows them in
``report.md`` without recomputing; their numbers are checked against MAP searches made
independently (all starts, the fit's own path to the MAP) at dt/2 and without process noise.
``map.sensitivity = false``, the paper's settings and its sweep cells skip them; a refit that
fails is recorded as not available and the fit goes on; a stop during them keeps the MAP.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import symplid.workflow._fit as fit_module
import symplid.workflow._sensitivity as sensitivity
from symplid._stopping import StopRequested
from symplid.cli import main
from symplid.workflow._building import build_model, build_posterior
from symplid.workflow._fit import find_map_for, fit
from symplid.workflow._results import RunFolder
from symplid.workflow._settings import Settings, merge_overrides

TINY = ["--iterations", "600", "--burn-in", "300", "--chains", "2", "--no-progress"]
TINY += ["--dt", "0.25"]  # a fixed step: the step search is test_step_size.py's


def run(*args: str):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


@pytest.fixture(scope="module")
def harmonic_csv(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("data") / "harmonic.csv"
    result = run("simulate", "harmonic", "--out", path, "--num-obs", "15", "--t-end", "15",
                 "--noise-std", "0.02", "--seed", "3")
    assert result.exit_code == 0, result.output
    return path


@pytest.fixture(scope="module")
def default_run(tmp_path_factory, harmonic_csv) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("fit") / "run"
    result = run("fit", harmonic_csv, "--out", out, "--order", "2", "--x0", "1,0", *TINY)
    assert result.exit_code == 0, result.output
    return out, result.output


def _independent_map(folder: RunFolder, **model: object):
    """The MAP of the run's settings with ``model`` fields changed, by the fit's own search
    (all its starts; without process noise, its homotopy from the filter's MAP)."""
    settings = folder.read_settings()
    changed = dataclasses.replace(settings, model=dataclasses.replace(settings.model, **model))
    obs = folder.read_data()
    posterior = build_posterior(changed, obs, build_model(changed, obs))
    return find_map_for(changed, posterior), posterior


@pytest.mark.slow
def test_a_default_fit_saves_prints_and_reports_the_checks(default_run):
    out, output = default_run
    checks = json.loads((out / RunFolder.DIAGNOSTICS).read_text())
    step, noise = checks["step_size"], checks["process_noise"]
    assert set(step["shifts"]) == {"c[q1]", "c[q1^2]"} == set(noise["shifts"])
    assert step["dt_refit"] == pytest.approx(step["dt"] / 2)
    assert (noise["fitted"], noise["refit"]) == ("gap", "none")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["timings"]["diagnostics_s"] > 0
    assert f"{out}: sensitivity (MAP refits): halving dt moves a parameter" in output

    # the shifts against MAP searches made independently of the refits
    folder = RunFolder(out, "r")
    theta = np.asarray(folder.read_map()["theta"])
    sd = np.sqrt(np.diag(np.asarray(folder.read_map()["covariance"])))
    names = list(folder.read_map()["param_names"])
    half, _ = _independent_map(folder, dt=step["dt"] / 2)
    for name, z in step["shifts"].items():
        i = names.index(name)
        assert z == pytest.approx((half.theta[i] - theta[i]) / sd[i], abs=0.02), name
    without, posterior = _independent_map(folder, process_noise_per="none")
    other = list(posterior.param_names)
    for name, z in noise["shifts"].items():
        i = names.index(name)
        assert z == pytest.approx((without.theta[other.index(name)] - theta[i]) / sd[i],
                                  abs=0.02), name
    assert noise["log_evidence_refit"] == pytest.approx(without.log_evidence, abs=0.05)

    # the report shows them as saved: it does not refit (a refit now would raise)
    report = (out / "report.md").read_text()
    assert "## Sensitivity (MAP refits)" in report
    assert f"| c[q1^2] | {step['shifts']['c[q1^2]']:+.2f} |" in report
    saved = (out / RunFolder.DIAGNOSTICS).read_bytes()
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(sensitivity, "refit_map", _raise)
        result = run("report", out)
    assert result.exit_code == 0, result.output
    assert "sensitivity (MAP refits)" in result.output
    assert (out / RunFolder.DIAGNOSTICS).read_bytes() == saved
    assert "## Sensitivity (MAP refits)" in (out / "report.md").read_text()


def _raise(*args, **kwargs):
    raise RuntimeError("refit broken on purpose")


@pytest.mark.slow
def test_sensitivity_false_skips_them(tmp_path, harmonic_csv, monkeypatch):
    monkeypatch.setattr(fit_module, "sensitivity_checks", _raise)  # must not be called
    out = tmp_path / "off"
    result = run("fit", harmonic_csv, "--out", out, "--order", "2", "--x0", "1,0", *TINY,
                 "--set", "map.sensitivity=false")
    assert result.exit_code == 0, result.output
    assert not (out / RunFolder.DIAGNOSTICS).exists()
    assert "sensitivity (MAP refits)" not in result.output
    assert "diagnostics_s" not in json.loads((out / "summary.json").read_text())["timings"]
    assert "Sensitivity" not in (out / "report.md").read_text()


def test_the_papers_settings_and_cells_skip_them():
    from symplid.studies._paper import EXPERIMENT, PaperConfig, paper_settings
    from symplid.workflow._sweep_spec import cell_settings

    assert Settings().map.sensitivity  # a user's fit: on
    for approach in ("leapfrog", "rk2"):
        assert not paper_settings(PaperConfig.quick(), approach).map.sensitivity
    assert not cell_settings({"seed": 1}, experiment=EXPERIMENT).map.sensitivity


@pytest.mark.slow
def test_a_failed_refit_is_not_available_and_the_fit_goes_on(tmp_path, harmonic_csv,
                                                             monkeypatch):
    monkeypatch.setattr(sensitivity, "refit_map", _raise)
    out = tmp_path / "broken"
    result = run("fit", harmonic_csv, "--out", out, "--order", "2", "--x0", "1,0", *TINY)
    assert result.exit_code == 0, result.output
    checks = json.loads((out / RunFolder.DIAGNOSTICS).read_text())
    for key in ("step_size", "process_noise"):
        assert checks[key] == {"not_available": "RuntimeError: refit broken on purpose"}
    assert "step-size check not available (RuntimeError" in result.output
    assert "Step-size check: not available" in (out / "report.md").read_text()
    assert (out / "posterior.nc").exists() and not (out / RunFolder.MARKER).exists()


def _stop(*args, **kwargs):
    raise StopRequested(15)  # what find_map's evaluation raises after a SIGTERM


@pytest.mark.slow
def test_a_stop_during_the_checks_keeps_the_map(tmp_path, harmonic_csv, monkeypatch):
    from symplid.io import read_observations

    monkeypatch.setattr(sensitivity, "refit_map", _stop)
    obs = read_observations(harmonic_csv)
    settings = merge_overrides(Settings(), {
        "model.order": 2, "model.dt": 0.25, "initial_state.x0": [1.0, 0.0],
        "sampler.num_iterations": 600,
        "sampler.burn_in": 300, "sampler.num_chains": 2})
    out = tmp_path / "stopped"
    with pytest.raises(StopRequested):
        fit(obs, settings, out=out, progress=False)
    folder = RunFolder(out, "r", allow_incomplete=True)
    assert "interrupted before any draw" in folder.incomplete_reason
    assert np.all(np.isfinite(folder.read_map()["theta"]))
    assert not (out / "posterior.nc").exists()
