"""The deterministic-trajectory likelihood (``process_noise_per="none"``) against NumPy.

The reference here is written from the model's definition alone: a NumPy leapfrog over
⌈gap/dt⌉ equal substeps (eq. 14) with the potential's gradient from the monomials' names, and
the sum of univariate Gaussian log densities of the measured values around that path (the
noise models give independent components: Γ + r·h(x)² on the diagonal).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import symplid
from symplid.model._posterior import Posterior

TIMES = np.array([0.7, 1.5, 2.0, 3.1, 3.6, 4.5, 6.0, 7.25])


# ----------------------------------------------------------------------------- NumPy reference
def _exponents(names: tuple[str, ...], dim: int) -> np.ndarray:
    """Each monomial's exponents from its name (``"q1^2*q2"`` → [2, 1])."""
    out = np.zeros((len(names), dim), dtype=int)
    for i, name in enumerate(names):
        for factor in name.split("*"):
            var, _, power = factor.partition("^")
            out[i, int(var[1:]) - 1] += int(power or 1)
    return out


def _grad_u(q: np.ndarray, coefficients: np.ndarray, exponents: np.ndarray) -> np.ndarray:
    grad = np.zeros_like(q)
    for c, e in zip(coefficients, exponents, strict=True):
        for j in range(q.size):
            if e[j] == 0:
                continue
            lowered = e.copy()
            lowered[j] -= 1
            grad[j] += c * e[j] * np.prod(q**lowered)
    return grad


def numpy_path(coefficients, exponents, x0, times, dt, t0=0.0) -> np.ndarray:
    """The leapfrog states at ``times``: ⌈gap/dt⌉ equal kick-drift-kick substeps per gap."""
    d = exponents.shape[1]
    q, p = np.array(x0[:d], float), np.array(x0[d:], float)
    states, t = [], t0
    for t_next in times:
        gap = t_next - t
        n = max(math.ceil(gap / dt - 1e-9), 1)
        h = gap / n
        for _ in range(n):
            p = p - 0.5 * h * _grad_u(q, coefficients, exponents)
            q = q + h * p
            p = p - 0.5 * h * _grad_u(q, coefficients, exponents)
        states.append(np.concatenate([q, p]))
        t = t_next
    return np.array(states)


def numpy_loglik(path, values, observe, obs_var, rel_var=None) -> float:
    """Σ over measured entries of log N(y; h(x), Γ_j + r_j h_j(x)²)."""
    clean = path @ observe.T
    var = np.broadcast_to(np.asarray(obs_var, float), clean.shape).copy()
    if rel_var is not None:
        var = var + np.asarray(rel_var, float) * clean**2
    measured = np.isfinite(values)
    r = values[measured] - clean[measured]
    v = var[measured]
    return float(np.sum(-0.5 * r**2 / v - 0.5 * np.log(2 * np.pi * v)))


def _close(a: float, b: float, tol: float = 1e-10) -> bool:
    return abs(float(a) - float(b)) <= tol * max(1.0, abs(float(b)))


# ----------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def exps(hh):
    return _exponents(hh.potential.param_names, hh.potential.dim)


@pytest.fixture(scope="module")
def coeffs(hh):
    """Away from the truth, so that the path differs from the data's."""
    return hh.coefficients + 0.03 * np.sin(np.arange(1, hh.potential.num_params + 1))


def _det_model(hh, **kw):
    return symplid.HamiltonianModel(hh.potential, process_noise_per="none", **kw)


# ----------------------------------------------------------------------------- values
def test_full_state_equals_numpy_least_squares(hh, hh_data, exps, coeffs):
    """The paper's data (20 observations, 5 s apart, leapfrog dt 0.25), one value missing."""
    values = np.array(hh_data.values)
    values[7, 2] = np.nan
    data = symplid.Observations(hh_data.times, values, hh_data.names)
    model = _det_model(hh, dt=0.25)
    assert model.num_params == hh.potential.num_params + 1
    assert "process_var" not in model.param_names
    theta = model.pack(coeffs, (), 0.04**2)
    ll = model.log_likelihood(theta, data, hh.initial_state)
    path = numpy_path(coeffs, exps, hh.initial_state, data.times, 0.25)
    ref = numpy_loglik(path, values, np.eye(4), 0.04**2)
    assert _close(ll, ref), (float(ll), ref)
    result = model.filter(theta, data, hh.initial_state)  # the path as the moments
    np.testing.assert_allclose(result.filtered_means, path, rtol=0, atol=1e-10)
    assert np.all(np.asarray(result.filtered_covs) == 0.0)


@pytest.mark.parametrize("noise", ["additive", "multiplicative", "both"])
def test_positions_only_irregular_gaps_noise_models(hh, exps, coeffs, noise):
    """Positions only, gaps that are no multiple of dt, per-kind/diagonal variances, and the
    multiplicative noise models, whose variance at a known state is Γ + r·h(x)²."""
    data = symplid.simulate(hh, times=TIMES, observation="positions", noise_std=0.05, seed=3,
                            observation_noise=noise)
    values = np.array(data.values)
    values[3, 0] = np.nan
    data = symplid.Observations(data.times, values, data.names)
    model = _det_model(hh, dt=0.3, observation="positions", noise="diagonal",
                       observation_noise=noise)
    obs_var = [0.03**2, 0.06**2] if noise != "multiplicative" else []
    rel_var = [0.04**2, 0.02**2] if noise != "additive" else []
    theta = model.pack(coeffs, (), obs_var, rel_var)
    ll = model.log_likelihood(theta, data, hh.initial_state)
    path = numpy_path(coeffs, exps, hh.initial_state, TIMES, 0.3)
    ref = numpy_loglik(path, values, np.eye(2, 4), obs_var or 0.0, rel_var or None)
    assert _close(ll, ref), (float(ll), ref)


def test_several_trajectories_learned_initial_state(hh, exps, coeffs):
    """A posterior over two trajectories, each with its learned x0: the sum of two paths."""
    datasets = [symplid.simulate(hh, times=TIMES, seed=s, x0=x0)
                for s, x0 in ((4, hh.initial_state), (5, [0.1, 0.2, -0.3, 0.1]))]
    model = _det_model(hh, dt=0.25)
    post = Posterior(model, datasets, learn_initial_state=True)
    x0s = [np.asarray(hh.initial_state) + 0.01, np.array([0.12, 0.18, -0.31, 0.09])]
    theta = np.concatenate([model.pack(coeffs, (), 0.05**2), *x0s])
    ref = sum(numpy_loglik(numpy_path(coeffs, exps, x0, d.times, 0.25), np.array(d.values),
                           np.eye(4), 0.05**2) for x0, d in zip(x0s, datasets, strict=True))
    assert _close(post.log_likelihood(theta), ref)


# ----------------------------------------------------------------------------- derivatives
def test_gradient_finite_and_matches_numpy_differences(hh, hh_data, exps, coeffs):
    model = _det_model(hh, dt=0.25)
    times, values = hh_data.times[:6], np.array(hh_data.values[:6])
    data = symplid.Observations(times, values, hh_data.names)
    theta = model.pack(coeffs, (), 0.05**2)
    grad = np.asarray(jax.grad(lambda t: model.log_likelihood(t, data, hh.initial_state))(
        jnp.asarray(theta)))
    assert np.all(np.isfinite(grad))

    def ref(t):
        path = numpy_path(t[:-1], exps, hh.initial_state, times, 0.25)
        return numpy_loglik(path, values, np.eye(4), t[-1])

    for i in (2, 6, 9):  # c[q1^2], c[q1^2*q2], obs_var
        step = 1e-6 * max(1.0, abs(theta[i]))
        up, down = theta.copy(), theta.copy()
        up[i] += step
        down[i] -= step
        fd = (ref(up) - ref(down)) / (2 * step)
        assert abs(grad[i] - fd) <= 1e-5 * max(1.0, abs(fd)), (i, grad[i], fd)


def test_non_finite_is_minus_infinity(hh, hh_data, coeffs):
    model = _det_model(hh, dt=0.25)
    fn = model.log_likelihood_fn(hh_data, hh.initial_state)
    assert fn(model.pack(coeffs, (), -1e-3)) == -np.inf  # a negative variance
    assert fn(model.pack(coeffs, (), 0.0)) == -np.inf
    exploding = model.pack(hh.coefficients - np.array([0, 0, 40, 0, 40, 60, 0, 0, 60]), (),
                           0.05**2)  # the path leaves every bound: inf - inf = NaN inside
    assert fn(exploding) == -np.inf
    grad = jax.grad(fn)(jnp.asarray(model.pack(coeffs, (), -1e-3)))
    assert not np.any(np.isnan(np.asarray(grad)))


# ----------------------------------------------------------------------------- settings
def test_spread_initial_state_is_refused(hh, hh_data):
    model = _det_model(hh, dt=0.25)
    with pytest.raises(ValueError, match="point initial state"):
        Posterior(model, hh_data, x0=hh.initial_state, P0=1e-4)
    Posterior(model, hh_data, x0=hh.initial_state)  # the default point start is fine
    # "negligible" is relative to the size of the motion: the same data in units 1000 times
    # larger (standardised fits divide p0_var by the scale²) keep the default start a point
    small = symplid.Observations(hh_data.times, 1e-3 * np.asarray(hh_data.values),
                                 hh_data.names)
    Posterior(model, small, x0=1e-3 * hh.initial_state, P0=1e-16)
    with pytest.raises(ValueError, match="point initial state"):
        Posterior(model, small, x0=1e-3 * hh.initial_state, P0=1e-4 * 1e-6)


def test_compiled_kernel_declines_and_names_the_reason(hh):
    from symplid.model._kernel import unsupported_reason

    model = _det_model(hh, dt=0.25)
    assert "no process noise" in unsupported_reason(model)
    assert model.likelihood_backend == "jax"
    with pytest.raises(ValueError, match="process_noise_per"):
        symplid.HamiltonianModel(hh.potential, process_noise_per="never")
