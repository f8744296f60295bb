"""The noisy Hamiltonian state-space model, eq. (7), and its UKF log marginal likelihood.

The likelihood itself is the free function :func:`symplid.model._likelihood.log_likelihood`;
the model holds the settings, the layout of θ and the data preparation, and delegates.

    X_k = Ψ(X_{k−1}; θ_Ψ) + ξ_k,   ξ_k ~ N(0, Σ(θ_Σ))
    Y_k = h(X_k) + η_k,            η_k ~ N(0, Γ(θ_Γ))

Ψ is an integrator applied over the gap between two observations in ⌈gap/dt⌉ equal substeps
(eq. 14). The parameter vector is laid out as::

    θ = [coefficients of U ..., process-noise variance(s) ..., observation-noise variance(s) ...]

(for a whole, non-separable H(q, p; θ), H's parameters take the place of U's coefficients),
with one variance each (``noise="isotropic"``: Σ = θ_Σ I, Γ = θ_Γ I, the paper's choice),
one per component (``noise="diagonal"``), or one Σ variance and one Γ variance per kind of
observed component (``noise="per-kind"``: positions and momenta; for data whose columns are
measured differently, e.g. a velocity column smoothed from positions). Variances, not standard
deviations. With ``process_noise_per="none"`` the model has no process noise and θ no
process variance: the states are one path of Ψ and the likelihood is the exact
deterministic-trajectory likelihood of :mod:`symplid.model._deterministic` (no filter).
With ``damping=True`` the damping rate γ (:mod:`symplid.dynamics._damping`) comes
right after the coefficients: θ_Ψ = [coefficients ..., γ].

``observation_noise`` picks the noise model of Y_k from
:data:`~symplid.filters._noise.OBSERVATION_NOISE`: ``"additive"`` (eq. 7, the default),
``"multiplicative"`` (Y = h(X)∘(1 + ε), ε ~ N(0, diag r)) or ``"both"``. The relative
variances r (``obs_rel_var``, laid out like Γ's) follow the additive ones, which a purely
multiplicative model does not have::

    θ = [coefficients ..., (γ), process var(s) ..., obs var(s) (additive) ..., obs rel var(s) ...]
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from functools import cached_property, partial
from typing import Any, Literal

import jax
import jax.numpy as jnp
import numpy as np

from symplid.dynamics._forcing import Force
from symplid.dynamics._hamiltonians import Hamiltonian, is_hamiltonian
from symplid.dynamics._integrators import Integrator
from symplid.dynamics._potentials import Potential, inverse_mass
from symplid.dynamics._potentials import hamiltonian as hamiltonian_value
from symplid.dynamics._trajectory import substeps
from symplid.filters import FilterResult
from symplid.filters._noise import ObservationNoise, get_observation_noise
from symplid.model._backends import check_backend, loglik_program, select
from symplid.model._construction import NOISE_LAYOUTS as NOISE_LAYOUTS  # the choices, also here
from symplid.model._construction import PROCESS_NOISE_CHOICES as PROCESS_NOISE_CHOICES
from symplid.model._construction import ModelFields, normalise_fields
from symplid.model._data import DataError, Observations
from symplid.model._inputs import node_table
from symplid.model._layout import ParameterLayout
from symplid.model._likelihood import JAX_BACKEND, ForcedGapInputs, GapInputs, PreparedData
from symplid.model._programs import compiled

__all__ = ["NOISE_LAYOUTS", "PROCESS_NOISE_CHOICES", "HamiltonianModel"]

Array = jax.Array
_POTENTIAL_RENAMED = ("HamiltonianModel's 'potential' is now 'hamiltonian' (it may hold a whole "
                      "H(q, p; θ)); the old name will be removed")
ObservationSpec = str | np.ndarray | Callable[[Array], Array]


class HamiltonianModel(ModelFields):
    """A Hamiltonian state-space model with a UKF marginal likelihood (Theorem 1).

    Parameters
    ----------
    hamiltonian
        The model's Hamiltonian: a potential U(q) (then H = ½pᵀM⁻¹p + U(q)) — a
        :class:`~symplid.dynamics._potentials.Polynomial`, a
        :class:`~._potentials.FunctionPotential`, or anything with the same interface — or a
        whole, possibly non-separable Hamiltonian H(q, p; θ)
        (:class:`~symplid.dynamics._hamiltonians.Hamiltonian`: ``FunctionHamiltonian``,
        ``DoublePendulum``, ...), whose parameters then lead θ in place of U's coefficients.
    integrator
        Name from :data:`~symplid.dynamics._integrators.INTEGRATORS` (``"leapfrog"``,
        ``"rk2-midpoint"``, ``"rk2-heun"``, ``"rk4"``, ``"euler"``, ``"yoshida4"``; for a
        non-separable H ``"tao"``, ``"tao4"``, ``"implicit-midpoint"``, ``"gauss4"`` or a
        Runge–Kutta method) or an ``Integrator``.
    dt
        Largest learning step; each gap is split into ⌈gap/dt⌉ equal substeps.
    observation
        ``"full"`` (the whole state), ``"positions"`` (q only), a ``(d_y, 2d)`` matrix, or a
        JAX function ``h(x) -> y`` (handled by the unscented transform).
    process_noise_per
        ``"gap"`` (default): sigma points are formed once per observation gap, pushed through
        all its substeps, and Σ is added once. ``"step"``: Σ is added after every substep.
        ``"none"``: no process noise (Σ = 0, no ``process_var`` in θ); the likelihood is that
        of the observations around one integrated path (:mod:`symplid.model._deterministic`).
    noise
        ``"isotropic"`` (one variance for Σ and one for Γ), ``"diagonal"`` (one per component)
        or ``"per-kind"`` (one for Σ, and one per kind of observed component for Γ: positions,
        momenta; needs ``observation="full"`` or ``"positions"``).
    observation_noise
        ``"additive"`` (Y = h(X) + η, eq. 7), ``"multiplicative"`` (Y = h(X)∘(1 + ε)) or
        ``"both"``: a name in :data:`~symplid.filters._noise.OBSERVATION_NOISE`. The relative
        variances have the layout of Γ's (``noise``).
    mass
        Constant mass matrix M (identity when None), as a ``(d, d)`` array or a length-d vector.
    alpha, beta, kappa
        Scaled unscented transform settings. The defaults α = 1, β = 2, κ = 0 give λ = 0:
        2n points of weight 1/(2n) and a centre point that only enters the covariance.
    jitter
        Added to the diagonal of the predicted covariance after every prediction (the
        filtered covariance is kept as a Cholesky factor and needs none); not used without
        process noise (there is no filter).
    unroll
        Unroll factor of the substep loop (``lax.fori_loop(unroll=...)``).
    backend
        Likelihood backend from :data:`~symplid.model._backends.LIKELIHOOD_BACKENDS`
        (``"jax"``: the reference) or ``"auto"`` (the best one that supports the model; see
        :attr:`likelihood_backend`). :meth:`filter` always runs the JAX reference.
    damping
        Learn a damping rate γ ≥ 0: ṗ = −∂U/∂q − γM⁻¹p (:mod:`symplid.dynamics._damping`). θ
        gets the entry ``gamma`` after the coefficients; a symplectic composition (leapfrog,
        yoshida4) becomes the conformally symplectic splitting, a Runge–Kutta method the
        damped Runge–Kutta step (``integrator`` is then the damped one, its ``base`` the
        named one). A separable H only.
    binding
        Tao's binding constant ω for ``"tao"``/``"tao4"`` (:mod:`symplid.dynamics._nonseparable`);
        None: ω = 1/dt. An error with any other integrator.
    potential
        Deprecated keyword for ``hamiltonian`` (a ``FutureWarning``); so is the attribute
        ``model.potential``.
    force
        A generalised force F(q, p, u(t), t; θ_F) (:class:`~symplid.dynamics._forcing.Force`):
        the driven system ṗ = −∂H/∂q + F. Its parameters θ_F follow H's in θ (block
        ``force``); the integrator becomes its forced form (:mod:`symplid.dynamics._forced`)
        and the data must carry the inputs (``Observations.inputs``). Not with ``damping``
        (write the friction into F) and only with ``process_noise_per="gap"``.

    The settings are checked and made normal by
    :func:`~symplid.model._construction.normalise_fields` before they are stored: the fields
    read back are the normal ones (``integrator`` an ``Integrator``, ``mass`` a matrix
    or None, a matrix ``observation`` as floats, canonical names). The backend is chosen
    by :mod:`symplid.model._backends`; the compiled programs are kept by
    :mod:`symplid.model._programs`.
    """

    def __init__(
        self,
        hamiltonian: Potential | Hamiltonian | None = None,
        integrator: str | Integrator = "leapfrog",
        dt: float = 0.25,
        observation: ObservationSpec = "full",
        process_noise_per: Literal["gap", "step", "none"] = "gap",
        noise: Literal["isotropic", "diagonal", "per-kind"] = "isotropic",
        mass: Any = None,
        alpha: float = 1.0,
        beta: float = 2.0,
        kappa: float = 0.0,
        jitter: float = 1e-12,
        unroll: int = 1,
        backend: str = "auto",
        damping: bool = False,
        observation_noise: str = "additive",
        binding: float | None = None,
        *,
        potential: Potential | None = None,
        force: Force | None = None,
    ) -> None:
        super().__init__(**normalise_fields(
            _renamed_potential(hamiltonian, potential), integrator, dt, observation,
            process_noise_per, noise, mass, alpha, beta, kappa, jitter, unroll, backend,
            damping, observation_noise, binding, force,
        ))
        check_backend(self)  # a forced backend must support the model

    @property
    def potential(self) -> Potential | Hamiltonian:
        """Deprecated: the field is ``hamiltonian``."""
        warnings.warn(_POTENTIAL_RENAMED, FutureWarning, stacklevel=2)
        return self.hamiltonian

    @property
    def separable(self) -> bool:
        """Whether H = ½pᵀM⁻¹p + U(q) (a potential), not a whole H(q, p; θ)."""
        return not is_hamiltonian(self.hamiltonian)

    # ------------------------------------------------------------------ layout of θ
    @property
    def state_dim(self) -> int:
        return 2 * self.hamiltonian.dim

    @property
    def observation_matrix(self) -> np.ndarray | None:
        """H for a linear observation operator, None for a function."""
        obs = self.observation
        d = self.hamiltonian.dim
        if isinstance(obs, str):
            return np.eye(2 * d) if obs == "full" else np.eye(d, 2 * d)
        if callable(obs):
            return None
        return np.asarray(obs)

    @property
    def obs_dim(self) -> int:
        matrix = self.observation_matrix
        if matrix is not None:
            return int(matrix.shape[0])
        out = jax.eval_shape(self.observation, jax.ShapeDtypeStruct((self.state_dim,), float))
        return int(np.prod(out.shape)) if out.shape else 1

    @property
    def deterministic(self) -> bool:
        """Whether the model has no process noise (``process_noise_per="none"``): its
        likelihood follows one integrated path (:mod:`symplid.model._deterministic`)."""
        return self.process_noise_per == "none"

    @property
    def noise_model(self) -> ObservationNoise:
        """The observation-noise model (:data:`~symplid.filters._noise.OBSERVATION_NOISE`)."""
        return get_observation_noise(self.observation_noise)

    @property
    def obs_noise_labels(self) -> tuple[str, ...]:
        """The label of each observation variance: ``""`` (isotropic), the component's index
        (diagonal) or its kind ``"q"``/``"p"`` (per-kind)."""
        if self.noise == "isotropic":
            return ("",)
        if self.noise == "diagonal":
            return tuple(str(i) for i in range(self.obs_dim))
        return ("q", "p") if self.observation == "full" else ("q",)

    @property
    def obs_noise_index(self) -> np.ndarray:
        """For each observed component, which of the observation variances it uses."""
        d_y = self.obs_dim
        if self.noise == "isotropic":
            return np.zeros(d_y, dtype=int)
        if self.noise == "diagonal":
            return np.arange(d_y)
        return np.arange(d_y) // self.hamiltonian.dim  # q1..qd → 0, p1..pd → 1

    @property
    def parameter_group(self) -> str:
        """The prior group, and layout block, of the Hamiltonian's parameters:
        ``coefficients``, or ``parameters`` for a user model's declared ones."""
        return getattr(self.hamiltonian, "parameter_group", "coefficients")

    @cached_property
    def layout(self) -> ParameterLayout:
        """θ's blocks (:mod:`symplid.model._layout`): the Hamiltonian's parameters, ``damping``,
        ``process_var``, ``obs_var``, ``obs_rel_var``; built once."""
        noise_model = self.noise_model
        return ParameterLayout.for_model(
            self.hamiltonian.param_names, self.parameter_group, damping=self.damping,
            noise=self.noise, state_dim=self.state_dim, obs_noise_labels=self.obs_noise_labels,
            additive=noise_model.additive, multiplicative=noise_model.multiplicative,
            deterministic=self.deterministic,
            force_names=self.force.names if self.force is not None else (),
        )

    @property
    def num_coefficients(self) -> int:
        return self.layout.size_of(self.parameter_group)

    @property
    def num_damping(self) -> int:
        """1 when the model learns a damping rate γ, else 0."""
        return self.layout.size_of("damping")

    @property
    def num_force(self) -> int:
        """How many parameters the model's force has (0 without a force)."""
        return self.layout.size_of("force")

    @property
    def num_dynamics_params(self) -> int:
        """Size of θ_Ψ, the propagator's parameters: the coefficients, then γ when damped, or
        the force's parameters θ_F."""
        return self.num_coefficients + self.num_damping + self.num_force

    @property
    def num_process_noise(self) -> int:
        """How many process variances θ holds (0 without process noise)."""
        return self.layout.size_of("process_var")

    @property
    def num_obs_noise(self) -> int:
        """How many additive observation variances θ holds (0 for multiplicative noise)."""
        return self.layout.size_of("obs_var")

    @property
    def num_rel_noise(self) -> int:
        """How many relative (multiplicative) observation variances θ holds."""
        return self.layout.size_of("obs_rel_var")

    @property
    def num_params(self) -> int:
        return self.layout.size

    @property
    def param_names(self) -> tuple[str, ...]:
        """Coefficient names (``c[q1^2]``: :func:`~symplid.dynamics._potentials.coefficient_name`),
        ``gamma`` when damped, then ``process_var``, ``obs_var`` and ``obs_rel_var`` (indexed
        by component when diagonal, by kind when per-kind)."""
        return self.layout.names

    @property
    def param_groups(self) -> tuple[str, ...]:
        """The prior group of each entry of θ (``coefficients``, ``damping``, ``process_var``,
        ``obs_var``, ``obs_rel_var``); a user model's declared parameters are ``parameters``
        (the potential's ``parameter_group``)."""
        return self.layout.groups

    @property
    def variance_slice(self) -> slice:
        """Where the variances sit in θ (they must be positive)."""
        return slice(self.num_dynamics_params, self.num_params)

    def split(self, theta: Array) -> tuple[Array, Array, Array]:
        """θ → (coefficients, Σ, Γ) with Σ and Γ as full matrices (γ: :meth:`damping_rate`)."""
        theta = jnp.asarray(theta)
        blocks, empty = self.layout.unpack(theta), theta[..., :0]
        coeffs = blocks.get(self.parameter_group, empty)
        q_var = blocks.get("process_var")
        if q_var is None:  # no process noise: Σ = 0
            proc = jnp.zeros((self.state_dim, self.state_dim), theta.dtype)
        else:
            proc = jnp.eye(self.state_dim) * (q_var[0] if q_var.shape[0] == 1 else q_var)
        r_var = blocks.get("obs_var")
        if r_var is None:  # multiplicative noise only: Γ = 0
            return coeffs, proc, jnp.zeros((self.obs_dim, self.obs_dim), theta.dtype)
        if self.noise == "per-kind":
            r_var = r_var[self.obs_noise_index]
        obs = jnp.eye(self.obs_dim) * (r_var[0] if r_var.shape[0] == 1 else r_var)
        return coeffs, proc, obs

    def standardised(self, a: float) -> Any:
        """θ = D θ' for data with positions and momenta over ``a`` (q' = q/a, p' = p/a): a
        :class:`~symplid.model._params.Reparameterisation` whose ``from_unconstrained`` maps a
        standardised θ' to the data's units (:mod:`symplid.model._standardise`; a model with a
        polynomial potential only)."""
        from symplid.model._standardise import standardised_map

        return standardised_map(self.hamiltonian, self.param_groups, a)

    def damping_rate(self, theta: Array) -> Array:
        """γ from θ (0 for an undamped model)."""
        theta = jnp.asarray(theta)
        if "damping" not in self.layout:
            return jnp.zeros(theta.shape[:-1])
        return theta[..., self.layout.slice("damping")][..., 0]

    def relative_variances(self, theta: Array) -> Array:
        """The relative variances r of multiplicative noise, one per observed component
        ``(d_y,)`` (zeros when the noise is additive only)."""
        theta = jnp.asarray(theta)
        if "obs_rel_var" not in self.layout:
            return jnp.zeros(self.obs_dim, theta.dtype)
        return theta[..., self.layout.slice("obs_rel_var")][..., self.obs_noise_index]

    def noise_covariance(self, theta: Array) -> Array | Callable[..., Array]:
        """What the update adds to S at θ: Γ, or ``moments -> R_k`` for multiplicative noise
        (:meth:`~symplid.filters._noise.ObservationNoise.covariance_fn`)."""
        _, _, obs = self.split(theta)
        if not self.noise_model.multiplicative:
            return obs
        return self.noise_model.covariance_fn(obs, self.relative_variances(theta))

    def pack(
        self, coefficients, process_var, obs_var=(), obs_rel_var=(), gamma=None
    ) -> np.ndarray:
        """(coefficients, process variance(s), observation variance(s), relative
        observation variance(s)) → θ; ``gamma`` (γ) is required for a damped model and refused
        otherwise; ``process_var`` is ``()`` for a model without process noise
        (:meth:`~symplid.model._layout.ParameterLayout.pack`)."""
        return self.layout.pack(
            **{self.parameter_group: coefficients}, damping=gamma, process_var=process_var,
            obs_var=obs_var, obs_rel_var=obs_rel_var,
        )

    # ------------------------------------------------------------------ data
    def prepare(self, data: Observations, t0: float = 0.0) -> PreparedData:
        """Turn observations into the arrays the compiled filter consumes (host-side, once)."""
        if not isinstance(data, Observations):
            raise TypeError("data must be a symplid.Observations")
        if data.dim != self.obs_dim:
            raise DataError(
                f"the data have {data.dim} observed components per time, "
                f"the model's observation operator gives {self.obs_dim}"
            )
        gaps = np.diff(np.concatenate([[float(t0)], data.times]))
        if gaps[0] <= 0:
            raise DataError(
                f"the first observation time {data.times[0]:g} is not after t0 = {t0:g}"
            )
        num_steps, step_size = substeps(gaps, self.dt)
        mask = data.mask
        return PreparedData(
            self._gap_inputs(data, float(t0), step_size, num_steps),
            jnp.asarray(np.where(mask, data.values, 0.0)),
            jnp.asarray(mask),
            int(num_steps.max()),
            bool(np.all(num_steps == num_steps.max())),
        )

    def _gap_inputs(self, data: Observations, t0: float, step_size: np.ndarray,
                    num_steps: np.ndarray) -> GapInputs | ForcedGapInputs:
        """Each gap's substeps, and for a forced model the inputs at its nodes
        (:func:`~symplid.model._inputs.node_table`)."""
        if self.force is None:
            return GapInputs(jnp.asarray(step_size), jnp.asarray(num_steps))
        times, inputs = node_table(data.inputs, t0, step_size, num_steps,
                                   self.integrator.nodes, self.force.num_inputs)
        return ForcedGapInputs(jnp.asarray(step_size), jnp.asarray(num_steps),
                               jnp.asarray(times), jnp.asarray(inputs))

    # ------------------------------------------------------------------ the likelihood
    @property
    def likelihood_backend(self) -> str:
        """The backend that computes this model's log-likelihood (``backend="auto"`` resolved).

        Chosen among :data:`~symplid.model._backends.LIKELIHOOD_BACKENDS` for the model
        alone (:func:`symplid.model._backends.select`); a backend that declines a particular
        data set hands it to the next one.
        """
        return select(self).name

    def _check_initial(self, x0, P0) -> tuple[Array, Array]:
        n = self.state_dim
        x0 = jnp.asarray(x0, dtype=float)
        if x0.shape != (n,):
            raise ValueError(f"x0 must have shape ({n},), got {x0.shape}")
        if P0 is None:
            P0 = 1e-16 * jnp.eye(n)
        P0 = jnp.asarray(P0, dtype=float)
        if P0.ndim == 0:
            P0 = P0 * jnp.eye(n)
        elif P0.ndim == 1:
            P0 = jnp.diag(P0)
        if P0.shape != (n, n):
            raise ValueError(f"P0 must have shape ({n}, {n}), got {P0.shape}")
        return x0, P0

    def _check_theta(self, theta: Array) -> Array:
        theta = jnp.asarray(theta, dtype=float)
        if theta.shape[-1] != self.num_params:
            raise ValueError(
                f"θ must have {self.num_params} entries ({', '.join(self.param_names)}), "
                f"got {theta.shape[-1]}"
            )
        return theta

    def filter(
        self,
        theta: Array,
        data: Observations | PreparedData,
        x0: Array,
        P0: Array | None = None,
        t0: float = 0.0,
    ) -> FilterResult:
        """Run the UKF; returns the log-likelihood and the filtered and predicted moments.

        Without process noise (``process_noise_per="none"``) there is no filter: the
        moments are the integrated path with zero covariances (:mod:`._deterministic`).

        ``P0=None`` means a known initial state (P0 = 1e-16·I); a scalar or a vector is
        read as a multiple of the identity or a diagonal.
        """
        prepared = data if isinstance(data, PreparedData) else self.prepare(data, t0)
        x0, P0 = self._check_initial(x0, P0)
        theta = self._check_theta(theta)
        fn = compiled(self, prepared, JAX_BACKEND)  # the moments: the reference
        return fn(theta, prepared.inputs, prepared.ys, prepared.masks, x0, P0)

    def log_likelihood(
        self,
        theta: Array,
        data: Observations | PreparedData,
        x0: Array,
        P0: Array | None = None,
        t0: float = 0.0,
    ) -> Array:
        """log p(y_1..n | θ) by the UKF (Theorem 1); −∞ when the filter fails or θ is invalid.

        ``theta``, ``x0`` and ``P0`` may be traced: the function can be ``jit``-ed,
        ``vmap``-ed over θ and differentiated. ``data`` must be concrete (it fixes the
        number of substeps per gap). Computed by :attr:`likelihood_backend`; the free function
        :func:`symplid.model._likelihood.log_likelihood` is the JAX reference.
        """
        prepared = data if isinstance(data, PreparedData) else self.prepare(data, t0)
        x0, P0 = self._check_initial(x0, P0)
        theta = self._check_theta(theta)
        fn = loglik_program(self, prepared)
        return fn(theta, prepared.inputs, prepared.ys, prepared.masks, x0, P0)

    def log_likelihood_fn(
        self, data: Observations, x0: Array, P0: Array | None = None, t0: float = 0.0
    ) -> Callable[[Array], Array]:
        """A pure function θ ↦ log-likelihood with the data bound (prepared once)."""
        prepared = self.prepare(data, t0)
        x0, P0 = self._check_initial(x0, P0)
        fn = loglik_program(self, prepared)
        return partial(_bound_loglik, fn, prepared, x0, P0)

    def energy(self, theta_or_coefficients: Array, state: Array) -> Array:
        """H(q, p) under the model's potential and mass (or its whole H), for θ or bare
        coefficients."""
        c = jnp.asarray(theta_or_coefficients)[..., : self.num_coefficients]
        inv_mass = inverse_mass(self.mass, self.hamiltonian.dim)
        return hamiltonian_value(self.hamiltonian, c, state, inv_mass)


def _renamed_potential(hamiltonian: Any, potential: Any) -> Any:
    """The ``hamiltonian`` argument, or the deprecated keyword ``potential`` with a warning."""
    if potential is None:
        if hamiltonian is None:
            raise TypeError("HamiltonianModel() missing required argument: 'hamiltonian'")
        return hamiltonian
    if hamiltonian is not None:
        raise TypeError("HamiltonianModel() got both 'hamiltonian' and its old name 'potential'")
    warnings.warn(_POTENTIAL_RENAMED, FutureWarning, stacklevel=3)
    return potential


def _bound_loglik(fn: Callable[..., Array], prepared: PreparedData, x0, P0, theta) -> Array:
    return fn(theta, prepared.inputs, prepared.ys, prepared.masks, x0, P0)
