"""Families of potentials and Hamiltonians that settings, the command line and sweeps name.

A run's settings describe the model by name (``model.potential = "polynomial"`` with
``model.order``; ``model.potential = "mlp"`` with ``model.width`` and ``model.depth``;
``model.hamiltonian = "double-pendulum"``). Each name is an entry of one of the two
registries below, and the entry builds the object for the data's dimension::

    from symplid.dynamics._families import POTENTIAL_FAMILIES, Family

    POTENTIAL_FAMILIES.register("mine", Family(
        "mine", lambda dim, options: MyPotential(dim, options.order), "U(q) of my kind"))

``options`` is a :class:`FamilyOptions`: the typed values a builder may read (``order``,
``width``, ``depth``, ...), so a family reads the ones it needs and ignores the rest. This
module reads no settings: the workflow makes the options from a run's model settings
(:mod:`symplid.workflow._model_builder`), and a user who builds a family in Python gives them.

* :data:`POTENTIAL_FAMILIES`: U(q; θ) for the separable H = ½pᵀM⁻¹p + U(q) (eq. 2).
* :data:`HAMILTONIAN_FAMILIES`: the Hamiltonian itself. ``"separable"`` (the default) means
  "½pᵀM⁻¹p plus the potential family above"; any other entry returns a whole H(q, p; θ),
  which replaces the potential family.

A value that is not a name (an expression such as ``"-GM/sqrt(q1^2 + q2^2)"``, or
``"file:model.py:U"``) is a user's own model: :func:`family_of` answers it with
:func:`user_family`, built by :mod:`symplid.dynamics._user_models` with the parameters that
``options.parameters`` names.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from symplid._registry import Registry
from symplid.dynamics._hamiltonians import DoublePendulum, PolynomialHamiltonian
from symplid.dynamics._potentials import Polynomial
from symplid.dynamics._user_models import (
    MAX_EXPRESSION_SIZE,
    QUADRATIC,
    build_user_model,
    is_user_model,
)

__all__ = [
    "DEFAULT_POTENTIAL", "HAMILTONIAN_FAMILIES", "POTENTIAL_FAMILIES", "SEPARABLE", "Family",
    "FamilyOptions", "build_family", "family_of", "user_family",
]

#: The name of the Hamiltonian family ½pᵀM⁻¹p + U(q) with U from ``model.potential``.
SEPARABLE = "separable"
#: The potential family when none is named: the polynomial of eq. (13).
DEFAULT_POTENTIAL = "polynomial"


@dataclass(frozen=True)
class FamilyOptions:
    """The values a family's builder may read (each family reads its own, ignores the rest).

    Attributes
    ----------
    order
        Polynomial order ℓ (``"polynomial"``: monomials of degree 2..ℓ, eq. 13;
        ``"polynomial-qp"``: degree 1..ℓ in q and p).
    width, depth, activation, network_seed
        An ``"mlp"`` network: units per hidden layer, hidden layers, activation (a name in
        :data:`~symplid.dynamics._neural.ACTIVATIONS`), seed of the initial weights.
    parameters
        The names of a user model's own parameters, in order.
    kinetic
        The T(p) of a user's potential: ``"quadratic"`` (½pᵀM⁻¹p) or an expression.
    max_expression_size
        The most tokens a user's expression may have
        (:data:`~symplid.dynamics._user_models.MAX_EXPRESSION_SIZE`).
    """

    order: int = 3
    width: int = 32
    depth: int = 2
    activation: str = "tanh"
    network_seed: int = 0
    parameters: tuple[str, ...] = ()
    kinetic: str = QUADRATIC
    max_expression_size: int = MAX_EXPRESSION_SIZE


BuildFn = Callable[[int, FamilyOptions], Any]


@dataclass(frozen=True)
class Family:
    """A named family: ``build(dim, options)`` returns a potential (or a Hamiltonian) of
    ``dim`` coordinates, ``options`` a :class:`FamilyOptions`.

    Attributes
    ----------
    name, build, description
        The registry name, the builder and one line for help texts.
    coefficient_prior
        The default prior of the family's coefficients, as text that
        :func:`symplid.model._priors.as_prior` reads (``"normal(0, 1)"``); ``None``: the
        settings' own default, the paper's Laplace(0, 10). This is the one place a family's
        default prior is decided; ``priors.coefficients`` in the settings overrides it.
    neural
        The coefficients are many network weights: the run's MAP takes the scalable path
        (:mod:`symplid.inference.map._neural`: Adam then L-BFGS, Gauss–Newton Laplace) instead
        of multistart L-BFGS-B with the exact Hessian, and random-walk DRAM is refused.
    """

    name: str
    build: BuildFn
    description: str = ""
    coefficient_prior: str | None = None
    neural: bool = False


POTENTIAL_FAMILIES: Registry[Family] = Registry("potential family")
HAMILTONIAN_FAMILIES: Registry[Family] = Registry("Hamiltonian family")

POTENTIAL_FAMILIES.register(
    DEFAULT_POTENTIAL,
    Family(
        DEFAULT_POTENTIAL,
        lambda dim, options: Polynomial(dim, options.order),
        "U(q) = Σ c_α q^α over the monomials of degree 2..order (eq. 13)",
    ),
)
POTENTIAL_FAMILIES.register(
    "mlp",
    Family(
        "mlp",
        lambda dim, options: _mlp(dim, options),
        "U(q; w) an MLP of model.width units × model.depth hidden layers (dynamics.neural)",
        coefficient_prior="normal(0, 1)",
        neural=True,
    ),
    aliases=("neural",),
)
HAMILTONIAN_FAMILIES.register(
    SEPARABLE,
    Family(SEPARABLE, lambda dim, options: None, "H = ½pᵀM⁻¹p + U(q), U from model.potential"),
)



def _double_pendulum(dim: int, options: FamilyOptions) -> DoublePendulum:
    if dim != 2:
        raise ValueError(f"the double pendulum has 2 angles; the data's system has {dim} "
                         "coordinates")
    return DoublePendulum()


HAMILTONIAN_FAMILIES.register(
    "double-pendulum",
    Family(
        "double-pendulum",
        _double_pendulum,
        "planar double pendulum, θ = (log m1/m2, log l1/l2, log (g/l2)/9.81): what angles identify",
    ),
)
HAMILTONIAN_FAMILIES.register(
    "polynomial-qp",
    Family(
        "polynomial-qp",
        lambda dim, options: PolynomialHamiltonian(dim, options.order),
        "H(q, p) = Σ c_α (q, p)^α over the monomials of degree 1..order in q and p together",
    ),
)


HAMILTONIAN_FAMILIES.register(
    "mlp",
    Family(
        "mlp",
        lambda dim, options: _mlp(dim, options, hamiltonian=True),
        "H(q, p; w) an MLP on (q, p), non-separable (dynamics.neural.MLPHamiltonian); "
        "model.width, model.depth",
        coefficient_prior="normal(0, 1)",
        neural=True,
    ),
    aliases=("neural",),
)


def _mlp(dim: int, options: FamilyOptions, hamiltonian: bool = False) -> Any:
    from symplid.dynamics._neural import MLPHamiltonian, MLPPotential  # Equinox only now

    return (MLPHamiltonian if hamiltonian else MLPPotential)(
        dim,
        width=options.width,
        depth=options.depth,
        seed=options.network_seed,
        activation=options.activation,
    )


def user_family(text: str, kind: str) -> Family:
    """The family of a user's own model (:mod:`symplid.dynamics._user_models`): the expression
    or ``file:PATH:NAME`` ``text`` as ``model.<kind>``, its parameters named by
    ``options.parameters``, ``options.kinetic`` its T(p)."""

    def build(dim: int, options: FamilyOptions) -> Any:
        return build_user_model(text, kind, dim, list(options.parameters), options.kinetic,
                                options.max_expression_size)

    return Family("user", build, f"the user's {kind} {text}")


def family_of(hamiltonian: str = SEPARABLE, potential: str = DEFAULT_POTENTIAL) -> Family:
    """The family that a model's ``hamiltonian`` and ``potential`` name: a Hamiltonian family
    other than ``"separable"``, else the potential family; a user's expression or file for
    either (:func:`user_family`). ``ValueError`` for an unknown name."""
    if is_user_model(hamiltonian):
        return user_family(hamiltonian, "hamiltonian")
    entry = HAMILTONIAN_FAMILIES.get_entry(hamiltonian)
    if entry.name != SEPARABLE:
        return entry
    if is_user_model(potential):
        return user_family(potential, "potential")
    return POTENTIAL_FAMILIES.get_entry(potential)


def build_family(
    dim: int,
    hamiltonian: str = SEPARABLE,
    potential: str = DEFAULT_POTENTIAL,
    options: FamilyOptions | None = None,
) -> Any:
    """The potential or Hamiltonian of ``dim`` coordinates that the names give
    (:func:`family_of`), built with ``options`` (default :class:`FamilyOptions`)."""
    return family_of(hamiltonian, potential).build(dim, options or FamilyOptions())
