"""Potential energies U(q; θ) and the separable Hamiltonian H = ½pᵀM⁻¹p + U(q) (eqs 2, 4, 13).

A potential is an object with ``dim`` (number of generalised coordinates), ``num_params``,
``param_names``, ``value(q, coefficients)`` and ``gradient(q, coefficients)``; ``q`` is one
point of shape ``(dim,)`` or a batch of points of shape ``(dim, ...)`` (coordinates first,
batch axes trailing: the filter pushes all sigma points through at once in this layout).
Two kinds ship with the library:

* :class:`Polynomial`: every monomial of total degree 1..ℓ (eq. 13, the paper's model form),
  with a closed-form gradient.
* :class:`FunctionPotential`: any JAX function ``U(q, coefficients)``; its gradient is taken
  by automatic differentiation.

Basis order (fixed; ``docs/explanation/conventions.md``): by total degree, then
lexicographically with the first coordinate's power highest. For ``dim=2, order=3``::

    q1, q2, q1^2, q1*q2, q2^2, q1^3, q1^2*q2, q1*q2^2, q2^3

The coefficients are those of **U**. The paper's θ1..θ9 in eqs (17)–(18) are the
coefficients of **−U** in this same order.
"""

from __future__ import annotations

import itertools
import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "FunctionPotential",
    "Polynomial",
    "Potential",
    "coefficient_name",
    "degree_scaling",
    "hamiltonian",
    "has_kinetic",
    "inverse_mass",
    "kinetic_energy",
    "mass_matrix",
    "monomial_exponents",
    "over_points",
]

Array = jax.Array


def degree_scaling(degrees: Any, a: float) -> np.ndarray:
    """a^(2−k) for each total degree k: the factor of a monomial's coefficient when positions
    and momenta are over ``a`` (:meth:`Polynomial.standardised`)."""
    a = float(a)
    if not (math.isfinite(a) and a > 0):
        raise ValueError(f"the position scale must be a positive number, got {a!r}")
    return np.array([a ** (2 - int(k)) for k in degrees], dtype=float)


@runtime_checkable
class Potential(Protocol):
    """What the integrators and the model need from a potential energy."""

    dim: int
    num_params: int

    @property
    def param_names(self) -> tuple[str, ...]: ...

    def value(self, q: Array, coefficients: Array) -> Array: ...

    def gradient(self, q: Array, coefficients: Array) -> Array: ...


def monomial_exponents(dim: int, order: int) -> tuple[tuple[int, ...], ...]:
    """Exponent tuples of every monomial of total degree 1..order, in the library's basis order.

    Within one degree the tuples are sorted lexicographically in decreasing order, so the
    first coordinate's power is highest first: ``(2, 0), (1, 1), (0, 2)``.
    """
    if not isinstance(dim, int | np.integer) or dim < 1:
        raise ValueError(f"dim must be a positive integer, got {dim!r}")
    if not isinstance(order, int | np.integer) or order < 1:
        raise ValueError(f"order must be a positive integer, got {order!r}")
    exponents: list[tuple[int, ...]] = []
    for degree in range(1, order + 1):
        of_degree = [
            e for e in itertools.product(range(degree, -1, -1), repeat=dim) if sum(e) == degree
        ]
        exponents.extend(sorted(of_degree, reverse=True))
    return tuple(exponents)


_MONOMIAL = re.compile(r"^q[1-9][0-9]*(\^[0-9]+)?(\*q[1-9][0-9]*(\^[0-9]+)?)*$")


def coefficient_name(term: str) -> str:
    """The name of a coefficient in θ: a monomial's ``q1^2`` becomes ``c[q1^2]`` (a bare
    ``q1`` would read as the state's position q1); any other name is kept."""
    return f"c[{term}]" if _MONOMIAL.match(term) else term


def term_name(exponent: tuple[int, ...]) -> str:
    """Readable name of a monomial: ``(2, 1) -> 'q1^2*q2'``."""
    factors = []
    for i, e in enumerate(exponent):
        if e == 1:
            factors.append(f"q{i + 1}")
        elif e > 1:
            factors.append(f"q{i + 1}^{e}")
    return "*".join(factors) if factors else "1"


def _powers(q: Array, order: int) -> list[list[Array]]:
    """``powers[i][k] = q_i**k`` for k = 0..order, by repeated multiplication (no pow)."""
    out = []
    for i in range(q.shape[0]):
        qi = q[i]
        row = [jnp.ones_like(qi), qi]
        for _ in range(2, order + 1):
            row.append(row[-1] * qi)
        out.append(row[: order + 1])
    return out


@dataclass(frozen=True)
class Polynomial:
    """Polynomial potential of total order ≤ ``order`` in ``dim`` coordinates (eq. 13).

    There is no constant term: it does not change the dynamics and cannot be identified.

    Parameters
    ----------
    dim
        Number of generalised coordinates ``d`` (the state has ``2d`` components).
    order
        Highest total degree ℓ.

    Examples
    --------
    >>> pot = Polynomial(dim=2, order=3)
    >>> pot.num_params, pot.param_names[:3]
    (9, ('q1', 'q2', 'q1^2'))
    """

    dim: int
    order: int
    exponents: tuple[tuple[int, ...], ...] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "exponents", monomial_exponents(self.dim, self.order))

    @property
    def num_params(self) -> int:
        return len(self.exponents)

    @property
    def param_names(self) -> tuple[str, ...]:
        return tuple(term_name(e) for e in self.exponents)

    def standardised(self, a: float) -> np.ndarray:
        """The scaling law of the coefficients in positions and momenta over ``a``
        (q' = q/a, p' = p/a, t' = t): c = D c' with ``D_α = a**(2 − deg α)``, since
        H'(q', p') = H(a q', a p') / a² generates the same motion (eqs 2 and 13) and
        ``c'_α = c_α · a**(deg α − 2)`` (deg α the monomial's total degree).

        >>> Polynomial(dim=1, order=4).standardised(10.0)
        array([10.  ,  1.  ,  0.1 ,  0.01])
        """
        return degree_scaling([sum(e) for e in self.exponents], a)

    def _check(self, q: Array, coefficients: Array) -> None:
        if q.shape[0] != self.dim:
            raise ValueError(f"q has {q.shape[0]} coordinates, the potential has dim={self.dim}")
        if coefficients.shape[0] != self.num_params:
            raise ValueError(
                f"expected {self.num_params} coefficients ({', '.join(self.param_names)}), "
                f"got {coefficients.shape[0]}"
            )

    def value(self, q: Array, coefficients: Array) -> Array:
        """U(q) = Σ_m c_m Π_i q_i^{e_mi}. ``q`` may carry trailing batch axes: ``(dim, ...)``."""
        q = jnp.asarray(q)
        coefficients = jnp.asarray(coefficients)
        self._check(q, coefficients)
        pw = _powers(q, self.order)
        total = jnp.zeros_like(q[0])
        for m, e in enumerate(self.exponents):
            term = coefficients[m]
            for i, ei in enumerate(e):
                if ei:
                    term = term * pw[i][ei]
            total = total + term
        return total

    def gradient(self, q: Array, coefficients: Array) -> Array:
        """∂U/∂q in closed form, unrolled at trace time so that XLA fuses it into one kernel."""
        q = jnp.asarray(q)
        coefficients = jnp.asarray(coefficients)
        self._check(q, coefficients)
        pw = _powers(q, self.order)
        grads = []
        for j in range(self.dim):
            gj = jnp.zeros_like(q[0])
            for m, e in enumerate(self.exponents):
                if e[j] == 0:
                    continue
                term = coefficients[m] * e[j]
                for i, ei in enumerate(e):
                    power = ei - 1 if i == j else ei
                    if power:
                        term = term * pw[i][power]
                gj = gj + term
            grads.append(gj)
        return jnp.stack(grads)

    def coefficients_from(self, terms: Mapping[str | tuple[int, ...], float]) -> np.ndarray:
        """Coefficient vector from ``{term: value}``; terms by name (``'q1^2*q2'``, or its θ
        name ``'c[q1^2*q2]'``) or exponent.

        Terms not named are zero. An unknown term is an error, not silently dropped.
        """
        index = {e: m for m, e in enumerate(self.exponents)}
        by_name = {term_name(e): m for m, e in enumerate(self.exponents)}
        by_name |= {coefficient_name(name): m for name, m in by_name.items()}
        out = np.zeros(self.num_params)
        for key, val in terms.items():
            if isinstance(key, str):
                if key not in by_name:
                    raise ValueError(
                        f"unknown term {key!r}; the basis is {', '.join(self.param_names)}"
                    )
                out[by_name[key]] += val
            else:
                key = tuple(int(k) for k in key)
                if key not in index:
                    raise ValueError(f"term with exponents {key} is not in the basis")
                out[index[key]] += val
        return out


def over_points(f: Callable[[Array], Array], q: Array) -> Array:
    """Apply ``f`` (of one point ``(dim,)``) to every point of ``q`` of shape ``(dim, ...)``.

    Trailing axes of ``q`` are batch axes (sigma points travel as columns); the result keeps
    them as its own trailing axes.
    """
    if q.ndim == 1:
        return f(q)
    flat = q.reshape(q.shape[0], -1)
    out = jax.vmap(f, in_axes=1, out_axes=-1)(flat)
    return out.reshape(out.shape[:-1] + q.shape[1:])


@dataclass(frozen=True)
class FunctionPotential:
    """A potential from any JAX function ``fn(q, coefficients) -> scalar``.

    The force is ``-jax.grad(fn)``. ``fn`` must be written with ``jax.numpy`` and must accept
    ``q`` of shape ``(dim,)`` and ``coefficients`` of shape ``(num_params,)``.

    Examples
    --------
    >>> pot = FunctionPotential(lambda q, c: c[0] * jnp.cosh(q[0]), dim=1, num_params=1)
    """

    fn: Callable[[Array, Array], Array]
    dim: int
    num_params: int
    names: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        if not callable(self.fn):
            raise TypeError("fn must be a callable U(q, coefficients) -> scalar")
        if self.dim < 1 or self.num_params < 0:
            raise ValueError("dim must be ≥ 1 and num_params ≥ 0")
        if self.names is not None and len(self.names) != self.num_params:
            raise ValueError(f"{len(self.names)} names given for {self.num_params} parameters")

    @property
    def param_names(self) -> tuple[str, ...]:
        if self.names is not None:
            return tuple(self.names)
        return tuple(f"c{m + 1}" for m in range(self.num_params))

    def value(self, q: Array, coefficients: Array) -> Array:
        """U(q); ``q`` has shape ``(dim,)`` or ``(dim, ...)`` with trailing batch axes."""
        coefficients = jnp.asarray(coefficients)
        return over_points(lambda x: self.fn(x, coefficients), jnp.asarray(q, dtype=float))

    def gradient(self, q: Array, coefficients: Array) -> Array:
        """∂U/∂q by ``jax.grad``; same shape as ``q``."""
        coefficients = jnp.asarray(coefficients)
        grad = jax.grad(lambda x: self.fn(x, coefficients))
        return over_points(grad, jnp.asarray(q, dtype=float))


def mass_matrix(mass: Any, dim: int) -> np.ndarray | None:
    """A validated constant mass matrix M from a ``(d, d)`` array or a length-d vector.

    ``None`` stands for the identity. Raises ``ValueError`` unless M is symmetric positive
    definite and of the right size.
    """
    if mass is None:
        return None
    m = np.asarray(mass, dtype=float)
    if m.ndim == 1:
        m = np.diag(m)
    if m.shape != (dim, dim):
        raise ValueError(f"mass must be ({dim}, {dim}) or a length-{dim} vector, got {m.shape}")
    if not np.allclose(m, m.T) or np.any(np.linalg.eigvalsh(m) <= 0):
        raise ValueError("mass must be symmetric positive definite")
    return m


def inverse_mass(mass: Any, dim: int) -> Array | None:
    """M⁻¹ for :func:`mass_matrix`'s inputs (None for the identity)."""
    m = mass_matrix(mass, dim)
    return None if m is None else jnp.asarray(np.linalg.inv(m))


def kinetic_energy(p: Array, inv_mass: Array | None = None) -> Array:
    """½ pᵀ M⁻¹ p; ``inv_mass`` is M⁻¹ (identity when None)."""
    if inv_mass is None:
        return 0.5 * jnp.sum(p * p, axis=-1)
    return 0.5 * jnp.einsum("...i,ij,...j->...", p, inv_mass, p)


def has_kinetic(obj: object) -> bool:
    """Whether ``obj`` carries its own kinetic energy T(p; θ) with its gradient ``velocity``
    (a :class:`~symplid.dynamics._separable.SeparablePotential`) instead of ½pᵀM⁻¹p."""
    return callable(getattr(obj, "velocity", None)) and callable(getattr(obj, "kinetic", None))


def hamiltonian(
    potential: Potential, coefficients: Array, state: Array, inv_mass: Array | None = None
) -> Array:
    """H(q, p) = ½pᵀM⁻¹p + U(q) (eq. 2) for ``state = (q, p)`` of shape ``(..., 2·dim)``.

    ``potential`` may also be a whole (non-separable) Hamiltonian with ``value(q, p, params)``
    (:mod:`symplid.dynamics._hamiltonians`); ``inv_mass`` must then be None.
    """
    state = jnp.asarray(state)
    d = potential.dim
    q, p = state[..., :d], state[..., d:]
    if hasattr(potential, "grad_p"):
        if inv_mass is not None:
            raise ValueError("a constant mass matrix applies to a separable H only")
        return jnp.vectorize(
            lambda qq, pp: potential.value(qq, pp, coefficients), signature="(d),(d)->()"
        )(q, p)
    u = jnp.vectorize(lambda qq: potential.value(qq, coefficients), signature="(d)->()")(q)
    if has_kinetic(potential):  # its own T(p), a SeparablePotential
        if inv_mass is not None:
            raise ValueError("a constant mass matrix applies to H = ½pᵀM⁻¹p + U(q) only")
        t = jnp.vectorize(lambda pp: potential.kinetic(pp, coefficients), signature="(d)->()")
        return t(p) + u
    return kinetic_energy(p, inv_mass) + u
