"""The command line: several trajectories, figures, quiet short runs,
a fast ``--version``.

Several trajectories, from two files or from one file with a ``trajectory`` column, must give
the same MAP as each other and as the Python API's log posterior at that point; the figures'
options and notes are checked on the figures themselves; the computed U(q) band against a
direct NumPy evaluation.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from symplid.cli import main
from symplid.dynamics._potentials import Polynomial
from symplid.inference._measures import potential_slices
from symplid.io import read_trajectories
from symplid.model._posterior import Posterior
from symplid.plotting import plot_pair, plot_predictive, plot_process_noise, plot_traces
from symplid.plotting._paper import first_exit, plot_hamiltonians
from symplid.plotting._style import Curves
from symplid.workflow._fit import build_model, build_posterior
from symplid.workflow._results import RunFolder
from symplid.workflow._settings import load_settings

#: Known initial states, one per trajectory (K·2d numbers): A from (1, 0), B from (0, 0.8).
SHORT = ["--order", "2", "--x0", "1,0,0,0.8", "--chains", "1", "--no-progress", "--set",
         "map.num_starts=1", "--set", "prediction.num_paths=5"]
SHORT += ["--dt", "0.25"]  # a fixed step: the step search is test_step_size.py's
SHORT += ["--set", "map.sensitivity=false"]  # the MAP refits: test_fit_diagnostics.py


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def _rows(times, x0, seed):
    """A harmonic oscillator's (q, p) from x0 with noise 0.02."""
    rng = np.random.default_rng(seed)
    t = np.asarray(times, dtype=float)
    q = x0[0] * np.cos(t) + x0[1] * np.sin(t) + 0.02 * rng.normal(size=t.size)
    p = -x0[0] * np.sin(t) + x0[1] * np.cos(t) + 0.02 * rng.normal(size=t.size)
    return [f"{a!r},{b!r},{c!r}" for a, b, c in zip(t.tolist(), q.tolist(), p.tolist(),
                                                   strict=True)]


@pytest.fixture(scope="module")
def two_trajectories(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("data")
    a, b = _rows(np.arange(1, 8.0), (1.0, 0.0), 0), _rows(np.arange(0.5, 7.0), (0.0, 0.8), 1)
    (folder / "A.csv").write_text("t,q1,p1\n" + "\n".join(a) + "\n")
    (folder / "B.csv").write_text("t,q1,p1\n" + "\n".join(b) + "\n")
    (folder / "AB.csv").write_text("t,q1,p1,trajectory\n" + "\n".join(
        [f"{r},A" for r in a] + ["# a comment line", *(f"{r},B" for r in b)]) + "\n")
    return {"A": folder / "A.csv", "B": folder / "B.csv", "AB": folder / "AB.csv",
            "runs": tmp_path_factory.mktemp("runs")}


@pytest.fixture(scope="module")
def two_runs(two_trajectories) -> tuple[Path, Path, str]:
    d = two_trajectories
    files, column = d["runs"] / "files", d["runs"] / "column"
    first = run("fit", d["A"], d["B"], "--out", files, "--iterations", "40", "--burn-in", "20",
                "--time-unit", "ms", *SHORT)
    assert first.exit_code == 0, first.output
    # One draw per chain: R-hat and ESS cannot be computed; that must be one line, no noise.
    second = run("fit", d["AB"], "--out", column, "--iterations", "21", "--burn-in", "20",
                 "--no-report", *SHORT)
    assert second.exit_code == 0, second.output
    return files, column, second.output


def test_two_files_and_a_trajectory_column_give_the_python_api_posterior(two_trajectories,
                                                                         two_runs):
    files, column, _ = two_runs
    maps = [RunFolder(r, "r").read_map() for r in (files, column)]
    np.testing.assert_array_equal(maps[0]["theta"], maps[1]["theta"])
    assert maps[0]["log_posterior"] == maps[1]["log_posterior"]
    # The Python API, from the original files (not the run's copy), at the run's MAP.
    data = [read_trajectories([two_trajectories[k]]) for k in ("A", "B")]
    settings = load_settings(files / "settings.toml")
    model = build_model(settings, data)
    direct = Posterior(model, data, x0=[[1.0, 0.0], [0.0, 0.8]], t0=0.0,
                       prior=settings.priors.prior_spec(False))
    assert direct.num_trajectories == 2
    assert float(direct.log_density(maps[0]["theta"])) == pytest.approx(
        maps[0]["log_posterior"], rel=1e-12, abs=1e-9)
    assert build_posterior(settings, data, model).param_names == direct.param_names
    stored = RunFolder(files, "r").read_data()
    assert len(stored) == 2 and all(
        np.array_equal(s.values, o.values) for s, o in zip(stored, data, strict=True))


def test_several_trajectories_are_predicted_and_reported_each(two_runs):
    files, _, _ = two_runs
    figures = {p.name for p in (files / "figures").iterdir()}
    assert {"traces.png", "pairs.png", "potential.png", "fit_0.png", "fit_1.png"} <= figures
    result = run("predict", files, "--t-end", "9", "--num-paths", "3")
    assert result.exit_code == 0 and "2 trajectories" in result.output, result.output
    with np.load(files / "predictions.npz") as arrays:
        assert {"map_path_0", "map_path_1", "band_lower_1"} <= set(arrays.files)
        # Each trajectory starts from its own initial state.
        np.testing.assert_array_equal(arrays["map_path_0"][0], [1.0, 0.0])
        np.testing.assert_array_equal(arrays["map_path_1"][0], [0.0, 0.8])
    report = (files / "report.md").read_text()
    assert "2 trajectories" in report and " ms" in report


def test_a_one_draw_run_says_so_in_one_line_without_raw_warnings(two_runs):
    output = two_runs[2]
    assert "only 1 draw(s) per chain" in output and "not computable" in output
    for noise in ("Degrees of freedom", "invalid value", "All-NaN", "arviz - WARNING"):
        assert noise not in output, output


def test_mismatched_trajectories_are_one_line(tmp_path, two_trajectories):
    q_only = tmp_path / "q.csv"
    q_only.write_text("t,q1\n1,0.5\n2,0.1\n")
    result = run("fit", two_trajectories["A"], q_only, "--out", tmp_path / "r", *SHORT)
    assert result.exit_code == 2 and "differ from those of" in result.output


def test_version_does_not_start_jax():
    code = "import sys, symplid.cli; print('jax' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "False"
    version = subprocess.run([sys.executable, "-m", "symplid.cli", "--version"],
                             capture_output=True, text=True, check=True)
    assert "version" in version.stdout


# ----------------------------------------------------------------------------- figures
DRAWS = np.random.default_rng(0).normal(size=(2, 50, 8))
NAMES = [f"θ{i}" for i in range(8)]


def _texts(fig) -> str:
    texts = [t.get_text() for t in fig.texts]
    if fig._suptitle is not None:
        texts.append(fig._suptitle.get_text())
    for ax in fig.axes:
        texts += [t.get_text() for t in ax.texts]
        legend = ax.get_legend()
        texts += [t.get_text() for t in legend.get_texts()] if legend else []
    for legend in fig.legends:
        texts += [t.get_text() for t in legend.get_texts()]
    return " | ".join(texts)


def test_pair_and_trace_plots_say_when_they_leave_parameters_out():
    pair = plot_pair(DRAWS, NAMES, max_params=3, option="plots.max_pair_params",
                     map_values=dict(zip(NAMES, np.zeros(8), strict=True)), reference=[0.1] * 3)
    assert "first 3 of 8 parameters" in _texts(pair) and "plots.max_pair_params" in _texts(pair)
    assert "MAP" in _texts(pair) and "truth" in _texts(pair)
    assert len(pair.axes) == 6  # 3 diagonal + 3 below
    full = plot_pair(DRAWS[..., :3], NAMES[:3], max_params=3)
    assert "parameters" not in _texts(full)
    traces = plot_traces(DRAWS, NAMES, max_params=5)
    assert "first 5 of 8" in _texts(traces) and len(traces.axes) == 10


def test_time_axes_use_the_given_unit():
    from types import SimpleNamespace

    t = np.linspace(0.0, 1.0, 5)
    band = SimpleNamespace(times=t, quantile_levels=(0.025, 0.975), quantiles=np.zeros((2, 5, 2)),
                           median=np.zeros((5, 2)), paths=np.zeros((3, 5, 2)),
                           lower=np.zeros((5, 2)), upper=np.zeros((5, 2)))
    fig = plot_predictive(band, time_unit="ms")
    assert fig.axes[-1].get_xlabel() == "t [ms]"
    fig = plot_hamiltonians([Curves("m", t, np.zeros(5))], (t, np.zeros(5)), time_unit="h")
    assert fig.axes[-1].get_xlabel() == "t [h]"


def test_fig4_keeps_its_axis_when_the_map_is_far_below_the_draws():
    draws = {"leapfrog": np.random.default_rng(1).lognormal(np.log(1e-7), 0.3, 500)}
    fig = plot_process_noise(draws, {"leapfrog": 1e-14})
    low, high = fig.axes[0].get_xlim()
    assert low > 1e-9 and high < 1e-5  # not stretched down to 1e-14
    assert "off the axis" in _texts(fig)
    inside = plot_process_noise(draws, {"leapfrog": 1e-7})
    assert "off the axis" not in _texts(inside)


def test_fig2_marks_where_an_energy_escapes():
    t = np.linspace(0.0, 200.0, 401)
    truth = np.full_like(t, 0.12)
    runaway = np.where(t < 112.0, 0.12, 0.12 + (t - 112.0) ** 2)
    assert first_exit(t, runaway, (0.1, 0.14)) == pytest.approx(112.5)
    assert first_exit(t, truth, (0.1, 0.14)) is None
    fig = plot_hamiltonians([Curves("leapfrog", t, truth)], (t, truth),
                            coarse=[Curves("RK2", t, runaway)])
    assert "RK2 escaped" in _texts(fig) and "leapfrog escaped" not in _texts(fig)


def test_potential_band_against_numpy():
    pot = Polynomial(1, 3)  # U = c1 q + c2 q² + c3 q³
    draws = np.random.default_rng(2).normal([0.0, 0.5, -0.1], 0.05, size=(300, 3))
    (one,) = potential_slices(pot, draws, [0.0], [-1.5], [2.0], num=7)
    q = np.linspace(-1.5, 2.0, 7)
    values = draws[:, :1] * q + draws[:, 1:2] * q**2 + draws[:, 2:] * q**3
    np.testing.assert_allclose(one["q"], q)
    np.testing.assert_allclose(one["quantiles"], np.quantile(values, (0.025, 0.5, 0.975),
                                                             axis=0), rtol=1e-12, atol=1e-14)
    pot2 = Polynomial(2, 2)
    slices = potential_slices(pot2, np.arange(1.0, 6.0), [0.3, -0.2], [-1, -1], [1, 1], num=3)
    assert len(slices) == 2
    assert np.all(slices[1]["points"][:, 0] == 0.3)  # q1 held at the centre along q2


def test_one_initial_state_for_all_or_a_wrong_count(two_trajectories, two_runs, tmp_path):
    d = two_trajectories
    wrong = run("fit", d["A"], d["B"], "--out", tmp_path / "r", "--x0", "1,0,0,0,0,0",
                "--order", "2")
    assert wrong.exit_code == 2 and "(or 4: one state per trajectory)" in wrong.output
    summary = json.loads((two_runs[0] / "summary.json").read_text())
    assert summary["param_names"] == ["c[q1]", "c[q1^2]", "process_var", "obs_var[q]", "obs_var[p]"]


def test_the_truth_of_a_named_system_by_the_models_coefficient_names(two_trajectories):
    from symplid.workflow._run_figures import truth_values
    from symplid.workflow._settings import Settings, merge_overrides

    data = read_trajectories([two_trajectories["A"]])
    settings = merge_overrides(Settings(), {"plots.truth": "harmonic", "model.order": 3,
                                            "model.dt": 0.25})
    system, values = truth_values(settings, build_model(settings, data))
    assert system.name == "harmonic"
    # U = q²/2: the model's other terms (q, q³) are truly zero.
    assert values == {"c[q1]": 0.0, "c[q1^2]": 0.5, "c[q1^3]": 0.0}
    assert truth_values(merge_overrides(settings, {"plots.truth": ""}), None) is None
