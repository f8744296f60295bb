"""Stand-in cell functions for the sweep tests: real but cheap work with the core.

They run in Dask worker processes, so they live in a module the workers can import (this
directory is on their path). Each call leaves a file in ``$SYMPLID_TEST_CALLS`` (when set), so
that a test can count how often the cell function really ran.
"""

from __future__ import annotations

import functools
import os
import uuid
import warnings
from pathlib import Path

import jax
import numpy as np

import symplid
from symplid.studies._paper import cell_data

CALLS_ENV = "SYMPLID_TEST_CALLS"
FAIL_ENV = "SYMPLID_TEST_FAIL"


def _log_call(cell: dict) -> None:
    folder = os.environ.get(CALLS_ENV)
    if folder:
        name = f"{cell['seed']}-{cell['integrator']}-{cell['dt']}-{uuid.uuid4().hex[:8]}.call"
        (Path(folder) / name).write_text(f"{os.getpid()}\n", encoding="utf-8")


@functools.cache
def _model(dim: int, order: int, integrator: str, dt: float) -> symplid.HamiltonianModel:
    """One model per setting and worker process, so that its compiled filter is reused."""
    return symplid.HamiltonianModel(symplid.Polynomial(dim, order), integrator=integrator, dt=dt)


def loglik_at_truth(cell: dict) -> float:
    """Log-likelihood of the cell's data at the true θ, with the cell's integrator and dt."""
    system, data = cell_data(cell)
    model = _model(system.dim, cell["order"], cell["integrator"], cell["dt"])
    coefficients = model.hamiltonian.coefficients_from(
        dict(zip(system.potential.param_names, system.coefficients, strict=True))
    )
    theta = model.pack(coefficients, 1e-6, cell["noise_std"] ** 2)
    return float(model.log_likelihood(theta, data, x0=system.initial_state))


def loglik_cell(cell: dict) -> dict:
    """Metrics of a cell: the log-likelihood at the truth and where it was computed."""
    _log_call(cell)
    warnings.warn(f"stand-in warning for seed {cell['seed']}", UserWarning, stacklevel=1)
    return _loglik_metrics(cell)


def _loglik_metrics(cell: dict) -> dict:
    _, data = cell_data(cell)
    return {
        "loglik": loglik_at_truth(cell),
        "first_obs_q1": float(np.asarray(data.values)[0, 0]),
        "x64": bool(jax.config.jax_enable_x64),
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
        "pid": os.getpid(),
    }


def flaky_cell(cell: dict) -> dict:
    """Like :func:`loglik_cell`, but raises for seed 1 while ``$SYMPLID_TEST_FAIL`` names a file
    that exists."""
    _log_call(cell)
    flag = os.environ.get(FAIL_ENV)
    if cell["seed"] == 1 and flag and Path(flag).exists():
        raise RuntimeError(f"planned failure for seed {cell['seed']} ({cell['integrator']})")
    return _loglik_metrics(cell)


def claims_cell(cell: dict) -> dict:
    """Metrics shaped like the paper's ``run_cell``, from cheap formulas (no inference).

    The "learned" H is the energy of the first noisy observation; the process noise and the
    horizon are made from the data's noise so that they vary by seed, with RK2's noise ten
    times larger and its horizon shorter. Only the plumbing of the study is under test here,
    not the method.
    """
    _log_call(cell)
    system, data = cell_data(cell)
    truth = symplid.true_trajectory(
        system.potential, system.coefficients, system.initial_state, data.times
    )
    noise = np.asarray(data.values) - truth  # the drawn observation noise
    h_true = float(symplid.hamiltonian(system.potential, system.coefficients, system.initial_state))
    h_obs = float(symplid.hamiltonian(system.potential, system.coefficients, data.values[0]))
    ll = loglik_at_truth(cell)
    leapfrog = cell["integrator"] == "leapfrog"
    k = 1 if leapfrog else 3  # different noise draws: the ratio varies by seed
    variance = (1.0 if leapfrog else 10.0) * 1e-5 * float(np.exp(noise[k, 0] / cell["noise_std"]))
    horizon = (150.0 if leapfrog else 20.0) + 10.0 * float(noise[2, 0] / cell["noise_std"])
    return {
        "true_hamiltonian": h_true,
        "map_hamiltonian": h_obs,
        "hamiltonian_rel_error": abs(h_obs - h_true) / abs(h_true) * (1.0 if leapfrog else 2.0),
        "process_noise_map": variance,
        "process_noise_median": variance,
        "process_noise_q025": 0.5 * variance,
        "process_noise_q975": 2.0 * variance,
        "prediction_horizon_s": horizon,
        "acceptance_rate": 0.3,
        "rhat_max": 1.0,
        "ess_min": 100.0,
        "loglik": ll,
        "wall_time_s": 0.0,
    }


def slow_cell(cell: dict) -> dict:
    """A cell that takes minutes (it sleeps): for stopping a sweep while cells run."""
    import time

    _log_call(cell)
    time.sleep(600.0)
    return {"loglik": 0.0}
