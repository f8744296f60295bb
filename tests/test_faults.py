"""The faults a probe of the command line still found, each sent for real to a subprocess.

Each ends as docs/howto/reliability.md promises: one line, the documented exit code, nothing
finished lost, nothing unfinished that looks complete.

* a signal in a command's first second, while it imports JAX (a Ctrl-C was swallowed in
  JAX's gc callback and the fit ran on to exit 0; a SIGHUP killed ``report`` silently);
* a stop in the burn-in, or while sampling: one line (the sampler's warning made two);
* two fits started into one folder: the second names the first, never advises overwriting;
* ``compare --candidates a.toml,a.toml``, or two files of one model: refused in one line;
* a chunk file copied in from another run: named and ignored, the run's own draws kept;
* SIGTERM during a chunk of NUTS iterations that takes many seconds, and during the sampler's
  compilation: obeyed within about a second (stops are checked by time, not by iteration
  count);
* ``study paper-claims --update-readme`` with no README: one line before the study runs.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from symplid.io._chunks import read_chunks
from symplid.sampling import draws_array
from symplid.workflow._results import RunFolder

FIT = ["--order", "2", "--x0", "1,0", "--chains", "2", "--no-progress", "--no-report",
       "--set", "map.num_starts=1", "--set", "map.sensitivity=false",
       "--set", "map.evidence=laplace"]
FIT += ["--dt", "0.25"]  # a fixed step: the step search is test_step_size.py's


def _environment(cache: bool = True) -> dict[str, str]:
    folder = os.environ.get("SYMPLID_TEST_CACHE_DIR") or os.path.join(
        tempfile.gettempdir(), f"symplid-test-jax-cache-{os.getuid()}")
    return {**os.environ, "SYMPLID_CACHE_DIR": folder if cache else "off"}


def _default_sigint() -> None:  # a suite run as a background job ignores SIGINT
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _start(*args, cache: bool = True) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "symplid.cli", *map(str, args)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_default_sigint, env=_environment(cache))


def _finish(process: subprocess.Popen, timeout: float = 300) -> tuple[str, str]:
    try:
        return process.communicate(timeout=timeout)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()


def _wait_for(path: Path, process: subprocess.Popen, timeout: float = 300) -> None:
    end = time.monotonic() + timeout
    while not path.exists():
        assert process.poll() is None, f"{path} never appeared (exit {process.poll()})"
        assert time.monotonic() < end, f"{path} never appeared"
        time.sleep(0.01)


def _lines(stdout: str, stderr: str) -> list[str]:
    """Everything the command said, warnings and empty lines included."""
    return (stdout + stderr).splitlines()


def _catches_sigterm(pid: int) -> bool:
    """Whether the process has a handler for SIGTERM (Python's default has none)."""
    with open(f"/proc/{pid}/status") as status:
        caught = next(line for line in status if line.startswith("SigCgt:"))
    return bool(int(caught.split()[1], 16) >> (signal.SIGTERM - 1) & 1)


# ----------------------------------------------------------------------------- first second
@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads /proc")
@pytest.mark.parametrize("command, signum", [("fit", signal.SIGINT), ("report", signal.SIGHUP)],
                         ids=["fit-SIGINT", "report-SIGHUP"])
def test_a_signal_while_the_command_imports_is_obeyed_in_one_line(data_csv, tmp_path, command,
                                                                   signum):
    """Sent the moment the process handles signals (at most 1 s after it starts): JAX is
    being imported then. The command stops before it does anything: no run folder."""
    out = tmp_path / "run"
    args = [data_csv, "--out", out, "--iterations", "3000", "--burn-in", "100", *FIT]
    process = _start(command, *(args if command == "fit" else [out]))
    began = time.monotonic()
    while not _catches_sigterm(process.pid) and time.monotonic() < began + 1.0:
        time.sleep(0.005)
    process.send_signal(signum)
    stdout, stderr = _finish(process)
    said = _lines(stdout, stderr)
    assert process.returncode == 128 + signum, (process.returncode, said)
    assert said == ["symplid: interrupted"], said  # no traceback, no "Exception ignored"
    assert not out.exists()


# ----------------------------------------------------------------------------- one line
@pytest.mark.slow
@pytest.mark.parametrize("phase", ["burn-in", "sampling"])
def test_a_stop_while_sampling_is_one_line(data_csv, tmp_path, phase):
    out = tmp_path / "run"
    burn_in = "1000000" if phase == "burn-in" else "100"
    fit = _start("fit", data_csv, "--out", out, "--iterations", "2000000", "--burn-in", burn_in,
                 "--set", "sampler.chunk_size=500", *FIT)
    _wait_for(out / RunFolder.CHUNKS / "chunk-000000.npz", fit)
    fit.send_signal(signal.SIGINT)
    stdout, stderr = _finish(fit)
    said = _lines(stdout, stderr)
    assert fit.returncode == 130 and len(said) == 1, said
    assert "interrupted" in said[0] and "--resume" in said[0], said
    marker = RunFolder(out, "r", allow_incomplete=True).incomplete_reason
    assert marker.startswith("interrupted: in the burn-in" if phase == "burn-in"
                             else "interrupted: after"), marker


# ----------------------------------------------------------------------------- two writers
@pytest.mark.slow
def test_the_second_of_two_fits_into_one_folder_names_the_first(data_csv, tmp_path):
    """Once the first holds the folder (deterministic), and started at the same instant
    (either may win): the other is refused in one line naming the winner's pid, and is
    never told to overwrite."""
    args = ["--iterations", "2000000", "--burn-in", "100", *FIT]
    for together in (False, True):
        out = tmp_path / f"run-{together}"
        first = _start("fit", data_csv, "--out", out, *args)
        if not together:
            _wait_for(out / ".lock", first)
        second = _start("fit", data_csv, "--out", out, *args)
        pair = {first.pid: first, second.pid: second}
        while all(p.poll() is None for p in pair.values()):
            time.sleep(0.05)
        loser = next(p for p in pair.values() if p.poll() is not None)
        winner = next(p for p in pair.values() if p is not loser)
        _, lost = _finish(loser)
        winner.send_signal(signal.SIGTERM)
        _finish(winner)
        assert loser.returncode == 2, lost
        line, = lost.splitlines()
        assert f"another symplid process (pid {winner.pid})" in line, line
        assert "overwrit" not in line, line
        assert winner.returncode == 143


# ----------------------------------------------------------------------------- compare
def _model_file(path: Path) -> Path:
    path.write_text("[model]\norder = 2\n\n[map]\nnum_starts = 1\nsensitivity = false\n")
    return path


@pytest.mark.parametrize("same_file", [True, False], ids=["one-file-twice", "two-equal-files"])
def test_compare_refuses_one_model_twice(data_csv, tmp_path, same_file):
    a = _model_file(tmp_path / "a.toml")
    b = a if same_file else _model_file(tmp_path / "b.toml")
    process = _start("compare", data_csv, "--x0", "1,0", "--no-progress",
                     "--candidates", f"{a},{b}")
    stdout, stderr = _finish(process)
    said = _lines(stdout, stderr)
    assert process.returncode == 2 and len(said) == 1, said
    assert ("twice" if same_file else "the same model") in said[0], said


def test_compare_settings_refuses_a_label_or_a_model_twice():
    from symplid.workflow._compare_candidates import check_distinct
    from symplid.workflow._settings import Settings, merge_overrides

    two = merge_overrides(Settings(), {"model.order": 2}, source="test")
    three = merge_overrides(Settings(), {"model.order": 3}, source="test")
    check_distinct([("two", two), ("three", three)])  # distinct: nothing to say
    with pytest.raises(ValueError, match="named 'm'"):
        check_distinct([("m", two), ("m", three)])
    with pytest.raises(ValueError, match="'a' and 'b' are the same model"):
        check_distinct([("a", two), ("b", merge_overrides(two, {"sampler.num_chains": 8},
                                                          source="test"))])


# ----------------------------------------------------------------------------- chunks
CHUNKED = ["--iterations", "3000", "--burn-in", "500", "--set", "sampler.chunk_size=200", *FIT]


def _killed_after(data_csv: Path, out: Path, chunks: int, seed: int) -> int:
    """A fit killed with SIGKILL once ``chunks`` chunk files are on disk; the chunks kept."""
    fit = _start("fit", data_csv, "--out", out, "--seed", seed, *CHUNKED)
    _wait_for(out / RunFolder.CHUNKS / f"chunk-{chunks - 1:06d}.npz", fit)
    fit.send_signal(signal.SIGKILL)
    _finish(fit)
    return read_chunks(out / RunFolder.CHUNKS).count


@pytest.mark.slow
def test_a_chunk_copied_from_another_run_is_named_and_ignored(data_csv, tmp_path):
    """The reference is the same fit made in one go: the resumed run's draws equal its draws
    bit for bit, so nothing of the other run was kept."""
    whole = tmp_path / "whole"
    done = _start("fit", data_csv, "--out", whole, *CHUNKED)
    _finish(done)
    assert done.returncode == 0
    mine, other = tmp_path / "mine", tmp_path / "other"
    count = _killed_after(data_csv, mine, 3, seed=0)
    assert _killed_after(data_csv, other, count + 2, seed=1) > count
    copied = f"chunk-{count:06d}.npz"
    shutil.copyfile(other / RunFolder.CHUNKS / copied, mine / RunFolder.CHUNKS / copied)
    resumed = _start("fit", "--out", mine, "--resume", "--no-progress", "--no-report")
    _, stderr = _finish(resumed)
    assert resumed.returncode == 0, stderr
    named = [line for line in stderr.splitlines() if copied in line]
    assert len(named) == 1 and "another run" in named[0], stderr
    np.testing.assert_array_equal(draws_array(RunFolder(mine, "r").read_posterior()),
                                  draws_array(RunFolder(whole, "r").read_posterior()))


# ----------------------------------------------------------------------------- by time
@pytest.mark.slow
def test_sigterm_during_a_long_nuts_chunk_is_obeyed_within_seconds(data_csv, tmp_path):
    """Chunks of 5,000 NUTS iterations (ten seconds or more each): sent as the first is
    written, the stop is obeyed between two calls of about half a second, not after the
    whole second chunk, and the iterations done are kept as a shorter last chunk."""
    out = tmp_path / "run"
    fit = _start("fit", data_csv, "--out", out, "--method", "nuts", "--iterations", "200000",
                 "--burn-in", "100", "--set", "sampler.chunk_size=5000", *FIT)
    _wait_for(out / RunFolder.CHUNKS / "chunk-000000.npz", fit)
    time.sleep(0.5)  # inside chunk 1
    fit.send_signal(signal.SIGTERM)
    sent = time.time()
    stdout, stderr = _finish(fit, timeout=300)
    said = _lines(stdout, stderr)
    assert fit.returncode == 143 and len(said) == 1 and "interrupted" in said[0], said
    last = out / RunFolder.CHUNKS / "chunk-000001.npz"
    assert last.stat().st_mtime - sent < 2.0, last.stat().st_mtime - sent  # written at once
    chunks = read_chunks(out / RunFolder.CHUNKS)
    assert chunks.count == 2 and not chunks.note, chunks.note
    assert 5000 < chunks.iterations_done < 10000  # chunk 1 cut short, its iterations kept
    kept = RunFolder(out, "r", allow_incomplete=True).read_posterior()
    np.testing.assert_array_equal(draws_array(kept), chunks.draws["theta"])


def test_a_stop_inside_a_chunk_keeps_its_iterations_and_resumes_to_the_same_draws(
        monkeypatch):
    """Pieces of 7 iterations and a stop after the 20th look: the run ends inside its second
    chunk, its draws a prefix of the uninterrupted run's (made in one call per chunk), and
    resumed from there it gives that run's draws bit for bit."""
    import itertools

    from sampler_targets import Gaussian2D
    from symplid.sampling import RunOptions, sample
    from symplid.sampling import _pacing as pacing
    from symplid.sampling import _run as runner
    from symplid.sampling._resume import checkpoint_arrays, resume_sampling
    from symplid.sampling._run import SamplingInterrupted

    target = Gaussian2D()
    budget = {"num_draws": 150, "num_chains": 2, "seed": 3, "burn_in": 40,
              "init": target.map_result()}
    options = RunOptions(chunk_size=100, progress=False)
    full = sample(target, "dram", **budget, options=options)
    looks = itertools.count()
    monkeypatch.setattr(pacing.Pacer, "length", lambda self, remaining: min(remaining, 7))
    monkeypatch.setattr(runner, "stop_requested",
                        lambda: signal.SIGTERM if next(looks) >= 20 else None)
    with pytest.warns(SamplingInterrupted):
        part, checkpoint = sample(target, "dram", **budget,
                                  options=dataclasses.replace(options, return_state=True))
    monkeypatch.undo()
    done = checkpoint.iterations_done
    assert 100 < done < 190 and done % 100 != 0  # inside the second chunk
    np.testing.assert_array_equal(draws_array(part), draws_array(full)[:, :done - 40])
    resumed = resume_sampling(target, part, checkpoint_arrays(checkpoint),
                              options=RunOptions(progress=False))
    np.testing.assert_array_equal(draws_array(resumed), draws_array(full))


@pytest.mark.slow
def test_sigterm_during_the_samplers_compilation_is_obeyed_at_once(data_csv, tmp_path):
    """Without the compilation cache the sampler's chunk compiles for many seconds; the
    compilation runs in a worker thread, so the stop does not wait for it."""
    out = tmp_path / "run"
    fit = _start("fit", data_csv, "--out", out, "--method", "nuts", "--iterations", "20000",
                 "--burn-in", "500", *FIT, cache=False)
    _wait_for(out / RunFolder.SAMPLER_ATTRS, fit)  # written just before the chunk compiles
    time.sleep(0.5)
    fit.send_signal(signal.SIGTERM)
    sent = time.monotonic()
    stdout, stderr = _finish(fit, timeout=300)
    took = time.monotonic() - sent
    said = _lines(stdout, stderr)
    assert fit.returncode == 143 and len(said) == 1 and "interrupted" in said[0], said
    assert took < 5.0, took
    marker = RunFolder(out, "r", allow_incomplete=True).incomplete_reason
    assert marker.startswith("interrupted:"), marker  # --resume continues from the start


# ----------------------------------------------------------------------------- studies
def test_update_readme_without_a_readme_is_one_line_before_the_study(tmp_path):
    missing = tmp_path / "no" / "README.md"
    process = _start("study", "paper-claims", "--out", tmp_path / "study", "--report-only",
                     "--update-readme", missing, "--no-progress")
    stdout, stderr = _finish(process)
    said = _lines(stdout, stderr)
    assert process.returncode == 2 and len(said) == 1 and str(missing) in said[0], said
