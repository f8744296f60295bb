"""The compiled likelihood kernel: the UKF of Theorem 1 (eqs 10–12) in C++, through XLA's FFI.

For the common case — a :class:`~._potentials.Polynomial` potential of any dimension and
order, one of the library's integrators (the symplectic compositions of the leapfrog of
eqs 5–6, or an explicit Runge–Kutta method) as the propagator Ψ of eq. (14), a linear
observation operator in the state-space model of eq. (7), missing values, additive isotropic,
diagonal or per-kind noise, Σ once per gap or once per substep, a constant mass matrix — the
log marginal likelihood is computed by a C++ kernel (``csrc/ukf_kernel.cc``) that propagates
the sigma points as vector lanes. It equals the JAX reference
(:func:`~._likelihood.filter_result`) to rounding and is

* ``jit``-able: it is an XLA custom call, ~0.2 µs of overhead inside a compiled loop;
* ``vmap``-able over θ (and over x0, P0 or the data): a batch reaches the kernel as one call,
  which propagates eight parameter vectors at once when they share the data;
* differentiable: a ``jax.custom_jvp``. The gradient over θ (``jax.grad``,
  ``value_and_grad``, a JVP along θ) is compiled too, as an adjoint: a second FFI target
  (``csrc/ukf_adjoint.cc``) runs the filter forward recording each gap's substeps, moments and
  update, then one reverse sweep through them, and returns the value with the gradient, equal
  to the JAX tier's gradient to rounding, for the symplectic compositions with Σ once per gap
  (any number of parameters). Second derivatives (the Laplace/MAP Hessian), derivatives in
  x0, P0 or the data, Runge–Kutta propagators and Σ per substep use the JAX reference's
  derivatives exactly.

The kernel is built by ``pip install`` from the project's own files (an optional extension:
a failed build does not fail the install). When the shared library is missing or cannot be
loaded, :func:`available` is False, :func:`log_likelihood` computes the JAX reference, and one
warning per process says so.
"""

from __future__ import annotations

import ctypes
import importlib.util
import os
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero

from symplid.dynamics._potentials import Polynomial, inverse_mass
from symplid.dynamics._schemes import Composition
from symplid.dynamics._user_models import UserPotential
from symplid.filters import unscented_weights
from symplid.filters._backends import LikelihoodBackend
from symplid.model import _user_kernel as user_kernel
from symplid.model._likelihood import (
    JAX_BACKEND,
    GapInputs,
    PreparedData,
    StateSpaceModel,
    build_filter,
)
from symplid.model._programs import compiled

Array = jax.Array

TARGET_NAME = "symplid_ukf_loglik"
GRADIENT_TARGET_NAME = "symplid_ukf_loglik_grad"
_LIBRARY_STEM = "_ukf_kernel"


class KernelUnavailableWarning(UserWarning):
    """The compiled kernel is not built or cannot be loaded: the JAX tier is used."""


class _Library:
    """The loaded shared library (or why it is not there), found and registered once."""

    handle: ctypes.CDLL | None = None
    error: str | None = None
    loaded: bool = False
    warned: bool = False


def _library_path() -> Path | None:
    """The built extension in the ``symplid`` package folder (any platform suffix)."""
    spec = importlib.util.find_spec("symplid")
    for folder in (spec.submodule_search_locations or []) if spec else []:
        found = sorted(Path(folder).glob(f"{_LIBRARY_STEM}*.so")) + sorted(
            Path(folder).glob(f"{_LIBRARY_STEM}*.pyd")
        )
        if found:
            return found[0]
    return None


def _load_library() -> ctypes.CDLL:
    """Open the shared library and register its FFI handler with XLA (raises on failure)."""
    path = _library_path()
    if path is None:
        raise OSError("the compiled extension symplid._ukf_kernel was not built")
    handle = ctypes.CDLL(str(path))
    jax.ffi.register_ffi_target(
        TARGET_NAME, jax.ffi.pycapsule(handle.SymplidUkfLogLikelihood), platform="cpu"
    )
    jax.ffi.register_ffi_target(
        GRADIENT_TARGET_NAME,
        jax.ffi.pycapsule(handle.SymplidUkfLogLikelihoodGradient),
        platform="cpu",
    )
    handle.symplid_kernel_isa.restype = ctypes.c_char_p
    return handle


def _ensure_loaded() -> None:
    if _Library.loaded:
        return
    _Library.loaded = True
    try:
        _Library.handle = _load_library()
    except (OSError, AttributeError, RuntimeError, ValueError) as err:
        _Library.handle = None
        _Library.error = str(err)


def available() -> bool:
    """Whether the compiled kernel is built, loaded and registered with XLA."""
    _ensure_loaded()
    return _Library.handle is not None


def instruction_set() -> str | None:
    """The instruction set the kernel runs with (``'avx512'``, ``'avx2'``, ``'baseline'``)."""
    if not available():
        return None
    return _Library.handle.symplid_kernel_isa().decode()


def _warn_fallback() -> None:
    if not _Library.warned:
        _Library.warned = True
        warnings.warn(
            f"symplid's compiled likelihood kernel is unavailable ({_Library.error}); "
            "the JAX implementation is used instead",
            KernelUnavailableWarning,
            stacklevel=3,
        )


def unsupported_reason(model: StateSpaceModel, prepared: PreparedData | None = None) -> str | None:
    """Why the compiled kernel cannot evaluate this model (None when it can).

    The kernel covers a :class:`~symplid.dynamics._potentials.Polynomial` potential (and, with
    ``SYMPLID_USER_KERNEL=1``, a user's expression for U, through its compiled unit:
    :mod:`symplid.model._user_kernel`), the registry's integrators, a linear observation
    operator and float64 on the CPU. It does not say
    whether the extension is loaded: see :func:`available`.
    """
    if getattr(model, "process_noise_per", "gap") == "none":
        return "no process noise: the deterministic-trajectory likelihood needs no filter"
    if getattr(model, "damping", False):
        return "the model is damped (γ); the kernel propagates undamped dynamics only"
    if getattr(model, "force", None) is not None:
        return "the model is driven (a force F(q, p, u, t)); the kernel propagates free motion"
    if not isinstance(model.hamiltonian, Polynomial) and not _user_expression(model):
        return f"the potential is a {type(model.hamiltonian).__name__}, not a Polynomial"
    if model.integrator.scheme is None:
        return (f"the integrator {model.integrator.name!r} is a step function without a "
                "composition or Butcher tableau")
    if model.observation_matrix is None:
        return "the observation operator is a function, not a matrix"
    noise = getattr(model, "observation_noise", "additive")
    if noise != "additive":
        return f"the observation noise is {noise!r} (the kernel's update adds a constant Γ)"
    if not jax.config.read("jax_enable_x64"):
        return "float64 is switched off"
    if jax.default_backend() != "cpu":
        return f"the kernel runs on the CPU, the default backend is {jax.default_backend()!r}"
    if prepared is not None and prepared.max_steps < 1:
        return "no substeps"
    return None


def _user_expression(model: StateSpaceModel) -> bool:
    """Whether the model's U is a user's expression that the compiled user tier may take
    (:mod:`symplid.model._user_kernel`; ``SYMPLID_USER_KERNEL=1`` switches that tier on)."""
    return (
        os.environ.get("SYMPLID_USER_KERNEL", "0").strip().lower() in ("1", "on", "yes", "true")
        and isinstance(model.hamiltonian, UserPotential)
        and model.hamiltonian.expression is not None
    )


def _user_unit(model: StateSpaceModel) -> user_kernel.UserUnit | str | None:
    """The compiled unit of a user expression's model (or why there is none); None for a
    model of the built-in kernel."""
    if not isinstance(model.hamiltonian, UserPotential):
        return None
    return user_kernel.find_unit(model.hamiltonian, instruction_set())


def describe(model: StateSpaceModel, prepared: PreparedData | None = None) -> dict[str, Any]:
    """Which likelihood tier a run uses and why, for the run's recorded settings."""
    reason = unsupported_reason(model, prepared)
    if reason is None and not available():
        reason = f"the compiled kernel is unavailable ({_Library.error})"
    unit = _user_unit(model) if reason is None else None
    if isinstance(unit, str):
        reason = unit
    if reason is None:
        tier = {"likelihood_backend": "compiled", "instruction_set": instruction_set()}
        return tier | ({"user_unit": unit.key} if unit is not None else {})
    return {"likelihood_backend": "jax", "reason": reason}


def _attributes(model: StateSpaceModel, prepared: PreparedData) -> dict[str, Any]:
    """The model's static settings as FFI attributes (numbers and 1-D arrays)."""
    potential = model.hamiltonian
    d = potential.dim
    if isinstance(potential, Polynomial):
        order, exponents = potential.order, np.asarray(potential.exponents, dtype=np.int64)
    else:  # a user unit: its force reads θ's parameters itself (one zero row per parameter)
        order, exponents = 1, np.zeros((potential.num_params, d), dtype=np.int64)
    scheme = model.integrator.scheme
    weights = unscented_weights(model.state_dim, model.alpha, model.beta, model.kappa)
    inv_mass = inverse_mass(model.mass, d)
    placeholder = np.zeros(1)
    composition = isinstance(scheme, Composition)
    if composition:
        comp_weights, rk_a, rk_b = np.asarray(scheme.weights, float), placeholder, placeholder
    else:
        comp_weights = placeholder
        rk_a, rk_b = np.asarray(scheme.a, float).ravel(), np.asarray(scheme.b, float)
    return {
        "dim": np.int64(d),
        "order": np.int64(order),
        "exponents": exponents.ravel(),
        "composition": np.int64(composition),
        "comp_weights": comp_weights,
        "rk_a": rk_a,
        "rk_b": rk_b,
        "has_mass": np.int64(inv_mass is not None),
        "inv_mass": placeholder if inv_mass is None else np.asarray(inv_mass, float).ravel(),
        "obs_matrix": np.asarray(model.observation_matrix, dtype=float).ravel(),
        "weights_mean": np.asarray(weights.mean, dtype=float),
        "weights_cov": np.asarray(weights.cov, dtype=float),
        "scale": float(weights.scale),
        "jitter": float(model.jitter),
        "per_step": np.int64(model.process_noise_per == "step"),
        "diagonal": np.int64(model.noise != "isotropic"),  # per-kind: expanded, _kernel_theta
        "max_steps": np.int64(prepared.max_steps),
        "uniform": np.int64(prepared.uniform_steps),
    }


KernelFn = Callable[[Array, Array, Array, Array, Array, Array, Array], Array]
# Positions of θ, x0, P0, step sizes and ys among the kernel's arguments (the float ones).
_DIFFERENTIABLE = (0, 1, 2, 3, 5)


def _kernel_theta(model: StateSpaceModel) -> Callable[[Array], Array]:
    """θ in the kernel's layout: per-kind variances become the diagonal layout (Σ's one
    variance repeated over the state, each Γ variance over the components of its kind)."""
    if model.noise != "per-kind":
        return lambda theta: theta
    nc = model.num_coefficients
    index = np.concatenate(
        [np.arange(nc), np.full(model.state_dim, nc), nc + 1 + model.obs_noise_index]
    )
    return lambda theta: theta[..., index]


def _kernel_num_params(model: StateSpaceModel) -> int:
    """Entries of θ in the kernel's layout (coefficients, then Σ's and Γ's variances)."""
    if model.noise == "isotropic":
        return model.num_coefficients + 2
    return model.num_coefficients + model.state_dim + model.obs_dim


def _gradient_unsupported_reason(model: StateSpaceModel) -> str | None:
    """Why the compiled gradient (the kernel's adjoint) does not carry this model, or None:
    it covers the symplectic compositions with Σ added once per gap (the kernel's
    ``adjoint_supports``); Runge–Kutta propagators and Σ per substep keep the JAX tier's."""
    if not isinstance(model.integrator.scheme, Composition):
        return f"the integrator {model.integrator.name!r} is not a composition of leapfrog steps"
    if model.process_noise_per == "step":
        return "Σ is added after every substep"
    return None


def _reference_jvp(reference, derivative, primals, tangents):
    """The JVP of ``derivative(ref)`` (the log-likelihood, or its value and gradient) of the
    JAX reference filter, in the arguments whose tangent is not a symbolic zero."""
    live = [i for i in _DIFFERENTIABLE if not isinstance(tangents[i], SymbolicZero)]

    def ref(*args):
        full = list(primals)
        for i, arg in zip(live, args, strict=True):
            full[i] = arg
        theta, x0, p0, step_size, num_steps, ys, masks = full

        def loglik(th):
            return reference(th, GapInputs(step_size, num_steps), ys, masks, x0, p0).log_likelihood

        return derivative(loglik)(theta)

    return jax.jvp(ref, [primals[i] for i in live], [tangents[i] for i in live])


def _targets(model: StateSpaceModel) -> tuple[str, str]:
    """The FFI targets of the value and the gradient: the built-in kernel's, or the model's
    user unit's."""
    unit = _user_unit(model)
    if isinstance(unit, str):
        raise ValueError(f"the compiled kernel does not apply: {unit}")
    return (TARGET_NAME, GRADIENT_TARGET_NAME) if unit is None else (
        unit.value_target, unit.gradient_target)


def _build_value_and_gradient(model: StateSpaceModel, attrs: dict[str, Any], reference):
    """``(θ, x0, P0, step_size, num_steps, ys, masks) -> (log L, ∂ log L/∂θ)`` by the compiled
    gradient, differentiable once more through the JAX reference (Hessian-vector products
    are the reference's exactly); None for models the compiled gradient does not carry
    (:func:`_gradient_unsupported_reason`)."""
    if _gradient_unsupported_reason(model) is not None:
        return None
    call = jax.ffi.ffi_call(
        _targets(model)[1],
        (
            jax.ShapeDtypeStruct((), jnp.float64),
            jax.ShapeDtypeStruct((_kernel_num_params(model),), jnp.float64),
        ),
        vmap_method="expand_dims",
    )
    layout = _kernel_theta(model)

    @jax.custom_jvp
    def value_and_gradient(theta, x0, p0, step_size, num_steps, ys, masks):
        value, grad = call(layout(theta), x0, p0, step_size, num_steps, ys, masks, **attrs)
        _, pullback = jax.vjp(layout, theta)  # per-kind noise: sum the repeated entries
        return value, pullback(grad)[0]

    def value_and_gradient_jvp(primals, tangents):
        if all(isinstance(t, SymbolicZero) for t in tangents):
            out = value_and_gradient(*primals)
            return out, tuple(jnp.zeros_like(o) for o in out)
        return _reference_jvp(reference, jax.value_and_grad, primals, tangents)

    value_and_gradient.defjvp(value_and_gradient_jvp, symbolic_zeros=True)
    return value_and_gradient


def _build_kernel(model: StateSpaceModel, prepared: PreparedData) -> KernelFn:
    """``(θ, x0, P0, step_size, num_steps, ys, masks) -> log L``: the FFI call, whose JVP along
    θ alone is the compiled gradient's, and along anything else the JAX reference's."""
    attrs = _attributes(model, prepared)
    call = jax.ffi.ffi_call(
        _targets(model)[0], jax.ShapeDtypeStruct((), jnp.float64), vmap_method="expand_dims"
    )
    reference = build_filter(model, prepared.max_steps, prepared.uniform_steps)
    layout = _kernel_theta(model)
    value_and_gradient = _build_value_and_gradient(model, attrs, reference)

    @jax.custom_jvp
    def kernel(theta, x0, p0, step_size, num_steps, ys, masks):
        return call(layout(theta), x0, p0, step_size, num_steps, ys, masks, **attrs)

    def kernel_jvp(primals, tangents):
        live = [i for i in _DIFFERENTIABLE if not isinstance(tangents[i], SymbolicZero)]
        if not live:
            value = kernel(*primals)
            return value, jnp.zeros_like(value)
        if live == [0] and value_and_gradient is not None:
            # The compiled gradient, with the value computed on the way (value_and_grad
            # costs one call).
            value, grad = value_and_gradient(*primals)
            return value, jnp.sum(grad * tangents[0], axis=-1)
        # Otherwise the reference's JVP, which computes its value on the way (equal to the
        # kernel's to rounding).
        return _reference_jvp(reference, lambda f: f, primals, tangents)

    kernel.defjvp(kernel_jvp, symbolic_zeros=True)
    return kernel


def _build_backend(model: StateSpaceModel, prepared: PreparedData) -> Callable[..., Array]:
    """The backend's ``fn(θ, inputs, ys, masks, x0, P0) -> log L`` (jitted and cached by
    :func:`symplid.model._programs.compiled` like every backend's program)."""
    kernel = _build_kernel(model, prepared)

    def fn(theta, inputs, ys, masks, x0, p0):
        return kernel(
            jnp.asarray(theta, jnp.float64),
            x0,
            p0,
            jnp.asarray(inputs.step_size, jnp.float64),
            jnp.asarray(inputs.num_steps, jnp.int64),
            jnp.asarray(ys, jnp.float64),
            jnp.asarray(masks, jnp.bool_),
        )

    return fn


def _supports(model: StateSpaceModel, prepared: PreparedData | None) -> str | None:
    reason = unsupported_reason(model, prepared)
    if reason is None and not available():
        _warn_fallback()
        reason = f"the compiled kernel is unavailable ({_Library.error})"
    unit = _user_unit(model) if reason is None else None
    return unit if isinstance(unit, str) else reason


def log_likelihood(
    model: StateSpaceModel,
    prepared: PreparedData,
    theta: Array,
    x0: Array,
    P0: Array | None = None,
) -> Array:
    """log p(y_1..n | θ) of Theorem 1 by the compiled kernel where it applies.

    Same value (to rounding), same conventions and same derivatives as
    :meth:`StateSpaceModel.log_likelihood` (−∞ for non-positive variances or a failed
    filter). ``theta``, ``x0`` and ``P0`` may be traced; the function can be ``jit``-ed,
    ``vmap``-ed (a batch is one kernel call) and differentiated. Where the kernel does not
    apply (:func:`unsupported_reason`) or is not built (:func:`available`, with one warning
    per process), the JAX reference is computed instead.
    """
    x0, P0 = model._check_initial(x0, P0)
    theta = jnp.asarray(theta, dtype=jnp.float64)
    if theta.shape[-1] != model.num_params:
        raise ValueError(f"θ must have {model.num_params} entries, got {theta.shape[-1]}")
    backend = COMPILED_BACKEND if _supports(model, prepared) is None else JAX_BACKEND
    fn = compiled(model, prepared, backend)
    value = fn(theta, prepared.inputs, prepared.ys, prepared.masks, x0, P0)
    return value if backend is COMPILED_BACKEND else value.log_likelihood


def log_likelihood_fn(
    model: StateSpaceModel, data, x0: Array, P0: Array | None = None, t0: float = 0.0
) -> Callable[[Array], Array]:
    """A pure function θ ↦ log-likelihood with the data bound, on the fastest tier that applies."""
    prepared = data if isinstance(data, PreparedData) else model.prepare(data, t0)

    def fn(theta: Array) -> Array:
        return log_likelihood(model, prepared, theta, x0, P0)

    return fn


__all__ = [
    "COMPILED_BACKEND",
    "GRADIENT_TARGET_NAME",
    "TARGET_NAME",
    "KernelUnavailableWarning",
    "available",
    "describe",
    "instruction_set",
    "log_likelihood",
    "log_likelihood_fn",
    "unsupported_reason",
]

#: The compiled kernel as a likelihood backend (registered as ``"compiled"`` by
#: :mod:`symplid.model._backends`): preferred by ``backend="auto"`` wherever it applies (see
#: :func:`unsupported_reason`) and is built.
COMPILED_BACKEND = LikelihoodBackend(
    name="compiled",
    supports=_supports,
    build=_build_backend,
    filtered_moments=False,
    priority=10,
    # One θ per lane of an eight-wide vector: eight θ cost about 3.5 times one
    # (benchmarks/speed_tiers.py); fewer than eight are evaluated one at a time.
    batch_width=8,
    custom_call=True,
    description="the C++ UKF kernel through XLA's FFI (polynomial U, linear observation)",
)
