"""What ``model.dt = "auto"`` costs and what it buys, against the fixed step, in one run.

Two pendulums U = k(1 − cos q), k = 2 and k = 2·10⁴ (time scales 100 times apart), 40 noisy
angles each (SciPy's DOP853, noise sd 0.05) at gaps of 0.25 and 0.0025, the known initial
state, no process noise (the problems of ``tests/test_step_size.py``). For each, in this
order and in this process:

* **fixed**: the fit's MAP (``find_map_for``: its starts, the Laplace covariance) at the
  data's gap, the step a fixed ``dt ≥ gap`` gives (one leapfrog step per gap);
* **auto**: :func:`symplid.workflow._step_size.choose_step`, then the fit's polish at the
  chosen step (one start from the search's MAP, the Laplace covariance);

with the CPU seconds of each (``time.process_time``: the wall clock means little on a shared
machine), the MAP's k and its Laplace sd, and the truth's distance in sds.

Run: ``nice python benchmarks/step_search.py`` (about a minute of CPU).
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
from scipy.integrate import solve_ivp

import symplid
from symplid.workflow._building import build_model, build_posterior
from symplid.workflow._fit import find_map_for
from symplid.workflow._settings import Settings, merge_overrides, resolve_for_data
from symplid.workflow._step_size import choose_step


def pendulum(speed: float, seed: int = 0) -> tuple[symplid.Observations, float]:
    k = 2.0 * speed**2
    times = 0.25 / speed * np.arange(1, 41)
    sol = solve_ivp(lambda _t, x: [x[1], -k * np.sin(x[0])], (0.0, times[-1]), [1.0, 0.0],
                    t_eval=times, method="DOP853", rtol=1e-11, atol=1e-13)
    q = sol.y[0] + 0.05 * np.random.default_rng(seed).standard_normal(times.size)
    return symplid.Observations(times, q[:, None], ("q1",)), k


def settings_for(speed: float, obs: symplid.Observations) -> Settings:
    return resolve_for_data(merge_overrides(Settings(), {
        "model.potential": "k*(1 - cos(q1))",
        "model.parameters.k": {"prior": "half-normal", "scale": 5.0 * speed**2},
        "model.dt": "auto", "model.process_noise_per": "none", "model.standardise": "off",
        "initial_state.x0": [1.0, 0.0], "map.num_starts": 1}), obs)


def map_at(settings: Settings, obs, dt: float, start=None):
    at = dataclasses.replace(settings, model=dataclasses.replace(settings.model, dt=dt))
    posterior = build_posterior(at, obs, build_model(at, obs))
    return find_map_for(at, posterior, start)


def main() -> None:
    rows = []
    for speed in (1.0, 100.0):
        obs, k = pendulum(speed)
        settings = settings_for(speed, obs)
        gap = float(np.min(np.diff(obs.times)))
        cpu = time.process_time()
        fixed = map_at(settings, obs, gap)
        fixed_cpu = time.process_time() - cpu
        cpu = time.process_time()
        choice = choose_step(settings, obs, search=find_map_for)
        auto = map_at(settings, obs, choice.record["dt"], choice.theta)
        auto_cpu = time.process_time() - cpu
        for name, result, dt, seconds, refits in (
                ("fixed", fixed, gap, fixed_cpu, 0),
                ("auto", auto, choice.record["dt"], auto_cpu, choice.record["refits"])):
            sd = float(np.sqrt(result.covariance[0, 0]))
            rows.append((f"k = {k:g}", name, dt, refits, seconds, float(result.theta[0]), sd,
                         (float(result.theta[0]) - k) / sd))
    print("| system | step | dt | MAP refits | CPU s | k (MAP) | sd | (MAP − truth)/sd |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for system, name, dt, refits, seconds, value, sd, z in rows:
        print(f"| {system} | {name} | {dt:.4g} | {refits} | {seconds:.1f} | {value:.6g} | "
              f"{sd:.3g} | {z:+.2f} |")


if __name__ == "__main__":
    main()
