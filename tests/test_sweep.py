"""Sweeps on Dask and the paper-claims study.

The cell functions are the stand-ins of ``sweep_cells.py`` (real but cheap work with the core).
One local cluster of two workers is shared by the tests that need a cluster but not the
default one; the 4-cell sweep starts its own through ``run_sweep`` (the default path).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

import sweep_cells
import symplid
from symplid.studies._paper import CELL_KEYS, cell_data
from symplid.studies._paper_study import (
    evaluate_claims,
    paper_claims_spec,
    run_paper_claims,
    select_variants,
)
from symplid.workflow._results import read_json
from symplid.workflow._sweep import (
    SweepError,
    _write_manifest,
    cell_settings,
    load_results,
    load_sweep_spec,
    run_sweep,
    sweep_spec_from_dict,
    worker_environment,
)
from symplid.workflow._sweep_results import MANIFEST
from symplid.workflow._sweep_tasks import same_cell_fn

TESTS_DIR = Path(__file__).resolve().parent
SMALL = {"base": {"num_iterations": 20, "burn_in": 10}}


def _test_cache_env() -> dict[str, str]:
    """The workers use the tests' compilation cache (set up in conftest.py), or none."""
    import jax

    return {"SYMPLID_CACHE_DIR": jax.config.jax_compilation_cache_dir or "off"}


def _calls(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.glob("*.call"))


def _small_spec(seeds=(0, 1), **sweep) -> dict:
    grid = {"seed": list(seeds), "integrator": ["leapfrog", "rk2-midpoint"]}
    return {**SMALL, "sweep": {"grid": grid, **sweep}}


# ----------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def shared_cluster(tmp_path_factory):
    """Two single-threaded worker processes with the sweep's worker environment."""
    from dask.distributed import LocalCluster

    calls = tmp_path_factory.mktemp("shared-calls")
    flag = tmp_path_factory.mktemp("flag") / "fail-now"
    env = worker_environment(
        {
            "PYTHONPATH": str(TESTS_DIR),
            sweep_cells.CALLS_ENV: str(calls),
            sweep_cells.FAIL_ENV: str(flag),
            **_test_cache_env(),
        }
    )
    with LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        processes=True,
        env=env,
        dashboard_address="127.0.0.1:0",  # a free port: no clash with other clusters
        silence_logs=logging.ERROR,
    ) as cluster:
        yield SimpleNamespace(address=cluster.scheduler_address, calls=calls, flag=flag)


@pytest.fixture(scope="module")
def four_cells(tmp_path_factory):
    """A 4-cell sweep (2 seeds × 2 propagators) run by run_sweep's own 2-worker cluster."""
    out = tmp_path_factory.mktemp("four-cells")
    calls = tmp_path_factory.mktemp("four-calls")
    spec = sweep_spec_from_dict(_small_spec(), source="four.toml")
    table = run_sweep(
        spec,
        out,
        workers=2,
        cell_fn="sweep_cells:loglik_cell",
        progress=False,
        worker_env={
            "PYTHONPATH": str(TESTS_DIR),
            sweep_cells.CALLS_ENV: str(calls),
            **_test_cache_env(),
        },
    )
    return SimpleNamespace(spec=spec, out=out, calls=calls, table=table)


# ----------------------------------------------------------------------------- running
def test_four_cell_sweep_on_two_workers(four_cells):
    table, spec, out = four_cells.table, four_cells.spec, four_cells.out
    assert table.attrs["sweep"]["ran"] == 4 and table.attrs["sweep"]["failed"] == 0
    assert list(table["status"]) == ["ok"] * 4
    assert len(_calls(four_cells.calls)) == 4
    assert sorted(p.stem for p in (out / "cells").glob("*.json")) == sorted(spec.ids)
    # one row per cell, in the spec's order: the grid product, last key fastest
    assert list(zip(table["seed"], table["integrator"], strict=True)) == [
        (0, "leapfrog"),
        (0, "rk2-midpoint"),
        (1, "leapfrog"),
        (1, "rk2-midpoint"),
    ]
    for row in table.itertuples():
        cell = spec.cells[row.Index].settings
        # the data: an independent call of the simulator with the cell's settings spelt out
        data = symplid.simulate("henon-heiles", times=5.0 * np.arange(1, 21), seed=row.seed)
        assert row.first_obs_q1 == data.values[0, 0]
        # the log-likelihood computed in the worker equals this process's, to float64 rounding
        assert row.loglik == pytest.approx(sweep_cells.loglik_at_truth(cell), rel=1e-12)
        assert row.x64
        assert "--xla_cpu_multi_thread_eigen=false" in row.xla_flags
        assert row.elapsed_s > 0
        assert row.warnings == f"UserWarning: stand-in warning for seed {row.seed}"
    assert table["pid"].nunique() <= 2
    # the workers share the tests' compilation cache
    record = read_json(out / "cells" / f"{row.cell_id}.json")
    assert record["worker"]["jax_cache"] == _test_cache_env()["SYMPLID_CACHE_DIR"]
    # the leapfrog model at the truth explains the data better than RK2 at dt = 0.25
    by = table.set_index(["seed", "integrator"])["loglik"]
    assert by[(0, "leapfrog")] > by[(0, "rk2-midpoint")]


def test_results_files_hold_the_same_table(four_cells):
    out, table = four_cells.out, four_cells.table
    csv = pd.read_csv(out / "results.csv")
    parquet = pd.read_parquet(out / "results.parquet")
    assert list(csv.columns) == list(table.columns) == list(parquet.columns)
    pd.testing.assert_frame_equal(parquet, table)
    for col in ("cell_id", "seed", "integrator", "status"):
        assert list(csv[col]) == list(table[col])
    for col in ("dt", "loglik", "elapsed_s"):
        np.testing.assert_allclose(csv[col], table[col], rtol=1e-15)
    assert list(load_results(out)["cell_id"]) == list(table["cell_id"])
    record = read_json(out / "cells" / f"{table['cell_id'][0]}.json")
    assert record["cell_fn"] == "sweep_cells:loglik_cell"
    assert record["settings"] == four_cells.spec.cells[0].settings
    assert record["status"] == "ok" and record["error"] is None
    # one figure per numeric metric of the stand-in
    for metric in ("loglik", "first_obs_q1"):
        assert (out / "figures" / f"{metric}.png").read_bytes()[:4] == b"\x89PNG"


def test_rerun_skips_finished_cells(four_cells):
    out = four_cells.out
    before = {p.name: read_json(p)["started"] for p in (out / "cells").glob("*.json")}
    mtimes = {p.name: p.stat().st_mtime_ns for p in (out / "cells").glob("*.json")}
    table = run_sweep(four_cells.spec, out, cell_fn="sweep_cells:loglik_cell", progress=False)
    assert table.attrs["sweep"]["skipped"] == 4 and table.attrs["sweep"]["ran"] == 0
    assert len(_calls(four_cells.calls)) == 4  # the cell function did not run again
    after = {p.name: read_json(p)["started"] for p in (out / "cells").glob("*.json")}
    assert after == before
    assert {p.name: p.stat().st_mtime_ns for p in (out / "cells").glob("*.json")} == mtimes
    pd.testing.assert_frame_equal(table, four_cells.table)


def test_another_cell_function_in_the_same_folder_is_refused(four_cells):
    with pytest.raises(SweepError, match="cell_fn 'sweep_cells:loglik_cell'"):
        run_sweep(four_cells.spec, four_cells.out, cell_fn="sweep_cells:flaky_cell")


def test_a_folder_of_the_previous_version_names_the_same_cell_function(tmp_path):
    """A manifest written before the modules became private names the study's cell function
    by its old path: the same function, so the folder is resumed, not refused."""
    old = "symplid.studies.paper:run_cell"
    assert same_cell_fn(old, "symplid.studies._paper:run_cell")
    assert not same_cell_fn(old, "symplid.studies._paper:cell_data")
    assert not same_cell_fn("sweep_cells:loglik_cell", "sweep_cells:flaky_cell")
    spec = sweep_spec_from_dict(_small_spec(), "<test>")
    (tmp_path / MANIFEST).write_text(json.dumps({"cell_fn": old}), encoding="utf-8")
    _write_manifest(tmp_path, spec, "symplid.studies._paper:run_cell")
    assert read_json(tmp_path / MANIFEST)["cell_fn"] == "symplid.studies._paper:run_cell"
    with pytest.raises(SweepError, match="not 'sweep_cells:loglik_cell'"):
        _write_manifest(tmp_path, spec, "sweep_cells:loglik_cell")


def test_failing_cell_is_recorded_and_retried(shared_cluster, tmp_path):
    out = tmp_path / "flaky"
    calls = shared_cluster.calls
    shared_cluster.flag.write_text("fail\n")
    n0 = len(_calls(calls))
    spec = sweep_spec_from_dict(_small_spec(seeds=(0, 1)), source="flaky.toml")
    table = run_sweep(
        spec,
        out,
        scheduler=shared_cluster.address,
        cell_fn=sweep_cells.flaky_cell,
        progress=False,
        figures=False,
    )
    assert len(_calls(calls)) - n0 == 4
    failed = table[table["status"] == "failed"]
    assert list(failed["seed"]) == [1, 1]
    assert (table[table["seed"] == 0]["status"] == "ok").all()
    assert failed["loglik"].isna().all() and table[table["seed"] == 0]["loglik"].notna().all()
    assert failed["error"].str.startswith("RuntimeError: planned failure for seed 1").all()
    record = read_json(out / "cells" / f"{failed['cell_id'].iloc[0]}.json")
    assert "flaky_cell" in record["traceback"] and "Traceback" in record["traceback"]
    assert record["cell_fn"] == "sweep_cells:flaky_cell"
    # the rerun retries only the two failed cells
    shared_cluster.flag.unlink()
    table = run_sweep(
        spec,
        out,
        scheduler=shared_cluster.address,
        cell_fn=sweep_cells.flaky_cell,
        progress=False,
        figures=False,
    )
    assert len(_calls(calls)) - n0 == 6
    assert table.attrs["sweep"]["skipped"] == 2 and table.attrs["sweep"]["ran"] == 2
    assert list(table["status"]) == ["ok"] * 4


_STOPPED_SWEEP = """
import signal, sys
signal.signal(signal.SIGINT, signal.default_int_handler)  # not ignored in a background job
sys.path.insert(0, {tests!r})
from symplid.studies._paper import EXPERIMENT
from symplid.workflow._sweep import run_sweep

if __name__ == "__main__":
    spec = {{"base": {{"num_iterations": 20, "burn_in": 10}},
            "sweep": {{"grid": {{"seed": [0, 1, 2]}}}}}}
    run_sweep(spec, {out!r}, workers=2, cell_fn="sweep_cells:slow_cell", progress=False,
              figures=False, experiment=EXPERIMENT,
              worker_env={{"PYTHONPATH": {tests!r}, {env!r}: {calls!r},
                          "SYMPLID_CACHE_DIR": "off"}})
"""


def _alive(pid: int) -> bool:
    """Whether the process runs (a zombie left for its new parent to reap does not)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return True
    return state != "Z"


@pytest.mark.skipif(os.name != "posix", reason="sends SIGINT")
def test_ctrl_c_ends_a_local_sweep_without_waiting_for_its_cells(tmp_path):
    """Ctrl-C while two workers run ten-minute cells: the sweep stops within seconds, its
    worker processes are gone, and no cell is recorded (a rerun runs them)."""
    calls = tmp_path / "calls"
    calls.mkdir()
    script = tmp_path / "sweep.py"
    script.write_text(_STOPPED_SWEEP.format(tests=str(TESTS_DIR), out=str(tmp_path / "out"),
                                            env=sweep_cells.CALLS_ENV, calls=str(calls)))
    log = tmp_path / "stderr.txt"
    with log.open("w") as err:
        proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.DEVNULL,
                                stderr=err)
    try:
        deadline = time.monotonic() + 120.0
        while len(_calls(calls)) < 2 and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.2)
        assert len(_calls(calls)) == 2, log.read_text()
        workers = [int(p.read_text()) for p in calls.glob("*.call")]
        start = time.monotonic()
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=60)
        stopped = time.monotonic() - start
    finally:
        proc.kill()
        proc.wait()
    assert proc.returncode != 0
    # Closing the cluster gracefully waits about 5 s for the running cells (then kills them).
    assert stopped < 3.0, f"the sweep took {stopped:.1f} s to stop"
    for _ in range(50):
        if not any(_alive(pid) for pid in workers):
            break
        time.sleep(0.1)
    assert not any(_alive(pid) for pid in workers)
    assert not list((tmp_path / "out" / "cells").glob("*.json"))


def test_unimportable_cell_function_is_a_clear_error(tmp_path):
    with pytest.raises(ValueError, match="cannot import 'no_such_module'"):
        run_sweep(_small_spec(), tmp_path, cell_fn="no_such_module:run")
    with pytest.raises(ValueError, match="has no function 'nothing'"):
        run_sweep(_small_spec(), tmp_path, cell_fn="sweep_cells:nothing")
    with pytest.raises(ValueError, match="do not give it with scheduler"):
        run_sweep(_small_spec(), tmp_path, scheduler="tcp://127.0.0.1:1", workers=2)


# ----------------------------------------------------------------------------- spec
def test_grid_and_cells_combine_and_ids_are_stable(tmp_path):
    path = tmp_path / "sweep.toml"
    path.write_text(
        """
[base]
num_iterations = 2000
burn_in = 1000

[sweep]
name = "demo"
grid = { seed = [0, 1], integrator = ["leapfrog", "RK2"] }
cells = [{}, { dt = 0.1 }, { noise_std = 0.01, "model.process_noise_per" = "step" }]
"""
    )
    spec = load_sweep_spec(path)
    assert spec.name == "demo" and len(spec.cells) == 12
    assert {c.settings["integrator"] for c in spec.cells} == {"leapfrog", "rk2-midpoint"}
    assert [c.settings["dt"] for c in spec.cells] == [0.25] * 4 + [0.1] * 4 + [0.25] * 4
    last = spec.cells[-1].settings
    assert last["noise_std"] == 0.01 and last["model.process_noise_per"] == "step"
    assert list(last)[: len(CELL_KEYS)] == list(CELL_KEYS)
    # the id is SHA-256 of the sorted JSON of every setting, defaults included
    for cell in spec.cells:
        text = json.dumps(cell.settings, sort_keys=True, separators=(",", ":"))
        assert cell.id == hashlib.sha256(text.encode()).hexdigest()[:12]
    # explicit defaults and another key order give the same ids; a changed value another id
    explicit = dict(reversed(list(spec.cells[0].settings.items())))
    same = sweep_spec_from_dict({"base": explicit})
    assert same.ids == [spec.cells[0].id]
    other = sweep_spec_from_dict({"base": {**explicit, "dt": 0.2500001}})
    assert other.ids != same.ids
    assert len(set(spec.ids)) == 12


def test_cell_settings_and_data():
    spec = sweep_spec_from_dict(
        {"base": {"seed": 3, "dt": 0.1, "num_obs": 5, "obs_interval": 2.0, "num_chains": 2}}
    )
    cell = spec.cells[0].settings
    settings = cell_settings(cell)
    assert settings.model.dt == 0.1 and settings.sampler.num_chains == 2
    assert settings.seed == settings.map.seed == settings.sampler.seed == 3
    assert settings.initial_state.x0 == (0.2, -0.25, 0.3, -0.25)
    system, data = cell_data(cell)
    np.testing.assert_array_equal(data.times, [2.0, 4.0, 6.0, 8.0, 10.0])
    direct = symplid.simulate(system, times=data.times, noise_std=0.05, seed=3)
    np.testing.assert_array_equal(data.values, direct.values)


BAD_SPECS = [
    ("[base]\nnois_std = 0.1\n", "unknown key 'nois_std' in [base]; did you mean 'noise_std'?"),
    ("[base]\ndt = -0.25\n", "[base] dt must be > 0, got -0.25"),
    ("[base]\nnum_chains = 2.5\n", "[base] num_chains must be an integer, got 2.5"),
    ("[base]\nintegrator = 'leapfrg'\n", "not a known integrator; did you mean 'leapfrog'?"),
    ("[base]\nsystem = 'henon'\n", "[base] system must be one of"),
    ("[sweep]\ngrid = { seed = 3 }\n", "sweep.grid.seed must be a list of values"),
    ("[sweep]\ngrid = { seed = [] }\n", "sweep.grid.seed is an empty list"),
    ("[sweep]\ngrid = { sed = [1] }\n", "unknown key 'sed' in sweep.grid; did you mean 'seed'?"),
    ("[sweep]\ngrid = { dt = [0.1, 0.1] }\n", "same resolved settings as the cell at grid point"),
    (
        "[sweep]\ngrid = { dt = [0.1] }\ncells = [{ dt = 0.5 }]\n",
        "sweep.cells[0].dt is also a sweep.grid axis",
    ),
    ("[sweep]\ncells = []\n", "sweep.cells must be a non-empty list"),
    ("[sweep]\ncell = [{}]\n", "unknown key 'cell' in [sweep]; did you mean 'cells'?"),
    ("[sweep]\ncell_fn = 'run_cell'\n", "sweep.cell_fn must be a 'module:function' string"),
    ("[bases]\ndt = 0.1\n", "unknown table [bases]; did you mean 'base'?"),
    ("[base]\nnum_iterations = 100\nburn_in = 100\n", "num_iterations (100) must be greater than"),
    ("[base]\n'model.dt' = 0.1\n", "is set by the short key 'dt' in a sweep"),
    ("[base]\n'sampler.gama' = 0.1\n", "did you mean 'sampler.gamma'?"),
    ("[base]\n'sampler.gamma' = -1.0\n", "sampler.gamma must be > 0"),
    ("[base\n", "not valid TOML"),
]


@pytest.mark.parametrize(("text", "message"), BAD_SPECS)
def test_bad_spec_names_the_file_and_the_key(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(SweepError) as info:
        load_sweep_spec(path)
    assert str(info.value).startswith(f"{path}: ")
    assert message in str(info.value)


def test_missing_spec_file(tmp_path):
    with pytest.raises(SweepError, match="no such sweep spec file"):
        load_sweep_spec(tmp_path / "nope.toml")


# ----------------------------------------------------------------------------- the study
def test_paper_claims_study_end_to_end(shared_cluster, tmp_path):
    out = tmp_path / "study"
    claims = run_paper_claims(
        out,
        seeds=2,
        budget="quick",
        scheduler=shared_cluster.address,
        variants="none",
        cell_fn="sweep_cells:claims_cell",
        progress=False,
    )
    stored = read_json(out / "claims.json")
    table = load_results(out)
    again = evaluate_claims(table, select_variants("none"))
    assert stored["claims"] == json.loads(json.dumps(again["claims"]))
    # two seeds × leapfrog, RK2 and yoshida4 (the calibration's third propagator)
    assert stored["study"]["cells"] == 6 and stored["study"]["cells_failed"] == 0
    assert claims["variants"][0]["name"] == "paper"
    # the stand-in makes RK2's horizon 130 s shorter and its H error twice leapfrog's
    assert claims["claims"]["prediction"]["per_variant"][0]["fraction"] == 1.0
    assert claims["claims"]["hamiltonian"]["per_variant"][0]["fraction"] == 1.0
    report = (out / "report.md").read_text()
    for name in ("claim_hamiltonian", "claim_process_noise", "claim_prediction"):
        png = out / "figures" / f"{name}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert f"(figures/{name}.png)" in report
    assert "| paper | rk2-midpoint | 2 | 2 |" in report

    # --report-only over more seeds than ran: nothing runs, the missing cells are pending and
    # out of every fraction.
    partial = run_paper_claims(out, seeds=3, budget="quick", variants="none",
                               report_only=True, progress=False)
    assert len(list((out / "cells").glob("*.json"))) == 6
    assert partial["study"]["cells"] == 9 and partial["study"]["cells_pending"] == 3
    assert partial["study"]["cells_failed"] == 0 and partial["study"]["failures"] == []
    assert (partial["study"]["cells_run"], partial["study"]["cells_skipped"]) == (0, 6)
    assert partial["variants"][0]["seeds"] == 2 and partial["variants"][0]["unpaired"] == 0
    assert partial["claims"] == claims["claims"]
    assert "3 not run yet" in (out / "report.md").read_text()
    with pytest.raises(FileNotFoundError, match="no cells to report on"):
        run_paper_claims(tmp_path / "empty", seeds=2, report_only=True, progress=False)


# ----------------------------------------------------------------------------- the real cell
PAPER_METRICS = (
    "map_hamiltonian",
    "true_hamiltonian",
    "hamiltonian_rel_error",
    "process_noise_map",
    "process_noise_median",
    "process_noise_q025",
    "process_noise_q975",
    "prediction_horizon_s",
    "acceptance_rate",
    "rhat_max",
    "ess_min",
    "wall_time_s",
)


def _has_run_cell() -> bool:
    try:
        from symplid.studies import _paper as paper
    except ImportError:
        return False
    return callable(getattr(paper, "run_cell", None))


@pytest.mark.slow
@pytest.mark.skipif(
    not _has_run_cell(), reason="symplid.studies._paper.run_cell not written yet"
)
def test_paper_run_cell_on_a_two_cell_sweep(tmp_path):
    """The real cell function (quick budget): seed 0, leapfrog and RK2, on 2 local workers."""
    spec = paper_claims_spec(seeds=1, budget="quick", variants="none")
    table = run_sweep(
        spec, tmp_path, workers=2, progress=False, figures=False, worker_env=_test_cache_env()
    )
    assert list(table["status"]) == ["ok"] * 3, list(table["error"])
    for metric in PAPER_METRICS:
        assert metric in table.columns
    system = symplid.get_system("henon-heiles")
    h_true = float(symplid.hamiltonian(system.potential, system.coefficients, system.initial_state))
    np.testing.assert_allclose(table["true_hamiltonian"], h_true, rtol=1e-12)
    rel = (table["map_hamiltonian"] - h_true).abs() / h_true
    np.testing.assert_allclose(table["hamiltonian_rel_error"], rel, rtol=1e-9)
    q = table[["process_noise_q025", "process_noise_median", "process_noise_q975"]].to_numpy()
    assert (q[:, 0] <= q[:, 1]).all() and (q[:, 1] <= q[:, 2]).all()
    assert ((table["prediction_horizon_s"] > 0) & (table["prediction_horizon_s"] <= 200)).all()
    claims = evaluate_claims(table, select_variants("none"))
    assert all(c["per_variant"][0]["n"] == 1 for c in claims["claims"].values())
    # calibration: the truth's rank among 99 thinned draws, σ² as the true noise variance
    assert table["calibration.c[q1^2].rank"].between(0, 99).all()
    np.testing.assert_allclose(table["calibration.obs_var.truth"], 0.05**2)
    inside = (table["calibration.c[q2^3].q025"] <= -1 / 3) & (table[
        "calibration.c[q2^3].q975"] >= -1 / 3)
    assert (inside == table["calibration.c[q2^3].covered"].astype(bool)).all()


# ----------------------------------------------------------------------------- experiments
def test_old_num_samples_key_is_read_with_a_future_warning():
    with pytest.warns(FutureWarning, match=r"num_samples in \[base\] is deprecated; use num_iter"):
        spec = sweep_spec_from_dict({"base": {"num_samples": 20, "burn_in": 10}})
    assert spec.cells[0].settings["num_iterations"] == 20
    assert cell_settings(spec.cells[0].settings).sampler.num_iterations == 20


def test_an_experiment_registered_here_runs_through_run_sweep(shared_cluster, tmp_path):
    from symplid.workflow._experiment import EXPERIMENTS, Experiment
    from symplid.workflow._validate import Spec

    keys = {
        "seed": Spec(int, 0, "data seed", minimum=0, setting="seed"),
        "integrator": Spec(str, "leapfrog", "propagator", choices=symplid.INTEGRATORS,
                           setting="model.integrator"),
        "dt": Spec(float, 0.25, "step", minimum=0.0, strict=True, setting="model.dt"),
        "order": Spec(int, 3, "order", minimum=1, setting="model.order"),
        "noise_std": Spec(float, 0.05, "noise", minimum=0.0),
    }
    EXPERIMENTS.register(
        "toy", Experiment("toy", keys, "sweep_cells:loglik_cell", metrics=("loglik",))
    )
    try:
        spec = sweep_spec_from_dict(
            {"sweep": {"experiment": "toy", "grid": {"integrator": ["leapfrog", "RK2"]}}}
        )
        assert list(spec.cells[0].settings) == list(keys)
        table = run_sweep(spec, tmp_path, scheduler=shared_cluster.address, progress=False)
        assert list(table["status"]) == ["ok", "ok"], list(table["error"])
        assert list(table["integrator"]) == ["leapfrog", "rk2-midpoint"]
        assert read_json(tmp_path / "sweep.json")["experiment"] == "toy"
        assert [p.name for p in (tmp_path / "figures").glob("*.png")] == ["loglik.png"]
        with pytest.raises(SweepError, match=r"unknown key 'system' in \[base\]"):
            sweep_spec_from_dict({"base": {"system": "harmonic"}, "sweep": {"experiment": "toy"}})
    finally:
        EXPERIMENTS.unregister("toy")
    with pytest.raises(SweepError, match="unknown experiment 'toy'"):
        sweep_spec_from_dict({"sweep": {"experiment": "toy"}})


# ----------------------------------------------------------------------------- wiring
def test_the_sweep_is_given_its_experiment_and_checks_the_name_the_spec_gives(tmp_path):
    """A spec that names another experiment than the one given is refused before any cell
    runs; one that names none takes the given experiment's keys (here the baselines')."""
    from symplid.studies import _baselines_study as baselines_study
    from symplid.studies import _paper as paper

    with pytest.raises(SweepError, match="is 'paper', but the sweep was given the experiment "
                                         "'baselines'"):
        sweep_spec_from_dict({"sweep": {"experiment": "paper"}},
                             experiment=baselines_study.EXPERIMENT)
    spec = sweep_spec_from_dict({"sweep": {"grid": {"method": ["hnn", "euler"]}}},
                                experiment=baselines_study.EXPERIMENT)
    assert spec.experiment == "baselines"
    assert list(spec.cells[0].settings) == list(baselines_study.CELL_KEYS)
    with pytest.raises(SweepError, match="but the sweep was given the experiment 'baselines'"):
        run_sweep(sweep_spec_from_dict({}, experiment=paper.EXPERIMENT), tmp_path / "out",
                  experiment=baselines_study.EXPERIMENT, progress=False)
    assert not (tmp_path / "out").exists()


def test_register_studies_lists_each_study_once_and_is_idempotent():
    from symplid._registry import Registry
    from symplid.studies import STUDIES, register_studies
    from symplid.studies import _baselines_study as baselines_study
    from symplid.studies import _paper as paper
    from symplid.studies import _sbc as sbc
    from symplid.studies import _sbc_defaults as sbc_defaults
    from symplid.studies import _shift as shift
    from symplid.workflow._sweep import get_experiment

    assert STUDIES == (paper.EXPERIMENT, baselines_study.EXPERIMENT, sbc.EXPERIMENT,
                       sbc_defaults.EXPERIMENT, shift.EXPERIMENT)
    registry = Registry("experiment")
    with pytest.raises(SweepError, match="no experiment is registered"):
        get_experiment("paper", "s.toml", registry)
    register_studies(registry)
    register_studies(registry)  # again: nothing changes
    assert registry.names() == ("paper", "baselines", "sbc", "sbc-defaults", "shift")
    assert registry["paper"] is paper.EXPERIMENT
    other = Registry("experiment")
    other.register("paper", baselines_study.EXPERIMENT)
    with pytest.raises(ValueError, match="named 'paper' is registered already"):
        register_studies(other)


def test_the_sweep_command_names_an_unknown_experiment_in_one_line(tmp_path):
    from click.testing import CliRunner

    from symplid.cli import main

    spec = tmp_path / "s.toml"
    spec.write_text('[sweep]\nexperiment = "paperr"\n', encoding="utf-8")
    result = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2, result.output
    assert result.stderr.strip().splitlines() == [
        f"symplid: error: {spec}: sweep.experiment is 'paperr': unknown experiment 'paperr' "
        "(did you mean 'paper'?); choose one of paper, baselines, sbc, sbc-defaults, shift"]
