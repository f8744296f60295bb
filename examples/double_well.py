"""A double well from a data file with irregular times and gaps: choose the order, then fit.
=========================================================================================

What it shows
-------------
1. Data as a user has them: a CSV (``t, q1, p1``) with irregular times (gaps of 0.3–1.7 s,
   never a multiple of the learning dt) and missing values (empty cells), and a TOML settings
   file. Both are written into the output folder and read back, as ``symplid fit`` would.
2. **Model comparison** (:func:`symplid.workflow._compare.compare_models`): polynomial orders
   2..5 of U(q) ranked by the Laplace evidence. The true U = −½q² + ¼q⁴ needs the quartic
   term: orders 2 and 3 have one well and lose by tens of nats; order 5 fits as well as 4 but
   pays an Occam factor for its unneeded q⁵ coefficient.
3. A fit of order 4 from the settings file (:func:`symplid.workflow.fit`): MAP, Laplace sd and
   a short DRAM run, with the **initial state learned** with θ (its prior centred on the
   first observation, which lacks p here).
4. Figures: ``compare.png`` (log evidence by order), ``potential.png`` (learned U(q) with its
   95 % posterior band against the truth), ``predictive.png`` (posterior predictive band of q
   and p past the end of the data, against the truth).

Run: ``python examples/double_well.py [OUT]`` (default ``examples/out/double_well``). A few
minutes on a laptop core; most of it is compiling the model once per candidate order.
"""

from __future__ import annotations

import argparse
import os
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from matplotlib.figure import Figure

import symplid
from symplid import runtime
from symplid.io import read_observations
from symplid.plotting import plot_predictive, save_figure
from symplid.predict import posterior_predictive
from symplid.samplers import draws_array
from symplid.workflow import compare_models, fit, format_table, load_settings

SETTINGS = """\
# Settings shared by the comparison and the fit (every key not given takes its default).
seed = 1

[model]
order = 4                 # the comparison below checks this choice
integrator = "leapfrog"
dt = 0.25

[initial_state]
mode = "learned"          # x0 at t0 = 0 joins θ; its prior is centred on the first observation
t0 = 0.0

[map]
num_starts = 2

[sampler]
method = "dram"
num_iterations = 6000     # per chain, burn-in included (a short run for an example)
burn_in = 3000
num_chains = 2
"""

T_PREDICT = 60.0
QUICK = os.environ.get("SYMPLID_EXAMPLE_BUDGET", "full") == "quick"  # the docs build's budget


def make_data(folder: Path, system: symplid.System) -> Path:
    """Simulate 32 irregular observations with missing values and write them as a CSV."""
    rng = np.random.default_rng(11)
    times = np.round(np.cumsum(rng.uniform(0.3, 1.7, size=32)), 3)
    obs = symplid.simulate(system, times=times, noise_std=0.05, seed=4)
    values = np.array(obs.values)
    values[[0, 5, 9, 17, 26], 1] = np.nan  # p not measured (the first row included)
    values[[3, 12, 21], 0] = np.nan  # q not measured
    values[14] = np.nan  # nothing measured at that time
    path = folder / "data.csv"
    lines = ["t,q1,p1"] + [
        ",".join(["" if np.isnan(v) else f"{v:.6f}" for v in (t, *row)])
        for t, row in zip(times, values, strict=True)
    ]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def plot_evidence(table, path: Path) -> None:
    rows = table.sort_values("order")
    orders, evidence = rows["order"].to_numpy(), rows["log_evidence"].to_numpy()
    best = float(np.nanmax(evidence))
    fig = Figure(figsize=(5.0, 3.4), layout="constrained")
    ax = fig.subplots()
    ax.plot(orders, evidence, "-", color="0.7", zorder=1)
    colors = ["#1f5fa8" if v == best else "#9bb7d9" for v in evidence]
    ax.scatter(orders, evidence, s=60, c=colors, zorder=2)
    for o, v in zip(orders, evidence, strict=True):
        text = "best" if v == best else f"{v - best:+.1f}"
        ax.annotate(text, (o, v), textcoords="offset points", xytext=(0, 8), ha="center",
                    fontsize=8)
    ax.set_xticks(orders)
    ax.margins(y=0.15)
    ax.set_xlabel("polynomial order of U(q)")
    ax.set_ylabel("Laplace log evidence")
    ax.set_title("Which order? (leapfrog, dt = 0.25)", fontsize=10)
    ax.grid(alpha=0.3)
    save_figure(fig, path)


def plot_potential(system, coefficient_draws, map_coefficients, path: Path) -> None:
    q = np.linspace(-1.7, 1.7, 241)

    def u(c):
        return jax.vmap(lambda x: system.potential.value(jnp.array([x]), c))(jnp.asarray(q))

    curves = np.asarray(jax.vmap(u)(jnp.asarray(coefficient_draws)))
    lo, hi = np.quantile(curves, [0.025, 0.975], axis=0)
    fig = Figure(figsize=(5.5, 3.6), layout="constrained")
    ax = fig.subplots()
    ax.fill_between(q, lo, hi, color="#1f5fa8", alpha=0.25, lw=0, label="95 % posterior band")
    ax.plot(q, np.asarray(u(jnp.asarray(map_coefficients))), color="#1f5fa8", lw=1.6,
            label="MAP")
    ax.plot(q, np.asarray(u(jnp.asarray(system.coefficients))), color="#2ca02c", lw=1.2,
            ls="--", label="truth: −½q² + ¼q⁴")
    ax.set_xlabel("q")
    ax.set_ylabel("U(q)")
    ax.set_ylim(-0.4, 0.5)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    save_figure(fig, path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("out", nargs="?", default="examples/out/double_well", type=Path)
    args = parser.parse_args()
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    runtime.enable_compilation_cache()  # reruns reuse the compiled models (as the CLI does)
    system = symplid.get_system("double-well")

    # 1. the data file and the settings file, read back as a user would
    data_path = make_data(out, system)
    text = SETTINGS
    if QUICK:
        for full, quick in (("6000", "300"), ("3000", "150"), ("num_starts = 2", "num_starts = 1")):
            text = text.replace(full, quick)
    (out / "settings.toml").write_text(text, encoding="utf-8")
    obs = read_observations(data_path)
    settings = load_settings(out / "settings.toml")
    missing = int(np.sum(~obs.mask))
    print(f"{data_path}: {obs.num_times} times, gaps {np.diff(obs.times).min():.2f}–"
          f"{np.diff(obs.times).max():.2f} s, {missing} missing values")

    # 2. which polynomial order?
    table = compare_models(obs, settings, orders="2,4" if QUICK else "2..5",
                           out=out / "compare")
    print(format_table(table))
    plot_evidence(table, out / "compare.png")
    order = int(table.loc[0, "order"])
    if order != settings.model.order:
        print(f"note: the evidence prefers order {order}; the fit below uses the settings' "
              f"order {settings.model.order}")

    # 3. the fit from the settings file
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", symplid.BoundWarning)
        outcome = fit(obs, settings, out=out / "run", overwrite=True)
    posterior, result = outcome.posterior, outcome.map_result
    nc = outcome.model.num_coefficients
    print("\nMAP ± Laplace sd (truth):")
    # the true value of each entry of θ by its name: one observation variance per kind of
    # column when the file has q and p columns (model.noise = "auto"), σ² = 0.05² each
    noise_vars = [0.05**2] * outcome.model.num_obs_noise
    truth = [*system.coefficients, np.nan, *noise_vars, *system.initial_state]
    for name, value, sd, t in zip(posterior.param_names, result.theta, result.std, truth,
                                  strict=True):
        truth_text = "-" if np.isnan(t) else f"{t:.4g}"
        print(f"  {name:<12} {value:>11.4g} ± {sd:<8.2g} truth {truth_text}")

    # 4. figures: the learned potential and the predictive band past the data
    draws = draws_array(outcome.idata).reshape(-1, posterior.num_params)
    plot_potential(system, draws[:, :nc], result.theta[:nc], out / "potential.png")
    x0_draws = draws[:, posterior.initial_state_slice(0)]
    predictive = posterior_predictive(
        outcome.model, draws[:, :nc], x0_draws, T_PREDICT, dt=0.01, num_paths=40, seed=0
    )
    truth_states = np.concatenate([
        system.initial_state[None],
        symplid.true_trajectory(system.potential, system.coefficients, system.initial_state,
                                predictive.times[1:]),
    ])
    x0_map = result.theta[posterior.initial_state_slice(0)]
    map_path = symplid.predict.predict_trajectory(
        outcome.model, result.theta[:nc], x0_map, T_PREDICT, dt=0.01
    )
    plot_predictive(predictive, obs, truth=(predictive.times, truth_states), map_path=map_path,
                    path=out / "predictive.png")
    horizon = symplid.predict.prediction_horizon(
        map_path[0], map_path[1], np.concatenate([
            system.initial_state[None],
            symplid.true_trajectory(system.potential, system.coefficients,
                                    system.initial_state, map_path[0][1:]),
        ]), threshold=0.1,
    )
    print(f"\nThe MAP model stays within 0.1 of the true q for {horizon:.1f} s "
          f"(data end at {obs.times[-1]:.1f} s).")
    print(f"Figures and run folder in {out}/")


if __name__ == "__main__":
    main()
