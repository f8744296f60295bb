"""Small analytic targets with the interface of ``symplid.Posterior``, for the sampler tests.

Each target knows its exact mean and covariance, and comes with a MAP-like object
(``theta``, ``covariance``, ``hessian``, ``log_posterior``) computed by hand.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from symplid.inference._diagnostics import import_arviz

az = import_arviz()


@dataclass
class MapResult:
    theta: np.ndarray
    covariance: np.ndarray
    hessian: np.ndarray
    log_posterior: float


class _Unbounded:
    """A target on all of R^d: its unconstrained coordinates are θ itself."""

    def to_unconstrained(self, theta):
        return theta

    def from_unconstrained(self, z):
        return z

    def log_density_unconstrained(self, z):
        return self.log_density(z)


class Gaussian2D(_Unbounded):
    """Correlated Gaussian: mean (1, −2), standard deviations (1, 2), correlation 0.8."""

    num_params = 2
    param_names = ("a", "b")
    lower = np.full(2, -np.inf)
    upper = np.full(2, np.inf)
    mean = np.array([1.0, -2.0])
    cov = np.array([[1.0, 1.6], [1.6, 4.0]])

    def __init__(self) -> None:
        self._precision = jnp.asarray(np.linalg.inv(self.cov))

    def log_density(self, theta):
        r = theta - jnp.asarray(self.mean)
        return -0.5 * r @ self._precision @ r

    def map_result(self) -> MapResult:
        return MapResult(self.mean.copy(), self.cov.copy(), np.linalg.inv(self.cov), 0.0)


class Banana(_Unbounded):
    """Twisted Gaussian (Haario et al. 1999): x1 ~ N(0, 1), x2 | x1 ~ N(b (x1² − 1), 1).

    Mean (0, 0); covariance diag(1, 1 + 2 b²) since Var(x1²) = 2 and Cov(x1, x1³ − x1) = 0.
    The mode is (0, −b) with Hessian I.
    """

    num_params = 2
    param_names = ("x1", "x2")
    lower = np.full(2, -np.inf)
    upper = np.full(2, np.inf)

    def __init__(self, b: float = 1.0) -> None:
        self.b = b
        self.mean = np.zeros(2)
        self.cov = np.diag([1.0, 1.0 + 2.0 * b**2])

    def log_density(self, theta):
        x1, x2 = theta[0], theta[1]
        return -0.5 * x1**2 - 0.5 * (x2 - self.b * (x1**2 - 1.0)) ** 2

    def map_result(self) -> MapResult:
        return MapResult(np.array([0.0, -self.b]), np.eye(2), np.eye(2), 0.0)


class GammaVariance:
    """Independent m ~ N(0, 1) and v ~ Gamma(shape 3, rate 2) (support v > 0).

    Mean (0, 1.5), covariance diag(1, 0.75). Unconstrained coordinates (m, log v), whose log
    density carries the log-Jacobian log v. Mode (0, 1), Hessian diag(1, 2).
    """

    num_params = 2
    param_names = ("m", "v")
    lower = np.array([-np.inf, 0.0])
    upper = np.full(2, np.inf)
    mean = np.array([0.0, 1.5])
    cov = np.diag([1.0, 0.75])
    shape, rate = 3.0, 2.0

    def log_density(self, theta):
        m, v = theta[0], theta[1]
        safe_v = jnp.where(v > 0, v, 1.0)
        value = -0.5 * m**2 + (self.shape - 1.0) * jnp.log(safe_v) - self.rate * safe_v
        return jnp.where(v > 0, value, -jnp.inf)

    def to_unconstrained(self, theta):
        return jnp.stack([theta[0], jnp.log(theta[1])])

    def from_unconstrained(self, z):
        return jnp.stack([z[0], jnp.exp(z[1])])

    def log_density_unconstrained(self, z):
        return self.log_density(self.from_unconstrained(z)) + z[1]

    def map_result(self) -> MapResult:
        hessian = np.diag([1.0, 2.0])
        return MapResult(np.array([0.0, 1.0]), np.linalg.inv(hessian), hessian, 0.0)


def moment_z_scores(draws: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> dict[str, float]:
    """Errors of the sample mean and covariance in units of their Monte-Carlo standard error.

    ``draws`` is ``(chain, draw, d)``. For each mean component and each covariance entry
    ``E[(x_i − μ_i)(x_j − μ_j)] = Σ_ij`` (exact μ), the MCSE comes from ArviZ's effective
    sample size of that quantity over all chains.
    """
    scores = {}
    d = draws.shape[-1]
    for i in range(d):
        scores[f"mean[{i}]"] = _z(draws[..., i], mean[i])
    centred = draws - mean
    for i in range(d):
        for j in range(i, d):
            scores[f"cov[{i},{j}]"] = _z(centred[..., i] * centred[..., j], cov[i, j])
    return scores


def _z(values: np.ndarray, truth: float) -> float:
    mcse = float(az.mcse(values, method="mean"))
    return (float(values.mean()) - truth) / mcse


class TwoModes(_Unbounded):
    """Mixture of N(0, I) and N(m, I) in two dimensions, m = (30, 30), the second component's
    log weight ``gap`` nats below the first's: log p = logaddexp(log N(x; 0, I),
    log N(x; m, I) − gap) (unnormalised). At ``gap = 60`` the second mode holds e⁻⁶⁰ of the
    mass, so the posterior's mean and covariance are those of N(0, I) to far below any
    Monte-Carlo error; at ``gap = 0`` both modes are equal. The modes are ~42 standard
    deviations apart: no chain crosses from one to the other.
    """

    num_params = 2
    param_names = ("x", "y")
    lower = np.full(2, -np.inf)
    upper = np.full(2, np.inf)
    far = np.array([30.0, 30.0])

    def __init__(self, gap: float) -> None:
        self.gap = gap
        self.mean = np.zeros(2)
        self.cov = np.eye(2)

    def log_density(self, theta):
        near = -0.5 * jnp.sum(theta**2)
        far = -0.5 * jnp.sum((theta - jnp.asarray(self.far)) ** 2) - self.gap
        return jnp.logaddexp(near, far)

    def map_result(self) -> MapResult:
        return MapResult(np.zeros(2), np.eye(2), np.eye(2), 0.0)
