"""Chains stuck in a mode of negligible mass are restarted at the end of the burn-in.

Against analytic answers: a chain started in a mode 60 nats below the main one is restarted
and the pooled draws have the main component's moments (N(0, I)); chains split between two
equal modes are left alone. A run in which no chain is stuck is the run without the rule,
bit for bit, and a run with a restart resumes (from memory, from the arrays a run folder
stores, from chunk files) to the uninterrupted run's draws.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from sampler_targets import Gaussian2D, TwoModes, moment_z_scores
from symplid.io._chunks import ChunkWriter, read_chunks
from symplid.sampling import InterruptedInBurnIn, RunOptions, draws_array, sample
from symplid.sampling._restart import burn_in_window, restart_threshold
from symplid.sampling._resume import (
    checkpoint_arrays,
    inference_data,
    resume_sampling,
)
from symplid.sampling._run import SamplingInterrupted, StuckChainsRestarted

# burn_in 90 is not on the chunk grid of 40: the chunk that crosses it is cut there.
SMALL = {"num_draws": 150, "num_chains": 4, "seed": 3, "burn_in": 90}
RUNNER = {"chunk_size": 40, "progress": False}


def _starts(far_chains: tuple[int, ...]) -> np.ndarray:
    starts = np.zeros((4, 2))
    starts[list(far_chains)] = TwoModes.far
    return starts


def _stats(idata) -> dict[str, np.ndarray]:
    return {k: np.asarray(v.values) for k, v in idata.sample_stats.data_vars.items()}


def _same_run(a, b) -> None:
    np.testing.assert_array_equal(draws_array(a), draws_array(b))
    for name, value in _stats(a).items():
        np.testing.assert_array_equal(_stats(b)[name], value, err_msg=name)


def _stop_at(iterations: int):
    def callback(report):
        if report.iterations_done == iterations:
            raise KeyboardInterrupt

    return callback


def test_the_threshold_and_the_window():
    # Δ(d) = max(10, 5 √(d/2)): the floor for small d, 5 sds of a Gaussian mode's log density.
    assert restart_threshold(2) == 10.0
    assert restart_threshold(11) == pytest.approx(5 * np.sqrt(5.5))
    # The last quarter of the burn-in, thinned to at most 1000 iterations, ending at it.
    assert burn_in_window(90) == (69, 1)
    first, stride = burn_in_window(100_000)
    assert stride == 25 and first == 100_000 - 999 * 25
    assert burn_in_window(0) == (0, 1)


@pytest.mark.parametrize("method", ["dram", "nuts"])
def test_no_stuck_chain_gives_the_draws_of_a_run_without_the_rule(method, recwarn):
    target = Gaussian2D()
    on = sample(target, method, init=target.map_result(), **SMALL, options=RunOptions(**RUNNER))
    off = sample(target, method, init=target.map_result(), **SMALL,
                 options=RunOptions(**RUNNER, restart_stuck_chains=False))
    _same_run(on, off)
    assert on.attrs["restarted_chains"] == [] and off.attrs["restarted_chains"] == []
    assert not [w for w in recwarn if issubclass(w.category, StuckChainsRestarted)]
    assert json.loads(on.attrs["settings"])["restart_stuck_chains"] is True


@pytest.mark.parametrize("method", ["dram", "nuts"])
def test_a_chain_in_a_mode_60_nats_down_is_restarted_and_the_draws_are_the_main_mode(method):
    target = TwoModes(gap=60.0)
    budget = {**SMALL, "num_draws": 2000, "burn_in": 600}
    with pytest.warns(StuckChainsRestarted, match="chain 3"):
        idata = sample(target, method, init=target.map_result(),
                       **budget, options=RunOptions(chunk_size=500, progress=False,
                                                    initial_positions=_starts((3,))))
    (restart,) = idata.attrs["restarted_chains"]
    assert restart["chain"] == 3 and restart["from_chain"] in (0, 1, 2)
    assert restart["best_lp_median"] - restart["lp_median"] == pytest.approx(60.0, abs=5.0)
    draws = draws_array(idata)
    assert np.abs(draws).max() < 10  # no kept draw in the far mode
    for name, z in moment_z_scores(draws, target.mean, target.cov).items():
        assert abs(z) < 4.5, (name, z)
    # Without the rule the chain stays there: the pooled mean is a quarter of the way out.
    kept = sample(target, method, init=target.map_result(), **budget,
                  options=RunOptions(chunk_size=500, progress=False,
                                     initial_positions=_starts((3,)),
                                     restart_stuck_chains=False))
    assert kept.attrs["restarted_chains"] == []
    assert draws_array(kept)[3].mean(axis=0) == pytest.approx(TwoModes.far, abs=0.5)


def test_chains_split_between_two_equal_modes_are_left_alone(recwarn):
    target = TwoModes(gap=0.0)
    on = sample(target, "dram", init=target.map_result(), **SMALL,
                options=RunOptions(**RUNNER, initial_positions=_starts((2, 3))))
    off = sample(target, "dram", init=target.map_result(), **SMALL,
                 options=RunOptions(**RUNNER, initial_positions=_starts((2, 3)),
                                    restart_stuck_chains=False))
    assert on.attrs["restarted_chains"] == []
    assert not [w for w in recwarn if issubclass(w.category, StuckChainsRestarted)]
    _same_run(on, off)
    assert draws_array(on)[2:].mean() == pytest.approx(30.0, abs=1.0)


@pytest.mark.parametrize("stop", [40, 80, 120, 160])
def test_a_run_with_a_restart_resumes_to_the_uninterrupted_run(stop, tmp_path):
    """Stopped before the window (40), inside it (80), right after the chunk in which the
    burn-in ends and the decision is taken (120) and later (160)."""
    target = TwoModes(gap=60.0)
    init, starts = target.map_result(), _starts((1,))
    with pytest.warns(StuckChainsRestarted):
        full = sample(target, "dram", init=init, **SMALL,
                      options=RunOptions(**RUNNER, initial_positions=starts))
    assert [r["chain"] for r in full.attrs["restarted_chains"]] == [1]
    with pytest.warns(SamplingInterrupted):
        try:
            part, checkpoint = sample(target, "dram", init=init, **SMALL,
                                      options=RunOptions(**RUNNER, initial_positions=starts,
                                                         callback=_stop_at(stop),
                                                         return_state=True))
        except InterruptedInBurnIn as burn_in:
            part, checkpoint = burn_in.attrs, burn_in.checkpoint
    np.savez(tmp_path / "state.npz", **checkpoint_arrays(checkpoint))
    with np.load(tmp_path / "state.npz") as stored:
        resumed = resume_sampling(target, part, dict(stored), options=RunOptions(**RUNNER))
    _same_run(full, resumed)
    assert resumed.attrs["restarted_chains"] == full.attrs["restarted_chains"]


def test_a_restart_survives_the_chunk_files(tmp_path):
    """The window read so far and the decision are kept with each chunk's states, so a run
    continued from its chunk files (``fit --resume``) equals the uninterrupted one."""
    target = TwoModes(gap=60.0)
    init, starts = target.map_result(), _starts((0,))
    with pytest.warns(StuckChainsRestarted):
        full = sample(target, "dram", init=init, **SMALL,
                      options=RunOptions(**RUNNER, initial_positions=starts))
    for stop in (80, 160):
        folder = tmp_path / str(stop)
        saved = {}
        sink = ChunkWriter(folder, begin=saved.update)
        with pytest.warns(SamplingInterrupted), pytest.raises((InterruptedInBurnIn,)) \
                if stop < SMALL["burn_in"] else _nothing():
            sample(target, "dram", init=init, **SMALL,
                   options=RunOptions(**RUNNER, initial_positions=starts, callback=_stop_at(stop),
                                      sink=sink))
        chunks = read_chunks(folder)
        assert chunks.iterations_done == stop
        attrs = {**saved, "iterations": stop, "interrupted": 1}
        kept = chunks.draws["theta"].shape[1] if chunks.draws else 0
        so_far = inference_data(chunks.draws, attrs) if kept else attrs
        resumed = resume_sampling(target, so_far, chunks.state, options=RunOptions(**RUNNER))
        _same_run(full, resumed)
        assert resumed.attrs["restarted_chains"] == full.attrs["restarted_chains"]


def test_a_stop_inside_the_cut_chunk_takes_the_decision_again(monkeypatch):
    """Ctrl-C while the second half of the chunk in which the burn-in ends runs: the run stops
    at the chunk's start, the decision undone, and resumes to the uninterrupted run."""
    from symplid.sampling import _run as run_module

    target = TwoModes(gap=60.0)
    init, starts = target.map_result(), _starts((3,))
    with pytest.warns(StuckChainsRestarted):
        full = sample(target, "dram", init=init, **SMALL,
                      options=RunOptions(**RUNNER, initial_positions=starts))
    compute = run_module._Loop._compute

    def interrupted_after_the_decision(self, states, start, num_active):
        if start == SMALL["burn_in"]:
            raise KeyboardInterrupt
        return compute(self, states, start, num_active)

    monkeypatch.setattr(run_module._Loop, "_compute", interrupted_after_the_decision)
    with pytest.warns(SamplingInterrupted), pytest.raises(InterruptedInBurnIn) as info:
        sample(target, "dram", init=init, **SMALL,
               options=RunOptions(**RUNNER, initial_positions=starts))
    monkeypatch.setattr(run_module._Loop, "_compute", compute)
    stop = info.value
    assert stop.checkpoint.iterations_done == 80 and "window" in stop.checkpoint.monitor
    with pytest.warns(StuckChainsRestarted):
        resumed = resume_sampling(target, stop.attrs, checkpoint_arrays(stop.checkpoint),
                                  options=RunOptions(**RUNNER))
    _same_run(full, resumed)


def test_the_chunks_seen_from_outside_do_not_change():
    """The sink and the callback see the run's grid of chunks, the burn-in's end inside one."""
    target = TwoModes(gap=60.0)
    seen = []
    with pytest.warns(StuckChainsRestarted):
        sample(target, "dram", init=target.map_result(), **SMALL,
               options=RunOptions(**RUNNER, initial_positions=_starts((0,)),
                                  callback=lambda report: seen.append(report.iterations_done)))
    assert seen == [40, 80, 120, 160, 200, 240]


class _nothing:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def test_a_fit_reports_its_restarted_chains():
    """``summary.json``'s count, the fit's line and the report's paragraph."""
    from types import SimpleNamespace

    from symplid.workflow._fit_command import fit_result_line
    from symplid.workflow._fit_files import fit_summary
    from symplid.workflow._run_tools import _restart_lines

    target = TwoModes(gap=60.0)
    with pytest.warns(StuckChainsRestarted):
        idata = sample(target, "dram", init=target.map_result(),
                       **SMALL, options=RunOptions(**RUNNER, initial_positions=_starts((2,))))
    map_result = SimpleNamespace(theta=np.zeros(2), log_posterior=0.0, log_evidence=0.0)
    summary = fit_summary(target, map_result, idata)
    assert summary["restarted_chains"] == 1
    (line, _) = _restart_lines(idata)
    assert "chain 2 (median log density -6" in line and "10.0 nats" in line
    outcome = SimpleNamespace(summary=summary, interrupted=False,
                              settings=SimpleNamespace(sampler=SimpleNamespace(num_chains=4)))
    assert "1 chain(s) stuck far below the others restarted" in fit_result_line(
        "runs/x", outcome, 1.0)
    quiet = sample(Gaussian2D(), "dram", init=Gaussian2D().map_result(), **SMALL,
                   options=RunOptions(**RUNNER))
    assert fit_summary(target, map_result, quiet)["restarted_chains"] == 0
    assert _restart_lines(quiet) == []
