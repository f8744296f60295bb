"""The fit's convergence columns (R-hat, bulk and tail ESS) equal ArviZ's ``summary``.

:func:`symplid.inference.diagnostics.convergence_table` reimplements the rank normalisation
(and R-hat) for speed; ArviZ's own ``az.summary`` is the independent reference. The draws
are autocorrelated AR(1) chains with repeated values (as a Metropolis chain's rejections
make), so that ties in the ranks matter, one chain shifted so that R-hat is far from 1, a
vector parameter, and the short and single-chain cases where ArviZ gives NaN.
"""

from __future__ import annotations

import numpy as np
import pytest

from symplid.inference.diagnostics import convergence_table, import_arviz, summary

az = import_arviz()
COLUMNS = ["ess_bulk", "ess_tail", "r_hat"]


def _chains(rng: np.random.Generator, chains: int, draws: int, rho: float = 0.9) -> np.ndarray:
    out = np.empty((chains, draws))
    out[:, 0] = rng.normal(size=chains)
    for t in range(1, draws):
        out[:, t] = rho * out[:, t - 1] + np.sqrt(1 - rho**2) * rng.normal(size=chains)
    stay = rng.random((chains, draws)) < 0.3  # a rejected proposal repeats the last value
    for t in range(1, draws):
        out[:, t] = np.where(stay[:, t], out[:, t - 1], out[:, t])
    return out


def _reference(idata):
    return az.summary(idata, round_to="none")[COLUMNS]


@pytest.mark.parametrize(("chains", "draws"), [(4, 2000), (2, 501), (1, 300)])
def test_equals_arviz_summary(chains, draws):
    rng = np.random.default_rng(chains * 1000 + draws)
    a = _chains(rng, chains, draws)
    a[0] += 0.5  # one chain elsewhere: R-hat well above 1 (when there are several)
    b = np.stack([_chains(rng, chains, draws) for _ in range(3)], axis=-1)
    idata = az.from_dict(posterior={"a": a, "b": b, "rounded": np.round(a, 1)})
    ours = convergence_table(idata)
    ref = _reference(idata)
    assert list(ours.index) == list(ref.index)
    np.testing.assert_allclose(ours[COLUMNS].to_numpy(), ref.to_numpy(), rtol=1e-12,
                               atol=0, equal_nan=True)
    if chains > 1:
        assert ours.loc["a", "r_hat"] > 1.01


def test_too_few_draws_is_nan_as_in_arviz():
    rng = np.random.default_rng(3)
    idata = az.from_dict(posterior={"x": rng.normal(size=(4, 3))})
    assert np.isnan(convergence_table(idata).to_numpy()).all()
    assert np.isnan(_reference(idata).to_numpy()).all()


def test_summary_convergence_columns_match_the_full_table():
    rng = np.random.default_rng(5)
    idata = az.from_dict(posterior={"x": _chains(rng, 4, 1000)})
    full = summary(idata, show=False, warn=False)
    short = summary(idata, show=False, warn=False, columns="convergence")
    assert list(short.columns) == COLUMNS
    np.testing.assert_allclose(short.to_numpy(), full[COLUMNS].to_numpy(), rtol=1e-12)
    with pytest.raises(ValueError, match="columns"):
        summary(idata, show=False, columns="some")
