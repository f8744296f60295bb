"""The baselines study: its cells, one baseline and one posterior cell, and its report."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

import symplid
from symplid.cli import main
from symplid.inference import _baselines as baselines
from symplid.studies._baselines_report import (
    deciding_numbers,
    format_report,
    medians,
    plot_error_vs_size,
)
from symplid.studies._baselines_study import (
    METHODS,
    _energy,
    baselines_spec,
    cell_data,
    run_cell,
)
from symplid.workflow._experiment import EXPERIMENTS
from symplid.workflow._sweep import SweepError, resolve_cell

TINY = {"num_obs": 12, "t_span": 30.0, "budget": "quick", "t_end": 30.0}


def cell(**kw):
    return resolve_cell({**TINY, **kw}, experiment="baselines")


def test_spec_has_one_cell_per_seed_size_method_and_potential():
    spec = baselines_spec(seeds=3, sizes=(20, 50), potentials=("polynomial", "mlp"),
                          mlp_seeds=1)
    assert EXPERIMENTS.get_entry("baselines").name == spec.experiment == "baselines"
    methods = set(METHODS.names())
    assert methods == {"ukf-leapfrog", "ukf-rk2", "hnn", "euler", "rk4", "leapfrog-ls"}
    assert len(spec.cells) == (3 + 1) * 2 * len(methods)
    assert len(set(spec.ids)) == len(spec.cells)
    mlp = [c for c in spec.cells if c.settings["potential"] == "mlp"]
    assert {c.settings["seed"] for c in mlp} == {0}
    with pytest.raises(SweepError, match="potential"):
        baselines_spec(seeds=1, potentials=("spline",))
    with pytest.raises(ValueError, match="seeds"):
        baselines_spec(seeds=0)


def test_baseline_cell_is_the_baseline_fit_scored_against_the_truth(hh):
    c = cell(method="rk4", seed=2)
    metrics = run_cell(c)
    data = cell_data(c)
    np.testing.assert_allclose(data.times, np.linspace(2.5, 30.0, 12))
    coef = baselines.fit(hh.potential, data, "rk4")
    x0 = hh.initial_state
    h = float(symplid.hamiltonian(hh.potential, coef, x0))
    h_true = float(symplid.hamiltonian(hh.potential, hh.coefficients, x0))
    assert metrics["hamiltonian_rel_error"] == pytest.approx(abs(h - h_true) / h_true, rel=1e-9)
    assert metrics["coefficient_error"] == pytest.approx(np.max(np.abs(coef - hh.coefficients)))
    assert 0 < metrics["prediction_horizon_s"] <= 30.0
    assert math.isnan(metrics["h_covered"])  # a point estimate has no interval


def test_posterior_cell_beats_the_finite_difference_loss_and_covers(hh):
    ukf = run_cell(cell(method="ukf-leapfrog"))
    hnn = run_cell(cell(method="hnn"))
    assert ukf["hamiltonian_rel_error"] < hnn["hamiltonian_rel_error"]
    assert ukf["coefficient_error"] < hnn["coefficient_error"]
    assert ukf["h_covered"] in (0.0, 1.0) and 0 <= ukf["coefficient_coverage"] <= 1


def test_energy_of_a_network_is_measured_from_u_at_the_origin():
    U = symplid.MLPPotential(dim=2, width=4, depth=1, seed=1)
    w = U.initial_coefficients()
    x0 = np.array([0.2, -0.25, 0.3, -0.25])
    net = U.network(w)
    expected = 0.5 * (0.3**2 + 0.25**2) + float(net(x0[:2])) - float(net(np.zeros(2)))
    assert _energy(U, w, x0)[0] == pytest.approx(expected, rel=1e-12)
    assert _energy(U, np.stack([w, 2 * w]), x0).shape == (2,)


def _table():
    """A hand-made results table with known medians."""
    rows = []
    errors = {  # method: {n: error per seed}
        "ukf-leapfrog": {20: [0.01, 0.02, 0.03], 50: [0.005] * 3},
        "hnn": {20: [0.2, 0.4, 0.6], 50: [0.1] * 3},
        "rk4": {20: [0.1, 0.1, 0.1], 50: [0.02, 0.01, 0.02]},
        "euler": {20: [np.inf, 0.3, 0.3], 50: [0.3] * 3},
    }
    for method, by_n in errors.items():
        for n, values in by_n.items():
            for seed, v in enumerate(values):
                rows.append({"cell_id": f"{method}{n}{seed}", "seed": seed, "num_obs": n,
                             "method": method, "potential": "polynomial", "status": "ok",
                             "hamiltonian_rel_error": v, "prediction_horizon_s": 10.0 * n,
                             "h_covered": float(seed < 2) if method == "ukf-leapfrog" else np.nan})
    rows.append({**rows[0], "cell_id": "bad", "status": "failed", "hamiltonian_rel_error": 9.0})
    return pd.DataFrame(rows)


def test_deciding_numbers_from_the_medians():
    table = _table()
    med = medians(table, "hamiltonian_rel_error")
    assert med[("polynomial", "ukf-leapfrog", 20)] == (pytest.approx(0.02), 3)  # failed row out
    assert med[("polynomial", "euler", 20)][0] == pytest.approx(0.3)  # ∞ is a large value
    coverage = medians(table, "h_covered")[("polynomial", "ukf-leapfrog", 20)][0]
    assert coverage == pytest.approx(2 / 3)
    d = deciding_numbers(table)["polynomial"]
    assert d["n0"] == 20 and d["reference_error"] == pytest.approx(0.02)
    assert d["methods"]["hnn"] == {"ratio": pytest.approx(20.0), "reached_at": None,
                                   "largest_size": 50}
    assert d["methods"]["rk4"] == {"ratio": pytest.approx(5.0), "reached_at": 50,
                                   "largest_size": 50}
    text = format_report(table, {"posterior": "MAP + Laplace"})
    assert "ratio 20 at n = 20; does not reach it by n = 50" in text
    assert "ratio 5 at n = 20; reaches it at n = 50" in text
    assert "| polynomial | HNN loss, eq. 1 | 0.4 | 0.1 |" in text


def test_figure_has_one_file_per_metric(tmp_path):
    paths = plot_error_vs_size(_table(), tmp_path)
    assert set(paths) == {"hamiltonian_rel_error", "prediction_horizon_s"}
    assert all(p.stat().st_size > 1000 for p in paths.values())


def test_cli_study_rejects_an_unknown_potential_in_one_line(tmp_path):
    out = CliRunner().invoke(main, ["study", "baselines", "--out", str(tmp_path / "s"),
                                    "--potentials", "spline", "--no-progress"])
    assert out.exit_code == 2 and "Traceback" not in out.output
    assert "potential" in out.output
