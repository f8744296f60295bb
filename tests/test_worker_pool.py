"""Jobs in pinned worker processes that hand back a first part early (workflow.worker_pool), and
the fit's hook that gives it the draws before they are summarised and written (fit.py).

* A posted message reaches the parent while its job still runs: each job waits, after
  posting, until the parent has received its message (a file the parent writes then); if
  messages came only with the results, the jobs would time out and fail.
* Each job runs in its own process, pinned to its own core; the results come in the jobs'
  order; a job that posts nothing ends the waiting all the same; a failing job's error is
  raised from :meth:`WorkerPool.messages`; with one worker the jobs run in this process with
  the same messages and results.
* ``fit(on_sampled=...)`` sees the draws before ``posterior.nc`` exists, and they are the
  draws that are then written (read back, bit for bit), in the data's units also when the
  fit ran in standardised coordinates.
"""

from __future__ import annotations

import os
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from symplid.workflow._worker_pool import WorkerPool, post

WAIT_S = 120.0


def _job(args: tuple[int, str, bool]) -> dict[str, object]:
    k, folder, posts = args
    if posts:
        post({"job": k, "pid": os.getpid()})
        seen = Path(folder) / f"seen-{k}"
        deadline = time.monotonic() + WAIT_S
        while not seen.exists():  # the parent writes it when it has the message
            if time.monotonic() > deadline:
                raise TimeoutError(f"job {k}: the parent never got the message")
            time.sleep(0.01)
    return {"job": k, "pid": os.getpid(), "affinity": sorted(os.sched_getaffinity(0))}


def _failing(args: tuple[int, str, bool]) -> None:
    raise ValueError(f"job {args[0]} failed on purpose")


def _collect(pool: WorkerPool, folder: Path) -> list[dict]:
    got = []
    for message in pool.messages():
        got.append(message)
        (folder / f"seen-{message['job']}").write_text("")
    return got


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="no CPU affinity here")
def test_messages_arrive_while_the_jobs_run_in_pinned_processes(tmp_path):
    jobs = [(0, str(tmp_path), True), (1, str(tmp_path), True)]
    with WorkerPool(_job, jobs, workers=2) as pool:
        messages = _collect(pool, tmp_path)
        results = pool.results()
    assert sorted(m["job"] for m in messages) == [0, 1]
    assert [r["job"] for r in results] == [0, 1]
    pids = {r["pid"] for r in results}
    assert len(pids) == 2 and os.getpid() not in pids
    assert {m["job"]: m["pid"] for m in messages} == {r["job"]: r["pid"] for r in results}
    if len(os.sched_getaffinity(0)) >= 2:
        assert all(len(r["affinity"]) == 1 for r in results)
        assert results[0]["affinity"] != results[1]["affinity"]


def test_a_job_that_posts_nothing_ends_the_waiting(tmp_path):
    jobs = [(0, str(tmp_path), False), (1, str(tmp_path), True)]
    with WorkerPool(_job, jobs, workers=2) as pool:
        messages = _collect(pool, tmp_path)
        results = pool.results()
    assert [m["job"] for m in messages] == [1]
    assert [r["job"] for r in results] == [0, 1]


def test_a_failing_job_is_raised_from_the_messages(tmp_path):
    with WorkerPool(_failing, [(0, str(tmp_path), True), (1, str(tmp_path), True)],
                    workers=2) as pool, pytest.raises(ValueError, match="failed on purpose"):
        list(pool.messages())


def test_one_worker_runs_the_jobs_here_with_the_same_messages(tmp_path):
    for k in range(2):  # nothing to wait for in this process: the jobs run one after the other
        (tmp_path / f"seen-{k}").write_text("")
    jobs = [(0, str(tmp_path), True), (1, str(tmp_path), False)]
    with WorkerPool(_job, jobs, workers=1) as pool:
        messages = list(pool.messages())
        results = pool.results()
    assert messages == [{"job": 0, "pid": os.getpid()}]
    assert [r["job"] for r in results] == [0, 1]
    assert {r["pid"] for r in results} == {os.getpid()}
    post({"job": 9})  # outside a job: dropped, no error


@pytest.mark.slow
@pytest.mark.parametrize("standardise", ["off", "on"])
def test_fit_hands_over_the_draws_before_writing_them(tmp_path, standardise):
    """Before ``posterior.nc`` exists, with the MAP and the names; in the data's units also
    when the fit ran in standardised coordinates: the very draws then written."""
    from symplid.dynamics._systems import get_system
    from symplid.model._simulate import simulate
    from symplid.sampling import draws_array
    from symplid.workflow._fit import fit
    from symplid.workflow._results import RunFolder
    from symplid.workflow._settings import Settings, merge_overrides

    system = get_system("henon-heiles")
    obs = simulate(system, times=5.0 * np.arange(1, 11), noise_std=0.05, seed=1)
    settings = merge_overrides(Settings(), {
        "model.order": 3, "model.dt": 0.25, "map.sensitivity": False, "map.num_starts": 1,
        "initial_state.x0": [float(v) for v in system.initial_state],
        "sampler.num_iterations": 400, "sampler.burn_in": 200, "sampler.num_chains": 2,
        "model.standardise": standardise})
    out, seen = tmp_path / "run", {}

    def sampled(done):
        seen["done"] = done
        seen["written"] = (out / RunFolder.POSTERIOR).exists()

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        outcome = fit(obs, settings, out=out, progress=False, on_sampled=sampled)
    done = seen["done"]
    assert seen["written"] is False
    assert outcome.summary and (out / RunFolder.POSTERIOR).exists()
    assert (outcome.standardised_scale is not None) == (standardise == "on")
    assert done.param_names == tuple(outcome.posterior.param_names)
    np.testing.assert_array_equal(done.map_result.theta, outcome.map_result.theta)
    back = draws_array(RunFolder(out, "r").read_posterior())
    assert done.draws.shape == (2, 200, len(outcome.posterior.param_names))
    np.testing.assert_array_equal(back, done.draws)
