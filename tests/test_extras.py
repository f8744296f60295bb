"""The ``sweeps`` extra: Dask and pyarrow are needed by the sweeps only.

Without them, the core, the command line and ``symplid reproduce`` still import, and a sweep
command stops before it starts with one line naming the install command. "Not installed" is
made by ``sys.modules[name] = None``, under which ``import name`` raises ``ImportError``
exactly as for a package that is absent.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from symplid.cli import main

SRC = Path(__file__).resolve().parents[1] / "src"
SWEEP_ONLY = ("dask", "distributed", "pyarrow")

_WITHOUT_SWEEP_MODULES = """
import sys
for name in {blocked!r}:
    sys.modules[name] = None                      # as if not installed
import symplid
from symplid.cli import main                      # every command's module
from symplid.studies._paper import PaperConfig, reproduce   # what `symplid reproduce` imports
import symplid.studies, symplid.workflow._sweep, symplid.workflow._fit
loaded = sorted(m for m, v in sys.modules.items()
                if v is not None and m.split(".")[0] in {blocked!r})
print("loaded:", loaded)
"""


def test_the_core_and_reproduce_import_without_dask_or_pyarrow():
    code = _WITHOUT_SWEEP_MODULES.format(blocked=SWEEP_ONLY)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={"PYTHONPATH": str(SRC), "PATH": "/usr/bin:/bin",
                              "JAX_PLATFORMS": "cpu"}, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "loaded: []" in out.stdout


@pytest.mark.parametrize("missing", [("dask.distributed",), ("pyarrow",)])
def test_a_sweep_without_the_sweeps_extra_is_one_line_and_exit_2(tmp_path, monkeypatch,
                                                                 missing):
    for name in missing:
        monkeypatch.setitem(sys.modules, name, None)
    spec = tmp_path / "sweep.toml"
    spec.write_text("[sweep]\ngrid = { seed = [0, 1] }\n", encoding="utf-8")
    out = tmp_path / "out"
    result = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out)])
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, lines
    assert lines[0] == (f"symplid: error: a sweep needs {missing[0]}, which is not installed: "
                        "pip install 'symplid[sweeps]'")
    assert not out.exists()  # stopped before it started


def test_the_study_commands_need_the_extra_too(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "dask.distributed", None)
    result = CliRunner().invoke(main, ["study", "paper-claims", "--out", str(tmp_path / "o"),
                                       "--seeds", "1", "--budget", "quick", "--variants", "none"])
    assert result.exit_code == 2, result.output
    assert "pip install 'symplid[sweeps]'" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
