"""File-system faults made for real (issue 23, class 4): one line, no crash, no temporary file.

A read-only output folder (a read-only bind mount, or an immutable folder where mounting is not
allowed; tests run as root, for whom permission bits stop nothing), a file-size limit
(``RLIMIT_FSIZE`` in a subprocess) and a full file system (a tiny tmpfs) while a fit writes its
files. A user's fault (read-only) is exit code 2, the environment's (full, too large) exit
code 1; the run is marked failed and no hidden temporary file is left.
"""

from __future__ import annotations

import contextlib
import os
import resource
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

FIT = ["--order", "2", "--x0", "1,0", "--iterations", "400", "--burn-in", "200", "--chains",
       "2", "--no-progress", "--no-report", "--set", "map.num_starts=1"]
FIT += ["--dt", "0.25"]  # a fixed step: the step search is test_step_size.py's
FIT += ["--set", "map.sensitivity=false"]  # the MAP refits: test_fit_diagnostics.py


def symplid(*args, limit_bytes: int | None = None, timeout: float = 300):
    """``python -m symplid.cli ARGS`` in a subprocess (optionally under RLIMIT_FSIZE)."""

    def limit() -> None:
        if limit_bytes is not None:
            resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, resource.RLIM_INFINITY))

    env = {**os.environ, "SYMPLID_CACHE_DIR": "off"}  # the cache would meet the limit too
    return subprocess.run([sys.executable, "-m", "symplid.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=timeout, env=env,
                          preexec_fn=limit)


def one_error_line(result, *words, code: int) -> str:
    assert result.returncode == code, result.stderr
    assert "Traceback" not in result.stderr, result.stderr
    errors = [line for line in result.stderr.splitlines() if not line.startswith(
        "symplid: warning:")]
    assert len(errors) == 1 and errors[0].startswith("symplid: error:"), result.stderr
    for word in words:
        assert word in errors[0], errors[0]
    return errors[0]


def no_temporary_files(folder: Path) -> None:
    assert not [p for p in folder.rglob(".*.tmp*")], sorted(folder.rglob("*"))


def _run(*command: str) -> bool:
    return subprocess.run(command, capture_output=True).returncode == 0


def _writable(folder: Path) -> bool:
    try:
        (folder / ".probe").write_text("x")
    except OSError:
        return False
    (folder / ".probe").unlink()
    return True


@contextlib.contextmanager
def read_only(folder: Path) -> Iterator[None]:
    """``folder`` read-only for this process, or the test skipped where it cannot be made."""
    if os.geteuid() != 0:
        folder.chmod(0o555)
        try:
            if _writable(folder):
                pytest.skip("a read-only folder cannot be made here")
            yield
        finally:
            folder.chmod(0o755)
        return
    if _run("mount", "--bind", str(folder), str(folder)):
        try:
            if _run("mount", "-o", "remount,bind,ro", str(folder)) and not _writable(folder):
                yield
                return
        finally:
            _run("umount", str(folder))
    if _run("chattr", "+i", str(folder)):
        try:
            if not _writable(folder):
                yield
                return
        finally:
            _run("chattr", "-i", str(folder))
    pytest.skip("neither a read-only bind mount nor an immutable folder can be made here")


@contextlib.contextmanager
def tiny_file_system(folder: Path, size: str) -> Iterator[Path]:
    folder.mkdir()
    if os.geteuid() != 0 or not _run("mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs",
                                     str(folder)):
        pytest.skip("a small tmpfs cannot be mounted here")
    try:
        yield folder
    finally:
        _run("umount", str(folder))



@pytest.fixture(scope="module")
def finished(data_csv, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("runs") / "finished"
    result = symplid("fit", data_csv, "--out", out, *FIT)
    assert result.returncode == 0, result.stderr
    return out


def test_a_read_only_output_parent_is_one_line(data_csv, tmp_path):
    parent = tmp_path / "parent"
    parent.mkdir()
    with read_only(parent):
        result = symplid("fit", data_csv, "--out", parent / "run", *FIT)
        one_error_line(result, f"{parent / 'run'}", "cannot write", code=2)
    assert not (parent / "run").exists()


@pytest.mark.parametrize("command", [["predict", "--t-end", "15", "--num-paths", "2"],
                                     ["report"], ["predict", "--from", "end", "--t-end", "15"]])
def test_updating_a_read_only_run_is_one_line_and_changes_nothing(finished, tmp_path, command):
    run = tmp_path / "run"
    shutil.copytree(finished, run)
    before = {p.name: p.read_bytes() for p in run.iterdir()}
    with read_only(run):
        result = symplid(command[0], run, *command[1:])
        one_error_line(result, str(run), "cannot write", code=2)
    assert {p.name: p.read_bytes() for p in run.iterdir()} == before  # still finished


def test_a_file_size_limit_while_writing_the_posterior(data_csv, tmp_path):
    """posterior.nc (~70 kB) passes a 40 kB limit that the other files do not reach: exit 1,
    one line, the run marked failed, no temporary file (HDF5 writing to disk crashed here)."""
    out = tmp_path / "run"
    result = symplid("fit", data_csv, "--out", out, *FIT, limit_bytes=40_000)
    one_error_line(result, f"{out / 'posterior.nc'}", "File too large", code=1)
    assert (out / ".incomplete").read_text().startswith("failed: StorageError")
    assert not (out / "posterior.nc").exists()
    no_temporary_files(out)


def test_a_full_file_system_while_writing_the_posterior(data_csv, tmp_path):
    with tiny_file_system(tmp_path / "small", "32k") as small:
        out = small / "run"
        result = symplid("fit", data_csv, "--out", out, *FIT)
        line = one_error_line(result, "No space left on device", code=1)
        assert str(out) in line
        assert (out / ".incomplete").exists()
        assert not (out / "posterior.nc").exists()
        no_temporary_files(out)


def test_write_bytes_survives_a_default_sigxfsz():
    """A host program may leave SIGXFSZ at its default (kill): writing past the limit is
    still an exception."""
    code = (
        "import resource, signal, sys, tempfile\n"
        "from symplid.io._files import StorageError, write_bytes\n"
        "signal.signal(signal.SIGXFSZ, signal.SIG_DFL)\n"
        "resource.setrlimit(resource.RLIMIT_FSIZE, (1000, resource.RLIM_INFINITY))\n"
        "folder = tempfile.mkdtemp()\n"
        "try:\n"
        "    write_bytes(folder + '/big', bytes(5000))\n"
        "except StorageError as err:\n"
        "    print(err); import os; print(os.listdir(folder)); sys.exit(3)\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 3, (result.returncode, result.stderr)
    assert "File too large" in result.stdout and result.stdout.strip().endswith("[]")
