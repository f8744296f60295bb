"""Broken run files (issue 23, classes 3 and 8): every unreadable file is one line naming it.

A run's files damaged for real (emptied, cut in half, overwritten with noise) make ``predict``,
``report``, ``predict --from end`` and ``fit --resume`` stop with one line on stderr that names
the file and says what to do, exit code 2. A resumed run's files have the formats of a fresh
run's (``map_theta`` and the other array attributes in posterior.nc, the types in
summary.json), read back with h5netcdf and json directly rather than through symplid.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from symplid.cli import main
from symplid.sampling import sample

TINY = ["--order", "2", "--x0", "1,0", "--iterations", "400", "--burn-in", "200", "--chains",
        "2", "--no-progress", "--no-report", "--set", "map.num_starts=1", "--set",
        "sampler.chunk_size=100"]
TINY += ["--dt", "0.25"]  # a fixed step: the step search is test_step_size.py's
TINY += ["--set", "map.sensitivity=false"]  # the MAP refits: test_fit_diagnostics.py


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def one_line(result, *words, code=2):
    lines = result.output.strip().splitlines()
    assert result.exit_code == code, result.output
    assert len(lines) == 1 and lines[0].startswith("symplid: error:"), result.output
    for word in words:
        assert word in lines[0], lines[0]



def _fit(data_csv: Path, out: Path, stop_at: int | None = None):
    """A fit in chunks of 100 iterations, stopped (Ctrl-C) after ``stop_at`` of them."""
    import symplid.workflow._fit as fit_module

    def stop(report):
        if report.iterations_done == stop_at:
            raise KeyboardInterrupt

    extra = {"callback": stop} if stop_at else {}

    def stopped(*args, options, **kwargs):
        return sample(*args, options=dataclasses.replace(options, **extra), **kwargs)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(fit_module, "sample", stopped)
        return run("fit", data_csv, "--out", out, *TINY)


@pytest.fixture(scope="module")
def finished(data_csv, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("runs") / "finished"
    assert _fit(data_csv, out).exit_code == 0
    return out


@pytest.fixture(scope="module")
def interrupted(data_csv, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("runs") / "interrupted"
    assert _fit(data_csv, out, stop_at=300).exit_code == 130
    return out


def damage(path: Path, how: str) -> None:
    """Empty the file, cut it in half, or replace it with as many random bytes."""
    content = path.read_bytes()
    if how == "empty":
        path.write_bytes(b"")
    elif how == "truncated":
        path.write_bytes(content[: len(content) // 2])
    else:
        path.write_bytes(np.random.default_rng(1).bytes(len(content)))


def copy(run_folder: Path, tmp_path: Path) -> Path:
    target = tmp_path / "copy"
    shutil.copytree(run_folder, target)
    return target


COMMANDS = {
    "predict": ["predict", "{run}", "--t-end", "15", "--num-paths", "2"],
    "report": ["report", "{run}"],
    "forecast": ["predict", "{run}", "--from", "end", "--t-end", "15"],
}


@pytest.mark.parametrize("how", ["empty", "truncated", "garbage"])
@pytest.mark.parametrize("command", list(COMMANDS))
def test_a_damaged_posterior_is_one_line_in_every_reader(finished, tmp_path, command, how):
    folder = copy(finished, tmp_path)
    damage(folder / "posterior.nc", how)
    args = [a.format(run=folder) for a in COMMANDS[command]]
    one_line(run(*args), f"{folder / 'posterior.nc'}:", "fit it again")


@pytest.mark.parametrize("name", ["map.json", "summary.json", "settings.toml", "data.csv"])
@pytest.mark.parametrize("how", ["empty", "truncated", "garbage"])
def test_every_damaged_run_file_is_one_line(finished, tmp_path, name, how):
    if name == "data.csv" and how == "truncated":
        pytest.skip("half a CSV file is a shorter CSV file: nothing to detect")
    folder = copy(finished, tmp_path)
    damage(folder / name, how)
    one_line(run("report", folder), f"{folder / name}:", "fit it again")


@pytest.mark.parametrize("name", ["sampler_state.npz", "posterior.nc", "map.json",
                                  "sampler_attrs.json"])
@pytest.mark.parametrize("how", ["empty", "truncated", "garbage"])
def test_a_damaged_interrupted_run_cannot_be_resumed_in_one_line(interrupted, tmp_path, name,
                                                                 how):
    folder = copy(interrupted, tmp_path)
    if name in ("sampler_state.npz", "posterior.nc"):  # read when there are no chunk files
        shutil.rmtree(folder / "draws")  # (a run of an older version)
    damage(folder / name, how)
    result = run("fit", "--out", folder, "--resume", "--no-progress", "--no-report")
    one_line(result, f"{folder / name}:", "--resume is impossible")
    assert (folder / ".incomplete").read_text().startswith("interrupted:")  # left as it was


def _raw_attrs(path: Path) -> dict[str, object]:
    import h5netcdf

    with h5netcdf.File(path, "r") as f:
        return {key: f.attrs[key] for key in f.attrs}


def _json_only(value) -> bool:
    if isinstance(value, dict):
        return all(isinstance(k, str) and _json_only(v) for k, v in value.items())
    if isinstance(value, list):
        return all(_json_only(v) for v in value)
    return value is None or type(value) in (str, int, float, bool)


def test_a_resumed_run_has_the_file_formats_of_a_fresh_one(interrupted, finished, tmp_path):
    folder = copy(interrupted, tmp_path)
    assert run("fit", "--out", folder, "--resume", "--no-progress", "--no-report").exit_code == 0
    fresh, resumed = _raw_attrs(finished / "posterior.nc"), _raw_attrs(folder / "posterior.nc")
    assert isinstance(fresh["map_theta"], str)  # JSON text, however the attribute came
    assert set(fresh) == set(resumed)
    for key, value in fresh.items():
        assert type(resumed[key]) is type(value), key
    assert json.loads(resumed["map_theta"]) == json.loads(fresh["map_theta"])
    assert resumed["symplid_json_attrs"] == fresh["symplid_json_attrs"]
    # summary.json: only JSON's own types, the same keys and types as the fresh run's.
    one, other = (json.loads((f / "summary.json").read_text()) for f in (finished, folder))
    assert _json_only(other)
    assert set(other) == set(one) and set(other["timings"]) == set(one["timings"]) | {"resumed"}
    for key, value in one.items():
        assert type(other[key]) is type(value), key


def test_read_with_names_the_file_and_the_remedy(tmp_path):
    from symplid.io._files import RunFolderError, read_with

    path = tmp_path / "x.npz"
    path.write_bytes(os.urandom(64))
    with pytest.raises(RunFolderError, match=r"x.npz: unreadable \(.*\); do this$"):
        read_with(path, np.load, "do this")
    with pytest.raises(RunFolderError, match="no such file; do this"):
        read_with(tmp_path / "none", np.load, "do this")


def test_an_earlier_run_of_another_kind_is_overwritten_by_its_identity_file(tmp_path):
    """``symplid reproduce`` into its own earlier folder: the folder holds ``config.json``
    (no ``settings.toml``); named as the identity it is a run to overwrite, else refused."""
    from symplid.workflow._results import RunFolder, RunFolderError

    earlier = tmp_path / "paper"
    earlier.mkdir()
    (earlier / "config.json").write_text("{}", encoding="utf-8")
    (earlier / "summary.json").write_text('{"old": 1}', encoding="utf-8")
    (earlier / "notes.txt").write_text("mine", encoding="utf-8")
    with pytest.raises(RunFolderError, match="not a run folder"):
        RunFolder(earlier, "w", overwrite=True)
    folder = RunFolder(earlier, "w", overwrite=True, identity="config.json")
    assert not (earlier / "summary.json").exists()  # a run file of the earlier run: removed
    assert (earlier / "notes.txt").read_text(encoding="utf-8") == "mine"  # not a run file
    assert (earlier / RunFolder.MARKER).exists()
    folder.write_json("config.json", {"seed": 0})
    folder.finish(required=("config.json",))
    assert not (earlier / RunFolder.MARKER).exists()
    RunFolder(earlier, "w", overwrite=True, identity="config.json").finish(("config.json",))
