"""The worked examples of a user's own model, from the command line only, at a small budget.

The data are simulated by ``examples/user_models/simulate_data.py`` (SciPy's DOP853,
independent of symplid's integrators); each fit must recover the parameter that made them
within its posterior interval. Bad input must end in one line on stderr and exit code 2.
"""

from __future__ import annotations

import importlib.util
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from symplid.cli import main

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "user_models"
SMALL = ["--iterations", "600", "--burn-in", "300", "--chains", "2", "--no-progress"]


def _simulator():
    spec = importlib.util.spec_from_file_location("simulate_data", EXAMPLES / "simulate_data.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def _posterior_interval(out: Path, name: str) -> tuple[float, float, float]:
    """(2.5 %, 50 %, 97.5 %) of a parameter's draws in the run folder."""
    import arviz as az

    draws = np.asarray(az.from_netcdf(out / "posterior.nc").posterior[name]).ravel()
    return tuple(np.quantile(draws, [0.025, 0.5, 0.975]))


@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("user_models")
    sim = _simulator()
    for system, name in (("kepler", "kepler.csv"), ("lotka-volterra", "lv.csv"),
                         ("pendulum", "pendulum.csv")):
        sim.write_csv(system, folder / name)
    for name in ("kepler.toml", "lotka_volterra.toml", "pendulum.toml", "pendulum_model.py"):
        shutil.copy(EXAMPLES / name, folder / name)
    return folder


@pytest.mark.slow
def test_kepler_orbit_recovers_gm_with_an_interval(workdir):
    out = workdir / "kepler_run"
    result = run("fit", workdir / "kepler.csv", "--config", workdir / "kepler.toml",
                 "--out", out, *SMALL)
    assert result.exit_code == 0, result.output
    low, mid, high = _posterior_interval(out, "GM")
    gm_sun = _simulator().GM_SUN
    assert low < gm_sun < high
    assert (high - low) / mid < 0.01  # 25 positions pin GM to a fraction of a per cent
    forecast = run("predict", out, "--from", "end", "--t-end", 480, "--no-progress")
    assert forecast.exit_code == 0, forecast.output
    assert (out / "forecast.npz").exists()
    assert "Potential U(q)" in (out / "report.md").read_text()


@pytest.mark.slow
def test_lotka_volterra_in_log_coordinates(workdir, monkeypatch):
    from symplid.dynamics import _user_models as user_models

    parsed, parse = [], user_models.parse_expression
    monkeypatch.setattr(user_models, "parse_expression",
                        lambda text, *a, **k: parsed.append(text) or parse(text, *a, **k))
    out = workdir / "lv_run"
    result = run("fit", workdir / "lv.csv", "--config", workdir / "lotka_volterra.toml",
                 "--out", out, "--holdout", "0.2", *SMALL)
    assert result.exit_code == 0, result.output
    # one parse for the whole run: checks, MAP, both sensitivity refits, report, held-out scores
    assert len(parsed) == 1, parsed
    settings = (out / "settings.toml").read_text()
    assert 'integrator = "leapfrog"' in settings  # separable: explicit leapfrog on T(p) + U(q)
    truth = {"alpha": 1.1, "beta": 0.4, "gamma": 0.4, "delta": 0.1}
    for name, value in truth.items():
        low, mid, high = _posterior_interval(out, name)
        width = high - low
        assert low - 0.5 * width < value < high + 0.5 * width, (name, low, high)
        assert abs(mid - value) < 0.1 * value, (name, mid)
    holdout = json.loads((out / "summary.json").read_text())["holdout"]
    assert holdout["coverage_95"] >= 0.7


@pytest.mark.slow
def test_pendulum_from_a_python_file_then_report_and_predict(workdir):
    out = workdir / "pendulum_run"
    result = run("fit", workdir / "pendulum.csv", "--config", workdir / "pendulum.toml",
                 "--potential", workdir / "pendulum_model.py:U", "--out", out, *SMALL)
    assert result.exit_code == 0, result.output
    low, _, high = _posterior_interval(out, "k")
    assert low < 2.0 < high
    assert "file:" in (out / "settings.toml").read_text()
    for args in (("report", out, "--no-progress"), ("predict", out, "--no-progress")):
        again = run(*args)
        assert again.exit_code == 0, again.output
    assert (out / "predictions.npz").exists()


@pytest.mark.slow
def test_compare_ranks_two_user_models(workdir, tmp_path):
    """A pendulum against a harmonic well with its k fitted too, on data of a large swing
    (amplitude 2.5 rad): the evidence must prefer the true U = k(1 − cos q)."""
    sim = _simulator()
    field, _, times, columns, sd, names = sim.SYSTEMS["pendulum"]
    sim.SYSTEMS["swing"] = (field, np.array([2.5, 0.0]), times, columns, sd, names)
    sim.write_csv("swing", tmp_path / "swing.csv")
    true = (workdir / "pendulum.toml").read_text().replace("x0 = [1.0, 0.0]", "x0 = [2.5, 0.0]")
    (tmp_path / "pendulum.toml").write_text(true)
    (tmp_path / "harmonic.toml").write_text(true.replace("k*(1 - cos(q1))", "0.5*k*q1^2"))
    result = run("compare", tmp_path / "swing.csv", "--candidates",
                 f"{tmp_path / 'pendulum.toml'},{tmp_path / 'harmonic.toml'}",
                 "--out", tmp_path / "cmp", "--no-progress")
    assert result.exit_code == 0, result.output
    assert "best: pendulum with leapfrog" in result.output
    table = (tmp_path / "cmp" / "compare.csv").read_text()
    assert "harmonic" in table and "pendulum" in table


@pytest.mark.parametrize(("option", "value", "message"), [
    ("--potential", "k*(1 - cos(x1))", "unknown symbol 'x1'"),
    ("--potential", "PY:V", "does not define a function 'V'"),
    ("--potential", "PY:not_traceable", "is not a JAX-traceable"),
    ("--potential", "missing.py:U", "no such file"),
    ("--potential", "q1^2", "do not appear"),
    ("--hamiltonian", "k*q1*p1 + p1^2 + q9", "uses coordinate 9"),
])
def test_bad_models_end_in_one_line_and_exit_2(workdir, tmp_path, option, value, message):
    model = tmp_path / "m.py"
    model.write_text("import numpy as np\n\ndef U(q, params):\n    return params['k'] * q[0]**2\n"
                     "\ndef not_traceable(q, params):\n    return float(np.cos(q[0]))\n")
    out = tmp_path / "run"
    result = run("fit", workdir / "pendulum.csv", "--config", workdir / "pendulum.toml",
                 option, value.replace("PY", str(model)), "--out", out, *SMALL)
    assert result.exit_code == 2
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("symplid: error:"), result.output
    assert message in lines[0]
    assert not (out / "summary.json").exists() and not (out / "posterior.nc").exists()


def test_a_parameter_without_a_prior_exits_2(workdir, tmp_path):
    config = tmp_path / "c.toml"
    config.write_text((workdir / "pendulum.toml").read_text().replace(
        'k = { prior = "half-normal", scale = 5 }', "k = { scale = 5 }"))
    result = run("fit", workdir / "pendulum.csv", "--config", config, "--out", tmp_path / "r",
                 *SMALL)
    assert result.exit_code == 2
    assert "model.parameters.k has no prior" in result.output


@pytest.mark.slow
def test_polynomial_qp_from_the_command_line_reports(tmp_path):
    """The report of a non-separable polynomial H used to fail in the U(q) figure."""
    data = tmp_path / "d.csv"
    t = np.linspace(0.5, 10.0, 20)
    values = np.column_stack([np.cos(t), -np.sin(t)]) + 0.01 * np.random.default_rng(0).normal(
        size=(20, 2))
    np.savetxt(data, np.column_stack([t, values]), delimiter=",", header="t,q1,p1", comments="")
    out = tmp_path / "run"
    result = run("fit", data, "--out", out, "--x0", "1,0", "--dt", "0.25",
                 "--set", "model.hamiltonian=polynomial-qp", "--set", "model.order=2",
                 "--integrator", "implicit-midpoint",
                 "--set", "prediction.integrator=implicit-midpoint", "--iterations", "200",
                 "--burn-in", "100", "--chains", "2", "--no-progress")
    assert result.exit_code == 0, result.output
    assert "writing its report failed" not in result.output
    again = run("report", out, "--no-progress")
    assert again.exit_code == 0, again.output
    assert "Potential U(q)" not in (out / "report.md").read_text()
