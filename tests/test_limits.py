"""Resource limits and one-line rules (issue 23, classes 6 and 7).

A sampler whose chains × draws × parameters cannot fit in memory is refused before anything is
allocated, in one line, like a gap needing too many substeps. The memory estimate is checked
against what real samplers record (an upper bound of the bytes of their draws).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from sampler_targets import Gaussian2D
from symplid.cli import main
from symplid.sampling import RunOptions, sample
from symplid.workflow import _settings_data as settings_data
from symplid.workflow._settings import Settings, SettingsError, merge_overrides


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def one_line(result, *words, code=2) -> str:
    lines = result.output.strip().splitlines()
    assert result.exit_code == code, result.output
    assert len(lines) == 1 and lines[0].startswith("symplid: error:"), result.output
    for word in words:
        assert word in lines[0], lines[0]
    return lines[0]



# ----------------------------------------------------------------------------- class 6: memory
def test_a_hundred_thousand_chains_are_one_line_before_any_allocation(data_csv, tmp_path):
    out = tmp_path / "run"
    line = one_line(run("fit", data_csv, "--out", out, "--order", "2", "--x0", "1,0",
                        "--no-progress", "--set", "sampler.num_chains=100000"),
                    "sampler.num_chains", "GiB of memory")
    assert "100,000" in line
    assert not out.exists()  # refused before the run folder was made


def test_the_memory_check_uses_the_machine_s_memory(data_csv, tmp_path, monkeypatch):
    """The same settings pass with a larger machine and fail with a smaller one."""
    settings = merge_overrides(Settings(), {"sampler.num_chains": 4}, source="test")
    need = settings_data.run_memory(settings, num_params=5, num_times=12, state_dim=2)
    monkeypatch.setattr(settings_data, "available_memory", lambda: need)
    settings_data._check_memory(settings, 5, 12, 2, "test")
    monkeypatch.setattr(settings_data, "available_memory", lambda: need - 1)
    with pytest.raises(SettingsError, match=r"sampler\.num_chains"):
        settings_data._check_memory(settings, 5, 12, 2, "test")
    monkeypatch.setattr(settings_data, "available_memory", lambda: None)  # unknown: no check
    settings_data._check_memory(settings, 5, 12, 2, "test")


@pytest.mark.parametrize("method", ["dram", "nuts"])
def test_the_estimate_bounds_what_the_samplers_record(method):
    """Three copies of every recorded array (θ and every statistic) fit in the estimate."""
    target = Gaussian2D()
    chains, draws, burn_in = 3, 60, 20
    idata = sample(target, method, init=target.map_result(), num_draws=draws,
                   num_chains=chains, burn_in=burn_in, options=RunOptions(progress=False))
    recorded = sum(v.values.nbytes for v in idata.posterior.data_vars.values())
    recorded += sum(np.asarray(v.values, dtype=np.float64).nbytes
                    for v in idata.sample_stats.data_vars.values())
    settings = merge_overrides(Settings(), {"sampler.num_chains": chains,
                                            "sampler.num_iterations": draws + burn_in,
                                            "sampler.burn_in": burn_in}, source="test")
    estimate = settings_data.run_memory(settings, num_params=2, num_times=0, state_dim=0)
    assert 3 * recorded <= estimate


# ----------------------------------------------------------------------------- class 7: one line
def symplid(*args, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "symplid.cli", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, timeout=300)


def stderr_is_one_line(result, *words) -> None:
    """Exactly one line on stderr (no warning before it, nothing after), exit code 2."""
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("symplid: error:"), result.stderr
    for word in words:
        assert word in lines[0], lines[0]


TWO_NAMES = {
    "options": ["--samples", "400", "--iterations", "400"],
    "set": ["--set", "sampler.num_samples=400", "--set", "sampler.num_iterations=400"],
    "toml": ["--config", "{dir}/both.toml"],
}


@pytest.mark.parametrize("how", list(TWO_NAMES))
def test_old_and_new_name_together_are_one_line(data_csv, tmp_path, how):
    (tmp_path / "both.toml").write_text("[sampler]\nnum_samples = 400\nnum_iterations = 400\n")
    args = [a.format(dir=tmp_path) for a in TWO_NAMES[how]]
    result = symplid("fit", data_csv, "--out", tmp_path / "run", "--no-progress", *args)
    stderr_is_one_line(result, "same")
    assert "deprecated" not in result.stderr


@pytest.mark.parametrize("where", [
    "[base]\nnum_samples = 100\nnum_iterations = 100\n",
    "[sweep]\ncells = [{num_samples = 100, num_iterations = 100}]\n",
])
def test_old_and_new_name_in_a_sweep_are_one_line(tmp_path, where):
    spec = tmp_path / "sweep.toml"
    spec.write_text(where)
    stderr_is_one_line(symplid("sweep", spec, "--out", tmp_path / "out", "--no-progress"),
                       "num_samples and num_iterations", "same setting")


def test_a_sweep_cell_with_burn_in_beyond_its_iterations_is_one_line(tmp_path):
    spec = tmp_path / "sweep.toml"
    spec.write_text("[base]\nnum_iterations = 100\nburn_in = 50\n"
                    "[sweep]\ngrid = { burn_in = [10, 200] }\n")
    stderr_is_one_line(symplid("sweep", spec, "--out", tmp_path / "out", "--no-progress"),
                       "burn_in = 200", "must be greater than sampler.burn_in (200)")


def test_data_values_of_1e200_are_one_line(tmp_path):
    t = np.arange(1, 13.0)
    q = np.cos(t)
    q[3] = 1e200
    data = tmp_path / "big.csv"
    data.write_text("t,q1,p1\n" + "".join(f"{a!r},{b!r},{c!r}\n" for a, b, c in
                                          zip(t.tolist(), q.tolist(), (-np.sin(t)).tolist(),
                                              strict=True)))
    result = symplid("fit", data, "--out", tmp_path / "run", "--order", "2", "--x0", "1,0",
                     "--no-progress")
    stderr_is_one_line(result, "1e+200", "q1", "t = 4")
    assert not (tmp_path / "run").exists()
