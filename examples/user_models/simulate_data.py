"""Simulated data for the user-model examples: a Kepler orbit, Lotka–Volterra, pendulums.

Each system is integrated by SciPy's adaptive Runge–Kutta (``solve_ivp``, DOP853, tolerance
1e-11), independently of symplid's integrators, and observed with Gaussian noise. The files
are what a user would bring: a CSV with ``t`` and the observed columns.

* ``kepler``: a planet around the Sun in the plane, GM = 2.959122e-4 AU³/day² (the Gaussian
  gravitational constant squared), semi-major axis 1.2 AU, eccentricity 0.2, positions only
  (``t, q1, q2`` in days and AU), 25 observations over 400 days, noise sd 1e-3 AU.
* ``lotka-volterra``: predators y and prey x, ẋ = αx − βxy, ẏ = δxy − γy with (α, β, γ, δ) =
  (1.1, 0.4, 0.4, 0.1), in log coordinates q1 = log y, p1 = log x (both observed, noise sd
  0.05), 50 observations over 30 time units.
* ``pendulum``: θ̈ = −k sin θ with k = 2 (angle and momentum observed, noise sd 0.05), 40
  observations over 10 s, from (1, 0) at t = 0.
* ``elastic-pendulum``: a unit mass on a spring of stiffness k = 40 and rest length L = 1
  swinging in the vertical plane under g = 9.81 (y up, the pivot at the origin), U = k/2
  (|q| − L)² + g·q2; positions only (``t, q1, q2``), 30 observations 0.2 s apart, noise sd
  0.02, from q = (0.8, −1.0) at rest at t = 0. The spring's period is about 1 s, the swing's
  about 2.2 s.

Run: ``python simulate_data.py SYSTEM OUT.csv [--seed N]``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

GM_SUN = 2.959122082855911e-4  # AU³/day²


def kepler_state(a: float = 1.2, e: float = 0.2) -> np.ndarray:
    """The state at perihelion of an orbit with semi-major axis ``a`` and eccentricity ``e``."""
    r = a * (1 - e)
    v = np.sqrt(GM_SUN * (1 + e) / r)  # vis-viva at perihelion
    return np.array([r, 0.0, 0.0, v])


def _kepler(_t: float, x: np.ndarray) -> list[float]:
    r3 = np.hypot(x[0], x[1]) ** 3
    return [x[2], x[3], -GM_SUN * x[0] / r3, -GM_SUN * x[1] / r3]


def _lotka_volterra(_t: float, x: np.ndarray) -> list[float]:
    alpha, beta, gamma, delta = 1.1, 0.4, 0.4, 0.1
    return [delta * np.exp(x[1]) - gamma, alpha - beta * np.exp(x[0])]  # q = log y, p = log x


def _pendulum(_t: float, x: np.ndarray) -> list[float]:
    return [x[1], -2.0 * np.sin(x[0])]


ELASTIC = {"k": 40.0, "L": 1.0, "g": 9.81}


def _elastic_pendulum(_t: float, x: np.ndarray) -> list[float]:
    k, length, g = ELASTIC["k"], ELASTIC["L"], ELASTIC["g"]
    r = np.hypot(x[0], x[1])
    pull = k * (r - length) / r  # −∂U/∂q = −pull·q − (0, g)
    return [x[2], x[3], -pull * x[0], -pull * x[1] - g]


SYSTEMS = {
    # name: (vector field, x0, times, observed columns, noise sd, column names)
    "kepler": (_kepler, kepler_state(), np.linspace(16.0, 400.0, 25), [0, 1], 1e-3,
               ["q1", "q2"]),
    "lotka-volterra": (_lotka_volterra, np.array([np.log(2.0), np.log(6.0)]),
                       np.linspace(0.6, 30.0, 50), [0, 1], 0.05, ["q1", "p1"]),
    "pendulum": (_pendulum, np.array([1.0, 0.0]), np.linspace(0.25, 10.0, 40), [0, 1], 0.05,
                 ["q1", "p1"]),
    "elastic-pendulum": (_elastic_pendulum, np.array([0.8, -1.0, 0.0, 0.0]),
                         0.2 * np.arange(1, 31), [0, 1], 0.02, ["q1", "q2"]),
}


def simulate(system: str, seed: int = 0) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """(times, noisy observations, column names) of ``system``."""
    field, x0, times, columns, sd, names = SYSTEMS[system]
    sol = solve_ivp(field, (0.0, float(times[-1])), x0, t_eval=times, method="DOP853",
                    rtol=1e-11, atol=1e-13)
    rng = np.random.default_rng(seed)
    clean = sol.y.T[:, columns]
    return times, clean + sd * rng.standard_normal(clean.shape), names


def write_csv(system: str, out: Path, seed: int = 0) -> Path:
    """Simulate ``system`` and write ``t`` and its observed columns to ``out``."""
    times, values, names = simulate(system, seed)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(out, np.column_stack([times, values]), delimiter=",", fmt="%.10g",
               header=",".join(["t", *names]), comments="")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("system", choices=sorted(SYSTEMS))
    parser.add_argument("out", type=Path)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    print(write_csv(args.system, args.out, args.seed))


if __name__ == "__main__":
    main()
