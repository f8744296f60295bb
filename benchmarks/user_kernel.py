"""The compiled kernel for user models against the built-in polynomial kernel and the JAX tier.

Workload (seed paper, Section IV, as ``benchmarks/compiled_kernel.py``): d = 2, leapfrog at
dt = 0.25, 20 full-state observations 5 s apart (20 gaps × 20 substeps × 9 sigma points),
isotropic noise added once per gap. Models, all with d = 2:

* the paper's cubic polynomial (9 coefficients) by the built-in kernel (its compile-time
  Horner force), the same polynomial written as a user expression in ``c1..c9`` (the user
  unit), and that expression on the JAX tier;
* Kepler ``-GM/sqrt(q1^2 + q2^2)`` (sqrt), two pendulums ``k*(2 - cos(q1) - cos(q2))`` (cos)
  and a radial Morse potential ``D*(1 - exp(-a*(sqrt(q1^2 + q2^2) - r)))^2`` (exp, sqrt),
  each on data simulated from itself.

Every number is the time per evaluation inside one compiled ``lax.fori_loop`` (what a sampler
sees): CPU time of the process (``time.process_time``, so that other people's work on a
shared machine does not count), minimum over repeats with the rows interleaved in every
repeat, XLA on one thread. Columns: log L for
one θ, log L per θ of a vmap batch of eight, and ``jax.value_and_grad``; the ratio column is
the one-θ value time over the built-in polynomial kernel's.

``--flags`` compiles the Kepler unit with -O2 and with -O3 (CPU seconds of the compiler)
and times its value, in separate temporary caches.

Run on one core: ``SYMPLID_USER_KERNEL=1 taskset -c 0 python benchmarks/user_kernel.py``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os

os.environ.setdefault(
    "XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
)
os.environ.setdefault("SYMPLID_USER_KERNEL", "1")

import resource
import tempfile
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

import symplid
from compiled_kernel import loop_runner
from symplid.dynamics._user_models import build_user_model
from symplid.model import _kernel as compiled_kernel
from symplid.model import _user_kernel as user_kernel

USER_MODELS = {
    "Kepler (sqrt)": ("-GM/sqrt(q1^2 + q2^2)", ("GM",), (1.0,), (1.0, 0.0, 0.0, 1.0)),
    "pendulums (cos)": ("k*(2 - cos(q1) - cos(q2))", ("k",), (1.0,), (1.0, -0.5, 0.0, 0.3)),
    "Morse (exp, sqrt)": ("D*(1 - exp(-a*(sqrt(q1^2 + q2^2) - r)))^2", ("D", "a", "r"),
                          (1.0, 1.0, 1.0), (1.2, 0.0, 0.0, 0.8)),
}


def best_times(runners: list[Callable[[], float]], repeats: int) -> list[float]:
    """The minimum over ``repeats`` rounds of each runner, the runners interleaved in every
    round (so that a busy spell of a shared machine hits them all alike)."""
    best = [float("inf")] * len(runners)
    for _ in range(repeats):
        for i, once in enumerate(runners):
            best[i] = min(best[i], once())
    return best


def _polynomial_text(potential) -> str:
    terms = []
    for m, e in enumerate(potential.exponents):
        factors = [f"q{i + 1}^{k}" if k > 1 else f"q{i + 1}" for i, k in enumerate(e) if k]
        terms.append("*".join([f"c{m + 1}", *factors]))
    return " + ".join(terms)


def _simulate(model, coefficients, x0, times) -> np.ndarray:
    """The model's own noiseless path at ``times`` (leapfrog at dt / 8), plus 1 % noise."""
    coefficients = jnp.asarray(coefficients, float)
    grad = jax.jit(lambda q: model.hamiltonian.gradient(q, coefficients))
    q, p = np.array(x0[:2], float), np.array(x0[2:], float)
    h, t, rows = 0.25 / 8, 0.0, []
    for target in times:
        while t < target - 1e-12:
            p = p - 0.5 * h * np.asarray(grad(q))
            q = q + h * p
            p = p - 0.5 * h * np.asarray(grad(q))
            t += h
        rows.append(np.r_[q, p])
    rng = np.random.default_rng(0)
    return np.array(rows) + 0.01 * rng.standard_normal((len(rows), 4))


def _tiers(model, data, x0) -> dict[str, Callable]:
    prepared = model.prepare(data)
    return {
        "kernel": lambda th: compiled_kernel.log_likelihood(model, prepared, th, x0),
        "jax": dataclasses.replace(model, backend="jax").log_likelihood_fn(data, x0),
    }


def _runners(fn, theta) -> list[Callable[[], float]]:
    """One θ, a vmap batch of eight (per θ) and value and gradient."""
    key = jax.random.key(0)
    singles = theta * (1.0 + 1e-3 * jax.random.normal(key, (200, theta.shape[0])))
    batches = singles.reshape(25, 8, -1)
    batch = loop_runner(jax.vmap(fn), batches)
    return [loop_runner(fn, singles), lambda: batch() / 8,
            loop_runner(lambda th: sum(jax.value_and_grad(fn)(th)[1]), singles[:50])]


def main(repeats: int) -> None:
    if not compiled_kernel.available():
        raise SystemExit("the compiled kernel is not built: pip install the package first")
    system = symplid.get_system("henon-heiles")
    data = symplid.simulate(system, seed=0)
    x0 = system.initial_state
    poly = symplid.HamiltonianModel(system.potential, integrator="leapfrog", dt=0.25)
    theta = jnp.asarray(poly.pack(system.coefficients, 1e-6, 0.05**2))
    names = tuple(f"c{m + 1}" for m in range(system.potential.num_params))
    as_user = symplid.HamiltonianModel(
        build_user_model(_polynomial_text(system.potential), "potential", 2, names),
        integrator="leapfrog", dt=0.25)
    rows = [("polynomial, built-in kernel", _tiers(poly, data, x0)["kernel"], theta)]
    user = _tiers(as_user, data, x0)
    start = resource.getrusage(resource.RUSAGE_CHILDREN)
    print(f"kernel instruction set: {compiled_kernel.instruction_set()}; user tier: "
          f"{compiled_kernel.describe(as_user, as_user.prepare(data))}")
    rows += [("polynomial, user expression (user unit)", user["kernel"], theta),
             ("polynomial, user expression (JAX tier)", user["jax"], theta)]
    diff = abs(float(user["kernel"](theta)) - float(rows[0][1](theta)))
    for label, (text, params, values, start_state) in USER_MODELS.items():
        model = symplid.HamiltonianModel(build_user_model(text, "potential", 2, params),
                                         integrator="leapfrog", dt=0.25)
        th = jnp.asarray(model.pack(np.array(values), 1e-6, 0.05**2))
        sim = symplid.Observations(data.times, _simulate(model, values, start_state, data.times))
        tiers = _tiers(model, sim, np.array(start_state))
        tier = compiled_kernel.describe(model, model.prepare(sim))["likelihood_backend"]
        values_now = float(tiers["kernel"](th)), float(tiers["jax"](th))
        print(f"{label}: {tier}, log L = {values_now[0]:.6f} (JAX {values_now[1]:.6f})")
        rows += [(f"{label}, user unit", tiers["kernel"], th),
                 (f"{label}, JAX tier", tiers["jax"], th)]
    end = resource.getrusage(resource.RUSAGE_CHILDREN)
    compiler = end.ru_utime + end.ru_stime - start.ru_utime - start.ru_stime
    print(f"(the compiler's CPU time for the units not cached: {compiler:.1f} s;"
          f" |user unit − built-in| on the polynomial: {diff:.2e})\n")
    print("| model, tier | log L (µs) | log L, vmap 8 (µs per θ) | value and gradient (µs) |"
          " value / built-in polynomial |")
    print("|---|---:|---:|---:|---:|")
    runners = [r for _, fn, th in rows for r in _runners(fn, th)]
    times = np.array(best_times(runners, repeats)).reshape(len(rows), 3) * 1e6
    for (label, _, _), (value, batch, grad) in zip(rows, times, strict=True):
        print(f"| {label} | {value:.1f} | {batch:.1f} | {grad:.1f} | {value / times[0, 0]:.2f}× |")


def flags(repeats: int) -> None:
    """Compile time (the compiler's CPU seconds) and value time of the Kepler unit, -O2/-O3."""
    text, params, values, start_state = USER_MODELS["Kepler (sqrt)"]
    system = symplid.get_system("henon-heiles")
    times = symplid.simulate(system, seed=0).times
    print("\n| flags | compile (CPU s) | log L (µs) |\n|---|---:|---:|")
    base_flags = list(user_kernel._OPT_FLAGS)
    for level in ("-O2", "-O3"):
        user_kernel._OPT_FLAGS[:] = [level] + [f for f in base_flags if not f.startswith("-O")]
        with tempfile.TemporaryDirectory() as cache:
            os.environ["SYMPLID_KERNEL_CACHE"] = cache
            user_kernel._Units.found.clear()
            model = symplid.HamiltonianModel(build_user_model(text, "potential", 2, params),
                                             integrator="leapfrog", dt=0.25)
            th = jnp.asarray(model.pack(np.array(values), 1e-6, 0.05**2))
            sim = symplid.Observations(times, _simulate(model, values, start_state, times))
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            tiers = _tiers(model, sim, np.array(start_state))
            tiers["kernel"](th)
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
            value = best_times(_runners(tiers["kernel"], th)[:1], repeats)[0] * 1e6
            print(f"| {level} | {cpu:.1f} | {value:.1f} |")
    user_kernel._OPT_FLAGS[:] = base_flags


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--flags", action="store_true", help="also time -O2 against -O3")
    args = parser.parse_args()
    main(args.repeats)
    if args.flags:
        flags(args.repeats)
