"""The compiled likelihood kernel against the JAX reference, same run, on the paper's workload.

Workload (seed paper, Section IV): Hénon–Heiles, cubic potential (9 coefficients), leapfrog at
dt = 0.25, 20 full-state observations 5 s apart (20 gaps × 20 substeps × 9 sigma points),
isotropic noise added once per gap.

Every row is the time per evaluation inside one compiled ``lax.fori_loop`` (what a sampler
sees), the minimum over repeats:

* ``log L``: one θ per iteration;
* ``log L, vmap 64``: a batch of 64 θ per iteration, time per θ;
* ``value and gradient``: ``jax.value_and_grad`` of log L (the compiled tier's is the
  kernel's adjoint gradient, one custom call; the JAX tier's is reverse-mode autodiff of
  its filter). The line below the table gives the compiled gradient's cost in compiled values.

With ``--previous`` the first two rows also time the other build in the same loop. With
``--map`` a table times the paper's MAP with the compiled gradient against the JAX tier's
gradient (the compiled value either way), in the same process.

Times are the process's CPU time (``time.process_time``), the minimum over repeats: on a
shared machine wall time would count other people's work. XLA runs on one thread.

A second table times the propagators on the same workload (leapfrog, the paper's RK2
reference ``rk2-midpoint``, ``rk4``), µs per call for one θ and for a vmap batch of eight θ
(one call), JAX reference against the kernel. ``--previous PATH`` adds a column for another
build of the kernel (e.g. the one before a change), loaded beside this one under its own FFI
target so that both run in the same process and loop, and reports the largest difference
between the two builds' values; a third table then times both builds on other shapes, some
outside the AVX-512 register path (a mass matrix, forward Euler, Runge–Kutta for d = 3 at
degree 4).

Run on one idle core: ``taskset -c 0 python benchmarks/compiled_kernel.py [--previous SO]``.
"""

from __future__ import annotations

import argparse
import ctypes
import dataclasses
import os

os.environ.setdefault(
    "XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
)

import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

import symplid
from symplid.model import _kernel as compiled_kernel


def loop_runner(step: Callable[[jax.Array], jax.Array], thetas: jax.Array
                ) -> Callable[[], float]:
    """A timer of ``step`` in a compiled ``fori_loop`` over ``thetas``: each call returns the
    CPU seconds per iteration of one run (compiled and run once here)."""
    count = thetas.shape[0]

    @jax.jit
    def run(thetas):
        def body(i, total):
            return total + jnp.sum(step(thetas[i]))

        return jax.lax.fori_loop(0, count, body, 0.0)

    jax.block_until_ready(run(thetas))

    def once() -> float:
        start = time.process_time()
        jax.block_until_ready(run(thetas))
        return (time.process_time() - start) / count

    return once


def loop_time(step: Callable[[jax.Array], jax.Array], thetas: jax.Array, repeats: int) -> float:
    """CPU seconds per iteration of ``step`` in a compiled ``fori_loop`` (minimum of repeats)."""
    once = loop_runner(step, thetas)
    return min(once() for _ in range(repeats))


def main(repeats: int = 7, make_previous: Callable | None = None) -> None:
    if not compiled_kernel.available():
        raise SystemExit("the compiled kernel is not built: pip install the package first")
    system = symplid.get_system("henon-heiles")
    data = symplid.simulate(system, seed=0)
    x0 = system.initial_state
    model = symplid.HamiltonianModel(system.potential, integrator="leapfrog", dt=0.25)
    theta = jnp.asarray(model.pack(system.coefficients, 1e-6, 0.05**2))
    prepared = model.prepare(data)
    # the JAX tier explicitly: backend="auto" would pick the compiled kernel itself
    reference = dataclasses.replace(model, backend="jax").log_likelihood_fn(data, x0)

    def compiled(th):
        return compiled_kernel.log_likelihood(model, prepared, th, x0)

    key = jax.random.key(0)
    singles = theta * (1.0 + 1e-3 * jax.random.normal(key, (400, theta.shape[0])))
    batches = theta * (1.0 + 1e-3 * jax.random.normal(key, (20, 64, theta.shape[0])))
    grads = singles[:100]

    rows = [
        ("log L", lambda f: loop_time(f, singles, repeats), 1),
        ("log L, vmap 64 (per θ)", lambda f: loop_time(jax.vmap(f), batches, repeats), 64),
        ("value and gradient", lambda f: loop_time(_value_and_grad(f), grads, repeats), 1),
    ]
    previous = make_previous(model, prepared, x0) if make_previous else None
    print(f"kernel instruction set: {compiled_kernel.instruction_set()}\n")
    head = "| per evaluation | JAX reference (µs) | compiled kernel (µs) | speed-up |"
    rule = "|---|---:|---:|---:|"
    if previous:
        head, rule = head + " previous kernel (µs) | previous / kernel |", rule + "---:|---:|"
    print(f"{head}\n{rule}")
    compiled_times = {}
    for name, timer, per in rows:
        t_ref = timer(reference) / per * 1e6
        t_new = compiled_times[name] = timer(compiled) / per * 1e6
        row = f"| {name} | {t_ref:.2f} | {t_new:.2f} | {t_ref / t_new:.1f}× |"
        if previous and name != "value and gradient":  # (no derivative rule for that build)
            t_old = timer(previous) / per * 1e6
            row += f" {t_old:.2f} | {t_old / t_new:.2f}× |"
        print(row)
    ratio = compiled_times["value and gradient"] / compiled_times["log L"]
    print(f"\ncompiled value and gradient / compiled value = {ratio:.1f}")


PROPAGATORS = ("leapfrog", "rk2-midpoint", "rk4")
PREVIOUS_TARGET = "symplid_ukf_loglik_previous"


def previous_build(path: str) -> Callable[..., Callable[[jax.Array], jax.Array]]:
    """``make(model, prepared, x0)``: θ ↦ log L by the kernel build at ``path`` (its handler
    registered under its own FFI target, beside the package's)."""
    handle = ctypes.CDLL(os.path.abspath(path))
    jax.ffi.register_ffi_target(
        PREVIOUS_TARGET, jax.ffi.pycapsule(handle.SymplidUkfLogLikelihood), platform="cpu"
    )
    call = jax.ffi.ffi_call(
        PREVIOUS_TARGET, jax.ShapeDtypeStruct((), jnp.float64), vmap_method="expand_dims"
    )

    def make(model, prepared, x0):
        attrs = compiled_kernel._attributes(model, prepared)
        x0, p0 = model._check_initial(x0, None)
        step_size = jnp.asarray(prepared.inputs.step_size, jnp.float64)
        num_steps = jnp.asarray(prepared.inputs.num_steps, jnp.int64)
        ys, masks = jnp.asarray(prepared.ys), jnp.asarray(prepared.masks, jnp.bool_)
        return lambda th: call(th, x0, p0, step_size, num_steps, ys, masks, **attrs)

    return make


def propagators(repeats: int, make_previous: Callable | None) -> None:
    """µs per call by propagator, one θ and a batch of eight, on the paper's workload
    (``make_previous``: another build, from :func:`previous_build`)."""
    system = symplid.get_system("henon-heiles")
    data = symplid.simulate(system, seed=0)
    x0 = system.initial_state
    key = jax.random.key(0)
    head = "| propagator | θ per call | JAX reference (µs) | kernel (µs) |"
    rule = "|---|---:|---:|---:|"
    if make_previous:
        head += " previous kernel (µs) | previous / kernel |"
        rule += "---:|---:|"
    print(f"\n{head}\n{rule}")
    for name in PROPAGATORS:
        model = symplid.HamiltonianModel(system.potential, integrator=name, dt=0.25)
        prepared = model.prepare(data)
        theta = jnp.asarray(model.pack(system.coefficients, 1e-6, 0.05**2))
        thetas = theta * (1.0 + 1e-3 * jax.random.normal(key, (400, theta.shape[0])))
        tiers = {
            "ref": dataclasses.replace(model, backend="jax").log_likelihood_fn(data, x0),
            "new": lambda th, m=model, pr=prepared: compiled_kernel.log_likelihood(m, pr, th, x0),
        }
        if make_previous:
            tiers["old"] = make_previous(model, prepared, x0)
            diff = np.max(np.abs(jax.vmap(tiers["old"])(thetas) - jax.vmap(tiers["new"])(thetas)))
            print(f"<!-- {name}: largest |previous − kernel| over 400 θ: {diff:.3g} -->")
        for per in (1, 8):
            batch = thetas if per == 1 else thetas.reshape(50, 8, -1)
            times = {
                k: loop_time(f if per == 1 else jax.vmap(f), batch, repeats) * 1e6
                for k, f in tiers.items()
            }
            row = f"| {name} | {per} | {times['ref']:.1f} | {times['new']:.1f} |"
            if make_previous:
                row += f" {times['old']:.1f} | {times['old'] / times['new']:.2f}× |"
            print(row)


# Shapes outside the AVX-512 register path (a mass matrix, forward Euler, Runge–Kutta for
# d = 3 at degree 4) and two inside it, for the --previous comparison: (d, order, integrator,
# mass).
SHAPES = (
    (2, 3, "leapfrog", ((2.0, 0.5), (0.5, 1.0))),
    (1, 4, "euler", None),
    (3, 4, "rk2-midpoint", None),
    (3, 4, "leapfrog", None),
    (3, 3, "rk4", None),
)


def shapes(repeats: int, make_previous: Callable) -> None:
    """µs per call for one θ on other shapes (20 full-state observations, confining potential),
    this build against another (``make_previous``), with the largest difference between them."""
    rng = np.random.default_rng(0)
    times = np.arange(1, 21) * 5.0
    print("\n| d, order | propagator | mass | kernel (µs) | previous kernel (µs) |"
          " previous / kernel | largest difference |\n|---|---|---|---:|---:|---:|---:|")
    for d, order, name, mass in SHAPES:
        potential = symplid.Polynomial(d, order)
        bowl = [0.5 if sum(e) == 2 and max(e) == 2 else 0.0 for e in potential.exponents]
        model = symplid.HamiltonianModel(potential, integrator=name, dt=0.25, mass=mass)
        data = symplid.Observations(times, 0.1 * rng.standard_normal((times.size, 2 * d)))
        prepared = model.prepare(data)
        x0 = np.r_[np.full(d, 0.2), np.full(d, -0.1)]
        theta = jnp.asarray(model.pack(np.asarray(bowl), 1e-6, 0.05**2))
        thetas = theta * (1.0 + 1e-3 * jax.random.normal(jax.random.key(0), (200, theta.size)))
        def new(th, m=model, pr=prepared, x0=x0):
            return compiled_kernel.log_likelihood(m, pr, th, x0)

        old = make_previous(model, prepared, x0)
        diff = np.max(np.abs(jax.vmap(old)(thetas) - jax.vmap(new)(thetas)))
        t_new, t_old = (loop_time(f, thetas, repeats) * 1e6 for f in (new, old))
        print(f"| {d}, {order} | {name} | {'yes' if mass else 'no'} | {t_new:.1f} | {t_old:.1f} |"
              f" {t_old / t_new:.2f}× | {diff:.3g} |")


def _value_and_grad(fn: Callable[[jax.Array], jax.Array]) -> Callable[[jax.Array], jax.Array]:
    def step(th):
        value, grad = jax.value_and_grad(fn)(th)
        return value + jnp.sum(grad)

    return step


def map_times(repeats: int = 2) -> None:
    """The paper's MAP (``find_map(posterior, seed=0)``: four starts and the Hessian) with the
    compiled gradient and with the JAX tier's gradient under the compiled value (what the
    compiled tier did before it had its own gradient), each on a fresh posterior (so its
    programs are traced and compiled) and then again on the same one: CPU seconds."""
    import warnings

    from symplid.inference.map import find_map
    from symplid.model._posterior import Posterior

    system = symplid.get_system("henon-heiles")
    data = symplid.simulate(system, seed=0)
    own = compiled_kernel._gradient_unsupported_reason
    rows = []
    for label, reason in (("compiled gradient", own),
                          ("JAX tier's gradient", lambda model: "the baseline")):
        compiled_kernel._gradient_unsupported_reason = reason
        try:
            # a new model each time: the compiled programs are cached per model structure
            model = symplid.HamiltonianModel(system.potential, dt=0.25 * (1 + 1e-15 * len(rows)))
            posterior = Posterior(model, data, x0=system.initial_state)
            times = []
            for _ in range(repeats):
                start = time.process_time()
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    result = find_map(posterior, seed=0)
                times.append(time.process_time() - start)
            rows.append((label, times, np.asarray(result.theta)))
        finally:
            compiled_kernel._gradient_unsupported_reason = own
    print("\n| paper's MAP | first (CPU s) | again, same posterior (CPU s) |\n|---|---:|---:|")
    for label, times, _ in rows:
        print(f"| {label} | {times[0]:.1f} | {min(times[1:]):.1f} |")
    gap = np.max(np.abs(rows[0][2] - rows[1][2]))
    print(f"\nlargest difference between the two MAPs' θ: {gap:.1e}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--previous", help="another build of the kernel's shared library")
    parser.add_argument("--propagators-only", action="store_true")
    parser.add_argument("--first-table-only", action="store_true",
                        help="only the paper's workload (value, batch, value and gradient)")
    parser.add_argument("--map", action="store_true",
                        help="also the paper's MAP with the compiled and the JAX tier's gradient")
    args = parser.parse_args()
    make_previous = previous_build(args.previous) if args.previous else None
    if not args.propagators_only:
        main(make_previous=make_previous)
    if args.map:
        map_times()
    if args.first_table_only:
        raise SystemExit(0)
    propagators(7, make_previous)
    if make_previous:
        shapes(7, make_previous)
