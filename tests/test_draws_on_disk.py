"""Draws streamed to the run folder chunk by chunk (issue 23, class 2).

A fit killed outright (SIGKILL: no handler runs, as for the out-of-memory killer) keeps every
finished chunk in ``draws/``: each is readable, and ``symplid fit --resume`` continues from the
last one to the draws of an uninterrupted run with the same settings, bit for bit (the
independent reference: that run, made in one go). A damaged last chunk is named in one line
and made again.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from symplid.cli import main
from symplid.io._chunks import read_chunks
from symplid.sampling import draws_array
from symplid.workflow._results import RunFolder, RunFolderError

FIT = ["--order", "2", "--x0", "1,0", "--iterations", "6000", "--burn-in", "1000", "--chains",
       "2", "--no-progress", "--no-report", "--set", "map.num_starts=1", "--set",
       "sampler.chunk_size=200"]
FIT += ["--dt", "0.25"]  # a fixed step: the step search is test_step_size.py's
FIT += ["--set", "map.sensitivity=false"]  # the MAP refits: test_fit_diagnostics.py


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def _environment() -> dict[str, str]:
    cache = os.environ.get("SYMPLID_TEST_CACHE_DIR") or os.path.join(
        tempfile.gettempdir(), f"symplid-test-jax-cache-{os.getuid()}")
    return {**os.environ, "SYMPLID_CACHE_DIR": cache}


def _posterior(out: Path):
    return RunFolder(out, "r").read_posterior()


@pytest.fixture(scope="module")
def whole_run(data_csv, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("runs") / "whole"
    result = run("fit", data_csv, "--out", out, *FIT)
    assert result.exit_code == 0, result.output
    assert not (out / RunFolder.CHUNKS).exists()  # gathered into posterior.nc, then removed
    return out


def _killed_while_sampling(data_csv: Path, out: Path, chunks: int = 3) -> None:
    """A subprocess fit, killed with SIGKILL once ``chunks`` chunk files are on disk."""
    fit = subprocess.Popen([sys.executable, "-m", "symplid.cli", "fit", str(data_csv), "--out",
                            str(out), *FIT], stdout=subprocess.DEVNULL,
                           stderr=subprocess.DEVNULL, env=_environment())
    last = out / RunFolder.CHUNKS / f"chunk-{chunks - 1:06d}.npz"
    try:
        end = time.monotonic() + 300
        while not last.exists():
            assert fit.poll() is None, "the fit ended before it was killed"
            assert time.monotonic() < end, "no chunk appeared"
            time.sleep(0.01)
        fit.send_signal(signal.SIGKILL)
    finally:
        if fit.poll() is None:
            fit.kill()
        fit.wait()
    assert fit.returncode == -signal.SIGKILL


@pytest.mark.slow
def test_a_killed_fit_keeps_its_chunks_and_resumes_to_the_uninterrupted_draws(
        data_csv, whole_run, tmp_path):
    out = tmp_path / "run"
    _killed_while_sampling(data_csv, out)
    files = sorted((out / RunFolder.CHUNKS).glob("chunk-*.npz"))
    chunks = read_chunks(out / RunFolder.CHUNKS)
    assert chunks.count == len(files) >= 3 and not chunks.note  # every one readable, in line
    assert chunks.iterations_done == 200 * chunks.count
    # Never finished-looking; a reader is told to resume.
    with pytest.raises(RunFolderError, match="--resume"):
        RunFolder(out, "r")
    resumed = run("fit", "--out", out, "--resume", "--no-progress", "--no-report")
    assert resumed.exit_code == 0, resumed.output
    np.testing.assert_array_equal(draws_array(_posterior(out)), draws_array(_posterior(whole_run)))
    np.testing.assert_array_equal(_posterior(out).sample_stats["accepted"],
                                  _posterior(whole_run).sample_stats["accepted"])
    assert not (out / RunFolder.CHUNKS).exists()


@pytest.mark.slow
def test_a_truncated_last_chunk_is_named_once_and_made_again(data_csv, whole_run, tmp_path):
    out = tmp_path / "run"
    _killed_while_sampling(data_csv, out)
    last = sorted((out / RunFolder.CHUNKS).glob("chunk-*.npz"))[-1]
    last.write_bytes(last.read_bytes()[:100])  # a crash of the disk mid-write
    resumed = run("fit", "--out", out, "--resume", "--no-progress", "--no-report")
    assert resumed.exit_code == 0, resumed.output
    named = [line for line in resumed.output.splitlines() if last.name in line]
    assert len(named) == 1 and "ignored" in named[0], resumed.output
    np.testing.assert_array_equal(draws_array(_posterior(out)), draws_array(_posterior(whole_run)))


def test_chunks_out_of_line_stop_the_reading_with_one_note(tmp_path):
    from symplid.io._chunks import ChunkWriter

    states = {"x": np.arange(4.0).reshape(2, 2)}
    writer = ChunkWriter(tmp_path)
    for start in (0, 10, 20):
        writer({"theta": np.full((2, 3, 1), float(start))}, states, start, start + 10, 1.0)
    (tmp_path / "chunk-000001.npz").unlink()  # a gap: chunk 2 cannot follow chunk 0
    chunks = read_chunks(tmp_path)
    assert chunks.count == 1 and chunks.iterations_done == 10
    assert "chunk-000002.npz" in chunks.note and "chunk 1 is missing" in chunks.note
    np.testing.assert_array_equal(chunks.draws["theta"], np.zeros((2, 3, 1)))
    np.testing.assert_array_equal(chunks.state["leaf_0"], states["x"])
    assert read_chunks(tmp_path / "none").count == 0
