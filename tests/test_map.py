"""find_map: closed-form optima, Hessians and evidences; bounds; non-finite objectives; the
Hénon–Heiles MAP against the truth; a learned initial state recovered.
"""

from __future__ import annotations

import json
import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate

import symplid
from reference_filters import numpy_leapfrog, numpy_substeps, polynomial_gradient
from symplid.inference.map import BoundWarning, MapResult, default_start, find_map
from symplid.model._posterior import Posterior
from symplid.model._prior_spec import PriorSpec
from symplid.model._priors import Uniform


# ----------------------------------------------------------------------------- posterior-likes
class GaussianRegression:
    """y = Xθ + N(0, σ²I), θ ~ N(0, τ²I): MAP, Hessian and evidence in closed form."""

    def __init__(self, seed: int = 0, n: int = 30, d: int = 3, sigma: float = 0.3,
                 tau: float = 2.0):
        rng = np.random.default_rng(seed)
        base = rng.normal(size=(n, 1))
        X = base + 0.5 * rng.normal(size=(n, d))  # correlated columns
        y = X @ np.array([1.0, -0.5, 0.25])[:d] + sigma * rng.normal(size=n)
        self.X, self.y, self.sigma, self.tau = X, y, sigma, tau
        self.num_params = d
        self.param_names = tuple(f"b{i}" for i in range(d))
        self.lower = np.full(d, -np.inf)
        self.upper = np.full(d, np.inf)
        Xj, yj = jnp.asarray(X), jnp.asarray(y)

        def log_density(theta):
            r = yj - Xj @ theta
            return (-0.5 * jnp.sum(r * r) / sigma**2 - n * math.log(sigma)
                    - 0.5 * jnp.sum(theta * theta) / tau**2 - d * math.log(tau)
                    - 0.5 * (n + d) * math.log(2 * math.pi))

        self.log_density = jax.jit(log_density)

    @property
    def precision(self) -> np.ndarray:
        return self.X.T @ self.X / self.sigma**2 + np.eye(self.num_params) / self.tau**2

    @property
    def mode(self) -> np.ndarray:
        return np.linalg.solve(self.precision, self.X.T @ self.y / self.sigma**2)

    @property
    def log_evidence(self) -> float:
        n = self.y.shape[0]
        cov = self.sigma**2 * np.eye(n) + self.tau**2 * self.X @ self.X.T
        _, logdet = np.linalg.slogdet(cov)
        return float(-0.5 * self.y @ np.linalg.solve(cov, self.y) - 0.5 * logdet
                     - 0.5 * n * math.log(2 * math.pi))


class OnBounds:
    """a free and Gaussian; b on [0, 5] with log density −2b + 0.1b² (maximum at the bound 0,
    negative curvature of −log p there); c > 0 with log density −3c (maximum at the bound)."""

    num_params = 3
    param_names = ("a", "b", "c")
    lower = np.array([-np.inf, 0.0, 0.0])
    upper = np.array([np.inf, 5.0, np.inf])

    def __init__(self):
        def log_density(theta):
            a, b, c = theta
            value = -((a - 1.0) ** 2) / (2 * 0.25) - 2.0 * b + 0.1 * b**2 - 3.0 * c
            inside = (b >= 0) & (b <= 5) & (c > 0)
            return jnp.where(inside, value, -jnp.inf)

        self.log_density = jax.jit(log_density)


class NanRegion:
    """log p = −(θ − 9.5)², NaN below 9.2. From θ = 10 the first L-BFGS-B trial is θ = 9
    (a unit step along −g), inside the NaN region: the line search must back off."""

    num_params = 1
    param_names = ("x",)
    lower = np.array([-np.inf])
    upper = np.array([np.inf])

    def __init__(self):
        self.log_density = jax.jit(
            lambda t: jnp.where(t[0] < 9.2, jnp.nan, -((t[0] - 9.5) ** 2))
        )


# ----------------------------------------------------------------------------- closed forms
@pytest.fixture(scope="module")
def regression():
    return GaussianRegression()


@pytest.fixture(scope="module")
def regression_map(regression):
    return find_map(regression, seed=0, num_starts=3)


def test_closed_form_mode_hessian_covariance(regression, regression_map):
    r = regression_map
    np.testing.assert_allclose(r.theta, regression.mode, rtol=0, atol=1e-6)
    np.testing.assert_allclose(r.hessian, regression.precision, rtol=1e-9)
    np.testing.assert_allclose(r.covariance, np.linalg.inv(regression.precision), rtol=1e-9)
    assert not r.covariance_repaired and r.at_bounds == () and r.success
    assert r.log_posterior == pytest.approx(float(regression.log_density(regression.mode)),
                                            abs=1e-9)
    for start in r.starts:  # every start finds the same (unique) mode
        np.testing.assert_allclose(start.theta, regression.mode, atol=1e-6)


def test_laplace_evidence_is_exact_for_a_conjugate_gaussian(regression, regression_map):
    assert regression_map.log_evidence == pytest.approx(regression.log_evidence, abs=1e-8)


def test_same_seed_same_result(regression, regression_map):
    again = find_map(regression, seed=0, num_starts=3)
    for s1, s2 in zip(regression_map.starts, again.starts, strict=True):
        np.testing.assert_array_equal(s1.start, s2.start)
        np.testing.assert_array_equal(s1.theta, s2.theta)
    other = find_map(regression, seed=1, num_starts=3)
    assert not np.array_equal(other.starts[1].start, again.starts[1].start)
    np.testing.assert_array_equal(other.starts[0].start, default_start(regression))


def test_init_forms_and_errors(regression, regression_map):
    r = find_map(regression, num_starts=1, init={"b1": -0.4})
    np.testing.assert_array_equal(r.starts[0].start, [0.0, -0.4, 0.0])
    r = find_map(regression, num_starts=1, init=regression_map)
    np.testing.assert_array_equal(r.starts[0].start, regression_map.theta)
    with pytest.raises(ValueError, match="init names unknown parameter"):
        find_map(regression, init={"zz": 1.0})
    with pytest.raises(ValueError, match=r"init must have shape \(3,\)"):
        find_map(regression, init=[1.0, 2.0])
    with pytest.raises(ValueError, match="num_starts must be an integer"):
        find_map(regression, num_starts=0)
    with pytest.raises(ValueError, match="c = -1 is outside its bounds"):
        find_map(OnBounds(), init=[0.0, 1.0, -1.0])
    with pytest.raises(ValueError, match="not finite at init"):
        find_map(NanRegion(), init=[0.0])


def test_to_dict_is_json_and_round_trips(regression_map):
    d = json.loads(json.dumps(regression_map.to_dict()))
    back = MapResult.from_dict(d)
    np.testing.assert_array_equal(back.theta, regression_map.theta)
    np.testing.assert_array_equal(back.covariance, regression_map.covariance)
    assert back.param_names == regression_map.param_names
    assert back.log_evidence == regression_map.log_evidence
    assert len(back.starts) == 3 and back.starts[2].message == regression_map.starts[2].message
    assert d["params"]["b0"] == regression_map.theta[0]


def test_non_finite_objective_backs_off():
    r = find_map(NanRegion(), num_starts=1, init=[10.0])
    assert r.success
    assert r.theta[0] == pytest.approx(9.5, abs=1e-6)


# ----------------------------------------------------------------------------- bounds
def test_map_on_bounds_warns_and_decouples():
    post = OnBounds()
    with pytest.warns(BoundWarning, match=r"b = 0 \(its lower bound is 0\).*c = 1e-14"):
        r = find_map(post, num_starts=2, init=[0.0, 1.0, 1.0])
    assert r.at_bounds == ("b", "c")
    assert r.theta[0] == pytest.approx(1.0, abs=1e-6)
    assert r.theta[1] == 0.0
    assert r.theta[2] == pytest.approx(1e-14)  # the floor of a parameter bounded below only
    assert r.covariance_repaired
    # a: Gaussian, variance 0.25. b and c: the variance of their 1-D densities from the bound.
    zb = integrate.quad(lambda b: math.exp(-2 * b + 0.1 * b * b), 0, 5)[0]
    mb = integrate.quad(lambda b: b * math.exp(-2 * b + 0.1 * b * b), 0, 5)[0] / zb
    vb = integrate.quad(lambda b: (b - mb) ** 2 * math.exp(-2 * b + 0.1 * b * b), 0, 5)[0] / zb
    np.testing.assert_allclose(np.diag(r.covariance), [0.25, vb, 1 / 9], rtol=1e-2)
    np.testing.assert_array_equal(r.covariance - np.diag(np.diag(r.covariance)), 0.0)
    assert np.all(np.linalg.eigvalsh(r.covariance) > 0)
    # evidence: Gaussian integral over a, the two 1-D integrals over b and c (log p* = 0)
    exact = math.log(math.sqrt(2 * math.pi * 0.25)) + math.log(zb) + math.log(1 / 3)
    assert r.log_evidence == pytest.approx(exact, abs=1e-2)
    # the Hessian stays the raw autodiff one: −log p has curvature −0.2 along b
    assert r.hessian[1, 1] == pytest.approx(-0.2)


# ----------------------------------------------------------------------------- the real posterior
def _harmonic_pinned():
    """The harmonic oscillator with every model parameter pinned by a uniform prior of width
    2e-9 and the initial state learned: in x0 the model is linear and Gaussian, so the MAP of
    x0 and its Hessian block are those of a least-squares problem."""
    osc = symplid.get_system("harmonic")
    model = symplid.HamiltonianModel(osc.potential, dt=0.25, unroll=False)
    times = np.array([0.6, 1.4, 2.0, 3.1, 3.6, 4.5, 5.5, 6.1])
    data = symplid.simulate(osc, times=times, x0=[0.8, -0.3], noise_std=0.05, seed=7)
    w = 1e-9
    spec = PriorSpec(overrides={
        "q1": Uniform(-w, w), "q1^2": Uniform(0.5 - w, 0.5 + w),
        "process_var": Uniform(1e-14, 1e-14 + 2e-23),
        "obs_var": Uniform(0.05**2 * (1 - w), 0.05**2 * (1 + w)),
    })
    post = Posterior(model, data, prior=spec, learn_initial_state=True,
                     initial_state_prior=0.3)
    # closed form: y_k = F_k x0 + noise with F_k the product of the leapfrog gap maps
    step = numpy_leapfrog(polynomial_gradient(np.array([[1], [2]]), np.array([0.0, 0.5])))
    nums, sizes = numpy_substeps(times, 0.25)
    rows, F = [], np.eye(2)
    for m, h in zip(nums, sizes, strict=True):
        G = np.eye(2)
        for _ in range(m):
            G = step(G, h)
        F = G.T @ F
        rows.append(F)
    A = sum(Fk.T @ Fk for Fk in rows) / 0.05**2 + np.eye(2) / 0.3**2
    b = sum(Fk.T @ y for Fk, y in zip(rows, data.values, strict=True)) / 0.05**2
    b = b + data.values[0] / 0.3**2  # the prior is centred on y_1
    return post, np.linalg.solve(A, b), A


@pytest.mark.slow
def test_real_posterior_closed_form_learned_state():
    post, mode, precision = _harmonic_pinned()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BoundWarning)  # pinned parameters may touch a bound
        r = find_map(post, num_starts=2)
    np.testing.assert_allclose(r.theta[4:], mode, rtol=0, atol=1e-6)
    np.testing.assert_allclose(r.hessian[4:, 4:], precision, rtol=1e-6)


@pytest.fixture(scope="module")
def hh_model(hh):
    return symplid.HamiltonianModel(hh.potential, integrator="leapfrog", dt=0.25, unroll=False)


@pytest.fixture(scope="module")
def hh_map(hh_model, hh, hh_data):
    post = Posterior(hh_model, hh_data, x0=hh.initial_state)
    with pytest.warns(BoundWarning, match="process_var"):
        result = find_map(post, seed=0, num_starts=2)
    return post, result


@pytest.mark.slow
def test_henon_heiles_map_recovers_the_truth(hh, hh_map):
    """Under the model the MAP error is ≈ N(0, Laplace covariance): the noise (σ = 0.05,
    80 numbers) sets standard errors of 0.01–0.06 on the coefficients, and |error| < 4 sd
    fails with probability ~6e-5 per coefficient. Leapfrog's O(dt²) bias at dt = 0.25 is
    absorbed into the coefficients (a modified Hamiltonian) and stays well inside this."""
    _, r = hh_map
    assert r.success
    assert all(s.log_posterior == pytest.approx(r.log_posterior, abs=1e-6) for s in r.starts)
    err = r.theta[:9] - hh.coefficients
    sd = r.std[:9]
    assert np.all(np.abs(err) < 4 * sd), (err, sd)
    assert np.all(sd < 0.1)
    assert abs(r.theta[10] - 0.05**2) < 4 * r.std[10]
    # leapfrog leaves no detectable process noise: the variance sits on its bound
    assert r.at_bounds == ("process_var",)
    cov = r.covariance
    np.testing.assert_array_equal(cov, cov.T)
    assert np.all(np.linalg.eigvalsh(cov) > 0)


@pytest.mark.slow
def test_henon_heiles_learned_initial_state(hh, hh_model, hh_data):
    post = Posterior(hh_model, hh_data, learn_initial_state=True)
    with pytest.warns(BoundWarning):
        r = find_map(post, seed=0, num_starts=1)
    x0_hat = r.theta[post.initial_state_slice(0)]
    sd = r.std[post.initial_state_slice(0)]
    assert np.all(np.abs(x0_hat - hh.initial_state) < 4 * sd), (x0_hat, sd)
    assert np.all(sd < 0.05)  # the data pin x0 far below the prior's scale
    assert np.all(np.abs(r.theta[:9] - hh.coefficients) < 4 * r.std[:9])


@pytest.mark.slow
def test_default_start_of_the_real_posterior(hh_map):
    post, _ = hh_map
    start = default_start(post)
    np.testing.assert_array_equal(start[:9], 0.0)  # the Laplace prior's median
    var = float(np.mean(np.var(post.datasets[0].values, axis=0)))
    assert start[9] == pytest.approx(var) and start[10] == pytest.approx(0.1 * var)
