"""Simulated records of driven systems, for the driven-systems examples.

Each system is integrated by SciPy's adaptive Runge–Kutta (``solve_ivp``, DOP853, tolerance
1e-11) against the excitation signal itself, independently of symplid's integrators, and its
positions are observed with Gaussian noise (sd 0.05). The input is logged on a grid five
times denser than the positions: its rows leave ``q1`` empty, as a logger's fast input
channel beside a slower sensor does.

* ``duffing``: q̈ = −k1 q − k3 q³ − c q̇ + b u(t), (k1, k3, c, b) = (1, 0.5, 0.2, 1), from
  rest at t = 0, 200 positions 0.25 s apart;
* ``pendulum``: θ̈ = −k sin θ − c θ̇ + b u(t), (k, c, b) = (2, 0.15, 0.8), likewise.

The input is a multisine (``symplid.systems.multisine``: 8 tones over 0.05–0.5 Hz,
random phases from ``--seed``, RMS 1), or a chirp or steps (``--input``). ``--free`` records
the free decay instead (u = 0, from q = 1): the input gain b then has nothing to act on.

Run: ``python driven_data.py SYSTEM OUT.csv [--seed N] [--input NAME] [--free]``.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

from symplid.systems import SIGNALS

TRUTH = {
    "duffing": {"k1": 1.0, "k3": 0.5, "c": 0.2, "b": 1.0},
    "pendulum": {"k": 2.0, "c": 0.15, "b": 0.8},
}


def _rhs(system: str, u):
    p = TRUTH[system]
    if system == "duffing":
        return lambda t, x: [x[1], -p["k1"] * x[0] - p["k3"] * x[0] ** 3 - p["c"] * x[1]
                             + p["b"] * u(t)]
    return lambda t, x: [x[1], -p["k"] * np.sin(x[0]) - p["c"] * x[1] + p["b"] * u(t)]


def simulate(system: str, seed: int = 0, signal: str = "multisine", free: bool = False,
             num: int = 200, gap: float = 0.25, noise: float = 0.05, dense: int = 5):
    """(times, positions, input times, inputs) of one record."""
    duration = num * gap
    u = (lambda t: 0.0 * np.asarray(t, dtype=float)) if free else SIGNALS[signal](
        seed=seed, duration=duration + 1.0)
    t_obs = gap * np.arange(1, num + 1)
    t_in = np.arange(0, num * dense + 1) * (gap / dense)
    x0 = [1.0, 0.0] if free else [0.0, 0.0]
    sol = solve_ivp(_rhs(system, u), (0.0, duration), x0, t_eval=t_obs, method="DOP853",
                    rtol=1e-11, atol=1e-11)
    rng = np.random.default_rng(seed + 1000)
    return t_obs, sol.y[0] + noise * rng.normal(size=num), t_in, u(t_in)


def write(path: Path, t_obs, q, t_in, u) -> None:
    """One CSV ``t,q1,u1``: the inputs on their dense grid, q1 where it was measured."""
    measured = dict(zip(np.round(t_obs, 9), q, strict=True))
    with open(path, "w", newline="", encoding="utf-8") as handle:
        out = csv.writer(handle)
        out.writerow(["t", "q1", "u1"])
        for t, value in zip(t_in, u, strict=True):
            qv = measured.get(round(float(t), 9))
            out.writerow([f"{t:.6g}", "" if qv is None else repr(float(qv)), repr(float(value))])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("system", choices=sorted(TRUTH))
    parser.add_argument("out", type=Path)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--input", default="multisine", choices=sorted(SIGNALS))
    parser.add_argument("--free", action="store_true")
    parser.add_argument("--num", type=int, default=200)
    args = parser.parse_args()
    write(args.out, *simulate(args.system, args.seed, args.input, args.free, args.num))


if __name__ == "__main__":
    main()
