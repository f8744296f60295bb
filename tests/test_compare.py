"""Model comparison by the Laplace evidence (symplid.workflow._compare).

The end-to-end check: on the quartic double well U = −½q² + ¼q⁴ (30 full-state observations,
noise sd 0.05), the evidence over polynomial orders 2..5 must pick the true order 4. Orders 2
and 3 cannot make two wells; order 5 nests order 4, so it fits as well but pays an Occam
factor for its unneeded q⁵ coefficient.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

import symplid
from symplid.io import positions_only
from symplid.workflow._compare import (
    COLUMNS,
    compare_models,
    comparison_table,
    format_table,
    parse_integrators,
    parse_orders,
)
from symplid.workflow._settings import Settings, merge_overrides


# ----------------------------------------------------------------------------- parsing
@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("2..5", [2, 3, 4, 5]),
        ("3", [3]),
        ("2,4", [2, 4]),
        ("2..3,5, 7", [2, 3, 5, 7]),
        ("2-4", [2, 3, 4]),
        ("5,2..3,2", [2, 3, 5]),
        (4, [4]),
        ([5, 3, 3], [3, 5]),
    ],
)
def test_parse_orders(text, expected):
    assert parse_orders(text) == expected


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("5..2", "'5..2' is an empty range"),
        ("two", "'two' is not an order"),
        ("2..", "'2..' is not an order"),
        ("", r"expected e\.g\."),
        ("2,,3", r"expected e\.g\."),
        ("0..3", "0 is not a polynomial order"),
        ([2.5], "2.5 is not an integer"),
        ([], "at least one order"),
        (True, r"expected e\.g\."),
    ],
)
def test_parse_orders_errors_name_the_bad_part(text, match):
    with pytest.raises(ValueError, match=match):
        parse_orders(text)


def test_parse_integrators_resolves_aliases_and_rejects_unknown_names():
    assert parse_integrators("leapfrog, rk2,yoshida4,verlet") == [
        "leapfrog", "rk2-midpoint", "yoshida4",
    ]
    assert parse_integrators(["rk4"]) == ["rk4"]
    with pytest.raises(ValueError, match=r"'leepfrog' is not a known integrator \(choose from"):
        parse_integrators("leepfrog")
    with pytest.raises(ValueError, match=r"expected e\.g\."):
        parse_integrators("leapfrog,")


# ----------------------------------------------------------------------------- the double well
@pytest.fixture(scope="module")
def double_well():
    system = symplid.get_system("double-well")
    return system, symplid.simulate(system, seed=0)


@pytest.fixture(scope="module")
def settings(double_well):
    system, _ = double_well
    # one observation variance for q and p (the data share one noise level; the default
    # "auto" would give one per kind and a parameter more to every candidate)
    return merge_overrides(
        Settings(), {"initial_state.x0": list(system.initial_state), "map.num_starts": 1,
                     "model.noise": "isotropic", "model.dt": 0.25}
    )


@pytest.fixture(scope="module")
def compared(double_well, settings, tmp_path_factory):
    """Orders 2..5 with leapfrog (four MAP searches with Hessians), written to a folder."""
    _, data = double_well
    out = tmp_path_factory.mktemp("compare")
    table = compare_models(
        data, settings, orders="2..5", integrators="leapfrog", out=out, progress=False
    )
    return table, out


def _evidence(table: pd.DataFrame) -> dict[int, float]:
    return dict(zip(table["order"], table["log_evidence"], strict=True))


@pytest.mark.slow
def test_true_order_wins_on_the_double_well(compared):
    table, _ = compared
    ev = _evidence(table)
    loglik = dict(zip(table["order"], table["log_likelihood"], strict=True))
    assert table.loc[0, "order"] == 4 and table.loc[0, "rank"] == 1
    # Orders 2 and 3 have one well: the data (which cross the barrier) reject them by far
    # more than any Occam factor (measured margins ≈ 70 nats; 20 is a Bayes factor of e²⁰).
    assert ev[4] - ev[2] > 20 and ev[4] - ev[3] > 20
    # Order 5 nests order 4: its maximum likelihood can only be higher (up to the prior's
    # pull on the extra coefficient at the MAP) ...
    assert loglik[5] >= loglik[4] - 0.1
    # ... but its extra coefficient costs an Occam factor ≈ log(σ_post·√(2π)/(2b)) with the
    # Laplace(0, b = 10) prior density 1/(2b) at 0 and a posterior sd σ_post of order 1e-2:
    # about 6 nats, against a likelihood gain of ~½χ²₁ ≈ 0.5. Measured 7.2 (seed 0) and 6.5
    # (seed 1); "does not win" is asserted with a margin of a Bayes factor e² ≈ 7.
    assert ev[4] - ev[5] > 2.0
    assert ev[4] - ev[5] < 15.0  # an Occam factor, not a failed fit


@pytest.mark.slow
def test_table_columns_probabilities_and_bic(compared, double_well):
    table, _ = compared
    _, data = double_well
    coefficient_names = ["c[q1]", "c[q1^2]", "c[q1^3]", "c[q1^4]", "c[q1^5]"]
    assert tuple(table.columns) == (*COLUMNS, *coefficient_names)
    assert list(table["rank"]) == [1, 2, 3, 4]
    # each candidate's MAP coefficients, NaN (blank in the CSV) where it has no such term
    for row in table.itertuples(index=False):
        values = table.loc[table["order"] == row.order, coefficient_names].to_numpy()[0]
        assert np.all(np.isfinite(values[: row.order])) and np.all(np.isnan(values[row.order:]))
    best = table.loc[0]
    np.testing.assert_allclose(best[coefficient_names[:4]].to_numpy(float),
                               [0.0, -0.5, 0.0, 0.25], atol=0.05)  # U = -q²/2 + q⁴/4
    assert table["evidence_method"].eq("quadrature").all()
    assert np.all(np.diff(table["log_evidence"].to_numpy()) <= 0)
    assert table.loc[0, "delta_log_evidence"] == 0.0
    # probabilities: softmax of the evidences, recomputed independently
    ev = table["log_evidence"].to_numpy()
    expected = np.exp(ev - ev.max()) / np.sum(np.exp(ev - ev.max()))
    np.testing.assert_allclose(table["probability"], expected, rtol=1e-12)
    assert math.isclose(table["probability"].sum(), 1.0, rel_tol=1e-12)
    # parameters: order coefficients + process and observation variances (known x0)
    np.testing.assert_array_equal(table["num_params"], table["order"] + 2)
    # BIC with n = 60 measured values (30 times, q and p)
    n = data.values.size
    np.testing.assert_allclose(
        table["bic"], -2 * table["log_likelihood"] + table["num_params"] * np.log(n)
    )
    assert table["integrator"].eq("leapfrog").all()
    assert table["converged"].all()
    # the true model with leapfrog: the process noise is negligible (the paper's finding;
    # here it sits on its bound) and the observation variance is near the true 0.05²
    best = table.loc[0]
    assert best["process_var"] < 1e-5
    # on its floor, but integrated by quadrature in the evidence: not flagged "on a bound"
    assert "process_var" not in best["at_bounds"]
    assert (best["process_var"] > 1e-13) or best["at_floor"] == "process_var"
    assert 0.5 * 0.05**2 < best["obs_var"] < 2 * 0.05**2


@pytest.mark.slow
def test_files_hold_the_table(compared):
    table, out = compared
    back = pd.read_csv(out / "compare.csv", keep_default_na=False)
    assert tuple(back.columns[: len(COLUMNS)]) == COLUMNS
    assert (back.loc[table["order"].to_numpy() == 2, "c[q1^3]"] == "").all()  # blank
    for column in ("order", "num_params", "rank"):
        np.testing.assert_array_equal(back[column], table[column])
    for column in ("log_evidence", "log_likelihood", "bic", "probability"):
        np.testing.assert_allclose(back[column], table[column], rtol=1e-9)
    text = (out / "compare.txt").read_text()
    assert text.startswith("Model comparison: 4 candidate(s), 60 measured values")
    lines = text.splitlines()
    first_row = next(line for line in lines if line.strip().startswith("1 "))
    assert first_row.split()[:3] == ["1", "4", "leapfrog"]
    assert f"{table.loc[0, 'log_evidence']:.2f}" in first_row


def test_table_ranks_nan_evidence_last():
    """A candidate whose Hessian failed (NaN evidence) goes last, with probability 0."""

    class _Posterior:
        num_params = 3
        param_groups = ("coefficients", "process_var", "obs_var")
        datasets = (symplid.Observations([1.0, 2.0], [[0.0, 1.0], [1.0, np.nan]]),)

    class _Map:
        def __init__(self, ev):
            self.log_evidence, self.log_posterior = ev, 0.0
            self.theta, self.at_bounds, self.success = np.array([1.0, 2.0, 3.0]), (), True

    from symplid.workflow._compare import CandidateFit

    fits = [
        CandidateFit(o, "leapfrog", None, _Posterior(), _Map(ev), -1.0, 0.1)
        for o, ev in ((2, math.nan), (3, -5.0), (4, -2.0))
    ]
    table = comparison_table(fits)
    assert list(table["order"]) == [4, 3, 2]
    np.testing.assert_allclose(
        table["probability"], [1 / (1 + math.exp(-3)), math.exp(-3) / (1 + math.exp(-3)), 0]
    )
    assert math.isnan(table.loc[2, "delta_log_evidence"])
    # n = 3 measured values (one NaN)
    np.testing.assert_allclose(table["bic"], 2.0 + 3 * math.log(3))
    assert table.loc[0, "process_var"] == 2.0 and table.loc[0, "obs_var"] == 3.0
    last_row = next(line for line in format_table(table).splitlines()
                    if line.strip().startswith("3 "))
    assert "nan" in last_row


def test_bound_flag_and_coefficient_columns():
    """A variance on its floor is flagged "on a bound" only when the evidence did not
    integrate it; coefficient columns are the union of the candidates' names."""
    from symplid.workflow._compare import CandidateFit

    class _Posterior:
        def __init__(self, names):
            self.param_names = (*names, "process_var", "obs_var")
            self.param_groups = ("coefficients",) * len(names) + ("process_var", "obs_var")
            self.num_params = len(self.param_names)
            self.datasets = (symplid.Observations([1.0, 2.0], [[0.0, 1.0], [1.0, 0.5]]),)

    class _Map:
        def __init__(self, theta, method, bounds):
            self.theta, self.at_bounds, self.success = np.asarray(theta), bounds, True
            self.log_evidence, self.log_posterior = -float(len(theta)), 0.0
            self.evidence_method, self.log_evidence_laplace = method, -10.0
            self.evidence = {"variances": ["process_var", "obs_var"]} if method != "laplace" \
                else {}

    fits = [
        CandidateFit(1, "leapfrog", None, _Posterior(["q1"]),
                     _Map([0.5, 1e-14, 0.1], "quadrature", ("process_var",)), -1.0, 0.1),
        CandidateFit(2, "leapfrog", None, _Posterior(["q1", "q1^2"]),
                     _Map([0.1, 0.2, 1e-14, 0.1], "laplace", ("process_var",)), -1.0, 0.1),
        CandidateFit(3, "leapfrog", None, _Posterior(["q1", "order"]),
                     _Map([0.3, 7.0, 1e-14, 0.1], "quadrature", ("order", "process_var")),
                     -1.0, 0.1),
    ]
    table = comparison_table(fits).set_index("order")
    assert tuple(table.columns[-3:]) == ("q1", "q1^2", "coef:order")
    assert table.loc[1, "at_bounds"] == "" and table.loc[1, "at_floor"] == "process_var"
    assert table.loc[2, "at_bounds"] == "process_var"  # the Laplace evidence: flagged
    assert table.loc[3, "at_bounds"] == "order"  # a coefficient on a bound stays flagged
    assert table.loc[1, "q1"] == 0.5 and np.isnan(table.loc[1, "q1^2"])
    assert table.loc[3, "coef:order"] == 7.0 and table.loc[2, "evidence_method"] == "laplace"
    np.testing.assert_allclose(table["log_evidence_laplace"], -10.0)


def test_compare_models_checks_its_inputs(double_well, settings):
    _, data = double_well
    with pytest.raises(ValueError, match="orders: 'x' is not an order"):
        compare_models(data, settings, orders="x", progress=False)
    with pytest.raises(ValueError, match="'rk3' is not a known integrator"):
        compare_models(data, settings, orders="4", integrators="rk3", progress=False)
    with pytest.raises(ValueError, match="mode is 'known' but 2 trajectories were given"):
        compare_models([data, data], settings, orders="4", progress=False)
    learned = merge_overrides(settings, {"initial_state.mode": "learned"})
    positions = positions_only(data)
    with pytest.raises(symplid.DataError, match="trajectories compared together must share"):
        compare_models([data, positions], learned, orders="4", progress=False)
    with pytest.raises(TypeError, match=r"obs\[1\] must be a symplid.Observations"):
        compare_models([data, "x"], settings, orders="4", progress=False)


def test_a_non_separable_user_h_is_compared_with_the_integrator_its_fit_uses():
    """A user's non-separable H with the default leapfrog is fitted with Tao's method; compare
    without --integrators takes the same (it used to build the candidate with leapfrog and
    stop with a traceback). Data: SciPy DOP853 of H = ½p²(1 + a q²) + ½k q²."""
    from scipy.integrate import solve_ivp

    from symplid.model._data import Observations
    from symplid.workflow._settings import settings_from_dict

    a, k = 0.5, 2.0
    times = 0.5 * np.arange(1, 31)
    flow = solve_ivp(lambda _t, x: [x[1] * (1 + a * x[0] ** 2), -(a * x[0] * x[1] ** 2 + k * x[0])],
                     (0.0, times[-1]), [1.0, 0.0], t_eval=times, rtol=1e-11, atol=1e-12)
    noise = 0.02 * np.random.default_rng(0).standard_normal((times.size, 2))
    obs = Observations(times=times, values=flow.y.T + noise, names=("q1", "p1"))
    settings = settings_from_dict({
        "model": {"hamiltonian": "0.5*p1^2*(1 + a*q1^2) + 0.5*k*q1^2", "dt": 0.1,
                  "parameters": {"a": {"prior": "half-normal", "scale": 2},
                                 "k": {"prior": "half-normal", "scale": 5}}},
        "initial_state": {"x0": [1.0, 0.0]}, "map": {"num_starts": 1}})
    assert settings.model.integrator == "leapfrog"
    table = compare_models(obs, settings, progress=False)
    assert list(table["integrator"]) == ["tao"]
    assert bool(table.loc[0, "converged"]) and np.isfinite(table.loc[0, "log_evidence"])
    assert table.loc[0, "a"] == pytest.approx(a, rel=0.05)  # measured 0.508
    assert table.loc[0, "k"] == pytest.approx(k, rel=0.05)  # measured 1.989
