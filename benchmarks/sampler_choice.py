"""Which sampler reaches the target first: DRAM against NUTS on six systems, in one run.

Workload: ``symplid fit DATA --config FILE --method M --no-report`` with the budget set by the
answer (``sampler.num_iterations = "auto"``: every parameter's bulk and tail ESS ≥ 400 and
R-hat ≤ 1.01, checked between chunks, at most ``max_iterations``) and the map's sensitivity
refits off (they do not depend on the sampler). Systems: the paper's Hénon–Heiles (its
default data, a cubic polynomial U, full state observed, x0 learned), the three examples of
``examples/user_models/`` (Kepler, Lotka–Volterra, a pendulum), the elastic pendulum of
``benchmarks/own_models.py`` (two parameters, positions only) and a non-separable H made
here, a pendulum-like oscillator whose mass depends on q: H = p²/(2(1 + a q²)) + k q²/2
(a = 0.5, k = 2; 40 full-state observations over 10 s, SciPy's DOP853 at tolerance 1e-11).

Each (system, sampler) runs in its own child process on the same two cores with one compilation
cache per system; with ``--warm`` a short fit of each sampler (``--iterations 200``) fills it
first, else each sampler's programs compile in its timed fit (both samplers alike: the MAP's
programs are read back by the second). Reported: the number of sampled parameters d, the
gradient's cost against the log density's (the fastest of 50 compiled calls each at the MAP, on
the posterior the fit built), the sampling phase's seconds (``timings.sampler_s``: starting
points, adaptation, draws), the iterations per chain, the smallest bulk or tail ESS, ESS per
second and whether the target was reached. The machine may be shared: the load average is
printed; compare the two samplers' seconds on the same system.

Run: ``python benchmarks/sampler_choice.py [--systems pendulum kepler] [--src OTHER/src]
[--warm]``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import own_models  # noqa: E402  (the examples' data and the elastic pendulum)

SYSTEMS = ("henon-heiles", "kepler", "lotka-volterra", "pendulum", "elastic-pendulum",
           "nonseparable")
METHODS = ("dram", "nuts")
AUTO = ["--set", "sampler.num_iterations=auto", "--set", "sampler.burn_in=auto",
        "--set", "map.sensitivity=false"]

NONSEPARABLE = """# A non-separable H: an oscillator whose mass grows with q.
[model]
hamiltonian = "p1^2/(2*(1 + a*q1^2)) + k*q1^2/2"
dt = 0.05

[model.parameters]
a = { prior = "half-normal", scale = 2 }
k = { prior = "half-normal", scale = 5 }

[initial_state]
x0 = [1.5, 0.0]

[sampler]
num_chains = 2
"""

HENON = """# The paper's Hénon–Heiles system: a cubic polynomial U, the full state observed.
[model]
order = 3

[initial_state]
mode = "learned"

[sampler]
num_chains = 2
"""


def nonseparable_csv(path: Path, seed: int = 0) -> None:
    """40 noisy full-state observations of H = p²/(2(1 + a q²)) + k q²/2 (a = 0.5, k = 2)."""
    from scipy.integrate import solve_ivp

    a, k = 0.5, 2.0

    def rhs(_t, x):
        q, p = x
        m = 1.0 + a * q * q
        return [p / m, a * q * p * p / (m * m) - k * q]

    t = np.linspace(0.25, 10.0, 40)
    sol = solve_ivp(rhs, (0.0, 10.0), [1.5, 0.0], t_eval=t, method="DOP853",
                    rtol=1e-11, atol=1e-11)
    rng = np.random.default_rng(seed)
    x = sol.y.T + 0.02 * rng.standard_normal((t.size, 2))
    rows = "\n".join(f"{ti:.6g},{q:.10g},{p:.10g}" for ti, (q, p) in zip(t, x, strict=True))
    path.write_text("t,q1,p1\n" + rows + "\n", encoding="utf-8")


def prepare(system: str, folder: Path, src: Path) -> tuple[Path, Path]:
    """(data file, settings file) of ``system`` in ``folder``."""
    if system == "nonseparable":
        data, config = folder / "nonseparable.csv", folder / "nonseparable.toml"
        nonseparable_csv(data)
        config.write_text(NONSEPARABLE, encoding="utf-8")
        return data, config
    if system == "henon-heiles":
        data, config = folder / "henon-heiles.csv", folder / "henon-heiles.toml"
        subprocess.run([sys.executable, "-m", "symplid.cli", "simulate", "henon-heiles",
                        "--out", str(data)], env=dict(os.environ, PYTHONPATH=str(src)),
                       check=True, capture_output=True)
        config.write_text(HENON, encoding="utf-8")
        return data, config
    return own_models.prepare(system, folder)


CHILD = r"""
import json, sys, time
import jax
import numpy as np
from symplid.cli import main
from symplid.workflow._results import RunFolder
from symplid.workflow._run_tools import _load
data, config, out, extra = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4:]
start = time.perf_counter()
main(["fit", data, "--config", config, "--out", out, "--no-progress", "--no-report", *extra],
     standalone_mode=False)
wall = time.perf_counter() - start
folder = RunFolder(out, mode="r")
_, _, _, posterior = _load(folder)
theta = jax.numpy.asarray(folder.read_map()["theta"], dtype=float)
cost = {}
for name, fn in (("f", jax.jit(posterior.log_density)),
                 ("g", jax.jit(jax.value_and_grad(posterior.log_density)))):
    jax.block_until_ready(fn(theta))
    times = []
    for _ in range(50):  # the fastest call: the steadiest figure on a shared machine
        t = time.perf_counter()
        jax.block_until_ready(fn(theta))
        times.append(time.perf_counter() - t)
    cost[name] = min(times)
print("BENCH " + json.dumps({"wall": wall, "cost": cost, "d": int(theta.size)}))
"""


def run_child(src: Path, data: Path, config: Path, out: Path, cache: Path, extra: list[str],
              cores: list[int] | None) -> dict:
    """One fit in a child process; its clock, the gradient's cost and its summary."""
    clock, summary = own_models.child_fit(CHILD, src, data, config, out, cache, extra, cores)
    ess = min(summary["ess_min"], summary.get("ess_tail_min", summary["ess_min"]))
    sampling = summary["timings"]["sampler_s"]
    return {"d": clock["d"], "grad": clock["cost"]["g"] / clock["cost"]["f"],
            "sampling": sampling, "wall": clock["wall"], "iterations": summary["iterations"],
            "ess": ess, "rhat": summary["rhat_max"], "ess_per_s": ess / sampling,
            "reached": bool(summary["rhat_max"] <= 1.01 and ess >= 400)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--systems", nargs="+", choices=SYSTEMS, default=list(SYSTEMS))
    parser.add_argument("--warm", action="store_true", help="fill the cache first")
    parser.add_argument("--src", type=Path, default=HERE.parent / "src",
                        help="the src folder to run (default: this checkout's)")
    args = parser.parse_args()
    cores = own_models.two_cores()
    print(f"load average before: {os.getloadavg()[0]:.2f}; cores {cores}", flush=True)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for system in args.systems:
            data, config = prepare(system, folder, args.src.resolve())
            cache = folder / f"cache-{system}"
            for method in METHODS if args.warm else ():  # the MAP's and the samplers'
                run_child(args.src, data, config, folder / f"warm-{system}-{method}", cache,
                          ["--method", method, "--iterations", "200"], cores)
            for method in METHODS:
                out = folder / f"run-{system}-{method}"
                result = run_child(args.src, data, config, out, cache,
                                   ["--method", method, *AUTO], cores)
                rows.append((system, method, result))
                print(_row(system, method, result), flush=True)
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    print("\n" + HEADER + "\n" + "|---" * 10 + "|")
    for row in rows:
        print(_row(*row))


HEADER = ("| system | sampler | d | grad/f | sampling s | iterations | min ESS | max R-hat "
          "| ESS/s | target |")


def _row(system: str, method: str, r: dict) -> str:
    return (f"| {system} | {method} | {r['d']} | {r['grad']:.1f} | {r['sampling']:.1f} | "
            f"{r['iterations']} | {r['ess']:.0f} | {r['rhat']:.3f} | {r['ess_per_s']:.1f} | "
            f"{'reached' if r['reached'] else 'not reached'} |")


if __name__ == "__main__":
    main()
