"""DRAM on a user model's parameters: their natural scale against a log scale, in one run.

Workload: ``symplid fit DATA --config FILE --out RUN --no-progress --set
sampler.parameter_scale=SCALE`` with no budget given (the sampler runs until every bulk and
tail ESS is ≥ 400 and every R-hat ≤ 1.01, or its cap of 200,000 iterations per chain), for
seven systems, each fit in its own child process pinned to one core, the two scales taking
turns, after a short fit of each (2,000 iterations) has filled the compilation cache:

* the four examples of ``examples/user_models/`` (Kepler, Lotka–Volterra, a pendulum, the
  elastic pendulum; data by its ``simulate_data.py``);
* three made here with SciPy's DOP853, positions only, times and noise of their own:
  a quartic oscillator U = a q²/2 + b q⁴/4 (40 positions at random times over 15 s), a
  pendulum on a torsion spring U = k(1 − cos q) + c q²/2 (30 positions at random times over
  24 s), both linear in their coefficients, and a Morse oscillator U = D(1 − e^(−a q))²
  (25 positions over 20 s), where the small-oscillation frequency is a product, 2 D a².

Reported per system and scale: the iterations per chain when the sampler stopped and why
(``target`` or ``iterations``: the cap), the smallest bulk ESS, the largest R-hat, the
sampler's seconds and the whole fit's wall and CPU seconds, and each declared parameter's
posterior mean ± sd, so that the two scales can be seen to sample the same posterior. The
machine may be shared: the load average is printed; compare the two scales' iterations and
ratios, not the seconds.

Run: ``python benchmarks/parameter_scale.py [--systems quartic morse] [--seeds 0 1]``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

HERE = Path(__file__).resolve().parent
EXAMPLES = HERE.parent / "examples" / "user_models"
EXAMPLE_CONFIGS = {"kepler": "kepler.toml", "lotka-volterra": "lotka_volterra.toml",
                   "pendulum": "pendulum.toml", "elastic-pendulum": "elastic_pendulum.toml"}
SCALES = ("natural", "log")
WARM_UP = ("--iterations", "2000")

MADE = {
    "quartic": ("a*q1^2/2 + b*q1^4/4", {"a": 5, "b": 5}),
    "torsion": ("k*(1 - cos(q1)) + c*q1^2/2", {"k": 10, "c": 5}),
    "morse": ("D*(1 - exp(-a*q1))^2", {"D": 10, "a": 5}),
}
SYSTEMS = (*EXAMPLE_CONFIGS, *MADE)


def _made_data(system: str, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Observation times and noisy positions of one of the systems made here."""
    rng = np.random.default_rng(seed + 11)
    if system == "quartic":
        a, b = 1.5, 0.8
        times, x0, sd = np.sort(rng.uniform(0.2, 15.0, 40)), [1.3, 0.0], 0.05

        def rhs(_t, x):
            return [x[1], -a * x[0] - b * x[0] ** 3]
    elif system == "torsion":
        k, c = 3.0, 0.6
        times, x0, sd = np.sort(rng.uniform(0.3, 24.0, 30)), [1.6, 0.0], 0.03

        def rhs(_t, x):
            return [x[1], -k * math.sin(x[0]) - c * x[0]]
    else:
        depth, a = 2.0, 1.3
        times, x0, sd = np.linspace(0.0, 20.0, 26)[1:], [0.6, 0.4], 0.04

        def rhs(_t, x):
            e = math.exp(-a * x[0])
            return [x[1], -2.0 * depth * a * e * (1.0 - e)]
    sol = solve_ivp(rhs, (0.0, times[-1]), x0, t_eval=times, method="DOP853",
                    rtol=1e-11, atol=1e-12)
    return times, sol.y[0] + rng.normal(0.0, sd, times.size)


def prepare(system: str, folder: Path, seed: int) -> tuple[Path, Path]:
    """The data file and the settings file of ``system`` in ``folder``."""
    data = folder / f"{system}.csv"
    if system in EXAMPLE_CONFIGS:
        subprocess.run([sys.executable, str(EXAMPLES / "simulate_data.py"), system, str(data),
                        "--seed", str(seed)], check=True, capture_output=True)
        return data, EXAMPLES / EXAMPLE_CONFIGS[system]
    times, q = _made_data(system, seed)
    np.savetxt(data, np.c_[times, q], delimiter=",", header="t,q1", comments="")
    potential, scales = MADE[system]
    lines = ["[model]", f'potential = "{potential}"', "", "[model.parameters]"]
    lines += [f'{name} = {{ prior = "half-normal", scale = {s} }}' for name, s in scales.items()]
    lines += ["", "[initial_state]", 'mode = "learned"', "t0 = 0.0", ""]
    config = folder / f"{system}.toml"
    config.write_text("\n".join(lines))
    return data, config


def fit(data: Path, config: Path, scale: str, out: Path, cache: Path,
        extra: tuple[str, ...] = ()) -> dict:
    """One ``symplid fit`` in a child process on core 0: its summary and its costs."""
    env = dict(os.environ, SYMPLID_CACHE_DIR=str(cache))
    command = ["symplid", "fit", str(data), "--config", str(config), "--out", str(out),
               "--no-progress", "--set", f"sampler.parameter_scale={scale}", *extra]
    if shutil.which("taskset"):
        command = ["taskset", "-c", "0", *command]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run(command, check=True, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    summary = json.loads((out / "summary.json").read_text())
    return {"summary": summary, "wall": wall,
            "cpu": (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)}


def _posterior(summary: dict) -> str:
    """Each declared parameter's posterior median [2.5 %, 97.5 %] (noise and x0 left out)."""
    rows = summary["posterior"]
    names = [n for n in summary["param_names"]
             if not n.startswith(("process_var", "obs_var", "x0["))]
    return ", ".join(f"{n} {rows[n]['median']:.3g} [{rows[n]['q025']:.3g}, {rows[n]['q975']:.3g}]"
                     for n in names)


def _row(system: str, seed: int, scale: str, r: dict) -> str:
    s = r["summary"]
    return (f"| {system} | {seed} | {scale} | {s['iterations']:,} | {s['stopped_by']} | "
            f"{s['ess_min']:.0f} | {s['rhat_max']:.3f} | {s['timings']['sampler_s']:.1f} | "
            f"{r['wall']:.1f} | {r['cpu']:.1f} | {_posterior(s)} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--systems", nargs="+", choices=SYSTEMS, default=list(SYSTEMS))
    parser.add_argument("--seeds", nargs="+", type=int, default=[0])
    args = parser.parse_args()
    print(f"load average before: {os.getloadavg()[0]:.2f}")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        cache = root / "cache"
        for system in args.systems:
            for seed in args.seeds:
                folder = root / f"{system}-{seed}"
                folder.mkdir()
                data, config = prepare(system, folder, seed)
                for scale in SCALES:  # compile first: the timed fits find a warm cache
                    fit(data, config, scale, folder / f"warm-{scale}", cache, WARM_UP)
                for scale in SCALES:
                    result = fit(data, config, scale, folder / scale, cache)
                    rows.append(_row(system, seed, scale, result))
                    print(rows[-1], flush=True)
    print(f"load average after: {os.getloadavg()[0]:.2f}\n")
    print("| system | seed | scale | iterations | stopped by | min ESS | max R-hat | sampler s "
          "| wall s | CPU s | posterior median [95 %] |")
    print("|---" * 11 + "|")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
