"""A neural potential learned from the paper's 20 observations, against the polynomial.
====================================================================================

What it shows
-------------
The paper embeds a cubic polynomial U (eq. 13) in its symplectic UKF posterior and says any
potential could take its place. Here U(q; w) is an MLP (``symplid.MLPPotential``, 16 units ×
2 hidden layers, 336 weights, prior Normal(0, 1) on each), fitted to the paper's data
(Hénon–Heiles, 20 full-state observations 5 s apart, σ = 0.05, data seed 0) by the same UKF
marginal likelihood with leapfrog at dt = 0.25, known initial state: MAP by Adam then L-BFGS
and the Gauss–Newton Laplace covariance (``symplid.inference.map._neural``). The cubic
polynomial is fitted to the same data (MAP, exact Hessian) for comparison.

Printed: each model's learned H at the true initial state against the true 0.12271, its
prediction horizon (the MAP model integrated by leapfrog at dt = 0.01 from the true initial
state, valid while ``|q1 − q1_true| ≤ 0.1``; the paper: about 150 s for the polynomial), and for
the MLP how much of the true U lies inside its 95 % (linearised) Laplace band where the data
went, and how wide the band is there.

Figures: ``potential.png``: U along the lines q2 = 0 and q1 = 0 (shifted so that U(0) = 0: an
MLP's constant is arbitrary), the MLP's MAP and linearised 95 % Laplace band,
the polynomial's MAP and the truth; the shaded span is the range the true path covers over
the data's 100 s. ``q1.png``: q1 to 200 s, both MAP models against the truth.

Run: ``python examples/mlp_potential.py [OUT]`` (default ``examples/out/mlp_potential``).
"""

from __future__ import annotations

import argparse
import os
import time
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from matplotlib.figure import Figure

import symplid
from symplid import find_map_neural, neural_posterior, runtime
from symplid.plotting import save_figure
from symplid.predict import predict_trajectory, prediction_horizon

T_END = 200.0
QUICK = os.environ.get("SYMPLID_EXAMPLE_BUDGET", "full") == "quick"  # the docs build's budget
FINE_DT = 0.01


def fit_polynomial(system, data):
    model = symplid.HamiltonianModel(system.potential, "leapfrog", dt=0.25)
    posterior = symplid.Posterior(model, data, x0=system.initial_state)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", symplid.BoundWarning)
        result = symplid.find_map(posterior, seed=0, num_starts=1 if QUICK else 2)
    return result.theta[: system.potential.num_params]


def fit_mlp(system, data, width: int, depth: int):
    U = symplid.MLPPotential(dim=2, width=width, depth=depth, seed=0)
    model = symplid.HamiltonianModel(U, "leapfrog", dt=0.25)
    posterior = neural_posterior(model, data, x0=system.initial_state, weight_scale=1.0)
    result = find_map_neural(posterior, adam_steps=100 if QUICK else 1500,
                                    lbfgs_steps=50 if QUICK else 1000, polish="scipy")
    nc = U.num_params
    return U, result.theta[:nc], result.covariance[:nc, :nc]


def shifted_jax(potential, c, q):
    """U(q) − U(0) along the points ``q`` of shape (2, n) (a JAX function of ``c``)."""
    return potential.value(q, c) - potential.value(jnp.zeros(2), c)


def shifted(potential, coefficients, q):
    """:func:`shifted_jax` as NumPy, for one or many coefficient rows."""
    coefficients = jnp.atleast_2d(jnp.asarray(coefficients))
    return np.asarray(jax.vmap(lambda c: shifted_jax(potential, c, q))(coefficients))


def band(potential, w, cov, q) -> tuple[np.ndarray, np.ndarray]:
    """The linearised Laplace 95 % band of U(q) − U(0): U* ± 1.96·√diag(J Σ Jᵀ), J = ∂U/∂w.

    Weights drawn from N(w*, Σ) and pushed through the network scatter far beyond the data
    (Σ keeps the prior's width in the many directions the data do not see); the first-order
    expansion is the predictive that goes with the Gauss–Newton covariance.
    """
    J = np.asarray(jax.jacfwd(lambda c: shifted_jax(potential, c, q))(jnp.asarray(w)))
    mid = shifted(potential, w, q)[0]
    sd = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", J, cov, J), 0.0))
    return mid - 1.96 * sd, mid + 1.96 * sd


def energy(potential, coefficients, x0):
    return float(0.5 * np.sum(x0[2:] ** 2) + shifted(potential, coefficients, x0[:2, None])[0, 0])


def horizon(potential, coefficients, x0, truth_times, truth):
    times, path = predict_trajectory(potential, coefficients, x0, T_END, dt=FINE_DT)
    return prediction_horizon(times, path, truth, 0.1, 0), times, path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("out", nargs="?", default="examples/out/mlp_potential")
    parser.add_argument("--width", type=int, default=4 if QUICK else 16)
    parser.add_argument("--depth", type=int, default=2)
    args = parser.parse_args()
    runtime.enable_compilation_cache()
    out = Path(args.out)
    start = time.perf_counter()

    system = symplid.get_system("henon-heiles")
    data = symplid.simulate(system, seed=0)  # the paper's 20 observations
    x0 = np.asarray(system.initial_state)
    grid = FINE_DT * np.arange(round(T_END / FINE_DT) + 1)
    truth = np.concatenate([x0[None], symplid.true_trajectory(
        system.potential, system.coefficients, x0, grid[1:], 1e-3)])

    poly = fit_polynomial(system, data)
    U, w, cov = fit_mlp(system, data, args.width, args.depth)
    h_true = energy(system.potential, system.coefficients, x0)
    rows = {}
    paths = {}
    for name, pot, coef in (("polynomial (9 coefficients)", system.potential, poly),
                            (f"MLP {args.width}×{args.depth} ({U.num_params} weights)", U, w)):
        h = energy(pot, coef, x0)
        hz, _, path = horizon(pot, coef, x0, grid, truth)
        rows[name] = (h, abs(h - h_true) / h_true, hz)
        paths[name] = path

    coverage, width = plot_potential(out / "potential.png", system, U, w, cov, poly, truth)
    plot_q1(out / "q1.png", grid, truth, paths)
    print(f"true H(x0) = {h_true:.5f}")
    for name, (h, err, hz) in rows.items():
        print(f"{name:32s} H(x0) = {h:.5f} (error {err:.2%}), horizon {hz:6.1f} s")
    print(f"true U inside the MLP's 95 % band where the data went: {coverage:.0%} "
          f"(median width {width:.3g})")
    print(f"figures in {out}; {time.perf_counter() - start:.0f} s")


def plot_potential(path: Path, system, U, w, cov, poly, truth) -> tuple[float, float]:
    """Two slices of U with the MLP's band; returns the band's coverage of the true U and its
    median width inside the visited range."""
    fig = Figure(figsize=(10, 4), layout="constrained")
    axes = fig.subplots(1, 2)
    visited = truth[: round(100.0 / FINE_DT) + 1, :2]
    inside, widths = [], []
    for k, ax in enumerate(axes):
        s = np.linspace(-0.6, 0.6, 121)
        q = np.zeros((2, s.size))
        q[k] = s
        lower, upper = band(U, w, cov, jnp.asarray(q))
        true = shifted(system.potential, system.coefficients, jnp.asarray(q))[0]
        lo, hi = visited[:, k].min(), visited[:, k].max()
        ax.axvspan(lo, hi, color="0.9", label="range of the data's path")
        ax.fill_between(s, lower, upper, color="#7b3fa0", alpha=0.3, label="MLP 95 % band")
        ax.plot(s, shifted(U, w, jnp.asarray(q))[0], color="#7b3fa0", label="MLP MAP")
        ax.plot(s, shifted(system.potential, poly, jnp.asarray(q))[0], "--", color="#d98a00",
                label="polynomial MAP")
        ax.plot(s, true, "k:", label="truth")
        ax.set_ylim(-0.1, 0.4)
        ax.set_xlabel(f"q{k + 1} (q{2 - k} = 0)")
        ax.set_ylabel("U(q) − U(0)")
        keep = (s >= lo) & (s <= hi)
        inside.append((true[keep] >= lower[keep]) & (true[keep] <= upper[keep]))
        widths.append((upper - lower)[keep])
    axes[0].legend(fontsize=8)
    save_figure(fig, path)
    return float(np.mean(np.concatenate(inside))), float(np.median(np.concatenate(widths)))


def plot_q1(path: Path, grid, truth, paths) -> None:
    fig = Figure(figsize=(10, 3.5), layout="constrained")
    ax = fig.add_subplot()
    ax.plot(grid, truth[:, 0], "k", lw=1, label="truth")
    for (name, p), color in zip(paths.items(), ("#d98a00", "#7b3fa0"), strict=True):
        ax.plot(grid, p[:, 0], color=color, lw=1, label=name)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("q1")
    ax.legend(fontsize=8)
    save_figure(fig, path)


if __name__ == "__main__":
    main()
