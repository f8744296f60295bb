"""The noisy Hamiltonian state-space model, eq. (7), and its UKF log marginal likelihood.

The likelihood itself is the free function :func:`symplid.model.likelihood.log_likelihood`;
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
deterministic-trajectory likelihood of :mod:`symplid.model.deterministic` (no filter).
With ``damping=True`` the damping rate γ (:mod:`symplid.dynamics.damping`) comes
right after the coefficients: θ_Ψ = [coefficients ..., γ].

``observation_noise`` picks the noise model of Y_k from
:data:`~symplid.filters.noise.OBSERVATION_NOISE`: ``"additive"`` (eq. 7, the default),
``"multiplicative"`` (Y = h(X)∘(1 + ε), ε ~ N(0, diag r)) or ``"both"``. The relative
variances r (``obs_rel_var``, laid out like Γ's) follow the additive ones, which a purely
multiplicative model does not have::

    θ = [coefficients ..., (γ), process var(s) ..., obs var(s) (additive) ..., obs rel var(s) ...]
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Any, Literal

import jax
import jax.numpy as jnp
import numpy as np

from symplid.compiled import cached
from symplid.dynamics.damping import is_damped, with_damping
from symplid.dynamics.hamiltonians import is_hamiltonian
from symplid.dynamics.integrators import Integrator, get_integrator, separable_only_error
from symplid.dynamics.nonseparable import DEFAULT_BINDING_STEPS, TaoIntegrator, with_binding
from symplid.dynamics.potentials import (
    Potential,
    coefficient_name,
    hamiltonian,
    has_kinetic,
    inverse_mass,
    mass_matrix,
)
from symplid.dynamics.trajectory import substeps
from symplid.filters import FilterResult, unscented_weights
from symplid.filters.backends import LIKELIHOOD_BACKENDS, check_backend_name, select_backend
from symplid.filters.noise import ObservationNoise, get_observation_noise
from symplid.model import kernel  # noqa: F401  (registers the compiled backend)
from symplid.model.data import DataError, Observations
from symplid.model.likelihood import JAX_BACKEND, GapInputs, PreparedData

__all__ = ["NOISE_LAYOUTS", "PROCESS_NOISE_CHOICES", "HamiltonianModel"]

Array = jax.Array
#: Where the process noise enters (``HamiltonianModel.process_noise_per``); ``"none"``: nowhere.
PROCESS_NOISE_CHOICES = ("gap", "step", "none")
#: The layouts of the noise variances (``HamiltonianModel.noise``).
NOISE_LAYOUTS = ("isotropic", "diagonal", "per-kind")
ObservationSpec = str | np.ndarray | Callable[[Array], Array]


@dataclass(frozen=True, eq=False)
class HamiltonianModel:
    """A Hamiltonian state-space model with a UKF marginal likelihood (Theorem 1).

    Parameters
    ----------
    potential
        A :class:`~symplid.dynamics.potentials.Polynomial`, a
        :class:`~.potentials.FunctionPotential`, or anything with the same interface; or a
        whole, possibly non-separable Hamiltonian H(q, p; θ)
        (:class:`~symplid.dynamics.hamiltonians.Hamiltonian`: ``FunctionHamiltonian``,
        ``DoublePendulum``, ...), whose parameters then lead θ in place of U's coefficients.
    integrator
        Name from :data:`~symplid.dynamics.integrators.INTEGRATORS` (``"leapfrog"``,
        ``"rk2-midpoint"``, ``"rk2-heun"``, ``"rk4"``, ``"euler"``, ``"yoshida4"``; for a
        non-separable H ``"tao"``, ``"tao4"``, ``"implicit-midpoint"`` or a Runge–Kutta
        method) or an ``Integrator``.
    dt
        Largest learning step; each gap is split into ⌈gap/dt⌉ equal substeps.
    observation
        ``"full"`` (the whole state), ``"positions"`` (q only), a ``(d_y, 2d)`` matrix, or a
        JAX function ``h(x) -> y`` (handled by the unscented transform).
    process_noise_per
        ``"gap"`` (default): sigma points are formed once per observation gap, pushed through
        all its substeps, and Σ is added once. ``"step"``: Σ is added after every substep.
        ``"none"``: no process noise (Σ = 0, no ``process_var`` in θ); the likelihood is that
        of the observations around one integrated path (:mod:`symplid.model.deterministic`).
    noise
        ``"isotropic"`` (one variance for Σ and one for Γ), ``"diagonal"`` (one per component)
        or ``"per-kind"`` (one for Σ, and one per kind of observed component for Γ: positions,
        momenta; needs ``observation="full"`` or ``"positions"``).
    observation_noise
        ``"additive"`` (Y = h(X) + η, eq. 7), ``"multiplicative"`` (Y = h(X)∘(1 + ε)) or
        ``"both"``: a name in :data:`~symplid.filters.noise.OBSERVATION_NOISE`. The relative
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
        Likelihood backend from :data:`~symplid.filters.backends.LIKELIHOOD_BACKENDS`
        (``"jax"``: the reference) or ``"auto"`` (the best one that supports the model; see
        :attr:`likelihood_backend`). :meth:`filter` always runs the JAX reference.
    damping
        Learn a damping rate γ ≥ 0: ṗ = −∂U/∂q − γM⁻¹p (:mod:`symplid.dynamics.damping`). θ
        gets the entry ``gamma`` after the coefficients; a symplectic composition (leapfrog,
        yoshida4) becomes the conformally symplectic splitting, a Runge–Kutta method the
        damped Runge–Kutta step (:attr:`integrator` is then the damped one, its ``base`` the
        named one). A separable H only.
    binding
        Tao's binding constant ω for ``"tao"``/``"tao4"`` (:mod:`symplid.dynamics.nonseparable`);
        None: ω = 1/dt. An error with any other integrator.
    """

    potential: Potential
    integrator: str | Integrator = "leapfrog"
    dt: float = 0.25
    observation: ObservationSpec = "full"
    process_noise_per: Literal["gap", "step", "none"] = "gap"
    noise: Literal["isotropic", "diagonal", "per-kind"] = "isotropic"
    mass: Any = None
    alpha: float = 1.0
    beta: float = 2.0
    kappa: float = 0.0
    jitter: float = 1e-12
    unroll: int = 1
    backend: str = "auto"
    damping: bool = False
    observation_noise: str = "additive"
    binding: float | None = None

    def __post_init__(self) -> None:
        integrator = get_integrator(self.integrator)
        if is_damped(integrator) and not self.damping:
            raise ValueError(f"the integrator {integrator.name!r} is damped: pass damping=True")
        object.__setattr__(self, "damping", bool(self.damping))
        object.__setattr__(self, "integrator", integrator)
        self._check_hamiltonian()
        if self.damping:
            if has_kinetic(self.potential):
                raise ValueError("damping=True needs T = ½pᵀM⁻¹p (the friction is −γM⁻¹p); "
                                 "the model has its own kinetic energy T(p)")
            if not self.separable:
                raise ValueError("damping=True needs a separable H = ½pᵀM⁻¹p + U(q) (the "
                                 "friction is −γM⁻¹p); a non-separable H cannot be damped")
            object.__setattr__(self, "integrator", with_damping(self.integrator))
        if not np.isfinite(self.dt) or self.dt <= 0:
            raise ValueError(f"dt must be a positive number, got {self.dt}")
        if self.process_noise_per not in PROCESS_NOISE_CHOICES:
            raise ValueError(
                "process_noise_per must be 'gap', 'step' or 'none', got "
                f"{self.process_noise_per!r}"
            )
        if self.noise not in NOISE_LAYOUTS:
            raise ValueError(
                f"noise must be 'isotropic', 'diagonal' or 'per-kind', got {self.noise!r}"
            )
        object.__setattr__(
            self, "observation_noise", get_observation_noise(self.observation_noise).name
        )
        if self.jitter < 0:
            raise ValueError("jitter must be ≥ 0")
        unscented_weights(self.state_dim, self.alpha, self.beta, self.kappa)  # validates
        object.__setattr__(self, "mass", mass_matrix(self.mass, self.potential.dim))
        obs = self.observation
        if isinstance(obs, str):
            if obs not in ("full", "positions"):
                raise ValueError(
                    f"observation must be 'full', 'positions', a matrix or a function, got {obs!r}"
                )
        elif not callable(obs):
            matrix = np.atleast_2d(np.asarray(obs, dtype=float))
            if matrix.shape[1] != self.state_dim:
                raise ValueError(
                    f"observation matrix must have {self.state_dim} columns, got {matrix.shape}"
                )
            object.__setattr__(self, "observation", matrix)
        if self.noise == "per-kind" and not isinstance(self.observation, str):
            raise ValueError(
                "noise='per-kind' needs observation='full' or 'positions' (the kinds of the "
                "observed components); use 'diagonal' for a matrix or a function"
            )
        object.__setattr__(self, "backend", check_backend_name(self.backend))
        if self.backend != "auto":
            select_backend(self.backend, self)  # a forced backend must support the model

    def _check_hamiltonian(self) -> None:
        """A non-separable H needs a method that accepts it, and no constant mass; ω for Tao."""
        integrator = self.integrator
        if isinstance(integrator, TaoIntegrator):
            binding = DEFAULT_BINDING_STEPS / self.dt if self.binding is None else self.binding
            object.__setattr__(self, "integrator", with_binding(integrator, binding))
        elif self.binding is not None:
            with_binding(integrator, self.binding)  # raises: ω is Tao's
        if not self.separable:
            if not integrator.nonseparable:
                raise separable_only_error(f"the integrator {integrator.name!r}")
            if self.mass is not None:
                raise ValueError("mass applies to a separable H only; write the mass into the "
                                 "Hamiltonian (e.g. symplid.PositionDependentMass)")

    @property
    def separable(self) -> bool:
        """Whether H = ½pᵀM⁻¹p + U(q) (a potential), not a whole H(q, p; θ)."""
        return not is_hamiltonian(self.potential)

    # ------------------------------------------------------------------ layout of θ
    @property
    def state_dim(self) -> int:
        return 2 * self.potential.dim

    @property
    def observation_matrix(self) -> np.ndarray | None:
        """H for a linear observation operator, None for a function."""
        obs = self.observation
        d = self.potential.dim
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
    def num_coefficients(self) -> int:
        return self.potential.num_params

    @property
    def num_damping(self) -> int:
        """1 when the model learns a damping rate γ, else 0."""
        return int(self.damping)

    @property
    def num_dynamics_params(self) -> int:
        """Size of θ_Ψ, the propagator's parameters: the coefficients, then γ when damped."""
        return self.num_coefficients + self.num_damping

    @property
    def deterministic(self) -> bool:
        """Whether the model has no process noise (``process_noise_per="none"``): its
        likelihood follows one integrated path (:mod:`symplid.model.deterministic`)."""
        return self.process_noise_per == "none"

    @property
    def num_process_noise(self) -> int:
        """How many process variances θ holds (0 without process noise)."""
        if self.deterministic:
            return 0
        return self.state_dim if self.noise == "diagonal" else 1

    @property
    def noise_model(self) -> ObservationNoise:
        """The observation-noise model (:data:`~symplid.filters.noise.OBSERVATION_NOISE`)."""
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
        return np.arange(d_y) // self.potential.dim  # q1..qd → 0, p1..pd → 1

    @property
    def num_obs_noise(self) -> int:
        """How many additive observation variances θ holds (0 for multiplicative noise)."""
        return len(self.obs_noise_labels) if self.noise_model.additive else 0

    @property
    def num_rel_noise(self) -> int:
        """How many relative (multiplicative) observation variances θ holds."""
        return len(self.obs_noise_labels) if self.noise_model.multiplicative else 0

    @property
    def num_params(self) -> int:
        return (
            self.num_dynamics_params + self.num_process_noise + self.num_obs_noise
            + self.num_rel_noise
        )

    @property
    def param_names(self) -> tuple[str, ...]:
        """Coefficient names (``c[q1^2]``: :func:`~symplid.dynamics.potentials.coefficient_name`),
        ``gamma`` when damped, then ``process_var``, ``obs_var`` and ``obs_rel_var`` (indexed
        by component when diagonal, by kind when per-kind)."""
        names = [coefficient_name(n) for n in self.potential.param_names]
        names += ["gamma"] * self.num_damping
        if self.noise == "diagonal":
            names += [f"process_var[{i}]" for i in range(self.num_process_noise)]
        else:
            names += ["process_var"] * self.num_process_noise
        labels = [f"[{label}]" if label else "" for label in self.obs_noise_labels]
        names += [f"obs_var{label}" for label in labels][: self.num_obs_noise]
        names += [f"obs_rel_var{label}" for label in labels][: self.num_rel_noise]
        return tuple(names)

    @property
    def param_groups(self) -> tuple[str, ...]:
        """The prior group of each entry of θ (``coefficients``, ``damping``, ``process_var``,
        ``obs_var``, ``obs_rel_var``); a user model's declared parameters are ``parameters``
        (the potential's ``parameter_group``)."""
        return tuple(
            [getattr(self.potential, "parameter_group", "coefficients")] * self.num_coefficients
            + ["damping"] * self.num_damping
            + ["process_var"] * self.num_process_noise
            + ["obs_var"] * self.num_obs_noise
            + ["obs_rel_var"] * self.num_rel_noise
        )

    @property
    def variance_slice(self) -> slice:
        """Where the variances sit in θ (they must be positive)."""
        return slice(self.num_dynamics_params, self.num_params)

    def split(self, theta: Array) -> tuple[Array, Array, Array]:
        """θ → (coefficients, Σ, Γ) with Σ and Γ as full matrices (γ: :meth:`damping_rate`)."""
        theta = jnp.asarray(theta)
        nc, nd, nq = self.num_coefficients, self.num_dynamics_params, self.num_process_noise
        coeffs = theta[:nc]
        q_var = theta[nd : nd + nq]
        if nq == 0:  # no process noise: Σ = 0
            proc = jnp.zeros((self.state_dim, self.state_dim), theta.dtype)
        else:
            proc = jnp.eye(self.state_dim) * (q_var[0] if nq == 1 else q_var)
        if self.num_obs_noise == 0:  # multiplicative noise only: Γ = 0
            return coeffs, proc, jnp.zeros((self.obs_dim, self.obs_dim), theta.dtype)
        r_var = theta[nd + nq : nd + nq + self.num_obs_noise]
        if self.noise == "per-kind":
            r_var = r_var[self.obs_noise_index]
        obs = jnp.eye(self.obs_dim) * (r_var[0] if r_var.shape[0] == 1 else r_var)
        return coeffs, proc, obs

    def damping_rate(self, theta: Array) -> Array:
        """γ from θ (0 for an undamped model)."""
        theta = jnp.asarray(theta)
        return theta[..., self.num_coefficients] if self.damping else jnp.zeros(theta.shape[:-1])

    def relative_variances(self, theta: Array) -> Array:
        """The relative variances r of multiplicative noise, one per observed component
        ``(d_y,)`` (zeros when the noise is additive only)."""
        theta = jnp.asarray(theta)
        if self.num_rel_noise == 0:
            return jnp.zeros(self.obs_dim, theta.dtype)
        start = self.num_params - self.num_rel_noise
        return theta[..., start:][..., self.obs_noise_index]

    def noise_covariance(self, theta: Array) -> Array | Callable[..., Array]:
        """What the update adds to S at θ: Γ, or ``moments -> R_k`` for multiplicative noise
        (:meth:`~symplid.filters.noise.ObservationNoise.covariance_fn`)."""
        _, _, obs = self.split(theta)
        if not self.noise_model.multiplicative:
            return obs
        return self.noise_model.covariance_fn(obs, self.relative_variances(theta))

    def pack(
        self, coefficients, process_var, obs_var=(), obs_rel_var=(), gamma=None
    ) -> np.ndarray:
        """(coefficients, process variance(s), observation variance(s), relative
        observation variance(s)) → θ; ``gamma`` (γ) is required for a damped model and refused
        otherwise; ``process_var`` is ``()`` for a model without process noise."""
        if (gamma is None) == self.damping:
            need = "needs" if self.damping else "has no"
            raise ValueError(f"this model {need} a damping rate: pass gamma accordingly")
        damping = [] if gamma is None else [np.ravel(gamma)]
        out = np.concatenate(
            [np.ravel(coefficients), *damping, np.ravel(process_var), np.ravel(obs_var),
             np.ravel(obs_rel_var)]
        ).astype(float)
        if out.shape[0] != self.num_params:
            raise ValueError(
                f"θ has {self.num_params} entries ({self.param_names}), got {out.shape[0]}"
            )
        return out

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
            GapInputs(jnp.asarray(step_size), jnp.asarray(num_steps)),
            jnp.asarray(np.where(mask, data.values, 0.0)),
            jnp.asarray(mask),
            int(num_steps.max()),
            bool(np.all(num_steps == num_steps.max())),
        )

    # ------------------------------------------------------------------ the likelihood
    @property
    def likelihood_backend(self) -> str:
        """The backend that computes this model's log-likelihood (``backend="auto"`` resolved).

        Chosen among :data:`~symplid.filters.backends.LIKELIHOOD_BACKENDS` for the model
        alone; a backend that declines a particular data set hands it to the next one.
        """
        return select_backend(self.backend, self).name

    def _compiled(self, prepared: PreparedData, backend: str = "jax") -> Callable[..., Any]:
        """The jitted ``fn(theta, inputs, ys, masks, x0, P0)`` of ``backend``, cached on self."""
        key = ("likelihood", backend, prepared.max_steps, prepared.uniform_steps)
        entry = LIKELIHOOD_BACKENDS.get_entry(backend)
        return cached(self, key, lambda: jax.jit(entry.build(self, prepared)))

    def _loglik_program(self, prepared: PreparedData) -> Callable[..., Array]:
        """The selected backend's compiled ``fn(theta, inputs, ys, masks, x0, P0) -> ll``."""
        backend = select_backend(self.backend, self, prepared)
        fn = self._compiled(prepared, backend.name)
        return partial(_only_loglik, fn) if backend.filtered_moments else fn

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
        moments are the integrated path with zero covariances (:mod:`.deterministic`).

        ``P0=None`` means a known initial state (P0 = 1e-16·I); a scalar or a vector is
        read as a multiple of the identity or a diagonal.
        """
        prepared = data if isinstance(data, PreparedData) else self.prepare(data, t0)
        x0, P0 = self._check_initial(x0, P0)
        theta = self._check_theta(theta)
        fn = self._compiled(prepared, JAX_BACKEND.name)  # the moments: always the reference
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
        :func:`symplid.model.likelihood.log_likelihood` is the JAX reference.
        """
        prepared = data if isinstance(data, PreparedData) else self.prepare(data, t0)
        x0, P0 = self._check_initial(x0, P0)
        theta = self._check_theta(theta)
        fn = self._loglik_program(prepared)
        return fn(theta, prepared.inputs, prepared.ys, prepared.masks, x0, P0)

    def log_likelihood_fn(
        self, data: Observations, x0: Array, P0: Array | None = None, t0: float = 0.0
    ) -> Callable[[Array], Array]:
        """A pure function θ ↦ log-likelihood with the data bound (prepared once)."""
        prepared = self.prepare(data, t0)
        x0, P0 = self._check_initial(x0, P0)
        fn = self._loglik_program(prepared)
        return partial(_bound_loglik, fn, prepared, x0, P0)

    def hamiltonian(self, theta_or_coefficients: Array, state: Array) -> Array:
        """H(q, p) under the model's potential and mass (or its whole H), for θ or bare
        coefficients."""
        c = jnp.asarray(theta_or_coefficients)[..., : self.num_coefficients]
        return hamiltonian(self.potential, c, state, inverse_mass(self.mass, self.potential.dim))


def _only_loglik(fn: Callable[..., FilterResult], *args: Array) -> Array:
    return fn(*args).log_likelihood


def _bound_loglik(fn: Callable[..., Array], prepared: PreparedData, x0, P0, theta) -> Array:
    return fn(theta, prepared.inputs, prepared.ys, prepared.masks, x0, P0)
