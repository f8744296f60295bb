"""Learning with a fourth-order symplectic propagator: leapfrog, Yoshida-4 and RK2 against dt.

The seed paper learns Hénon–Heiles with leapfrog inside the likelihood (eq. 14) at the
learning step dt = 0.25 and names "more stable and accurate numerical integrators" as future
work (Section V). This benchmark fits the paper's data (20 full-state observations 5 s apart,
noise sd 0.05, data seed 0, known initial state, Laplace(0, 10) and half-normal(1) priors)
with three propagators at dt = 0.25 (the paper's), 0.5 and 1.0:

* ``leapfrog``: 2nd order, symplectic, one force evaluation per step;
* ``yoshida4``: 4th order, symplectic (three leapfrog sub-steps), three forces per step;
* ``rk2-midpoint``: 2nd order, not symplectic (the paper's comparison), two forces per step.

**MAP only** (no sampling, no Hessian): for each fit it reports

* ``H err %``: the relative error of the learned Hamiltonian at the true initial state,
  |H(x0; θ*) − H(x0; θ_true)| / H(x0; θ_true) (the paper: 0.7 % leapfrog, 1.3 % RK2);
* ``coef err``: the largest absolute error of the nine potential coefficients;
* ``process var``: the MAP process-noise variance θ_Σ (the model error the propagator leaves;
  the paper's Fig. 4 shows it an order of magnitude smaller with leapfrog than with RK2);
  ``1e-14`` is the search floor, i.e. no detectable process noise;
* ``horizon s``: how long the MAP model, integrated by leapfrog at the fine dt = 0.01 from the
  true initial state, stays within 0.1 of the truth in q1 (200 s = the whole window);
* ``fit s``: wall time of the MAP search (compilation included), ``search s``: the L-BFGS-B
  runs alone, ``evals``: log-density evaluations they made.

Run: ``python benchmarks/integrators_learning.py`` (``--dts 0.25,0.5`` or ``--starts 4`` to
change the grid; ``--json FILE`` to save the rows). Everything runs on one CPU thread.
"""

from __future__ import annotations

import os

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")
if hasattr(os, "sched_setaffinity"):
    os.sched_setaffinity(0, {0})  # pinned to one core: the machine may be shared

from symplid import runtime  # noqa: E402  (sets the small-loop flag before JAX starts)

runtime.limit_threads()  # one XLA thread, merged so that no flag is lost behind a bare token

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

import symplid  # noqa: E402
from symplid.inference._predict import predict_trajectory, prediction_horizon, time_grid  # noqa: E402
from symplid.inference.map import find_map  # noqa: E402
from symplid.model._posterior import Posterior  # noqa: E402

INTEGRATOR_NAMES = ("leapfrog", "yoshida4", "rk2-midpoint")
DTS = (0.25, 0.5, 1.0)
T_END = 200.0
FINE_DT = 0.01
THRESHOLD = 0.1


def fit_one(system: Any, data: Any, integrator: str, dt: float, starts: int, truth: Any) -> dict:
    """MAP of the paper's posterior with one propagator and learning step; one table row."""
    model = symplid.HamiltonianModel(system.potential, integrator=integrator, dt=dt)
    posterior = Posterior(model, data, x0=system.initial_state)
    t0 = time.perf_counter()
    result = find_map(posterior, seed=0, num_starts=starts, compute_hessian=False, warn=False)
    fit_s = time.perf_counter() - t0
    coeffs = result.theta[: model.num_coefficients]
    x0 = system.initial_state
    h_true = float(symplid.hamiltonian(system.potential, system.coefficients, x0))
    h_learned = float(symplid.hamiltonian(system.potential, coeffs, x0))
    times, states = predict_trajectory(system.potential, coeffs, x0, T_END, dt=FINE_DT)
    horizon = prediction_horizon(times, states, truth, threshold=THRESHOLD, component=0)
    return {
        "integrator": integrator,
        "dt": dt,
        "H_learned": h_learned,
        "H_true": h_true,
        "H_rel_error": abs(h_learned - h_true) / abs(h_true),
        "coef_max_abs_error": float(np.max(np.abs(coeffs - system.coefficients))),
        "process_var": float(result.theta[model.num_coefficients]),
        "obs_var": float(result.theta[model.num_coefficients + 1]),
        "log_posterior": float(result.log_posterior),
        "horizon_s": float(horizon),
        "fit_s": fit_s,
        "search_s": float(sum(s.seconds for s in result.starts)),
        "evals": int(sum(s.num_evaluations for s in result.starts)),
        "converged": bool(result.success),
    }


def format_rows(rows: list[dict]) -> str:
    header = (
        f"{'integrator':<13} {'dt':>5} {'H learned':>10} {'H err %':>8} {'coef err':>9} "
        f"{'process var':>12} {'obs var':>9} {'horizon s':>10} {'fit s':>7} {'search s':>9} "
        f"{'evals':>6}"
    )
    lines = [header, "-" * len(header)]
    for r in rows:
        lines.append(
            f"{r['integrator']:<13} {r['dt']:>5.2f} {r['H_learned']:>10.5f} "
            f"{100 * r['H_rel_error']:>8.2f} {r['coef_max_abs_error']:>9.3f} "
            f"{r['process_var']:>12.3g} {r['obs_var']:>9.2e} {r['horizon_s']:>10.1f} "
            f"{r['fit_s']:>7.1f} {r['search_s']:>9.1f} {r['evals']:>6d}"
            + ("" if r["converged"] else "  (not converged)")
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--integrators", default=",".join(INTEGRATOR_NAMES))
    parser.add_argument("--dts", default=",".join(str(d) for d in DTS))
    parser.add_argument("--starts", type=int, default=2, help="MAP starts per fit")
    parser.add_argument("--seed", type=int, default=0, help="seed of the data noise")
    parser.add_argument("--json", default=None, help="write the rows to this JSON file")
    args = parser.parse_args()
    integrators = [s.strip() for s in args.integrators.split(",") if s.strip()]
    dts = [float(s) for s in args.dts.split(",") if s.strip()]

    system = symplid.get_system("henon-heiles")
    data = symplid.simulate(system, seed=args.seed)
    grid, _, _ = time_grid(0.0, T_END, FINE_DT)  # the grid predict_trajectory uses
    later = symplid.true_trajectory(
        system.potential, system.coefficients, system.initial_state, grid[1:], dt=1e-3
    )
    truth = np.concatenate([system.initial_state[None], later])
    h_true = float(
        symplid.hamiltonian(system.potential, system.coefficients, system.initial_state)
    )
    print(
        f"Hénon–Heiles, {data.num_times} full-state observations (seed {args.seed}), MAP only "
        f"with {args.starts} start(s); true H = {h_true:.5f}"
    )
    rows = []
    for dt in dts:
        for name in integrators:
            row = fit_one(system, data, name, dt, args.starts, truth)
            rows.append(row)
            print(
                f"  {name:<13} dt={dt:<5g} H err {100 * row['H_rel_error']:.2f} %, process var "
                f"{row['process_var']:.3g}, {row['fit_s']:.0f} s",
                flush=True,
            )
    print()
    print(format_rows(rows))
    if args.json:
        with open(args.json, "w", encoding="utf-8") as handle:
            json.dump(rows, handle, indent=2)


if __name__ == "__main__":
    main()
