"""Real signals to a real fit (issue 23, class 1): SIGINT, SIGTERM and SIGHUP act alike.

A subprocess ``symplid fit`` is sent each signal while it finds the MAP (or compiles), and
while it samples, five times at varied delays (the races seen before showed in 1 of 8 to 3 of 5
trials: a signal swallowed in a library callback, two lines, a segmentation fault, draws lost
between two compiled chunks). Each time it must end with exit code 128 + the signal's number,
one line (no traceback, no "Exception ignored"), a run folder marked unfinished (interrupted
with its draws and chains' state, or failed before any draw), never finished-looking; once
sampling has started, the chunks on disk are readable and the draws are kept. A second Ctrl-C
while stopping changes none of this.
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

from symplid.io._chunks import read_chunks
from symplid.sampling import draws_array
from symplid.workflow._results import RunFolder

FIT = ["--order", "2", "--x0", "1,0", "--burn-in", "100", "--chains", "2", "--no-progress",
       "--no-report", "--set", "sampler.chunk_size=500", "--iterations", "2000000"]
FIT += ["--dt", "0.25"]  # a fixed step: the step search is test_step_size.py's
FIT += ["--set", "map.sensitivity=false"]  # the MAP refits: test_fit_diagnostics.py
#: A longer MAP search to land signals in; a short one to reach sampling soon.
STARTS = {"map": ["--set", "map.num_starts=8"],
          "sampling": ["--set", "map.num_starts=1", "--set", "map.evidence=laplace"]}
DELAYS = {"map": (0.0, 0.2, 0.5, 1.0, 1.5), "sampling": (0.0, 0.05, 0.15, 0.3, 0.6)}
SIGNALS = [signal.SIGINT, signal.SIGTERM, signal.SIGHUP]


def _environment() -> dict[str, str]:
    """The tests' compilation cache (conftest), so that each fit compiles little."""
    cache = os.environ.get("SYMPLID_TEST_CACHE_DIR") or os.path.join(
        tempfile.gettempdir(), f"symplid-test-jax-cache-{os.getuid()}")
    return {**os.environ, "SYMPLID_CACHE_DIR": cache}


def _default_sigint() -> None:  # a suite run as a background job ignores SIGINT
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _wait_for(path: Path, fit: subprocess.Popen, timeout: float = 180) -> None:
    end = time.monotonic() + timeout
    while not path.exists():
        if time.monotonic() > end or fit.poll() is not None:
            raise AssertionError(f"{path} never appeared (exit {fit.poll()})")
        time.sleep(0.01)


def _start(data: Path, out: Path, phase: str = "sampling") -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "symplid.cli", "fit", str(data), "--out",
                             str(out), *FIT, *STARTS[phase]], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, preexec_fn=_default_sigint,
                            env=_environment())


def _stop(fit: subprocess.Popen, signals: list[tuple[float, int]]) -> tuple[str, str]:
    """Send each (delay, signal) in turn; the fit's output."""
    try:
        for delay, signum in signals:
            time.sleep(delay)
            fit.send_signal(signum)
        return fit.communicate(timeout=120)
    finally:
        if fit.poll() is None:
            os.kill(fit.pid, signal.SIGKILL)
            fit.communicate()


def _check_stopped(fit: subprocess.Popen, stdout: str, stderr: str, out: Path, signum: int,
                   sampling: bool) -> None:
    what = f"exit {fit.returncode}: {stdout}{stderr}"
    assert fit.returncode == 128 + signum, what  # never -11 (a segmentation fault), never 0
    assert "Traceback" not in stderr and "Exception ignored" not in stderr, what
    said = [line for line in (stdout + stderr).splitlines()
            if not line.startswith("symplid: warning:")]
    assert len(said) == 1 and "interrupted" in said[0], what
    marker = RunFolder(out, "r", allow_incomplete=True).incomplete_reason
    assert marker is not None and marker.startswith(("interrupted:", "failed: interrupted")), \
        marker
    if sampling:  # it had started: the draws (or, in the burn-in, the chains' state) are kept
        assert marker.startswith("interrupted:"), marker
        chunks = read_chunks(out / RunFolder.CHUNKS)
        assert chunks.count >= 1 and not chunks.note
        if "in the burn-in" not in marker:
            kept = RunFolder(out, "r", allow_incomplete=True).read_posterior()
            np.testing.assert_array_equal(draws_array(kept), chunks.draws["theta"])
        assert (out / RunFolder.SAMPLER_STATE).exists()


@pytest.mark.slow
@pytest.mark.parametrize("phase", ["map", "sampling"])
@pytest.mark.parametrize("signum", SIGNALS, ids=lambda s: signal.Signals(s).name)
def test_each_signal_in_each_phase_stops_the_fit_alike(data_csv, tmp_path, signum, phase):
    for repeat, delay in enumerate(DELAYS[phase]):
        out = tmp_path / f"run{repeat}"
        fit = _start(data_csv, out, phase)
        if phase == "map":
            _wait_for(out / "data.csv", fit)  # written just before the MAP search
        else:
            _wait_for(out / RunFolder.CHUNKS / "chunk-000000.npz", fit)
        stdout, stderr = _stop(fit, [(delay, signum)])
        _check_stopped(fit, stdout, stderr, out, signum, sampling=phase == "sampling")


@pytest.mark.slow
def test_a_second_ctrl_c_while_stopping_keeps_the_draws(data_csv, tmp_path):
    for repeat, gap in enumerate((0.0, 0.01, 0.1)):
        out = tmp_path / f"run{repeat}"
        fit = _start(data_csv, out)
        _wait_for(out / RunFolder.CHUNKS / "chunk-000001.npz", fit)
        stdout, stderr = _stop(fit, [(0.0, signal.SIGINT), (gap, signal.SIGINT)])
        _check_stopped(fit, stdout, stderr, out, signal.SIGINT, sampling=True)
        assert "interrupted after" in stdout  # the draws were saved, not dropped


# ----------------------------------------------------------------------------- the mechanism
def test_a_signal_under_supervision_only_requests_a_stop():
    from symplid import _stopping as stopping
    from symplid.workflow._interrupts import supervised

    before = signal.getsignal(signal.SIGTERM)
    with supervised():
        os.kill(os.getpid(), signal.SIGTERM)  # the handler runs at the next bytecode
        time.sleep(0.01)
        assert stopping.requested() == signal.SIGTERM  # recorded; nothing was raised
        with pytest.raises(stopping.StopRequested) as stop:
            stopping.check()  # raised by the safe point, not by the handler
        assert stop.value.signum == signal.SIGTERM
    assert stopping.requested() is None and signal.getsignal(signal.SIGTERM) is before


_LONG_C_CALL = """
import time, numpy as np
from symplid.workflow._interrupts import supervised
a = np.random.default_rng(0).random((1500, 1500))
t = time.perf_counter()
np.linalg.svd(a)
print(time.perf_counter() - t, flush=True)  # how long one call takes here
with supervised():
    print("ready", flush=True)
    for _ in range(20):
        np.linalg.svd(a)  # one long C call after another: Python handlers wait for each
print("not stopped")
"""


def test_the_third_signal_of_a_kind_ends_the_process_at_once_in_one_line():
    child = subprocess.Popen([sys.executable, "-c", _LONG_C_CALL], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    try:
        one_call = float(child.stdout.readline())
        assert child.stdout.readline() == "ready\n"
        time.sleep(0.1 * one_call)  # inside a call
        for _ in range(3):  # apart: two of a kind pending at once are delivered as one
            child.send_signal(signal.SIGTERM)
            sent = time.perf_counter()
            time.sleep(0.3)
        stdout, stderr = child.communicate(timeout=300)
        took = time.perf_counter() - sent
    finally:
        if child.poll() is None:
            child.kill()
            child.communicate()
    assert child.returncode == 128 + signal.SIGTERM and stdout == "", (stdout, stderr)
    assert len(stderr.splitlines()) == 1 and "--resume" in stderr, stderr
    assert took < max(0.5 * one_call, 0.5), (took, one_call)  # not at the end of the call


def test_the_sampler_stops_before_the_next_chunk_with_the_draws_of_the_whole_run():
    from sampler_targets import Gaussian2D
    from symplid import _stopping as stopping
    from symplid.sampling import RunOptions, sample

    target = Gaussian2D()
    budget = {"num_draws": 200, "num_chains": 2, "burn_in": 40, "init": target.map_result()}
    full = sample(target, "dram", **budget, options=RunOptions(chunk_size=30, progress=False))

    def ask_to_stop(report):  # as a signal's handler would, after the third chunk
        if report.chunk == 2:
            stopping.request(signal.SIGTERM)

    try:
        with pytest.warns(UserWarning, match="interrupted after 90 of 240"):
            part = sample(target, "dram", **budget,
                          options=RunOptions(chunk_size=30, progress=False,
                                                                     callback=ask_to_stop))
    finally:
        stopping.clear()
    assert part.attrs["interrupted"] == 1 and part.attrs["iterations"] == 90
    np.testing.assert_array_equal(draws_array(part), draws_array(full)[:, :50])
