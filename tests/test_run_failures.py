"""A run that nothing can break (issue 11): interruptions, failed updates, bad input, one line.

Each class of case of the issue has a test: a failed or interrupted ``predict``/``report``
leaves a finished run finished; Ctrl-C and SIGTERM during sampling keep the draws, mark the run
and exit 130/143; a second Ctrl-C while saving loses nothing; impossible data (a gap of 1e9,
one row, an empty column) and usage mistakes are one line with exit code 2.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from csv_data import harmonic, write_csv
from symplid.cli import main
from symplid.workflow._interrupts import deferred_interrupts, supervised
from symplid.workflow._results import RunFolder

TINY = ["--iterations", "400", "--burn-in", "200", "--chains", "2", "--no-progress",
        "--no-report", "--set", "sampler.chunk_size=100"]
TINY += ["--dt", "0.25"]  # a fixed step: the step search is test_step_size.py's
TINY += ["--set", "map.sensitivity=false"]  # the MAP refits: test_fit_diagnostics.py


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def one_line_error(result, *words, code=2):
    assert result.exit_code == code, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("symplid: error:"), result.output
    assert "Traceback" not in result.output
    for word in words:
        assert word in lines[0], lines[0]


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory) -> Path:
    data = write_csv(tmp_path_factory.mktemp("d") / "h.csv", np.arange(1, 13.0),
                     harmonic(np.arange(1, 13.0)))
    out = tmp_path_factory.mktemp("runs") / "fit"
    result = run("fit", data, "--out", out, "--order", "2", "--x0", "1,0", *TINY)
    assert result.exit_code == 0, result.output
    return out


@pytest.fixture
def copy_of(finished_run, tmp_path) -> Path:
    target = tmp_path / "copy"
    shutil.copytree(finished_run, target)
    return target


def is_finished(folder: Path) -> bool:
    return RunFolder(folder, "r").is_complete


# ----------------------------------------------------------------------------- predict/report
@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--t-end", "-5"], ["--t-end"]),
        (["--t-end", "nan"], ["--t-end"]),
        (["--t-end", "20", "--dt", "0"], ["--dt"]),
        (["--t-end", "1e9"], ["steps"]),
    ],
)
def test_a_failed_predict_leaves_the_run_finished(copy_of, args, words):
    one_line_error(run("predict", copy_of, *args), *words)
    assert is_finished(copy_of) and not (copy_of / "predictions.npz").exists()
    assert run("predict", copy_of, "--t-end", "15", "--num-paths", "3").exit_code == 0


def test_a_crash_or_ctrl_c_during_predict_leaves_the_run_finished(copy_of, monkeypatch):
    import symplid.workflow._run_figures as figures
    import symplid.workflow._run_tools as tools

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(figures, "posterior_predictive", interrupted)
    result = run("predict", copy_of, "--t-end", "15")
    assert result.exit_code == 130 and "interrupted" in result.output
    assert is_finished(copy_of)

    def failing_write(self, name, **arrays):
        raise OSError("disk full")

    monkeypatch.undo()
    monkeypatch.setattr(RunFolder, "write_npz", failing_write)
    with pytest.raises(OSError, match="disk full"):
        tools.predict_run(copy_of, t_end=15.0, num_paths=0)
    assert is_finished(copy_of)  # the update's marker is removed again


def test_predict_t_end_defaults_to_the_settings(copy_of):
    result = run("predict", copy_of, "--num-paths", "0", "--dt", "0.05")
    assert result.exit_code == 0, result.output
    assert np.load(copy_of / "predictions.npz")["times"][-1] == pytest.approx(200.0)


def test_report_without_posterior_warns_in_one_line(copy_of):
    (copy_of / "posterior.nc").unlink()
    result = run("report", copy_of)  # the CLI shows warnings as one line
    assert result.exit_code == 0, result.output
    warning = [line for line in result.output.splitlines() if "warning" in line]
    assert len(warning) == 1 and "posterior.nc is missing" in warning[0]
    assert is_finished(copy_of)


def test_report_has_a_convergence_table(copy_of):
    assert run("report", copy_of).exit_code == 0
    report = (copy_of / "report.md").read_text()
    assert "## Convergence" in report and "| c[q1^2] |" in report and "R-hat" in report


# ----------------------------------------------------------------------------- interruptions
def _interrupt_sampler(monkeypatch, action):
    """Make the sampler of workflow.fit call ``action`` after 300 of its 400 iterations
    (chunks of 100: burn-in is over, 100 draws per chain are kept)."""
    import symplid.workflow._fit as fit_module

    def callback(report):
        if report.iterations_done == 300:
            action()

    sample = fit_module.sample

    def interrupted(*args, options, **kwargs):  # chunks of 100: TINY's sampler.chunk_size
        return sample(*args, options=dataclasses.replace(options, callback=callback), **kwargs)

    monkeypatch.setattr(fit_module, "sample", interrupted)


def _raise():
    raise KeyboardInterrupt


@pytest.mark.parametrize(
    ("action", "code"),
    [(_raise, 130), (lambda: os.kill(os.getpid(), signal.SIGTERM), 143)],
    ids=["ctrl-c", "sigterm"],
)
def test_interrupted_sampling_keeps_draws_marks_run_and_exits(tmp_path, monkeypatch, action,
                                                              code):
    data = write_csv(tmp_path / "h.csv", np.arange(1, 13.0), harmonic(np.arange(1, 13.0)))
    _interrupt_sampler(monkeypatch, action)
    out = tmp_path / "run"
    result = run("fit", data, "--out", out, "--order", "2", "--x0", "1,0", *TINY)
    assert result.exit_code == code, result.output
    assert "interrupted after 300 of 400 iterations" in result.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"] is True and summary["iterations_done"] == 300
    folder = RunFolder(out, "r", allow_incomplete=True)
    assert folder.incomplete_reason.startswith("interrupted: after 300 of 400")
    assert folder.read_posterior().posterior.sizes["draw"] == 100  # kept draws
    one_line_error(run("predict", out, "--t-end", "20"), "interrupted", "--overwrite")


def test_a_second_ctrl_c_while_saving_loses_nothing(tmp_path, monkeypatch):
    data = write_csv(tmp_path / "h.csv", np.arange(1, 13.0), harmonic(np.arange(1, 13.0)))
    _interrupt_sampler(monkeypatch, _raise)
    original = RunFolder.write_posterior

    def impatient(self, idata):
        os.kill(os.getpid(), signal.SIGINT)  # the user presses Ctrl-C again
        return original(self, idata)

    monkeypatch.setattr(RunFolder, "write_posterior", impatient)
    out = tmp_path / "run"
    result = run("fit", data, "--out", out, "--order", "2", "--x0", "1,0", *TINY)
    assert result.exit_code == 130, result.output
    assert (out / "posterior.nc").exists() and (out / "summary.json").exists()


def test_signal_helpers():
    from symplid import _stopping as stopping

    before = signal.getsignal(signal.SIGINT)  # SIG_IGN when the suite runs as a background job
    with deferred_interrupts() as held:
        os.kill(os.getpid(), signal.SIGINT)
        os.kill(os.getpid(), signal.SIGTERM)
    assert held == [signal.SIGINT, signal.SIGTERM]
    assert signal.getsignal(signal.SIGINT) is before  # the handler of before the block, again
    with supervised(), deferred_interrupts() as held:  # supervised: the stop is recorded there
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.01)
        assert held == [] and stopping.requested() == signal.SIGTERM


# ----------------------------------------------------------------------------- bad input
def test_a_gap_of_a_billion_is_one_line(tmp_path):
    times = np.array([1.0, 2.0, 3.0, 1e9])
    data = write_csv(tmp_path / "far.csv", times, harmonic(times))
    result = run("fit", data, "--out", tmp_path / "r", "--order", "2", "--x0", "1,0", *TINY)
    one_line_error(result, "integrator steps", "1,000,000")


def test_single_row_and_empty_column_are_refused(tmp_path):
    one = write_csv(tmp_path / "one.csv", [1.0], {"q1": np.array([1.0]), "p1": np.array([0.0])})
    one_line_error(run("fit", one, "--out", tmp_path / "a", "--x0", "1,0", *TINY), "at least 2")
    t = np.arange(1, 6.0)
    empty = write_csv(tmp_path / "e.csv", t, {"q1": np.cos(t), "p1": np.full(5, np.nan)})
    one_line_error(run("fit", empty, "--out", tmp_path / "b", "--x0", "1,0", *TINY),
                   "p1 has no values")


def test_too_many_parameters_warn(tmp_path):
    from symplid.io import read_observations
    from symplid.workflow._settings import Settings, merge_overrides, resolve_for_data

    t = np.arange(1, 9.0)
    obs = read_observations(write_csv(tmp_path / "h.csv", t, harmonic(t)))
    settings = merge_overrides(Settings(), {"model.order": 50, "initial_state.x0": [1, 0]})
    with pytest.warns(UserWarning, match="53 parameters .* for 16 data values"):
        resolve_for_data(settings, obs)


def test_out_below_a_file_and_usage_errors_are_one_line(tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("x")
    t = np.arange(1, 6.0)
    data = write_csv(tmp_path / "h.csv", t, harmonic(t))
    one_line_error(run("fit", data, "--out", afile / "run", "--x0", "1,0", *TINY), "afile")
    one_line_error(run("fit", data, "--out", afile), "--out")
    one_line_error(run("fit", data, "--out", tmp_path / "r", "--config", tmp_path), "--config")
    one_line_error(run("simulate", "harmonic", "--out", tmp_path / "s.csv", "--missing", "1.0"),
                   "--missing")
    one_line_error(run("study", "paper-claims", "--out", tmp_path / "c", "--seeds", "0"),
                   "--seeds")
    one_line_error(run("fit"), "DATA")


# ----------------------------------------------------------------------------- t0 = "first"
def test_t0_first_from_settings_and_cli(tmp_path):
    from symplid.workflow._settings import Settings, merge_overrides, settings_from_dict

    assert settings_from_dict({"initial_state": {"t0": "first"}}).initial_state.t0 == "first"
    with pytest.raises(ValueError, match='must be a number or \'first\''):
        merge_overrides(Settings(), {"initial_state.t0": "last"})
    t = np.arange(0.0, 12.0)  # data from t = 0
    data = write_csv(tmp_path / "h.csv", t, harmonic(t))
    out = tmp_path / "run"
    result = run("fit", data, "--out", out, "--order", "2", "--learn-initial-state",
                 "--t0", "first", *TINY)
    assert result.exit_code == 0, result.output
    assert 't0 = "first"' in (out / "settings.toml").read_text()
    result = run("predict", out, "--t-end", "15", "--num-paths", "3")
    assert result.exit_code == 0, result.output
    pred = np.load(out / "predictions.npz")
    assert pred["times"][0] == 0.0
    assert np.max(np.abs(pred["map_path"][:, 0] - np.cos(pred["times"]))) < 0.15


def test_learned_state_long_before_the_data_warns(tmp_path):
    from symplid.io import read_observations
    from symplid.workflow._settings import Settings, merge_overrides, resolve_for_data

    t = np.arange(5.0, 10.0, 0.5)
    obs = read_observations(write_csv(tmp_path / "h.csv", t, harmonic(t)))
    learned = merge_overrides(Settings(), {"initial_state.mode": "learned", "model.order": 2})
    with pytest.warns(UserWarning, match='t0 = "first"'):
        resolve_for_data(learned, obs)


# ----------------------------------------------------------------------------- positions only
def test_readme_walkthrough_positions_only(tmp_path):
    data = tmp_path / "q.csv"
    assert run("simulate", "harmonic", "--out", data, "--observation", "positions",
               "--num-obs", "15", "--t-end", "15", "--seed", "1").exit_code == 0
    out = tmp_path / "run"
    result = run("fit", data, "--out", out, "--order", "2", "--learn-initial-state", *TINY)
    assert result.exit_code == 0, result.output
    result = run("predict", out, "--t-end", "25", "--num-paths", "5")
    assert result.exit_code == 0, result.output
    assert (out / "figures" / "predictive.png").exists() and is_finished(out)
