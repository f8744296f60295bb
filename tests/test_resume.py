"""Resuming an interrupted run: the interrupted draws plus the continued ones are the draws of
the uninterrupted run with the same seed, bit for bit (sampler level and ``symplid fit
--resume``); a finished run or changed settings are refused in one line.
"""

from __future__ import annotations

import functools
import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from sampler_targets import Gaussian2D

from symplid.cli import main
from symplid.inference.samplers import draws_array, sample
from symplid.inference.samplers.resume import checkpoint_arrays, resume_sampling
from symplid.inference.samplers.run import SamplingInterrupted
from symplid.workflow.results import RunFolder

BUDGET = {"num_draws": 150, "num_chains": 2, "seed": 3, "burn_in": 90, "chunk_size": 40,
          "progress": False}


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
    full = sample(target, method, init=init, **BUDGET)
    with pytest.warns(SamplingInterrupted):
        part, checkpoint = sample(target, method, init=init, callback=_stop_at(stop),
                                  return_state=True, **BUDGET)
    assert part.attrs["interrupted"] == 1 and checkpoint.iterations_done == stop
    assert part.posterior.sizes["draw"] == stop - BUDGET["burn_in"]
    # Through a file, as a run folder stores it (the draws' file: the CLI test below).
    np.savez(tmp_path / "state.npz", **checkpoint_arrays(checkpoint))
    with np.load(tmp_path / "state.npz") as stored:
        resumed = resume_sampling(target, part, dict(stored), progress=False)
    assert resumed.attrs["interrupted"] == 0
    assert resumed.attrs["iterations"] == BUDGET["burn_in"] + BUDGET["num_draws"]
    np.testing.assert_array_equal(draws_array(resumed), draws_array(full))
    for name, value in _stats(full).items():
        np.testing.assert_array_equal(_stats(resumed)[name], value, err_msg=name)


def test_resuming_a_finished_run_or_a_foreign_state_is_refused():
    target = Gaussian2D()
    full, checkpoint = sample(target, "dram", init=target.map_result(), return_state=True,
                              **BUDGET)
    with pytest.raises(ValueError, match="the run is finished"):
        resume_sampling(target, full, checkpoint, progress=False)
    stored = checkpoint_arrays(checkpoint)
    stored["treedef"] = np.asarray("PyTreeDef(None)")
    with pytest.raises(ValueError, match="does not fit this sampler"):
        resume_sampling(target, full, stored, progress=False)
