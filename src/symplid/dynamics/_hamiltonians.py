"""Hamiltonians H(q, p; θ) that need not be separable (eqs 2–3 without the split of eq. 4).

A Hamiltonian is an object with ``dim`` (d; the state is ``(q, p)`` of size 2d),
``num_params``, ``param_names``, ``value(q, p, params)``, ``grad_q(q, p, params)`` and
``grad_p(q, p, params)``. As for a potential (:mod:`symplid.dynamics._potentials`), ``q`` and
``p`` are one point of shape ``(d,)`` or a batch ``(d, ...)`` with trailing batch axes (the
filter's sigma points travel as columns); gradients have the shape of ``q``.

Kinds shipped here:

* :class:`FunctionHamiltonian`: any JAX function ``H(q, p, params)``; gradients by autodiff.
* :class:`PolynomialHamiltonian`: every monomial in ``(q1..qd, p1..pd)`` of total degree
  1..ℓ, with closed-form gradients. Basis order: that of
  :func:`~symplid.dynamics._potentials.monomial_exponents` over the 2d variables
  ``z = (q1, …, qd, p1, …, pd)``: by total degree, then lexicographically with the first
  variable's power highest. For ``dim=1, order=2``: ``q1, p1, q1^2, q1*p1, p1^2``.
* :class:`PositionDependentMass`: H = ½pᵀM(q; θ)⁻¹p + U(q; θ), M symmetric positive definite.
* :class:`DoublePendulum`: the planar double pendulum in the three parameters that its angles
  identify (see the class).
* :class:`SeparableHamiltonian`: a potential and a constant mass viewed as an H, so that the
  non-separable integrators can be compared with leapfrog on the same system.

The integrators receive H through :func:`~symplid.dynamics._integrators.make_dynamics`, which
returns :class:`~symplid.dynamics._integrators.GeneralDynamics` for a Hamiltonian.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import jax
import jax.numpy as jnp
import numpy as np

from symplid.dynamics._potentials import (
    Polynomial,
    Potential,
    inverse_mass,
    over_points,
)

Array = jax.Array

__all__ = [
    "DoublePendulum",
    "FunctionHamiltonian",
    "Hamiltonian",
    "PolynomialHamiltonian",
    "PositionDependentMass",
    "SeparableHamiltonian",
    "is_hamiltonian",
]


@runtime_checkable
class Hamiltonian(Protocol):
    """What the integrators and the model need from a (possibly non-separable) H(q, p; θ)."""

    dim: int
    num_params: int

    @property
    def param_names(self) -> tuple[str, ...]: ...

    def value(self, q: Array, p: Array, params: Array) -> Array: ...

    def grad_q(self, q: Array, p: Array, params: Array) -> Array: ...

    def grad_p(self, q: Array, p: Array, params: Array) -> Array: ...


def is_hamiltonian(obj: Any) -> bool:
    """Whether ``obj`` is a whole H(q, p; θ) (has ``grad_q``/``grad_p``), not a potential U(q)."""
    return isinstance(obj, Hamiltonian)


def over_pairs(f: Callable[[Array, Array], Array], q: Array, p: Array) -> Array:
    """Apply ``f(q, p)`` of one point to every point of ``q, p`` of shape ``(d, ...)``.

    The batch convention of :func:`~symplid.dynamics._potentials.over_points`, for a function
    of the whole state.
    """
    q = jnp.asarray(q, dtype=float)
    p = jnp.asarray(p, dtype=float)
    if q.shape != p.shape:
        raise ValueError(f"q and p must have the same shape, got {q.shape} and {p.shape}")
    d = q.shape[0]
    return over_points(lambda z: f(z[:d], z[d:]), jnp.concatenate([q, p], axis=0))


def _check_sizes(dim: int, num_params: int, names: tuple[str, ...] | None) -> None:
    if not isinstance(dim, int | np.integer) or dim < 1:
        raise ValueError(f"dim must be a positive integer, got {dim!r}")
    if not isinstance(num_params, int | np.integer) or num_params < 0:
        raise ValueError(f"num_params must be an integer ≥ 0, got {num_params!r}")
    if names is not None and len(names) != num_params:
        raise ValueError(f"{len(names)} parameter names given for {num_params} parameters")


class _NamedParameters:
    """Parameter names of a Hamiltonian built from functions: ``names`` given, else c1..cN."""

    dim: int
    num_params: int
    names: tuple[str, ...] | None

    def _check_names(self) -> None:
        if self.names is not None:
            object.__setattr__(self, "names", tuple(str(n) for n in self.names))
        _check_sizes(self.dim, self.num_params, self.names)

    @property
    def param_names(self) -> tuple[str, ...]:
        if self.names is not None:
            return self.names
        return tuple(f"c{m + 1}" for m in range(self.num_params))


class _Autodiff:
    """``value``, ``grad_q`` and ``grad_p`` from ``_point(q, p, params)`` of one point."""

    dim: int

    def _point(self, q: Array, p: Array, params: Array) -> Array:  # pragma: no cover
        raise NotImplementedError

    def _checked(self, q: Array, p: Array, params: Array) -> tuple[Array, Array, Array]:
        q, p = jnp.asarray(q, dtype=float), jnp.asarray(p, dtype=float)
        if q.shape[0] != self.dim or p.shape[0] != self.dim:
            raise ValueError(
                f"q and p must have {self.dim} coordinates first, got {q.shape} and {p.shape}"
            )
        return q, p, jnp.asarray(params, dtype=float)

    def value(self, q: Array, p: Array, params: Array) -> Array:
        """H(q, p; θ); ``q``, ``p`` of shape ``(d,)`` or ``(d, ...)``."""
        q, p, params = self._checked(q, p, params)
        return over_pairs(lambda a, b: self._point(a, b, params), q, p)

    def grad_q(self, q: Array, p: Array, params: Array) -> Array:
        """∂H/∂q by ``jax.grad``; the shape of ``q``."""
        q, p, params = self._checked(q, p, params)
        return over_pairs(jax.grad(lambda a, b: self._point(a, b, params), 0), q, p)

    def grad_p(self, q: Array, p: Array, params: Array) -> Array:
        """∂H/∂p by ``jax.grad``; the shape of ``p``."""
        q, p, params = self._checked(q, p, params)
        return over_pairs(jax.grad(lambda a, b: self._point(a, b, params), 1), q, p)


@dataclass(frozen=True, eq=False)
class FunctionHamiltonian(_NamedParameters, _Autodiff):
    """A Hamiltonian from any JAX function ``fn(q, p, params) -> scalar``.

    ``fn`` takes ``q`` and ``p`` of shape ``(dim,)`` and ``params`` of shape
    ``(num_params,)``; Hamilton's equations (3) use its gradients by automatic differentiation.

    Examples
    --------
    >>> H = FunctionHamiltonian(lambda q, p, c: 0.5 * (1 + c[0] * q[0]**2) * p[0]**2
    ...                         + 0.5 * q[0]**2, dim=1, num_params=1)
    >>> H.param_names
    ('c1',)
    """

    fn: Callable[[Array, Array, Array], Array]
    dim: int
    num_params: int
    names: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        if not callable(self.fn):
            raise TypeError("fn must be a callable H(q, p, params) -> scalar")
        self._check_names()

    def _point(self, q: Array, p: Array, params: Array) -> Array:
        return jnp.asarray(self.fn(q, p, params)).reshape(())


def qp_term_name(exponent: tuple[int, ...], dim: int) -> str:
    """Name of a monomial in ``z = (q, p)``: ``(1, 0, 0, 2) -> 'q1*p2^2'`` for ``dim=2``."""
    factors = []
    for i, e in enumerate(exponent):
        var = f"q{i + 1}" if i < dim else f"p{i - dim + 1}"
        if e == 1:
            factors.append(var)
        elif e > 1:
            factors.append(f"{var}^{e}")
    return "*".join(factors) if factors else "1"


@dataclass(frozen=True, eq=False)
class PolynomialHamiltonian:
    """H(q, p) = Σ_m c_m z^{α_m}: every monomial of total degree 1..``order`` in z = (q, p).

    The monomials are those of a :class:`~symplid.dynamics._potentials.Polynomial` in the 2d
    variables ``z`` (the module docstring gives the basis order), and so are the closed-form
    gradients: ∂H/∂q and ∂H/∂p are the first and last d components of ∂H/∂z.

    Examples
    --------
    >>> H = PolynomialHamiltonian(dim=1, order=2)
    >>> H.param_names
    ('q1', 'p1', 'q1^2', 'q1*p1', 'p1^2')
    """

    dim: int
    order: int
    polynomial: Polynomial = field(init=False, repr=False)

    def __post_init__(self) -> None:
        _check_sizes(self.dim, 0, None)
        object.__setattr__(self, "polynomial", Polynomial(2 * self.dim, self.order))

    @property
    def num_params(self) -> int:
        return self.polynomial.num_params

    @property
    def exponents(self) -> tuple[tuple[int, ...], ...]:
        """Exponents of each monomial over ``z = (q, p)``, in the basis order."""
        return self.polynomial.exponents

    @property
    def param_names(self) -> tuple[str, ...]:
        return tuple(qp_term_name(e, self.dim) for e in self.polynomial.exponents)

    def coefficients_from(self, terms: dict[str, float]) -> np.ndarray:
        """Coefficient vector from ``{name: value}`` (``{'p1^2': 0.5, 'q1^2': 0.5}``)."""
        index = {name: m for m, name in enumerate(self.param_names)}
        out = np.zeros(self.num_params)
        for key, val in terms.items():
            if key not in index:
                raise ValueError(f"unknown term {key!r}; the basis is {', '.join(index)}")
            out[index[key]] += val
        return out

    def _z(self, q: Array, p: Array) -> Array:
        q, p = jnp.asarray(q, dtype=float), jnp.asarray(p, dtype=float)
        if q.shape[0] != self.dim or q.shape != p.shape:
            raise ValueError(f"q and p must both be ({self.dim}, ...), got {q.shape}, {p.shape}")
        return jnp.concatenate([q, p], axis=0)

    def value(self, q: Array, p: Array, params: Array) -> Array:
        return self.polynomial.value(self._z(q, p), params)

    def grad_q(self, q: Array, p: Array, params: Array) -> Array:
        return self.polynomial.gradient(self._z(q, p), params)[: self.dim]

    def grad_p(self, q: Array, p: Array, params: Array) -> Array:
        return self.polynomial.gradient(self._z(q, p), params)[self.dim :]


@dataclass(frozen=True, eq=False)
class PositionDependentMass(_NamedParameters, _Autodiff):
    """H = ½ pᵀ M(q; θ)⁻¹ p + U(q; θ): a mass matrix that depends on the position.

    ``mass_fn(q, params) -> (d, d)`` must be symmetric positive definite along the path and
    ``potential_fn(q, params) -> scalar``; both read the same parameter vector. The kinetic
    term is computed by a Cholesky solve; the gradients by automatic differentiation.

    Examples
    --------
    A particle on a line whose mass grows with ``|q|`` (θ = (a, k)):

    >>> H = PositionDependentMass(lambda q, c: (1 + c[0] * q**2)[:, None],
    ...                           lambda q, c: 0.5 * c[1] * q[0]**2, dim=1, num_params=2)
    """

    mass_fn: Callable[[Array, Array], Array]
    potential_fn: Callable[[Array, Array], Array]
    dim: int
    num_params: int
    names: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        if not callable(self.mass_fn) or not callable(self.potential_fn):
            raise TypeError("mass_fn(q, params) and potential_fn(q, params) must be callables")
        self._check_names()

    def mass(self, q: Array, params: Array) -> Array:
        """M(q; θ) at one point, shape ``(d, d)``."""
        return jnp.asarray(self.mass_fn(q, params), dtype=float).reshape(self.dim, self.dim)

    def _point(self, q: Array, p: Array, params: Array) -> Array:
        chol = jnp.linalg.cholesky(self.mass(q, params))
        w = jax.scipy.linalg.solve_triangular(chol, p, lower=True)  # ½pᵀM⁻¹p = ½|L⁻¹p|²
        return 0.5 * jnp.sum(w * w) + jnp.asarray(self.potential_fn(q, params)).reshape(())


#: Standard gravity (m/s²): the reference of the double pendulum's third parameter.
STANDARD_GRAVITY = 9.81


@dataclass(frozen=True, eq=False)
class DoublePendulum(_Autodiff):
    """The planar double pendulum, angles q = (φ1, φ2) from the downward vertical.

    With bob masses m1, m2 on massless rods of lengths l1, l2 under gravity g, the Lagrangian
    is L = ½(m1+m2)l1²φ̇1² + m2 l1 l2 φ̇1φ̇2 cos(φ1−φ2) + ½m2 l2²φ̇2² + (m1+m2)g l1 cos φ1
    + m2 g l2 cos φ2. Dividing L by m2 l2² leaves the motion of the angles unchanged, so the
    angles identify exactly three combinations,

        μ = m1/m2,   λ = l1/l2,   γ = g/l2,

    and H is written in the units m2 = l2 = 1 (the momenta are those of L/(m2 l2²)):

        H = [p1² − 2λ cos Δ p1 p2 + (1+μ)λ² p2²] / (2λ²(μ + sin²Δ))
            − (1+μ)γλ cos φ1 − γ cos φ2,     Δ = φ1 − φ2,

    the position-dependent mass H = ½pᵀM(q)⁻¹p + U(q) with M = [[(1+μ)λ², λ cos Δ],
    [λ cos Δ, 1]]. The parameters are logarithms, θ = (log μ, log λ, log(γ/g₀)) with
    g₀ = 9.81 m/s² (:data:`STANDARD_GRAVITY`): every real θ is a physical pendulum, and θ = 0
    is the reference one (equal masses, equal rods of 1 m, standard gravity), so the default
    coefficient prior (centred on 0) and the MAP's default start apply unchanged. Gradients are
    in closed form (the generic :class:`PositionDependentMass` gives the same H by autodiff).
    """

    dim: int = field(default=2, init=False)
    num_params: int = field(default=3, init=False)

    @property
    def param_names(self) -> tuple[str, ...]:
        return ("log_mass_ratio", "log_length_ratio", "log_gravity_per_length")

    @staticmethod
    def params_from(m1: float, m2: float, l1: float, l2: float, g: float) -> np.ndarray:
        """θ = (log m1/m2, log l1/l2, log (g/l2)/g₀) of a physical pendulum."""
        values = (m1, m2, l1, l2, g)
        if not all(math.isfinite(v) and v > 0 for v in values):
            raise ValueError(f"masses, lengths and g must be positive, got {values}")
        return np.log([m1 / m2, l1 / l2, g / l2 / STANDARD_GRAVITY])

    @staticmethod
    def ratios(params: Array) -> tuple[Array, Array, Array]:
        """(μ, λ, γ) = (m1/m2, l1/l2, g/l2) from θ."""
        params = jnp.asarray(params, dtype=float)
        return (jnp.exp(params[0]), jnp.exp(params[1]),
                STANDARD_GRAVITY * jnp.exp(params[2]))

    @classmethod
    def momenta(cls, q: Array, velocity: Array, params: Array) -> Array:
        """p = M(q)φ̇: the momenta (in the units of H) of the angular velocities φ̇."""
        mu, lam, _ = cls.ratios(params)
        c = jnp.cos(q[0] - q[1])
        return jnp.stack([(1 + mu) * lam**2 * velocity[0] + lam * c * velocity[1],
                          lam * c * velocity[0] + velocity[1]])

    def _point(self, q: Array, p: Array, params: Array) -> Array:
        mu, lam, gamma = self.ratios(params)
        c, s = jnp.cos(q[0] - q[1]), jnp.sin(q[0] - q[1])
        kinetic = (p[0] ** 2 - 2 * lam * c * p[0] * p[1] + (1 + mu) * lam**2 * p[1] ** 2) / (
            2 * lam**2 * (mu + s * s)
        )
        return kinetic - (1 + mu) * gamma * lam * jnp.cos(q[0]) - gamma * jnp.cos(q[1])

    def grad_q(self, q: Array, p: Array, params: Array) -> Array:
        """∂H/∂q in closed form; ``q``, ``p`` of shape ``(2,)`` or ``(2, ...)``."""
        q, p, params = self._checked(q, p, params)
        mu, lam, gamma = self.ratios(params)
        c, s = jnp.cos(q[0] - q[1]), jnp.sin(q[0] - q[1])
        den = mu + s * s
        num = p[0] ** 2 - 2 * lam * c * p[0] * p[1] + (1 + mu) * lam**2 * p[1] ** 2
        dk = s * (lam * p[0] * p[1] * den - num * c) / (lam**2 * den * den)  # ∂K/∂Δ
        return jnp.stack([dk + (1 + mu) * gamma * lam * jnp.sin(q[0]),
                          -dk + gamma * jnp.sin(q[1])])

    def grad_p(self, q: Array, p: Array, params: Array) -> Array:
        """∂H/∂p = M(q)⁻¹p in closed form."""
        q, p, params = self._checked(q, p, params)
        mu, lam, _ = self.ratios(params)
        c, s = jnp.cos(q[0] - q[1]), jnp.sin(q[0] - q[1])
        den = mu + s * s
        return jnp.stack([(p[0] - lam * c * p[1]) / (lam**2 * den),
                          ((1 + mu) * lam * p[1] - c * p[0]) / (lam * den)])


@dataclass(frozen=True, eq=False)
class SeparableHamiltonian:
    """H = ½pᵀM⁻¹p + U(q) (eq. 2) of a potential and a constant mass, as a Hamiltonian.

    Its parameters are the potential's coefficients. Used to run the non-separable
    integrators on a separable system and compare them with leapfrog or Yoshida.
    """

    potential: Potential
    mass: Any = None

    @property
    def dim(self) -> int:
        return int(self.potential.dim)

    @property
    def num_params(self) -> int:
        return int(self.potential.num_params)

    @property
    def param_names(self) -> tuple[str, ...]:
        return tuple(self.potential.param_names)

    def _velocity(self, p: Array) -> Array:
        inv = inverse_mass(self.mass, self.dim)
        p = jnp.asarray(p, dtype=float)
        return p if inv is None else jnp.tensordot(inv, p, axes=1)

    def value(self, q: Array, p: Array, params: Array) -> Array:
        p = jnp.asarray(p, dtype=float)
        return 0.5 * jnp.sum(p * self._velocity(p), axis=0) + self.potential.value(q, params)

    def grad_q(self, q: Array, p: Array, params: Array) -> Array:
        return self.potential.gradient(q, params)

    def grad_p(self, q: Array, p: Array, params: Array) -> Array:
        return self._velocity(p)
