"""The driven examples from the command line with their configurations as shipped: every
true value inside its 95 % interval (a forced Duffing oscillator and a driven damped
pendulum, each from a multisine record of 200 noisy positions simulated by DOP853)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from symplid.cli import main

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "driven"


def _simulator():
    spec = importlib.util.spec_from_file_location("driven_data", EXAMPLES / "driven_data.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.long
@pytest.mark.parametrize("system", ["duffing", "pendulum"])
def test_a_driven_example_holds_every_true_value(tmp_path, system):
    import arviz as az

    sim = _simulator()
    data = tmp_path / f"{system}.csv"
    sim.write(data, *sim.simulate(system))
    out = tmp_path / "run"
    result = CliRunner().invoke(main, ["fit", str(data), "--config",
                                       str(EXAMPLES / f"{system}.toml"), "--out", str(out),
                                       "--no-progress"], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    posterior = az.from_netcdf(out / "posterior.nc").posterior
    for name, truth in sim.TRUTH[system].items():
        lo, hi = np.quantile(np.asarray(posterior[name]).ravel(), [0.025, 0.975])
        assert lo < truth < hi, (name, lo, truth, hi)
    assert "## Power balance" in (out / "report.md").read_text()
