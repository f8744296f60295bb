"""The fit's convergence columns (R-hat, bulk and tail ESS) equal ArviZ's ``summary``.

:func:`symplid.inference._diagnostics.convergence_table` reimplements the rank normalisation
(and R-hat) for speed; ArviZ's own ``az.summary`` is the independent reference. The draws
are autocorrelated AR(1) chains with repeated values (as a Metropolis chain's rejections
make), so that ties in the ranks matter, one chain shifted so that R-hat is far from 1, a
vector parameter, and the short and single-chain cases where ArviZ gives NaN.
"""

from __future__ import annotations

import numpy as np
import pytest

from symplid.inference._diagnostics import convergence_table, import_arviz, quiet_arviz, summary

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
    with quiet_arviz():
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


# ---- against ArviZ's public functions: az.ess (bulk, tail) and az.rhat ----


def _public(idata) -> np.ndarray:
    """(parameters, 3) of ``az.ess(method="bulk")``, ``az.ess(method="tail")``, ``az.rhat``."""
    with quiet_arviz():
        bulk = az.ess(idata, method="bulk")
        tail = az.ess(idata, method="tail")
        rhat = az.rhat(idata)
    names = list(idata.posterior.data_vars)
    return np.array([[float(bulk[n]), float(tail[n]), float(rhat[n])] for n in names])


def _ours(idata) -> np.ndarray:
    return convergence_table(idata)[COLUMNS].to_numpy()


def _assert_equal_to_public(idata, columns=slice(None)) -> None:
    np.testing.assert_allclose(_ours(idata)[:, columns], _public(idata)[:, columns],
                               rtol=1e-12, atol=0, equal_nan=True)


def _ar1(rng: np.random.Generator, chains: int, draws: int, rho: float) -> np.ndarray:
    out = np.empty((chains, draws))
    out[:, 0] = rng.normal(size=chains) / np.sqrt(1 - rho**2)
    noise = rng.normal(size=(chains, draws))
    for t in range(1, draws):
        out[:, t] = rho * out[:, t - 1] + noise[:, t]
    return out


def test_strongly_autocorrelated_chains_equal_arviz():
    # τ of several hundred: Geyer's sequence runs over many lags (past the first FFT's
    # padding for ρ = 0.999, so the second, fully padded transform is exercised too)
    rng = np.random.default_rng(11)
    idata = az.from_dict(posterior={"slow": _ar1(rng, 4, 20_000, 0.99),
                                    "slower": _ar1(rng, 4, 20_000, 0.999),
                                    "anti": _ar1(rng, 4, 20_000, -0.6)})
    _assert_equal_to_public(idata)
    assert (_ours(idata)[:2, 0] < 2000).all()


def test_the_long_sequence_takes_the_fully_padded_transform(monkeypatch):
    from symplid.inference import _convergence

    calls = []
    original = _convergence._ess_lags

    def spy(stack, lags, work):
        calls.append(lags)
        return original(stack, lags, work)

    monkeypatch.setattr(_convergence, "_ess_lags", spy)
    rng = np.random.default_rng(12)
    idata = az.from_dict(posterior={"x": _ar1(rng, 4, 20_000, 0.999)})
    _assert_equal_to_public(idata)
    assert calls == [min(10_000, 2048 + 10_000 // 32), 10_000]


def test_several_parameters_with_ties_equal_arviz():
    rng = np.random.default_rng(13)
    base = _chains(rng, 4, 3000, rho=0.95)
    idata = az.from_dict(posterior={
        "smooth": base,
        "discrete": rng.integers(0, 5, size=(4, 3000)).astype(float),  # heavy ties
        "rounded": np.round(base, 1),
        "shifted": base + np.arange(4)[:, None] * 0.3,  # R-hat far from 1
        "skewed": np.exp(base),
    })
    _assert_equal_to_public(idata)
    ours = convergence_table(idata)
    assert ours.loc["shifted", "r_hat"] > 1.05


@pytest.mark.parametrize("draws", [3, 4, 5])
def test_short_chains_equal_arviz(draws):
    rng = np.random.default_rng(draws)
    idata = az.from_dict(posterior={"x": rng.normal(size=(4, draws)),
                                    "y": rng.normal(size=(4, draws)).cumsum(axis=1)})
    ours = _ours(idata)
    if draws < 4:
        assert np.isnan(ours).all()
    # az.rhat takes the median of the split draws, az.summary (and the table) of all of
    # them: the same for an even number of draws, so R-hat is compared with az.summary
    _assert_equal_to_public(idata, columns=slice(0, 2 if draws % 2 else 3))
    np.testing.assert_allclose(ours, _reference(idata).to_numpy(), rtol=1e-12, atol=0,
                               equal_nan=True)


def test_one_chain_equals_arviz():
    rng = np.random.default_rng(14)
    idata = az.from_dict(posterior={"x": _ar1(rng, 1, 4000, 0.8)})
    _assert_equal_to_public(idata)
    bulk, tail, rhat = _ours(idata)[0]
    assert np.isfinite(bulk) and np.isfinite(tail) and np.isnan(rhat)


def test_constant_and_nan_parameters_as_in_arviz():
    rng = np.random.default_rng(15)
    x = _chains(rng, 4, 500)
    with_nan = x.copy()
    with_nan[2, 17] = np.nan
    signs = np.where(rng.random((4, 500)) < 0.5, -1.0, 1.0)  # |x − median| constant
    signs[:, :250] = -signs[:, 250:]  # as many of each sign: the median is 0
    idata = az.from_dict(posterior={"constant": np.full((4, 500), 2.5), "nan": with_nan,
                                    "signs": signs, "x": x})
    _assert_equal_to_public(idata)
    np.testing.assert_allclose(_ours(idata), _reference(idata).to_numpy(), rtol=1e-12,
                               atol=0, equal_nan=True)
    ours = convergence_table(idata)
    assert ours.loc["constant", "ess_bulk"] == 4 * 500  # ArviZ: the number of draws
    assert np.isnan(ours.loc["constant", "r_hat"]) and np.isnan(ours.loc["nan"]).all()


@pytest.mark.parametrize("value", [0.1, 2.5, -7.95, 1e-300, 0.0])
def test_constant_parameters_of_any_value_as_in_arviz(value):
    # the 5 % quantile of equal draws, (1 − γ)·x + γ·x, may round below x: the indicators
    # are then all 0 rather than all 1, still constant (ArviZ: ESS = number of draws)
    idata = az.from_dict(posterior={"c": np.full((4, 101), value)})
    _assert_equal_to_public(idata, columns=slice(0, 2))
    np.testing.assert_allclose(_ours(idata), _reference(idata).to_numpy(), rtol=1e-12,
                               atol=0, equal_nan=True)
