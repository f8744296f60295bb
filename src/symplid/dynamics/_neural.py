"""Neural potentials and Hamiltonians: a multilayer perceptron whose weights are θ's coefficients.

The paper embeds a polynomial U (eq. 13) but argues that "any approach" to the potential can be
embedded in its symplectic propagator (eqs 5–6, 14). :class:`MLPPotential` is such a U: a
separable Hamiltonian H = ½pᵀM⁻¹p + U(q; w) with U an Equinox MLP ℝᵈ → ℝ. It has the
:class:`~symplid.dynamics._potentials.Potential` interface, so it plugs into
:class:`~symplid.model._statespace.HamiltonianModel`, :class:`~symplid.model._posterior.Posterior`
and the baseline objectives unchanged; its weights are the model's coefficients and get the
coefficients' prior (a Gaussian prior is the usual choice, ``Normal(0, s)``).

**Layout of the weights** (fixed): layer by layer from the input, each layer's weight matrix
row by row (``w{l}[i,j]`` connects input j of layer l to its output i), then its bias
(``b{l}[i]``). The last layer has no bias: a constant in U changes no force and cannot be
identified (the same reason :class:`~._potentials.Polynomial` has no constant term). For
``dim=2, width=32, depth=2`` that is ``w0`` (32×2), ``b0`` (32), ``w1`` (32×32), ``b1`` (32),
``w2`` (1×32): 1,184 weights.

:class:`MLPHamiltonian` is the non-separable counterpart: a whole H(q, p; w), the same network
on the 2d inputs (q, p), for the non-separable propagators.

Equinox is imported only when a network is built, so that ``import symplid``
stays fast.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from symplid._registry import Registry
from symplid.dynamics._potentials import over_points

Array = jax.Array

ACTIVATIONS: Registry[Callable[[Array], Array]] = Registry("activation")
"""Smooth activations by name (the force is their derivative, so it must be smooth too)."""

ACTIVATIONS.register("tanh", jnp.tanh)
ACTIVATIONS.register("softplus", jax.nn.softplus)
ACTIVATIONS.register("silu", jax.nn.silu, aliases=("swish",))
ACTIVATIONS.register("gelu", jax.nn.gelu)


class _Network:
    """An Equinox MLP ℝⁿ → ℝ whose flat weight vector is θ's coefficients (module docstring)."""

    def __init__(self, dim: int, in_size: int, width: int, depth: int, seed: int,
                 activation: str) -> None:
        for name, value, least in (("dim", dim, 1), ("width", width, 1), ("depth", depth, 0)):
            if not isinstance(value, int | np.integer) or isinstance(value, bool) or value < least:
                raise ValueError(f"{name} must be an integer ≥ {least}, got {value!r}")
        import equinox as eqx  # lazily: only neural models need it
        from jax.flatten_util import ravel_pytree

        self.dim = int(dim)
        self.width = int(width)
        self.depth = int(depth)
        self.seed = int(seed)
        self.activation = ACTIVATIONS.canonical(activation)
        mlp = eqx.nn.MLP(
            in_size=int(in_size),
            out_size="scalar",
            width_size=self.width,
            depth=self.depth,
            activation=ACTIVATIONS.get_entry(activation),
            use_final_bias=False,
            dtype=jnp.float64,
            key=jax.random.key(self.seed),
        )
        params, self._static = eqx.partition(mlp, eqx.is_inexact_array)
        flat, self._unravel = ravel_pytree(params)
        self._combine = eqx.combine
        self._names = _weight_names(mlp)
        if len(self._names) != flat.shape[0]:  # the layout promised in the module docstring
            raise RuntimeError("unexpected Equinox MLP layout")
        self.num_params = int(flat.shape[0])
        self._initial = np.asarray(flat, dtype=float)
        self._initial.setflags(write=False)

    @property
    def param_names(self) -> tuple[str, ...]:
        """``w{l}[i,j]`` and ``b{l}[i]``, layer by layer (module docstring)."""
        return self._names

    def initial_coefficients(self) -> np.ndarray:
        """The seed's initial weights (Equinox's default initialisation), a fresh copy."""
        return self._initial.copy()

    def network(self, coefficients: Array) -> Any:
        """The Equinox MLP with the given weights (a callable on one input point)."""
        coefficients = jnp.asarray(coefficients, dtype=float)
        if coefficients.shape != (self.num_params,):
            raise ValueError(
                f"expected {self.num_params} weights for this {type(self).__name__}, got "
                f"{coefficients.shape}"
            )
        return self._combine(self._unravel(coefficients), self._static)

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(dim={self.dim}, width={self.width}, depth={self.depth}, "
            f"seed={self.seed}, activation={self.activation!r})"
        )


class MLPPotential(_Network):
    """A separable neural potential U(q; w): an MLP from ℝᵈ to ℝ built with Equinox.

    Parameters
    ----------
    dim
        Number of generalised coordinates ``d``.
    width
        Units per hidden layer.
    depth
        Number of hidden layers.
    seed
        Seed of the initial weights (``jax.random.key(seed)``), returned by
        :meth:`initial_coefficients`.
    activation
        A name in :data:`ACTIVATIONS` (``"tanh"``, ``"softplus"``, ``"silu"``, ``"gelu"``).

    Attributes
    ----------
    dim, num_params, param_names
        The :class:`~symplid.dynamics._potentials.Potential` interface; the weights' layout is
        in the module docstring.

    Examples
    --------
    >>> U = MLPPotential(dim=2, width=8, depth=1)
    >>> U.num_params, U.param_names[:2]
    (32, ('w0[0,0]', 'w0[0,1]'))
    """

    def __init__(
        self, dim: int, width: int = 32, depth: int = 2, seed: int = 0, activation: str = "tanh"
    ) -> None:
        _Network.__init__(self, dim, dim, width, depth, seed, activation)

    def _batched(self, f: Callable[[Array], Array], q: Array) -> Array:
        """Apply ``f`` to each point of ``q`` of shape ``(dim,)`` or ``(dim, ...)``."""
        q = jnp.asarray(q, dtype=float)
        if q.shape[0] != self.dim:
            raise ValueError(f"q has {q.shape[0]} coordinates, the potential has dim={self.dim}")
        return over_points(f, q)

    def value(self, q: Array, coefficients: Array) -> Array:
        """U(q; w); ``q`` has shape ``(dim,)`` or ``(dim, ...)`` with trailing batch axes."""
        net = self.network(coefficients)
        return self._batched(net, q)

    def gradient(self, q: Array, coefficients: Array) -> Array:
        """∂U/∂q by ``jax.grad`` of the network; same shape as ``q``."""
        net = self.network(coefficients)
        return self._batched(jax.grad(net), q)


class MLPHamiltonian(_Network):
    """A non-separable neural Hamiltonian H(q, p; w): an MLP from ℝ²ᵈ to ℝ on z = (q, p).

    Nothing splits H into kinetic and potential parts, so it needs the non-separable
    propagators (``"implicit-midpoint"``, ``"tao"``); Hamilton's equations (3) take ∂H/∂q and
    ∂H/∂p by ``jax.grad`` of the network. It has the ``Hamiltonian`` interface (``dim``,
    ``num_params``, ``param_names``, ``value(q, p, w)``, ``grad_q``, ``grad_p``; ``q`` and ``p``
    of shape ``(dim,)`` or ``(dim, ...)`` with trailing batch axes), its weights are θ's
    coefficients and get the coefficients' prior, Normal(0, 1) by default (the ``"mlp"``
    family). The layout of the weights is that of the module docstring with 2·dim inputs,
    ``q`` first: for ``dim=2, width=32, depth=2``, 32×4 + 32 + 32×32 + 32 + 32 = 1,248 weights.
    As for :class:`MLPPotential`, H has no constant term (none can be identified).

    Parameters
    ----------
    dim, width, depth, seed, activation
        As for :class:`MLPPotential`; ``dim`` is the number of coordinates d (the network
        takes 2d inputs).

    Examples
    --------
    >>> H = MLPHamiltonian(dim=1, width=4, depth=1)
    >>> H.num_params
    16
    """

    def __init__(
        self, dim: int, width: int = 32, depth: int = 2, seed: int = 0, activation: str = "tanh"
    ) -> None:
        super().__init__(dim, 2 * int(dim) if isinstance(dim, int | np.integer) else dim,
                         width, depth, seed, activation)

    def _z(self, q: Array, p: Array) -> Array:
        q, p = jnp.asarray(q, dtype=float), jnp.asarray(p, dtype=float)
        if q.shape[0] != self.dim or q.shape != p.shape:
            raise ValueError(
                f"q and p must both have shape ({self.dim}, ...), got {q.shape} and {p.shape}"
            )
        return jnp.concatenate([q, p], axis=0)

    def value(self, q: Array, p: Array, coefficients: Array) -> Array:
        """H(q, p; w); the batch shape of ``q``."""
        return over_points(self.network(coefficients), self._z(q, p))

    def _grad(self, q: Array, p: Array, coefficients: Array) -> Array:
        return over_points(jax.grad(self.network(coefficients)), self._z(q, p))

    def grad_q(self, q: Array, p: Array, coefficients: Array) -> Array:
        """∂H/∂q; the shape of ``q``."""
        return self._grad(q, p, coefficients)[: self.dim]

    def grad_p(self, q: Array, p: Array, coefficients: Array) -> Array:
        """∂H/∂p; the shape of ``p``."""
        return self._grad(q, p, coefficients)[self.dim :]


def _weight_names(mlp: Any) -> tuple[str, ...]:
    names: list[str] = []
    for layer_index, layer in enumerate(mlp.layers):
        out_size, in_size = layer.weight.shape
        names += [f"w{layer_index}[{i},{j}]" for i in range(out_size) for j in range(in_size)]
        if layer.bias is not None:
            names += [f"b{layer_index}[{i}]" for i in range(layer.bias.shape[0])]
    return tuple(names)


__all__ = ["ACTIVATIONS", "MLPHamiltonian", "MLPPotential"]
