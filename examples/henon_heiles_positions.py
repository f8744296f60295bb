"""Hénon–Heiles from positions only, against the paper's full-state fit.
=====================================================================

What it shows
-------------
The paper observes the full state (q1, q2, p1, p2); in practice the momenta are rarely
measured. With the observation operator h(x) = q (``observation="positions"``) the UKF still
gives the marginal likelihood (Theorem 1), and the dynamics tie the momenta to how the
positions change. Three fits, MAP and Laplace sd each (no sampling):

A. **full state**, known initial state: the paper's setting (20 observations 5 s apart,
   noise sd 0.05, data seed 0);
B. **positions only**, known initial state: the same data with the p columns dropped;
C. **positions only, initial state unknown**: x0 (at the first observation) learned with θ,
   its prior centred on the first observation (the momenta on 0, with a wider prior). Here the
   positions are taken every 1 s for 100 s: at the paper's 5 s spacing, unknown momenta and a
   gap close to the period leave several modes of the posterior (try ``--spacing 5``).

Printed: the MAP coefficients ± Laplace sd against the truth, the learned energy, the noise
variances and the prediction horizon (how long the MAP model, integrated by leapfrog at
dt = 0.01, stays within 0.1 of the true q1; the paper: about 150 s for fit A's setting).

Figures: ``phase.png`` (q1–q2 portraits to 200 s), ``q1.png`` (q1 against time, each MAP
model against the truth; the dots are the paper's observations, those of A and B) and
``coefficients.png`` (MAP ± 2 sd against the truth).

Run: ``python examples/henon_heiles_positions.py [OUT]`` (default
``examples/out/henon_heiles_positions``). Several minutes, mostly compiling three models.
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
from symplid.io import positions_only
from symplid.plotting import (
    Curves,
    plot_phase_portraits,
    plot_trajectory_bands,
    save_figure,
)
from symplid.predict import predict_trajectory, prediction_horizon, time_grid

T_END = 200.0
QUICK = os.environ.get("SYMPLID_EXAMPLE_BUDGET", "full") == "quick"  # the docs build's budget
FINE_DT = 0.01


def map_fit(posterior):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", symplid.BoundWarning)
        return symplid.find_map(posterior, seed=0, num_starts=1 if QUICK else 2,
                                evidence="laplace")


def plot_coefficients(system, results, path: Path) -> None:
    names = system.potential.param_names
    nc = len(names)
    x = np.arange(nc)
    fig = Figure(figsize=(8.0, 3.6), layout="constrained")
    ax = fig.subplots()
    ax.plot(x, system.coefficients, "s", color="#2ca02c", ms=8, label="truth", zorder=3)
    colors = ("#1f5fa8", "#c0392b", "#7b3fa0")  # as in phase.png and q1.png
    for k, (label, result) in enumerate(results.items()):
        ax.errorbar(x + (k - 1) * 0.2, result.theta[:nc], yerr=2 * result.std[:nc], fmt="o",
                    ms=4, capsize=2, color=colors[k], label=label)
    ax.axhline(0.0, color="0.6", lw=0.6)
    ax.set_xticks(x, names, fontsize=8)
    ax.set_ylabel("coefficient of U")
    ax.set_title("Hénon–Heiles: MAP ± 2 Laplace sd", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    save_figure(fig, path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("out", nargs="?", default="examples/out/henon_heiles_positions",
                        type=Path)
    parser.add_argument("--spacing", type=float, default=1.0,
                        help="time between position observations for fit C [s]")
    args = parser.parse_args()
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    runtime.enable_compilation_cache()  # reruns reuse the compiled models (as the CLI does)
    hh = symplid.get_system("henon-heiles")
    x0 = hh.initial_state

    full = symplid.simulate(hh, seed=0)  # the paper's data
    positions = positions_only(full)
    dense_times = np.arange(args.spacing, 100.0 + 1e-9, args.spacing)
    dense = positions_only(symplid.simulate(hh, times=dense_times, seed=0))

    full_model = symplid.HamiltonianModel(hh.potential, dt=0.25, observation="full")
    pos_model = symplid.HamiltonianModel(hh.potential, dt=0.25, observation="positions")
    learned = symplid.Posterior(pos_model, dense, learn_initial_state=True, t0=None)
    results = {
        "A: full state": map_fit(symplid.Posterior(full_model, full, x0=x0)),
        "B: positions": map_fit(symplid.Posterior(pos_model, positions, x0=x0)),
        f"C: positions every {args.spacing:g} s, x0 learned": map_fit(learned),
    }
    label_c = list(results)[2]
    # Where each prediction starts: the known x0 at t = 0, or C's learned state at t_1.
    x0_c = results[label_c].theta[learned.initial_state_slice(0)]
    starts = {label: (0.0, x0) for label in list(results)[:2]}
    starts[label_c] = (float(dense.times[0]), x0_c)

    grid, _, _ = time_grid(0.0, T_END, FINE_DT)
    truth = np.concatenate([x0[None], symplid.true_trajectory(hh.potential, hh.coefficients, x0,
                                                              grid[1:])])
    h_true = float(symplid.hamiltonian(hh.potential, hh.coefficients, x0))
    nc = hh.potential.num_params

    print(f"{'coefficient':<10} {'truth':>7}" + "".join(f"  {k[0]:>17}" for k in results))
    for i, name in enumerate(hh.potential.param_names):
        cells = "".join(
            f"  {r.theta[i]:>8.4f} ± {r.std[i]:.4f}" for r in results.values()
        )
        print(f"{name:<10} {hh.coefficients[i]:>7.3f}{cells}")
    print()
    paths = {}
    for label, result in results.items():
        t_start, state = starts[label]
        times, states = predict_trajectory(hh.potential, result.theta[:nc], state, T_END,
                                           dt=FINE_DT, t0=t_start)
        paths[label] = (times, states)
        if t_start == 0.0:
            reference = truth
        else:
            reference = symplid.true_trajectory(hh.potential, hh.coefficients, x0, times)
        horizon = prediction_horizon(times, states, reference, threshold=0.1)
        h_learned = float(symplid.hamiltonian(hh.potential, result.theta[:nc], state))
        print(f"{label}: H = {h_learned:.5f} (true {h_true:.5f}, error "
              f"{100 * abs(h_learned - h_true) / h_true:.2f} %), process var "
              f"{result.theta[nc]:.3g}, obs var {result.theta[nc + 1]:.3g}, horizon "
              f"{horizon:.1f} s, MAP in {result.seconds:.0f} s")
    sd_c = results[label_c].std[learned.initial_state_slice(0)]
    state_t1 = symplid.true_trajectory(hh.potential, hh.coefficients, x0, dense.times[:1])[0]
    print(f"C's learned state at t = {dense.times[0]:g}: {np.round(x0_c, 4)} ± "
          f"{np.round(sd_c, 4)} (true {np.round(state_t1, 4)})")

    plot_phase_portraits({k: v[1] for k, v in paths.items()}, truth, full.values,
                         data_title="position data (A, B)", path=out / "phase.png")
    plot_trajectory_bands(
        [Curves(label, t, s[:, 0]) for label, (t, s) in paths.items()],
        truth=(grid, truth[:, 0]), data=(full.times, full.values[:, 0]),
        t_data_end=100.0, path=out / "q1.png",
    )
    plot_coefficients(hh, results, out / "coefficients.png")
    print(f"Figures in {out}/")


if __name__ == "__main__":
    main()
