"""A chain of three coupled anharmonic oscillators (FPU-α) from one and from two trajectories.
===========================================================================================

What it shows
-------------
1. A system with more degrees of freedom than the paper's: three masses between fixed walls,
   U = Σ ½(q_{i+1} − q_i)² + (α/3)(q_{i+1} − q_i)³ with α = 0.25 (``fpu-chain``), learned as a
   general cubic polynomial in (q1, q2, q3): **19 coefficients**, most of them truly zero (the
   Laplace prior favours that sparsity).
2. **Several trajectories sharing one potential** (``symplid.Posterior`` with a list): a second
   trajectory from another initial state, observed at its own irregular times. The MAP and the
   Laplace sd with trajectory a alone and with a and b together: the second trajectory
   explores other configurations and tightens the coefficients.
3. The learning propagator's discretisation error is absorbed by the coefficients: with
   leapfrog at dt = 0.25 the quadratic (spring) coefficients come out about 2 % too small,
   several Laplace sd from the truth, because leapfrog slows an oscillation of frequency ω
   by a relative (ω·dt)²/24 and the fastest mode here has ω ≈ 1.85. ``--integrator
   yoshida4`` (4th order) removes most of that bias at the same dt.
4. Figures: ``coefficients.png`` (MAP ± 2 Laplace sd against the truth, one and two
   trajectories), ``chain.png`` (q1, q2, q3 of trajectory a predicted by each MAP model
   past the data, against the truth) and ``energy.png`` (H along those predictions).

Run: ``python examples/fpu_chain.py [OUT]`` (default ``examples/out/fpu_chain``). Several
minutes on a laptop core, most of it compiling the Hessian of a 21-parameter posterior.
"""

from __future__ import annotations

import argparse
import os
import warnings
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

import symplid
from symplid import runtime
from symplid.plotting import save_figure
from symplid.predict import hamiltonian_along, predict_trajectory, prediction_horizon

T_PREDICT = 80.0
NOISE = 0.02
QUICK = os.environ.get("SYMPLID_EXAMPLE_BUDGET", "full") == "quick"  # the docs build's budget


def fit(model, data, x0):
    posterior = symplid.Posterior(model, data, x0=x0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", symplid.BoundWarning)
        return posterior, symplid.find_map(posterior, seed=0, num_starts=1 if QUICK else 2,
                                           evidence="laplace")


def plot_coefficients(system, fits, path: Path) -> None:
    names = system.potential.param_names
    x = np.arange(len(names))
    fig = Figure(figsize=(10.0, 3.8), layout="constrained")
    ax = fig.subplots()
    ax.plot(x, system.coefficients, "s", color="#2ca02c", ms=7, label="truth", zorder=3)
    for k, (label, (_, result)) in enumerate(fits.items()):
        nc = len(names)
        ax.errorbar(x + (k - 0.5) * 0.25, result.theta[:nc], yerr=2 * result.std[:nc],
                    fmt="o", ms=4, capsize=2, label=f"{label}: MAP ± 2 sd")
    ax.axhline(0.0, color="0.6", lw=0.6)
    ax.set_xticks(x, names, rotation=60, fontsize=8)
    ax.set_ylabel("coefficient of U")
    ax.set_title("FPU-α chain: the 19 coefficients of a cubic U(q1, q2, q3)", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    save_figure(fig, path)


def plot_chain(times, truth, predictions, t_data_end, path: Path) -> None:
    fig = Figure(figsize=(9.0, 6.5), layout="constrained")
    axes = fig.subplots(3, 1, sharex=True)
    for i, ax in enumerate(axes):
        ax.plot(times, truth[:, i], color="#2ca02c", lw=1.4, label="truth")
        for label, states in predictions.items():
            ax.plot(times, states[:, i], lw=0.9, label=f"MAP, {label}")
        ax.axvline(t_data_end, color="#d62fc4", ls="--", lw=1.0, label="end of data")
        ax.set_ylabel(f"q{i + 1}")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8, ncol=4, loc="upper right")
    axes[-1].set_xlabel("t [s]")
    save_figure(fig, path)


def plot_energy(times, energies, t_data_end, path: Path) -> None:
    fig = Figure(figsize=(8.0, 3.2), layout="constrained")
    ax = fig.subplots()
    for label, h in energies.items():
        ax.plot(times, h, lw=1.2, label=label,
                color="#2ca02c" if label == "truth" else None)
    ax.axvline(t_data_end, color="#d62fc4", ls="--", lw=1.0)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("H(q, p)")
    ax.set_title("Energy along the predictions (leapfrog, dt = 0.01), each in its own model",
                 fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    save_figure(fig, path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("out", nargs="?", default="examples/out/fpu_chain", type=Path)
    parser.add_argument("--integrator", default="leapfrog",
                        help="learning propagator (e.g. yoshida4)")
    args = parser.parse_args()
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    runtime.enable_compilation_cache()  # reruns reuse the compiled models (as the CLI does)
    system = symplid.get_system("fpu-chain")

    # Trajectory a: the system's default start, 40 observations 1 s apart.
    xa = system.initial_state
    a = symplid.simulate(system, noise_std=NOISE, seed=0)
    # Trajectory b: another start, 40 observations at irregular times (gaps 0.6–1.4 s).
    xb = np.array([-0.2, 0.25, 0.0, 0.0, -0.15, 0.2])
    rng = np.random.default_rng(3)
    times_b = np.round(np.cumsum(rng.uniform(0.6, 1.4, size=40)), 3)
    b = symplid.simulate(system, times=times_b, x0=xb, noise_std=NOISE, seed=1)

    model = symplid.HamiltonianModel(system.potential, integrator=args.integrator, dt=0.25)
    fits = {
        "trajectory a": fit(model, a, xa),
        "trajectories a and b": fit(model, [a, b], [xa, xb]),
    }

    nc = model.num_coefficients
    sd_one, sd_two = fits["trajectory a"][1].std[:nc], fits["trajectories a and b"][1].std[:nc]
    print(f"{'coefficient':<12} {'truth':>8} {'MAP (a)':>9} {'sd (a)':>8} {'MAP (a+b)':>10} "
          f"{'sd (a+b)':>9}")
    for i, name in enumerate(system.potential.param_names):
        print(f"{name:<12} {system.coefficients[i]:>8.4f} "
              f"{fits['trajectory a'][1].theta[i]:>9.4f} {sd_one[i]:>8.4f} "
              f"{fits['trajectories a and b'][1].theta[i]:>10.4f} {sd_two[i]:>9.4f}")
    print(f"sd(a+b) / sd(a): median {np.median(sd_two / sd_one):.2f}, "
          f"range {np.min(sd_two / sd_one):.2f}–{np.max(sd_two / sd_one):.2f}")
    for label, (_, result) in fits.items():
        print(f"{label}: process var {result.theta[nc]:.3g}, obs var {result.theta[nc + 1]:.3g} "
              f"(true {NOISE**2:.3g}), {result.seconds:.0f} s")

    plot_coefficients(system, fits, out / "coefficients.png")

    times, _ = predict_trajectory(system.potential, system.coefficients, xa, T_PREDICT)
    truth = np.concatenate([xa[None], symplid.true_trajectory(
        system.potential, system.coefficients, xa, times[1:], dt=1e-3)])
    predictions, energies = {}, {"truth": hamiltonian_along(system.potential,
                                                           system.coefficients, truth)}
    for label, (_, result) in fits.items():
        _, states = predict_trajectory(model, result.theta, xa, T_PREDICT)
        predictions[label] = states
        energies[f"MAP, {label}"] = hamiltonian_along(model, result.theta, states)
        horizon = prediction_horizon(times, states, truth, threshold=0.05, component=[0, 1, 2])
        print(f"{label}: the MAP model stays within 0.05 of the truth in q (Euclidean) for "
              f"{horizon:.1f} s (data end at {a.times[-1]:.0f} s)")
    plot_chain(times, truth, predictions, a.times[-1], out / "chain.png")
    plot_energy(times, energies, a.times[-1], out / "energy.png")
    print(f"Figures in {out}/")


if __name__ == "__main__":
    main()
