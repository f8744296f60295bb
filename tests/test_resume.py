"""Resuming an interrupted run: the interrupted draws plus the continued ones are the draws of
the uninterrupted run with the same seed, bit for bit (sampler level and ``symplid fit
--resume``); a finished run or changed settings are refused in one line.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from sampler_targets import Gaussian2D
from symplid.cli import main
from symplid.sampling import InterruptedInBurnIn, RunOptions, draws_array, sample
from symplid.sampling._resume import checkpoint_arrays, resume_sampling
from symplid.sampling._run import SamplingInterrupted
from symplid.workflow._results import RunFolder

BUDGET = {"num_draws": 150, "num_chains": 2, "seed": 3, "burn_in": 90}
RUNNER = {"chunk_size": 40, "progress": False}


def _stop_at(iterations: int):
    def callback(report):
        if report.iterations_done == iterations:
            raise KeyboardInterrupt

    return callback


def _stats(idata) -> dict[str, np.ndarray]:
    return {k: np.asarray(v.values) for k, v in idata.sample_stats.data_vars.items()}


@pytest.mark.parametrize(("method", "stop"), [("dram", 120), ("dram", 200), ("nuts", 160)])
def test_a_resumed_run_equals_the_uninterrupted_run(method, stop, tmp_path):
    target = Gaussian2D()
    init = target.map_result()
    full = sample(target, method, init=init, **BUDGET, options=RunOptions(**RUNNER))
    with pytest.warns(SamplingInterrupted):
        part, checkpoint = sample(target, method, init=init, **BUDGET,
                                  options=RunOptions(**RUNNER, callback=_stop_at(stop),
                                                     return_state=True))
    assert part.attrs["interrupted"] == 1 and checkpoint.iterations_done == stop
    assert part.posterior.sizes["draw"] == stop - BUDGET["burn_in"]
    # Through a file, as a run folder stores it (the draws' file: the CLI test below).
    np.savez(tmp_path / "state.npz", **checkpoint_arrays(checkpoint))
    with np.load(tmp_path / "state.npz") as stored:
        resumed = resume_sampling(target, part, dict(stored), options=RunOptions(**RUNNER))
    assert resumed.attrs["interrupted"] == 0
    assert resumed.attrs["iterations"] == BUDGET["burn_in"] + BUDGET["num_draws"]
    np.testing.assert_array_equal(draws_array(resumed), draws_array(full))
    for name, value in _stats(full).items():
        np.testing.assert_array_equal(_stats(resumed)[name], value, err_msg=name)


def test_a_run_stopped_in_its_burn_in_resumes_from_its_state_and_attributes():
    target = Gaussian2D()
    init = target.map_result()
    full = sample(target, "dram", init=init, **BUDGET, options=RunOptions(**RUNNER))
    with pytest.warns(SamplingInterrupted), pytest.raises(InterruptedInBurnIn) as info:
        sample(target, "dram", init=init, **BUDGET,
               options=RunOptions(**RUNNER, callback=_stop_at(80), return_state=True))
    stop = info.value
    assert isinstance(stop, KeyboardInterrupt) and stop.checkpoint.iterations_done == 80
    assert stop.attrs["iterations"] == 80
    resumed = resume_sampling(target, stop.attrs, checkpoint_arrays(stop.checkpoint),
                              options=RunOptions(**RUNNER))
    np.testing.assert_array_equal(draws_array(resumed), draws_array(full))


def test_resuming_a_finished_run_or_a_foreign_state_is_refused():
    target = Gaussian2D()
    full, checkpoint = sample(target, "dram", init=target.map_result(), **BUDGET,
                              options=RunOptions(**RUNNER, return_state=True))
    with pytest.raises(ValueError, match="the run is finished"):
        resume_sampling(target, full, checkpoint, options=RunOptions(**RUNNER))
    stored = checkpoint_arrays(checkpoint)
    stored["treedef"] = np.asarray("PyTreeDef(None)")
    with pytest.raises(ValueError, match="does not fit this sampler"):
        resume_sampling(target, full, stored, options=RunOptions(**RUNNER))


# ----------------------------------------------------------------------------- symplid fit
TINY = ["--order", "2", "--x0", "1,0", "--iterations", "400", "--burn-in", "200", "--chains",
        "2", "--no-progress", "--no-report", "--set", "map.num_starts=1", "--set",
        "sampler.chunk_size=100"]
TINY += ["--dt", "0.25"]  # a fixed step: the step search is test_step_size.py's
TINY += ["--set", "map.sensitivity=false"]  # the MAP refits: test_fit_diagnostics.py


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def _chunks_of_100(monkeypatch, stop_at: int | None = None):
    """workflow.fit's sampler (in chunks of 100 iterations: TINY) stopped (Ctrl-C) after
    ``stop_at``."""
    import symplid.workflow._fit as fit_module

    extra = {}
    if stop_at is not None:
        extra["callback"] = _stop_at(stop_at)

    def stopped(*args, options, **kwargs):
        return sample(*args, options=dataclasses.replace(options, **extra), **kwargs)

    monkeypatch.setattr(fit_module, "sample", stopped)



@pytest.fixture(scope="module")
def reference_run(data_csv, tmp_path_factory) -> Path:
    with pytest.MonkeyPatch.context() as mp:
        _chunks_of_100(mp)
        out = tmp_path_factory.mktemp("runs") / "whole"
        result = run("fit", data_csv, "--out", out, *TINY)
    assert result.exit_code == 0, result.output
    return out


def test_fit_resume_finishes_the_run_with_the_uninterrupted_draws(data_csv, reference_run,
                                                                  tmp_path, monkeypatch):
    out = tmp_path / "run"
    _chunks_of_100(monkeypatch, stop_at=300)
    stopped = run("fit", data_csv, "--out", out, *TINY)
    assert stopped.exit_code == 130 and "continue with --resume" in stopped.output
    assert (out / RunFolder.SAMPLER_STATE).exists()
    monkeypatch.undo()
    # The same command line again (the settings are checked, and equal).
    resumed = run("fit", data_csv, "--out", out, "--resume", *TINY)
    assert resumed.exit_code == 0, resumed.output
    folder = RunFolder(out, "r")  # finished: readable without allow_incomplete
    assert not (out / RunFolder.SAMPLER_STATE).exists()
    whole = RunFolder(reference_run, "r").read_posterior()
    mine = folder.read_posterior()
    assert mine.posterior.sizes["draw"] == 200 and mine.attrs["iterations"] == 400
    np.testing.assert_array_equal(draws_array(mine), draws_array(whole))
    np.testing.assert_array_equal(mine.sample_stats["accepted"], whole.sample_stats["accepted"])
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"] is False and summary["timings"]["resumed"] == 1
    # Resuming again: the run is finished.
    again = run("fit", "--out", out, "--resume", "--no-progress")
    assert again.exit_code == 2 and "nothing to resume" in again.output
    assert len(again.output.strip().splitlines()) == 1


def test_fit_stopped_in_the_burn_in_resumes_to_the_uninterrupted_draws(data_csv, reference_run,
                                                                       tmp_path, monkeypatch):
    out = tmp_path / "run"
    _chunks_of_100(monkeypatch, stop_at=100)  # burn-in: 200
    stopped = run("fit", data_csv, "--out", out, *TINY)
    assert stopped.exit_code == 130 and "continue with 'symplid fit --resume'" in stopped.output
    reason = RunFolder(out, "r", allow_incomplete=True).incomplete_reason
    assert reason.startswith("interrupted: in the burn-in, after 100 of 400")
    monkeypatch.undo()
    resumed = run("fit", "--out", out, "--resume", "--no-progress", "--no-report")
    assert resumed.exit_code == 0, resumed.output
    np.testing.assert_array_equal(draws_array(RunFolder(out, "r").read_posterior()),
                                  draws_array(RunFolder(reference_run, "r").read_posterior()))
    assert not (out / RunFolder.SAMPLER_ATTRS).exists()


def test_resume_refuses_changed_settings_or_data_in_one_line(data_csv, tmp_path, monkeypatch):
    out = tmp_path / "run"
    _chunks_of_100(monkeypatch, stop_at=300)
    assert run("fit", data_csv, "--out", out, *TINY).exit_code == 130
    monkeypatch.undo()
    changed = run("fit", "--out", out, "--resume", "--iterations", "800", "--no-progress")
    assert changed.exit_code == 2 and "sampler.num_iterations (400 in the run, 800 given)" in \
        changed.output, changed.output
    other = tmp_path / "other.csv"
    other.write_text(data_csv.read_text().replace("1.0,", "1.5,", 1))
    moved = run("fit", other, "--out", out, "--resume", "--no-progress")
    assert moved.exit_code == 2 and "not the data of the run" in moved.output
    for result in (changed, moved):
        assert len(result.output.strip().splitlines()) == 1, result.output
    # Still interrupted and resumable after the refusals; the run's own settings file is
    # the same settings (a file is merged onto the run's, not onto the defaults).
    assert RunFolder(out, "r", allow_incomplete=True).incomplete_reason.startswith("interrupted")
    same = run("fit", "--out", out, "--resume", "--config", out / "settings.toml",
               "--no-progress", "--no-report")
    assert same.exit_code == 0, same.output
    assert RunFolder(out, "r").read_posterior().posterior.sizes["draw"] == 200
