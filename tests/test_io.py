"""Data files: CSV and NPZ round trips (NaN, irregular times) and every bad-input message."""

from __future__ import annotations

import numpy as np
import pytest

import symplid
from symplid import DataError, Observations
from symplid.io import (
    Layout,
    column_names,
    observation_kind,
    observation_layout,
    positions_only,
    read_observations,
    write_observations,
)


@pytest.fixture
def irregular_obs():
    """Irregular times, full state in 2-D, a few values missing (one whole row of p)."""
    rng = np.random.default_rng(3)
    times = 0.3 + np.cumsum(rng.uniform(0.05, 2.0, size=12))
    values = rng.normal(size=(12, 4)) * 10.0 ** rng.integers(-12, 6, size=(12, 4))
    values[1, 0] = np.nan
    values[4, 2:] = np.nan
    values[7, 3] = np.nan
    return Observations(times, values, ("q1", "q2", "p1", "p2"))


def _same(a: Observations, b: Observations) -> None:
    np.testing.assert_array_equal(a.times, b.times)  # exact, NaN-aware
    np.testing.assert_array_equal(a.values, b.values)
    assert a.names == b.names


# ----------------------------------------------------------------------------- round trips
@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_round_trip_is_exact_with_nan_and_irregular_times(tmp_path, irregular_obs, suffix):
    path = write_observations(irregular_obs, tmp_path / f"data{suffix}")
    back = read_observations(path)
    _same(back, irregular_obs)
    assert observation_kind(back) == "full"
    assert not (tmp_path / f".data{suffix}.tmp").exists()


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_positions_only_round_trip(tmp_path, irregular_obs, suffix):
    q_only = positions_only(irregular_obs)
    assert q_only.names == ("q1", "q2")
    np.testing.assert_array_equal(q_only.values, irregular_obs.values[:, :2])
    back = read_observations(write_observations(q_only, tmp_path / f"q{suffix}"))
    _same(back, q_only)
    assert observation_layout(back) == Layout("positions", 2)


def test_simulated_data_round_trip(tmp_path, hh_data):
    data = hh_data
    back = read_observations(write_observations(data, tmp_path / "hh.csv"))
    np.testing.assert_array_equal(back.values, data.values)
    np.testing.assert_array_equal(back.times, np.arange(5.0, 101.0, 5.0))


def test_hand_written_csv(tmp_path):
    path = tmp_path / "d.csv"
    path.write_text(
        "# measured by hand\n"
        "T, Q1 ,q2\n"
        "\n"
        "0.5, 1.5, \n"
        "0.75,NaN,-2e-3\n"
        "# a comment line in the middle\n"
        "2,  3, NA\n"
    )
    obs = read_observations(path)
    np.testing.assert_array_equal(obs.times, [0.5, 0.75, 2.0])
    np.testing.assert_array_equal(obs.values, [[1.5, np.nan], [np.nan, -2e-3], [3.0, np.nan]])
    assert obs.names == ("q1", "q2")
    assert observation_kind(obs) == "positions"


def test_npz_layouts(tmp_path):
    t = np.array([1.0, 2.0, 4.0])
    values = np.arange(6.0).reshape(3, 2)
    np.savez(tmp_path / "named.npz", t=t, values=values, names=np.array(["q1", "p1"]))
    np.savez(tmp_path / "unnamed.npz", times=t, values=values)
    np.savez(tmp_path / "columns.npz", p1=values[:, 1], t=t, q1=values[:, 0])
    np.savez(tmp_path / "positions.npz", t=t, values=values, names=np.array(["q1", "q2"]))
    for name in ("named", "unnamed", "columns"):
        obs = read_observations(tmp_path / f"{name}.npz")
        np.testing.assert_array_equal(obs.times, t)
        np.testing.assert_array_equal(obs.values, values)
        assert obs.names == ("q1", "p1")
    assert observation_kind(read_observations(tmp_path / "positions.npz")) == "positions"


def test_layout_helpers():
    assert column_names(3) == ("q1", "q2", "q3", "p1", "p2", "p3")
    assert column_names(1, "positions") == ("q1",)
    assert observation_layout(Observations([1.0], [[1.0, 2.0]])) == Layout("full", 1)
    with pytest.raises(DataError, match="3 unnamed columns"):
        observation_layout(Observations([1.0], [[1.0, 2.0, 3.0]]))


def test_write_rejects_bad_names_and_suffix(tmp_path):
    obs = Observations([1.0], [[1.0, 2.0]], ("x", "y"))
    with pytest.raises(DataError, match="unknown column 'x'"):
        write_observations(obs, tmp_path / "a.csv")
    with pytest.raises(DataError, match=r"use \.csv or \.npz"):
        write_observations(Observations([1.0], [[1.0, 2.0]]), tmp_path / "a.json")


# ----------------------------------------------------------------------------- bad CSV files
BAD_CSV = {
    "empty": ("", ["the file is empty"]),
    "blank": ("\n  \n\n", ["empty"]),
    "no_header": ("1,2,3\n4,5,6\n", ["line 1", "no header"]),
    "no_t": ("time,q1\n1,2\n", ["no 't' column"]),
    "t_not_first": ("q1,t\n1,2\n", ["first column must be 't'"]),
    "text": ("t,q1,q2\n1,2,3\n2,4,abc\n", ["line 3", "column 'q2'", "'abc' is not a number"]),
    "text_time": ("t,q1\nx,2\n", ["line 2", "column 't'", "not a number"]),
    "decreasing": ("t,q1\n1,0\n3,0\n2,0\n", ["line 4", "strictly increasing"]),
    "repeated_time": ("t,q1\n1,0\n1,0\n", ["line 3", "strictly increasing"]),
    "missing_time": ("t,q1\n1,0\n,0\n", ["line 3", "time is missing"]),
    "p_without_q": ("t,q1,p1,p2\n1,2,3,4\n", ["'p2' has no matching 'q2'"]),
    "p_before_q": ("t,p1,q1\n1,2,3\n", ["out of order", "t,q1,p1"]),
    "q_swapped": ("t,q2,q1,p1,p2\n1,2,3,4,5\n", ["out of order"]),
    "missing_p": ("t,q1,q2,p1\n1,2,3,4\n", ["'p2' is missing"]),
    "missing_q": ("t,q2\n1,2\n", ["'q1' is missing"]),
    "unknown": ("t,q1,x\n1,2,3\n", ["unknown column 'x'"]),
    "duplicate": ("t,q1,q1\n1,2,3\n", ["'q1' appears twice"]),
    "only_t": ("t\n1\n", ["no value columns"]),
    "no_rows": ("t,q1,q2\n", ["no data rows"]),
    "ragged": ("t,q1\n1,2\n2,3,4\n", ["line 3", "3 fields", "2 columns"]),
    "infinite": ("t,q1\n1,inf\n", ["line 2", "infinite"]),
    "semicolons": ("t;q1\n1;2\n", ["separated by commas"]),
    "all_missing": ("t,q1\n1,\n2,nan\n", ["every value is missing"]),
}


@pytest.mark.parametrize("case", sorted(BAD_CSV))
def test_bad_csv_gives_one_line_data_error(tmp_path, case):
    text, words = BAD_CSV[case]
    path = tmp_path / f"{case}.csv"
    path.write_text(text)
    with pytest.raises(DataError) as info:
        read_observations(path)
    message = str(info.value)
    assert message.startswith(str(path))
    assert "\n" not in message
    for word in words:
        assert word in message


def test_missing_file_directory_and_suffix(tmp_path):
    with pytest.raises(DataError, match="no such file"):
        read_observations(tmp_path / "nope.csv")
    (tmp_path / "dir.csv").mkdir()
    with pytest.raises(DataError, match="is a directory"):
        read_observations(tmp_path / "dir.csv")
    (tmp_path / "data.txt").write_text("t,q1\n1,2\n")
    with pytest.raises(DataError, match=r"unknown data file type '\.txt'"):
        read_observations(tmp_path / "data.txt")
    (tmp_path / "binary.csv").write_bytes(b"\xff\xfe\x00\x81t,q1")
    with pytest.raises(DataError, match="not a UTF-8 text file"):
        read_observations(tmp_path / "binary.csv")


# ----------------------------------------------------------------------------- bad NPZ files
def _npz(path, **arrays):
    np.savez(path, **arrays)
    return path


T3 = np.array([1.0, 2.0, 3.0])
V32 = np.ones((3, 2))

BAD_NPZ = {
    "no_t": (dict(q1=T3), ["no 't' array"]),
    "unknown_array": (dict(t=T3, values=V32, extra=T3), ["unknown arrays extra"]),
    "unknown_column": (dict(t=T3, q1=T3, x=T3), ["unknown column 'x'"]),
    "p_without_q": (dict(t=T3, q1=T3, p2=T3), ["'p2' has no matching 'q2'"]),
    "rows": (dict(t=T3, values=np.ones((2, 2))), ["3 entries", "2 rows"]),
    "column_length": (dict(t=T3, q1=T3[:2]), ["'q1' has 2"]),
    "names_count": (dict(t=T3, values=V32, names=np.array(["q1"])), ["1 names for 2"]),
    "odd_unnamed": (dict(t=T3, values=np.ones((3, 3))), ["3 columns and no 'names'"]),
    "text_values": (dict(t=T3, q1=np.array(["a", "b", "c"])), ["not numbers"]),
    "decreasing": (dict(t=np.array([1.0, 3.0, 2.0]), q1=T3), ["strictly increasing"]),
    "nan_time": (dict(t=np.array([1.0, np.nan, 2.0]), q1=T3), ["finite"]),
    "empty_t": (dict(t=np.array([]), q1=np.array([])), ["no data rows"]),
    "infinite": (dict(t=T3, q1=np.array([1.0, np.inf, 2.0])), ["'q1' at row 1 is infinite"]),
    "2d_t": (dict(t=V32, q1=T3), ["'t' must be 1-D"]),
    "no_arrays": (dict(), ["no arrays"]),
}


@pytest.mark.parametrize("case", sorted(BAD_NPZ))
def test_bad_npz_gives_one_line_data_error(tmp_path, case):
    arrays, words = BAD_NPZ[case]
    path = _npz(tmp_path / f"{case}.npz", **arrays)
    with pytest.raises(DataError) as info:
        read_observations(path)
    message = str(info.value)
    assert message.startswith(str(path)) and "\n" not in message
    for word in words:
        assert word in message


def test_npz_refuses_pickles_and_garbage(tmp_path):
    path = tmp_path / "objects.npz"
    np.savez(path, t=T3, q1=np.array([1, "a", None], dtype=object))
    with pytest.raises(DataError, match="pickle"):
        read_observations(path)
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"this is not a zip file")
    with pytest.raises(DataError, match="not a valid NPZ file"):
        read_observations(garbage)


def test_file_feeds_the_likelihood_like_the_original(tmp_path, hh, small_data, small_theta):
    """Irregular times and a missing value, through a positions-only file and the settings
    that read its layout, give the same log-likelihood as the in-memory observations."""
    from symplid.workflow._settings import resolve_for_data, settings_from_dict

    q_only = positions_only(small_data)
    back = read_observations(write_observations(q_only, tmp_path / "q.csv"))
    settings = resolve_for_data(
        settings_from_dict({"initial_state": {"x0": list(np.asarray(hh.initial_state))}}), back
    )
    model = symplid.HamiltonianModel(hh.potential, observation=settings.model.observation)
    x0, P0 = np.asarray(settings.initial_state.x0), 1e-4 * np.eye(4)
    from_file = model.log_likelihood(small_theta, back, x0=x0, P0=P0)
    in_memory = model.log_likelihood(small_theta, q_only, x0=x0, P0=P0)
    assert settings.model.observation == "positions"
    assert np.isfinite(from_file) and from_file == in_memory
