"""Named reference systems with their true potentials, used by the simulator and the tests.

Each :class:`System` carries a potential (a :class:`~symplid.dynamics._potentials.Polynomial`,
or a :class:`~._potentials.FunctionPotential` for a system that no polynomial describes exactly)
and its true coefficients in the library's convention (coefficients of **U**, basis order of
``docs/explanation/conventions.md``), a true damping rate γ (0 for a conservative system),
plus a default initial state and observation schedule. A non-separable system carries a whole
Hamiltonian (:mod:`symplid.dynamics._hamiltonians`) and its true parameters instead, with an
integrator for its fine "truth" that accepts it.

To add a system, register a factory in :data:`SYSTEMS` (``SYSTEMS.register(name, factory)``).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from symplid._registry import Registry
from symplid.dynamics._hamiltonians import DoublePendulum, Hamiltonian
from symplid.dynamics._potentials import FunctionPotential, Polynomial, Potential

__all__ = [
    "SYSTEMS",
    "System",
    "damped_pendulum",
    "double_pendulum",
    "double_well",
    "fpu_chain",
    "get_system",
    "harmonic",
    "henon_heiles",
]


@dataclass(frozen=True)
class System:
    """A reference Hamiltonian system: H = ½|p|² + U(q), or a whole H.

    ``potential`` is the U (a polynomial, or a function that no polynomial describes exactly)
    or the Hamiltonian, and ``coefficients`` its true parameters; ``damping`` is a true damping
    rate γ of the friction −γp (:mod:`symplid.dynamics._damping`; 0 for a conservative system);
    ``truth_integrator`` integrates the fine truth (leapfrog for a separable H), and
    ``observation`` is what :func:`~symplid.model._simulate.simulate` observes by default.
    """

    name: str
    potential: Potential | Hamiltonian
    coefficients: np.ndarray
    initial_state: np.ndarray
    description: str
    obs_interval: float = 5.0
    num_obs: int = 20
    noise_std: float = 0.05
    damping: float = 0.0
    truth_integrator: str = "leapfrog"
    observation: str = "full"

    @property
    def dim(self) -> int:
        return self.potential.dim


def henon_heiles() -> System:
    """U = ½q1² + ½q2² + q1²q2 − ⅓q2³ (eq. 15), the paper's experiment.

    Initial state (0.2, −0.25, 0.3, −0.25): the paper prints −(−1/4) for p2, a typo; its data
    fit −0.25 and H = 0.12271 either way.
    """
    pot = Polynomial(2, 3)
    c = pot.coefficients_from({"q1^2": 0.5, "q2^2": 0.5, "q1^2*q2": 1.0, "q2^3": -1.0 / 3.0})
    return System(
        "henon-heiles",
        pot,
        c,
        np.array([0.2, -0.25, 0.3, -0.25]),
        "Hénon–Heiles: U = ½q1² + ½q2² + q1²q2 − ⅓q2³",
    )


def harmonic() -> System:
    """Unit harmonic oscillator U = ½q² (period 2π)."""
    pot = Polynomial(1, 2)
    return System(
        "harmonic",
        pot,
        pot.coefficients_from({"q1^2": 0.5}),
        np.array([1.0, 0.0]),
        "harmonic oscillator: U = ½q²",
        obs_interval=1.0,
        num_obs=20,
    )


def double_well() -> System:
    """Quartic double well U = −½q² + ¼q⁴ (minima at q = ±1, barrier height ¼)."""
    pot = Polynomial(1, 4)
    return System(
        "double-well",
        pot,
        pot.coefficients_from({"q1^2": -0.5, "q1^4": 0.25}),
        np.array([0.5, 0.6]),
        "quartic double well: U = −½q² + ¼q⁴",
        obs_interval=1.0,
        num_obs=30,
    )


def _expand_power(linear: dict[tuple[int, ...], float], k: int) -> dict[tuple[int, ...], float]:
    """Expand (Σ c_i q^{e_i})^k of a linear form into monomials."""
    terms = list(linear.items())
    out: dict[tuple[int, ...], float] = {}
    for combo in itertools.combinations_with_replacement(range(len(terms)), k):
        counts = [combo.count(i) for i in range(len(terms))]
        multinom = math.factorial(k)
        coeff = 1.0
        exp = np.zeros(len(terms[0][0]), dtype=int)
        for i, c in enumerate(counts):
            multinom //= math.factorial(c)
            coeff *= terms[i][1] ** c
            exp += c * np.asarray(terms[i][0])
        key = tuple(int(e) for e in exp)
        out[key] = out.get(key, 0.0) + multinom * coeff
    return out


def fpu_chain(n: int = 3, alpha: float = 0.25) -> System:
    """Fermi–Pasta–Ulam–Tsingou α chain of ``n`` masses with fixed ends.

    U = Σ_{i=0}^{n} [½(q_{i+1} − q_i)² + (α/3)(q_{i+1} − q_i)³] with q_0 = q_{n+1} = 0:
    coupled anharmonic oscillators with a cubic polynomial potential.
    """
    pot = Polynomial(n, 3)
    terms: dict[tuple[int, ...], float] = {}
    unit = np.eye(n, dtype=int)
    for i in range(n + 1):
        linear: dict[tuple[int, ...], float] = {}
        if i < n:
            linear[tuple(unit[i])] = 1.0  # + q_{i+1}
        if i > 0:
            linear[tuple(unit[i - 1])] = -1.0  # − q_i
        for k, c in ((2, 0.5), (3, alpha / 3.0)):
            for e, v in _expand_power(linear, k).items():
                terms[e] = terms.get(e, 0.0) + c * v
    x0 = np.zeros(2 * n)
    x0[0] = 0.3
    x0[n + n - 1] = -0.2
    return System(
        "fpu-chain",
        pot,
        pot.coefficients_from(terms),
        x0,
        f"FPUT-α chain of {n} masses, fixed ends, α = {alpha}",
        obs_interval=1.0,
        num_obs=40,
    )


def _pendulum_potential(q, coefficients):
    """U = ω²(1 − cos q) of a plane pendulum, ω² = g/l = ``coefficients[0]``."""
    return coefficients[0] * (1.0 - jnp.cos(q[0]))


def damped_pendulum(omega2: float = 1.0, gamma: float = 0.1) -> System:
    """A plane pendulum with linear friction: q̈ = −ω² sin q − γq̇ (ω² = g/l, unit mass).

    U = ω²(1 − cos q) is not a polynomial; its Taylor series ω²(q²/2 − q⁴/24 + q⁶/720 − …) is
    what a quartic model can learn (at the default amplitude of 1 rad the q⁶ term is below
    0.3 % of the energy). Densely sampled: 60 observations 0.5 apart, over which the energy
    falls by about e^{−γt} (to 5 % by t = 30).
    """
    pot = FunctionPotential(_pendulum_potential, dim=1, num_params=1, names=("omega2",))
    return System(
        "damped-pendulum",
        pot,
        np.array([float(omega2)]),
        np.array([1.0, 0.0]),
        f"damped pendulum: U = ω²(1 − cos q), ω² = {omega2:g}, friction −γp with γ = {gamma:g}",
        obs_interval=0.5,
        num_obs=60,
        damping=float(gamma),
    )


def double_pendulum(
    m1: float = 1.5, m2: float = 1.0, l1: float = 1.2, l2: float = 0.9, g: float = 9.81
) -> System:
    """The planar double pendulum (:class:`~._hamiltonians.DoublePendulum`), non-separable.

    Masses ``m1``, ``m2`` (kg), rod lengths ``l1``, ``l2`` (m) and gravity ``g`` (m/s²); the
    angles identify θ = (log m1/m2, log l1/l2, log (g/l2)/9.81), the system's true parameters
    (0.405, 0.288, 0.105 for the defaults). Started from rest at
    φ = (1.0, 0.5) rad (below the chaotic regime), observed in the angles alone every 0.25 s,
    40 times, with noise 0.02 rad; the truth is RK4 at the fine step (no leapfrog for a
    non-separable H).
    """
    ham = DoublePendulum()
    params = ham.params_from(m1, m2, l1, l2, g)
    return System(
        "double-pendulum",
        ham,
        params,
        np.array([1.0, 0.5, 0.0, 0.0]),
        f"double pendulum: m1 = {m1:g}, m2 = {m2:g}, l1 = {l1:g}, l2 = {l2:g}, g = {g:g}",
        obs_interval=0.25,
        num_obs=40,
        noise_std=0.02,
        truth_integrator="rk4",
        observation="positions",
    )


SYSTEMS: Registry[Callable[[], System]] = Registry("system")
"""Named reference systems: name → a function that builds the :class:`System`."""
SYSTEMS.register("henon-heiles", henon_heiles)
SYSTEMS.register("harmonic", harmonic)
SYSTEMS.register("double-well", double_well)
SYSTEMS.register("fpu-chain", fpu_chain)
SYSTEMS.register("damped-pendulum", damped_pendulum)
SYSTEMS.register("double-pendulum", double_pendulum)


def get_system(name: str) -> System:
    """A named reference system: one of :data:`SYSTEMS`."""
    return SYSTEMS.get_entry(name)()
