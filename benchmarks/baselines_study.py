"""Baseline objectives against the UKF posterior's MAP on Hénon–Heiles, on equal data.

For each data size n (observations evenly spread over 100 s, so more points are denser) and
each data seed (σ = 0.05, full state), fits the cubic polynomial potential by every baseline
objective of :mod:`symplid.inference._baselines` (one integrator step per gap, as their authors
use them; plus least squares through leapfrog with the UKF's ⌈gap/0.25⌉ substeps) and by the
MAP of the UKF posterior with leapfrog and with RK2 (known initial state, the paper's priors).
Prints a markdown table of the median relative error of the learned H at the true initial
state (true H = 0.12271) and the median largest coefficient error, then the numbers that decide
the comparison. Not a test: run it by hand, e.g.::

    python benchmarks/baselines_study.py --sizes 20 50 200 1000 --seeds 5

(about 15 minutes on one core, most of it the UKF MAPs at n = 1000; ``--sizes 20 50 200`` takes
about 8). The study with more seeds, an MLP potential, prediction horizons and interval
coverage is the sweep experiment ``"baselines"`` (``symplid study baselines``).
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings

import numpy as np

import symplid
from symplid.inference import _baselines as baselines


def _methods() -> dict[str, dict]:
    out: dict[str, dict] = {name: {"objective": name} for name in baselines.OBJECTIVES.names()}
    out["leapfrog, dt 0.25"] = {"objective": "leapfrog", "dt": 0.25}
    out["UKF leapfrog MAP"] = {"ukf": "leapfrog"}
    out["UKF RK2 MAP"] = {"ukf": "rk2-midpoint"}
    return out


def _fit(system, data, spec: dict) -> np.ndarray:
    if "ukf" in spec:
        model = symplid.HamiltonianModel(system.potential, spec["ukf"], dt=0.25)
        posterior = symplid.Posterior(model, data, x0=system.initial_state)
        result = symplid.find_map(posterior, num_starts=2, compute_hessian=False, warn=False)
        return result.theta[: system.potential.num_params]
    return baselines.fit(system.potential, data, spec["objective"], dt=spec.get("dt"))


def run(sizes: list[int], seeds: int) -> dict[tuple[str, int], np.ndarray]:
    """``{(method, n): array of (H relative error, max coefficient error) per seed}``."""
    hh = symplid.get_system("henon-heiles")
    x0 = hh.initial_state
    h_true = float(symplid.hamiltonian(hh.potential, hh.coefficients, x0))
    results: dict[tuple[str, int], np.ndarray] = {}
    for n in sizes:
        times = np.linspace(100.0 / n, 100.0, n)
        for name, spec in _methods().items():
            rows = []
            start = time.perf_counter()
            for seed in range(seeds):
                data = symplid.simulate(hh, times=times, noise_std=0.05, seed=seed)
                try:
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        coef = _fit(hh, data, spec)
                    h = float(symplid.hamiltonian(hh.potential, coef, x0))
                    rows.append((abs(h - h_true) / h_true, np.max(np.abs(coef - hh.coefficients))))
                except (FloatingPointError, ValueError) as err:
                    print(f"  {name}, n={n}, seed {seed}: failed ({err})", file=sys.stderr)
                    rows.append((np.inf, np.inf))
            results[(name, n)] = np.array(rows)
            print(f"n={n:5d} {name:20s} {time.perf_counter() - start:6.1f} s", file=sys.stderr)
    return results


def _fmt(x: float) -> str:
    return "diverged" if not np.isfinite(x) else f"{x:.3g}"


def report(results: dict[tuple[str, int], np.ndarray], sizes: list[int], seeds: int) -> str:
    names = list(dict.fromkeys(name for name, _ in results))
    med = {k: np.median(v, axis=0) for k, v in results.items()}
    lines = [
        f"Hénon–Heiles, σ = 0.05 over 100 s, median over {seeds} data seeds: "
        "relative error of the learned H at the true initial state / largest coefficient error",
        "",
        "| objective | " + " | ".join(f"n = {n}" for n in sizes) + " |",
        "|---|" + "---|" * len(sizes),
    ]
    for name in names:
        cells = [f"{_fmt(med[(name, n)][0])} / {_fmt(med[(name, n)][1])}" for n in sizes]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    reference = med[("UKF leapfrog MAP", sizes[0])][0]
    lines += ["", f"Numbers that decide it (UKF-leapfrog H error at n = {sizes[0]}: "
              f"{reference:.3g}):", ""]
    for name in names:
        if name == "UKF leapfrog MAP":
            continue
        ratio = med[(name, sizes[0])][0] / reference
        reached = [n for n in sizes if med[(name, n)][0] <= reference]
        where = f"n = {reached[0]}" if reached else f"not within n ≤ {sizes[-1]}"
        lines.append(
            f"- {name}: H-error ratio at n = {sizes[0]}: {_fmt(ratio)}; reaches UKF-leapfrog's "
            f"n = {sizes[0]} error at {where}"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[20, 50, 200, 1000])
    parser.add_argument("--seeds", type=int, default=5)
    args = parser.parse_args()
    start = time.perf_counter()
    results = run(args.sizes, args.seeds)
    print(report(results, args.sizes, args.seeds))
    print(f"\n(wall time {time.perf_counter() - start:.0f} s)")


if __name__ == "__main__":
    main()
