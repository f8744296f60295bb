"""A damped pendulum, as measured data: is damping needed, and what does it do to a forecast?
==========================================================================================

What it shows
-------------
Every fit, score and forecast here is a ``symplid`` command (the script only builds the data
file and draws one summary figure), so the same steps work on a real measurement:

1. ``symplid simulate damped-pendulum --observation positions``: a pendulum with friction,
   q̈ = −sin q − 0.1 q̇ (true U = 1 − cos q, not a polynomial), angle measured every 0.25 s
   for 30 s with noise σ = 0.02 rad. As with a real sensor there is no momentum column: it is
   made here the usual way, the derivative of a Savitzky–Golay smoothed angle (numpy/scipy),
   so its errors are smaller than the angle's but correlated in time (the model, isotropic
   noise by default, does not know that).
2. ``symplid compare --damping``: polynomial orders 2 and 4, each without and with a learned
   damping rate γ, ranked by the Laplace evidence (the initial state is learned too). The
   evidence answers "is damping needed?".
3. ``symplid fit --holdout 0.25``, with and without ``--damping`` (quartic U, NUTS): fit on
   the first 75 % of the record, forecast the last 25 % from the filter's state at the end
   of the fit, score it (RMSE, 95 % band coverage, log predictive density in
   ``summary.json["holdout"]``).
4. ``symplid predict RUN --from end``: both models forecast 17.5 s past the end of their
   data; ``forecast.png`` in this folder puts the two bands over the held-out data and the
   noise-free truth.

Run: ``python examples/damped_pendulum.py [OUT]`` (default ``examples/out/damped_pendulum``);
about 16 minutes on a loaded 2-core machine, most of it compiling and sampling.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from scipy.signal import savgol_filter

SPACING, T_END, NOISE, HORIZON = 0.25, 30.0, 0.02, 40.0
QUICK = os.environ.get("SYMPLID_EXAMPLE_BUDGET", "full") == "quick"  # the docs build's budget
SAMPLER = ["--method", "nuts", "--iterations", "1500", "--burn-in", "500", "--chains", "2"]
if QUICK:
    SAMPLER = ["--method", "nuts", "--iterations", "40", "--burn-in", "20", "--chains", "1"]
COMMON = ["--learn-initial-state", "--set", "initial_state.t0=first", "--no-progress"]
if QUICK:  # the docs build: the Laplace evidence this page prints, no sensitivity refits
    COMMON += ["--set", "map.evidence=laplace", "--set", "map.sensitivity=false"]


def symplid(*args: object) -> str:
    """Run one ``symplid`` command, echo it and its output, return the output."""
    exe = shutil.which("symplid")
    cmd = [exe] if exe else [sys.executable, "-m", "symplid.cli"]
    cmd += [str(a) for a in args]
    print("$ symplid", " ".join(str(a) for a in args), flush=True)
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        sys.exit(f"symplid {args[0]} failed:\n{done.stderr}")
    print(done.stdout.rstrip(), flush=True)
    return done.stdout


def read_csv(path: Path) -> tuple[list[str], np.ndarray]:
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    return rows[0], np.array([[float(v) if v else np.nan for v in r] for r in rows[1:]])


def measured_data(out: Path) -> Path:
    """Noisy angles from the CLI, with a momentum column from a smoothed derivative."""
    raw = out / "angles.csv"
    symplid("simulate", "damped-pendulum", "--out", raw, "--observation", "positions",
            "--num-obs", int(T_END / SPACING), "--t-end", T_END, "--noise-std", NOISE,
            "--seed", 0)
    _, table = read_csv(raw)
    t, q = table[:, 0], table[:, 1]
    p = savgol_filter(q, window_length=9, polyorder=3, deriv=1, delta=SPACING)  # unit mass
    path = out / "pendulum.csv"
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["t", "q1", "p1"])
        writer.writerows(zip(t, q, p, strict=True))
    return path


def forecast_figure(out: Path, runs: dict[str, Path], truth: np.ndarray) -> Path:
    """Both forecasts (95 % bands of new observations of q) over the data and the truth."""
    _, data = read_csv(out / "pendulum.csv")
    fig = Figure(figsize=(9, 3.6), layout="constrained")
    ax = fig.subplots()
    ax.plot(truth[:, 0], truth[:, 1], color="k", lw=0.8, label="truth (noise free)")
    for (label, run), color in zip(runs.items(), ("C0", "C3"), strict=True):
        fc = np.load(run / "forecast.npz")
        levels = list(fc["quantile_levels"])
        band = fc["obs_quantiles"][:, :, 0]
        ax.fill_between(fc["times"], band[0], band[-1], color=color, alpha=0.25, lw=0)
        ax.plot(fc["times"], band[levels.index(0.5)], color=color, label=f"forecast, {label}")
    t_fit = float(read_csv(runs["damped"] / "heldout.csv")[1][0, 0])
    fitted = data[:, 0] < t_fit
    ax.plot(data[fitted, 0], data[fitted, 1], ".", color="0.45", ms=3, label="angle, fitted")
    ax.plot(data[~fitted, 0], data[~fitted, 1], "x", color="k", ms=3.5, zorder=3,
            label="angle, held out")
    ax.axvline(t_fit, color="0.3", ls=":", lw=1)
    ax.set(xlabel="t", ylabel="q (rad)", title="Forecasts from the end of the fitted data "
           "(95 % bands of new observations)")
    ax.legend(loc="upper right", fontsize=8, ncols=3)
    path = out / "forecast.png"
    fig.savefig(path, dpi=110)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("out", nargs="?", default="examples/out/damped_pendulum", type=Path)
    out = parser.parse_args().out
    out.mkdir(parents=True, exist_ok=True)
    data = measured_data(out)

    orders = "2" if QUICK else "2,4"
    symplid("compare", data, "--orders", orders, "--damping", "--out", out / "compare", *COMMON)

    runs = {"damped": out / "runs" / "damped", "undamped": out / "runs" / "undamped"}
    for label, run in runs.items():
        flag = ["--damping"] if label == "damped" else []
        symplid("fit", data, "--out", run, "--order", 2 if QUICK else 4, *flag, "--holdout", 0.25,
                "--overwrite", *SAMPLER, *COMMON)
        symplid("predict", run, "--from", "end", "--t-end", HORIZON)

    truth_csv = out / "truth.csv"
    symplid("simulate", "damped-pendulum", "--out", truth_csv, "--noise-std", 0,
            "--t-end", HORIZON, "--num-obs", int(HORIZON / 0.05))
    _, truth = read_csv(truth_csv)
    figure = forecast_figure(out, runs, truth)

    print("\nWhat was measured")
    for label, run in runs.items():
        s = json.loads((run / "summary.json").read_text())
        h = s["holdout"]
        gamma = s.get("posterior", {}).get("gamma")
        g = f", γ median {gamma['median']:.4f} [{gamma['q025']:.4f}, {gamma['q975']:.4f}]" \
            if gamma else ""
        fc = np.load(run / "forecast.npz")
        median = fc["obs_quantiles"][list(fc["quantile_levels"]).index(0.5), :, 0]
        exact = np.interp(fc["times"], truth[:, 0], truth[:, 1])
        print(f"  {label:9s} log evidence {s['log_evidence_laplace']:.2f}; held out: RMSE "
              f"{h['rmse']:.4f}, 95 % coverage {h['coverage_95']:.0%}, log predictive density "
              f"{h['log_predictive_density']:.1f}{g}; forecast to t = {HORIZON:g}: RMSE of the "
              f"median angle against the truth {np.sqrt(np.mean((median - exact) ** 2)):.4f}")
    print(f"  figure: {figure}")


if __name__ == "__main__":
    main()
