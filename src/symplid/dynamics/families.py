"""Families of potentials and Hamiltonians that settings, the command line and sweeps name.

A run's settings describe the model by name (``model.potential = "polynomial"`` with
``model.order``; ``model.potential = "mlp"`` with ``model.width`` and ``model.depth``;
``model.hamiltonian = "double-pendulum"``). Each name is an entry of one of the two
registries below, and the entry builds the object for the data's dimension::

    from symplid.dynamics.families import POTENTIAL_FAMILIES, Family

    POTENTIAL_FAMILIES.register("mine", Family(
        "mine", lambda dim, options: MyPotential(dim, options.order), "U(q) of my kind"))

``options`` is the run's model settings (any object with attributes: ``order``, ``width``,
``depth``, ...), so a family reads the keys it needs and ignores the rest.

* :data:`POTENTIAL_FAMILIES`: U(q; θ) for the separable H = ½pᵀM⁻¹p + U(q) (eq. 2).
* :data:`HAMILTONIAN_FAMILIES`: the Hamiltonian itself. ``"separable"`` (the default) means
  "½pᵀM⁻¹p plus the potential family above"; any other entry returns a whole H(q, p; θ),
  which replaces the potential family.

A value that is not a name (an expression such as ``"-GM/sqrt(q1^2 + q2^2)"``, or
``"file:model.py:U"``) is a user's own model: :func:`family_of` answers it with
:func:`user_family`, built by :mod:`symplid.dynamics.user_models` with the parameters that
``options.parameters`` declares.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from symplid.dynamics.hamiltonians import DoublePendulum, PolynomialHamiltonian
from symplid.dynamics.potentials import Polynomial
from symplid.dynamics.user_models import QUADRATIC, build_user_model, is_user_model
from symplid.registry import Registry

__all__ = [
    "HAMILTONIAN_FAMILIES", "POTENTIAL_FAMILIES", "SEPARABLE", "Family", "build_family",
    "family_of", "user_family",
]

BuildFn = Callable[[int, Any], Any]

#: The name of the Hamiltonian family ½pᵀM⁻¹p + U(q) with U from ``model.potential``.
SEPARABLE = "separable"


@dataclass(frozen=True)
class Family:
    """A named family: ``build(dim, options)`` returns a potential (or a Hamiltonian).

    Attributes
    ----------
    name, build, description
        The registry name, the builder and one line for help texts.
    coefficient_prior
        The default prior of the family's coefficients, as text that
        :func:`symplid.model.priors.as_prior` reads (``"normal(0, 1)"``); ``None``: the
        settings' own default, the paper's Laplace(0, 10). This is the one place a family's
        default prior is decided; ``priors.coefficients`` in the settings overrides it.
    neural
        The coefficients are many network weights: the run's MAP takes the scalable path
        (:mod:`symplid.inference.neural_fit`: Adam then L-BFGS, Gauss–Newton Laplace) instead
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
    "polynomial",
    Family(
        "polynomial",
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



def _double_pendulum(dim: int, options: Any) -> DoublePendulum:
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


def _mlp(dim: int, options: Any, hamiltonian: bool = False) -> Any:
    from symplid.dynamics.neural import MLPHamiltonian, MLPPotential  # Equinox only now

    return (MLPHamiltonian if hamiltonian else MLPPotential)(
        dim,
        width=int(getattr(options, "width", 32)),
        depth=int(getattr(options, "depth", 2)),
        seed=int(getattr(options, "network_seed", 0)),
        activation=getattr(options, "activation", "tanh"),
    )


def user_family(text: str, kind: str) -> Family:
    """The family of a user's own model (:mod:`symplid.dynamics.user_models`): the expression
    or ``file:PATH:NAME`` ``text`` as ``model.<kind>``, its parameters those that
    ``options.parameters`` declare (objects with a ``name``), ``options.kinetic`` its T(p)."""

    def build(dim: int, options: Any) -> Any:
        names = [p.name for p in getattr(options, "parameters", ())]
        return build_user_model(text, kind, dim, names, getattr(options, "kinetic", QUADRATIC))

    return Family("user", build, f"the user's {kind} {text}")


def family_of(options: Any) -> Family:
    """The family entry that ``options`` (model settings) build: a Hamiltonian family other
    than ``"separable"``, else the potential family; a user's expression or file for either
    (:func:`user_family`)."""
    hamiltonian = getattr(options, "hamiltonian", SEPARABLE)
    if is_user_model(hamiltonian):
        return user_family(hamiltonian, "hamiltonian")
    entry = HAMILTONIAN_FAMILIES.get_entry(hamiltonian)
    if entry.name != SEPARABLE:
        return entry
    potential = getattr(options, "potential", "polynomial")
    if is_user_model(potential):
        return user_family(potential, "potential")
    return POTENTIAL_FAMILIES.get_entry(potential)


def build_family(dim: int, options: Any) -> Any:
    """The potential or Hamiltonian that ``options.hamiltonian`` / ``options.potential`` name.

    ``options.hamiltonian`` other than ``"separable"`` wins; otherwise the potential family
    ``options.potential`` (``"polynomial"`` when the attribute is absent) is built.
    """
    return family_of(options).build(dim, options)
