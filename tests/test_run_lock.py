"""The run-folder lock (issue 23, class 5), with real processes.

Two fits into the same ``--out`` (with ``--overwrite``) used to both finish and leave a mixed
folder; now the one that comes while the other writes is refused at once in one line (exit 2),
and the folder is wholly the other's. A ``report`` of the folder while the fit writes it is
refused too. A fit killed with SIGKILL leaves no stale lock.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from symplid.io._files import FolderLock, FolderLockedError

FIT = ["--order", "2", "--x0", "1,0", "--burn-in", "200", "--chains", "2", "--no-progress",
       "--no-report", "--set", "map.num_starts=1", "--overwrite"]
FIT += ["--dt", "0.25"]  # a fixed step: the step search is test_step_size.py's
FIT += ["--set", "map.sensitivity=false"]  # the MAP refits: test_fit_diagnostics.py


def start(*args) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "symplid.cli", *map(str, args)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def errors(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if not line.startswith("symplid: warning:")]



def test_two_fits_into_one_folder_one_runs_one_is_refused(data_csv, tmp_path):
    """The second fit starts once the first holds the folder (started together, either may
    win; the first is made to run long enough that the second meets it)."""
    out = tmp_path / "run"
    first = start("fit", data_csv, "--out", out, "--iterations", "200000", "--seed", "1", *FIT)
    _wait_for_lock(out, first.pid)
    second = start("fit", data_csv, "--out", out, "--iterations", "400", "--seed", "2", *FIT)
    _, lost = second.communicate(timeout=600)
    first.communicate(timeout=600)
    assert (first.returncode, second.returncode) == (0, 2), lost
    line, = lost.strip().splitlines()  # exactly one line on stderr
    assert line.startswith("symplid: error:") and "another symplid process" in line
    assert f"pid {first.pid}" in line
    # The folder is the first fit's alone: the seed of its settings is the one of its draws.
    assert "seed = 1" in (out / "settings.toml").read_text()
    import h5netcdf

    with h5netcdf.File(out / "posterior.nc", "r") as f:
        assert int(f.attrs["seed"]) == 1
    assert not (out / ".incomplete").exists() and not (out / FolderLock.NAME).exists()
    assert json.loads((out / "summary.json").read_text())["interrupted"] is False


def _wait_for_lock(out: Path, pid: int, timeout: float = 120) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if FolderLock(out).holder() == pid:
            return
        time.sleep(0.1)
    raise AssertionError(f"{out}: the fit never took the lock")


def test_a_report_while_fitting_is_refused_and_sigkill_leaves_no_stale_lock(data_csv, tmp_path):
    out = tmp_path / "run"
    long = start("fit", data_csv, "--out", out, "--iterations", "10000000", *FIT)
    try:
        _wait_for_lock(out, long.pid)
        report = subprocess.run([sys.executable, "-m", "symplid.cli", "report", str(out)],
                                capture_output=True, text=True, timeout=300)
        assert report.returncode == 2
        line, = errors(report.stderr)
        assert "is writing this run folder now" in line, line
        assert FolderLock(out).held_elsewhere()
    finally:
        long.send_signal(signal.SIGKILL)
        long.communicate(timeout=60)
    assert long.returncode == -signal.SIGKILL
    assert not FolderLock(out).held_elsewhere()  # the kernel released it with the process
    again = subprocess.run([sys.executable, "-m", "symplid.cli", "fit", str(data_csv), "--out",
                            str(out), "--iterations", "400", *FIT],
                           capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr


def test_the_lock_is_exclusive_between_open_files(tmp_path):
    """Two FolderLocks (two open files, as two processes have) on one folder."""
    one, two = FolderLock(tmp_path), FolderLock(tmp_path)
    one.acquire()
    assert two.held_elsewhere() and two.holder() == os.getpid()
    with pytest.raises(FolderLockedError, match=f"pid {os.getpid()}"):
        two.acquire()
    one.release()
    assert not (tmp_path / FolderLock.NAME).exists()
    two.acquire()
    assert two.held and one.held_elsewhere()
    two.release()
