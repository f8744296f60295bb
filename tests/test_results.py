"""Run folders: the incomplete marker, read-back of every file, JSON conventions, the table."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import NamedTuple

import arviz as az
import jax.numpy as jnp
import matplotlib
import numpy as np
import pytest

from symplid import DataError, Observations
from symplid.workflow._results import (
    RunFolder,
    RunFolderError,
    format_summary,
    read_json,
    to_jsonable,
    write_json,
)
from symplid.workflow._settings import Settings, resolve_for_data, settings_from_dict

matplotlib.use("Agg")


@pytest.fixture
def settings():
    return settings_from_dict({"seed": 3, "initial_state": {"x0": [0.2, -0.25, 0.3, -0.25]}})


@pytest.fixture
def data():
    values = np.arange(12.0).reshape(3, 4) / 7.0
    values[1, 2] = np.nan
    return Observations([0.5, 1.25, 4.0], values, ("q1", "q2", "p1", "p2"))


def _minimal_run(path, settings, data) -> RunFolder:
    run = RunFolder(path)
    run.write_settings(settings)
    run.write_data(data)
    return run


# ----------------------------------------------------------------------------- JSON
class MapLike(NamedTuple):
    theta: object
    log_posterior: float


@dataclass
class Nested:
    name: str
    values: tuple


def test_to_jsonable_converts_arrays_scalars_and_containers():
    obj = {
        "jax": jnp.array([1.0, 2.0]),
        "np_int": np.int32(4),
        "np_float": np.float64(0.5),
        "np_bool": np.bool_(True),
        "matrix": np.eye(2),
        "ints": np.arange(3),
        "named": MapLike(np.array([0.1]), -2.0),
        "dataclass": Nested("x", (1, 2)),
        "nonfinite": [math.nan, math.inf, -math.inf, np.array([1.0, np.nan])],
        "set": {"b", "a"},
        3: None,
    }
    out = to_jsonable(obj)
    assert out == {
        "jax": [1.0, 2.0],
        "np_int": 4,
        "np_float": 0.5,
        "np_bool": True,
        "matrix": [[1.0, 0.0], [0.0, 1.0]],
        "ints": [0, 1, 2],
        "named": {"theta": [0.1], "log_posterior": -2.0},
        "dataclass": {"name": "x", "values": [1, 2]},
        "nonfinite": ["nan", "inf", "-inf", [1.0, "nan"]],
        "set": ["a", "b"],
        "3": None,
    }
    json.dumps(out, allow_nan=False)  # strict JSON
    with pytest.raises(TypeError, match=r"at a\.b"):
        to_jsonable({"a": {"b": object()}})


def test_json_round_trip_keeps_nonfinite(tmp_path):
    path = write_json({"x": [1.5, math.nan, -math.inf], "s": "text"}, tmp_path / "a.json")
    text = path.read_text()
    assert "NaN" not in text and "Infinity" not in text
    back = read_json(path)
    assert back["s"] == "text" and back["x"][0] == 1.5
    assert math.isnan(back["x"][1]) and back["x"][2] == -math.inf
    with pytest.raises(RunFolderError, match="no such file"):
        read_json(tmp_path / "missing.json")


# ----------------------------------------------------------------------------- the marker
def test_new_run_is_incomplete_until_finished(tmp_path, settings, data):
    run = _minimal_run(tmp_path / "run", settings, data)
    assert (tmp_path / "run" / ".incomplete").exists()
    assert not run.is_complete and run.incomplete_reason == "run started"
    with pytest.raises(RunFolderError, match="did not finish"):
        RunFolder(tmp_path / "run", "r")
    peek = RunFolder(tmp_path / "run", "r", allow_incomplete=True)
    assert peek.read_settings() == settings
    run.finish()
    assert run.is_complete and run.incomplete_reason is None
    assert RunFolder(tmp_path / "run", "r").is_complete


def test_a_run_that_dies_midway_stays_incomplete(tmp_path, settings, data):
    """Nothing is cleaned up when the writer disappears: the marker was written first."""
    run = _minimal_run(tmp_path / "run", settings, data)
    run.write_json("map.json", {"theta": [1.0]})
    del run
    with pytest.raises(RunFolderError, match="did not finish"):
        RunFolder(tmp_path / "run", "r")


def test_context_manager_records_failure_and_finishes_on_success(tmp_path, settings, data):
    with pytest.raises(ZeroDivisionError), RunFolder(tmp_path / "bad") as run:
        run.write_settings(settings)
        run.write_data(data)
        1 / 0
    bad = RunFolder(tmp_path / "bad", "r", allow_incomplete=True)
    assert bad.incomplete_reason == "failed: ZeroDivisionError: division by zero"
    with pytest.raises(RunFolderError, match="failed: ZeroDivisionError"):
        RunFolder(tmp_path / "bad", "r")

    with RunFolder(tmp_path / "good") as run:
        run.write_settings(settings)
        run.write_data(data)
    assert RunFolder(tmp_path / "good", "r").is_complete


def test_finish_requires_settings_and_data(tmp_path, settings):
    run = RunFolder(tmp_path / "run")
    run.write_settings(settings)
    with pytest.raises(RuntimeError, match=r"missing data\.csv"):
        run.finish()
    assert not run.is_complete
    run.finish(required=())
    assert run.is_complete


def test_no_writes_after_finish_or_when_reading(tmp_path, settings, data):
    run = _minimal_run(tmp_path / "run", settings, data)
    run.finish()
    with pytest.raises(RuntimeError, match="already finished"):
        run.write_report("late")
    reader = RunFolder(tmp_path / "run", "r")
    with pytest.raises(RuntimeError, match="read-only"):
        reader.write_summary({"x": 1})


def test_append_mode_marks_until_finished(tmp_path, settings, data):
    _minimal_run(tmp_path / "run", settings, data).finish()
    update = RunFolder(tmp_path / "run", "a")
    assert update.incomplete_reason == "update started"
    update.write_report("# predictions")
    update.finish()
    assert RunFolder(tmp_path / "run", "r").read_report() == "# predictions\n"


def test_existing_folders(tmp_path, settings, data):
    _minimal_run(tmp_path / "run", settings, data).finish()
    (tmp_path / "run" / "notes.txt").write_text("mine")
    with pytest.raises(RunFolderError, match="already exists and is not empty"):
        RunFolder(tmp_path / "run")
    again = RunFolder(tmp_path / "run", overwrite=True)
    assert not (tmp_path / "run" / "settings.toml").exists()
    assert (tmp_path / "run" / "notes.txt").read_text() == "mine"  # not a run file: kept
    assert not again.is_complete

    other = tmp_path / "other"
    other.mkdir()
    (other / "thesis.tex").write_text("precious")
    with pytest.raises(RunFolderError, match="not a run folder"):
        RunFolder(other, overwrite=True)
    assert (other / "thesis.tex").exists()

    (tmp_path / "empty").mkdir()
    RunFolder(tmp_path / "empty")  # an empty folder is fine
    (tmp_path / "file").write_text("x")
    with pytest.raises(RunFolderError, match="not a folder"):
        RunFolder(tmp_path / "file")


@pytest.mark.parametrize(
    ("setup", "words"),
    [
        (lambda p: None, "no such run folder"),
        (lambda p: p.mkdir(), "not a run folder"),
    ],
)
def test_reading_what_is_not_a_run(tmp_path, setup, words):
    setup(tmp_path / "x")
    with pytest.raises(RunFolderError, match=words) as info:
        RunFolder(tmp_path / "x", "r")
    assert isinstance(info.value, DataError)  # the CLI catches it with the data errors


# ----------------------------------------------------------------------------- read back
def test_every_file_reads_back(tmp_path, settings, data):
    import matplotlib.pyplot as plt

    rng = np.random.default_rng(0)
    hessian = rng.normal(size=(3, 3))
    hessian = hessian @ hessian.T
    draws = rng.normal(size=(2, 50, 3))
    idata = az.from_dict(
        posterior={"theta": draws},
        sample_stats={"acceptance_rate": rng.uniform(size=(2, 50))},
        attrs={"seed": 3, "settings": {"x0": [0.2, -0.25]}, "hessian": hessian, "ok": True},
    )
    summary = {
        "true_hamiltonian": 0.12271,
        "leapfrog": {"map_hamiltonian": 0.1219, "rhat_max": 1.002},
        "rk2": {"map_hamiltonian": 0.1211, "rhat_max": math.nan},
        "seed": 3,
    }
    with RunFolder(tmp_path / "run") as run:
        run.write_settings(settings)
        run.write_data(data)
        run.write_map(
            MapLike(jnp.array([0.5, -1.0, 2e-6]), -12.5),
            hessian=hessian,
            param_names=["a", "b", "process_var"],
        )
        run.write_posterior(idata)
        run.write_summary(summary, table="extra table line")
        fig, ax = plt.subplots()
        ax.plot([0, 1], [1, 0])
        run.save_figure(fig, "fig1_phase")
        plt.close(fig)
        run.write_report("# Report\n![phase](figures/fig1_phase.png)")

    run = RunFolder(tmp_path / "run", "r")
    assert run.read_settings() == settings
    back = run.read_data()
    np.testing.assert_array_equal(back.values, data.values)
    np.testing.assert_array_equal(back.times, data.times)

    map_result = run.read_map()
    np.testing.assert_array_equal(map_result["theta"], [0.5, -1.0, 2e-6])
    np.testing.assert_array_equal(map_result["hessian"], hessian)
    assert map_result["log_posterior"] == -12.5
    assert map_result["param_names"] == ["a", "b", "process_var"]

    post = run.read_posterior()
    np.testing.assert_array_equal(post.posterior["theta"].values, draws)
    assert post.posterior["theta"].shape[:2] == (2, 50)
    np.testing.assert_array_equal(post.attrs["hessian"], hessian)
    assert post.attrs["ok"] is True and post.attrs["seed"] == 3
    np.testing.assert_array_equal(post.attrs["settings"]["x0"], [0.2, -0.25])

    back_summary = run.read_summary()
    assert back_summary["leapfrog"] == summary["leapfrog"]
    assert math.isnan(back_summary["rk2"]["rhat_max"])
    text = (tmp_path / "run" / "summary.txt").read_text()
    assert "extra table line" in text and "0.12271" in text

    (figure,) = run.figures()
    assert figure.name == "fig1_phase.png"
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "figures/fig1_phase.png" in run.read_report()
    hidden = [p.name for p in (tmp_path / "run").rglob(".*")]
    assert hidden == []  # no marker, no temporary files left


def test_missing_file_in_a_run(tmp_path, settings, data):
    _minimal_run(tmp_path / "run", settings, data).finish()
    with pytest.raises(RunFolderError, match=r"this run has no posterior\.nc"):
        RunFolder(tmp_path / "run", "r").read_posterior()


def test_simulated_run_settings_are_the_resolved_ones(tmp_path, hh_data):
    data = hh_data
    resolved = resolve_for_data(
        settings_from_dict({"initial_state": {"x0": [0.2, -0.25, 0.3, -0.25]}}), data
    )
    with RunFolder(tmp_path / "run") as run:
        run.write_settings(resolved)
        run.write_data(data)
    back = RunFolder(tmp_path / "run", "r").read_settings()
    assert back == resolved and back.model.observation == "full"
    assert back != Settings()


# ----------------------------------------------------------------------------- summary table
def test_format_summary_table():
    text = format_summary(
        {
            "true_hamiltonian": 0.122714,
            "leapfrog": {"map_hamiltonian": 0.1219, "acceptance_rate": 0.25},
            "rk2": {"map_hamiltonian": 0.1211, "extra": {"a": 1}},
            "seed": 0,
            "ok": True,
            "missing": None,
        }
    )
    lines = text.splitlines()
    rows = {line.split()[0]: line.split()[1:] for line in lines if line.strip()}
    assert rows["true_hamiltonian"] == ["0.122714"]
    assert rows["seed"] == ["0"] and rows["ok"] == ["true"] and rows["missing"] == ["—"]
    assert rows["leapfrog"] == ["rk2"]  # the header row of the table
    assert rows["map_hamiltonian"] == ["0.1219", "0.1211"]
    assert rows["acceptance_rate"] == ["0.25", "—"]
    assert rows["extra.a"] == ["—", "1"]
