"""Real signals to a real fit (issue 23, class 1): SIGINT, SIGTERM and SIGHUP act alike.

A subprocess fit is sent each signal in two phases (while it finds the MAP or compiles, and
while it samples). Each ends with exit code 128 + the signal's number, says "interrupted" once,
prints no traceback, and leaves the run marked unfinished (interrupted with its draws, or
failed before any draw), never finished-looking. SIGHUP used to kill the process with every
draw lost.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

FIT = ["--order", "2", "--x0", "1,0", "--burn-in", "100", "--chains", "2", "--no-progress",
       "--no-report", "--set", "map.num_starts=1", "--iterations", "2000000"]



def _default_sigint() -> None:  # a suite run as a background job ignores SIGINT
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _wait_for(path: Path, timeout: float = 180) -> None:
    end = time.monotonic() + timeout
    while not path.exists():
        if time.monotonic() > end:
            raise AssertionError(f"{path} never appeared")
        time.sleep(0.05)


@pytest.mark.parametrize("phase", ["map", "sampling"])
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_each_signal_in_each_phase_stops_the_fit_alike(data_csv, tmp_path, signum, phase):
    out = tmp_path / "run"
    fit = subprocess.Popen([sys.executable, "-m", "symplid.cli", "fit", str(data_csv), "--out",
                            str(out), *FIT], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                           text=True, preexec_fn=_default_sigint)
    try:
        _wait_for(out / "data.csv")  # the MAP search starts next
        if phase == "sampling":
            _wait_for(out / "map.json")
            time.sleep(8)  # compiled, and sampling (2 million iterations: not done yet)
        fit.send_signal(signum)
        stdout, stderr = fit.communicate(timeout=120)
    finally:
        if fit.poll() is None:
            os.kill(fit.pid, signal.SIGKILL)
            fit.communicate()
    assert fit.returncode == 128 + signum, (fit.returncode, stderr)
    assert "Traceback" not in stderr and "Exception ignored" not in stderr, stderr
    said = [line for line in (stdout + stderr).splitlines()
            if not line.startswith("symplid: warning:")]
    assert len(said) == 1 and "interrupted" in said[0], stdout + stderr
    marker = (out / ".incomplete").read_text()
    assert marker.startswith(("interrupted:", "failed: interrupted")), marker
    if marker.startswith("interrupted:"):  # the chains' state is kept, and the draws made
        assert (out / "sampler_state.npz").exists()
        if "in the burn-in" not in marker:
            assert (out / "posterior.nc").exists()
