"""The cells of the paper's sweeps: their keys, their data and their run settings.

A cell is one data set (a named system, a noise seed, a schedule) fitted with one propagator;
:data:`CELL_KEYS` are its keys, checked by the one validator
(:mod:`symplid.workflow._validate`). The experiment is registered, with its cell function, in
:mod:`symplid.studies._paper`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from symplid.dynamics._integrators import INTEGRATORS
from symplid.dynamics._systems import SYSTEMS, System, get_system
from symplid.inference.samplers import SAMPLERS
from symplid.model._data import Observations
from symplid.model._simulate import simulate
from symplid.workflow._settings import Settings, settings_to_dict
from symplid.workflow._validate import Spec

__all__ = [
    "CELL_KEYS",
    "PAPER_DT",
    "PAPER_MAP",
    "PAPER_MODEL",
    "PAPER_PRIORS",
    "PAPER_SAMPLER",
    "SWEEP_METRICS",
    "cell_data",
    "known_initial_state",
    "system_defaults",
]

_DEFAULTS = settings_to_dict(Settings())
#: The paper's model settings that differ from the library's "auto" defaults.
PAPER_MODEL = {"noise": "isotropic", "standardise": "off"}
#: The paper's learning step (Section IV), where a user's fit defaults to "auto".
PAPER_DT = 0.25
#: The paper's DRAM moves θ itself (the library's default moves the variances as log v).
PAPER_SAMPLER = {"variance_scale": "natural"}
#: The paper reports no evidence: the Laplace value (no extra fits) is recorded; nor do its
#: studies pay for a user's fit's sensitivity checks (two MAP refits).
PAPER_MAP = {"evidence": "laplace", "sensitivity": False}
#: The paper's half-normal(1) on the process variance, whatever a user's fit defaults to.
PAPER_PRIORS = {"process_var": "variances"}


def _mapped(tp: type, dotted: str, doc: str, **kw: Any) -> Spec:
    section, key = dotted.split(".")
    return Spec(tp, _DEFAULTS[section][key], doc, setting=dotted, **kw)


#: The keys of a cell of the paper's sweeps, in table-column order (a ``None`` default is the
#: system's). Keys with a ``setting`` stand for that run setting; the others are the data's
#: (``system``, ``noise_std``, ``num_obs``, ``obs_interval``) and the metrics' (``horizon_tol``).
CELL_KEYS: dict[str, Spec] = {
    "system": Spec(str, "henon-heiles", "named reference system", choices=SYSTEMS),
    "seed": Spec(
        int, 0, "seed of the data noise, the MAP starts and the sampler", minimum=0, setting="seed"
    ),
    "noise_std": Spec(float, None, "observation-noise standard deviation", minimum=0.0),
    "num_obs": Spec(int, None, "number of observations", minimum=1),
    "obs_interval": Spec(float, None, "time between observations", minimum=0.0, strict=True),
    "integrator": _mapped(str, "model.integrator", "learning propagator", choices=INTEGRATORS),
    # the paper's fixed step, not the library's "auto" default: the paper's cells (and their
    # ids) stay the paper's setting; a cell asks for "auto" by name
    "dt": Spec(float, PAPER_DT, 'learning step (eq. 14); "auto": chosen from the data',
               setting="model.dt", minimum=0.0, strict=True, words=("auto",)),
    "order": _mapped(int, "model.order", "order of the polynomial potential", minimum=1),
    "sampler": _mapped(str, "sampler.method", "MCMC method", choices=SAMPLERS),
    "num_iterations": _mapped(
        int, "sampler.num_iterations", "iterations per chain, burn-in included", minimum=1
    ),
    "burn_in": _mapped(int, "sampler.burn_in", "iterations discarded", minimum=0),
    "num_chains": _mapped(int, "sampler.num_chains", "number of chains", minimum=1),
    "num_starts": _mapped(int, "map.num_starts", "number of MAP starts", minimum=1),
    "prediction_dt": _mapped(
        float, "prediction.dt", "step of the predictions", minimum=0.0, strict=True
    ),
    "prediction_t_end": _mapped(
        float, "prediction.t_end", "end of the predictions", minimum=0.0, strict=True
    ),
    "horizon_tol": Spec(
        float, 0.1, "a prediction is valid while |q1 − q1_true| ≤ this", minimum=0.0, strict=True
    ),
}
#: The metrics of :func:`run_cell` drawn by the sweep, one figure each.
SWEEP_METRICS = (
    "hamiltonian_rel_error",
    "process_noise_median",
    "prediction_horizon_s",
    "acceptance_rate",
    "rhat_max",
    "ess_min",
)
_SYSTEM_DEFAULTS = ("noise_std", "num_obs", "obs_interval")


def system_defaults(given: Mapping[str, Any]) -> dict[str, Any]:
    """The data keys a cell leaves out take the system's values."""
    system = get_system(given.get("system", CELL_KEYS["system"].default))
    return {key: getattr(system, key) for key in _SYSTEM_DEFAULTS}


def known_initial_state(cell: Mapping[str, Any]) -> dict[str, Any]:
    """The paper's experiment: the initial state is the system's, known; one isotropic
    observation variance for q and p and no standardisation, as in the paper (the defaults
    "auto" would pick per-kind variances for full-state data), DRAM in θ and the Laplace
    evidence."""
    system = get_system(cell.get("system", CELL_KEYS["system"].default))
    return {
        "initial_state": {"mode": "known", "x0": list(system.initial_state)},
        "model": dict(PAPER_MODEL),
        "sampler": dict(PAPER_SAMPLER),
        "map": dict(PAPER_MAP),
        "priors": dict(PAPER_PRIORS),
    }


def cell_data(cell: Mapping[str, Any]) -> tuple[System, Observations]:
    """The system and the simulated data of a cell.

    Observations of the system's kind (the full state; the angles of the double pendulum) at
    ``obs_interval``, 2·``obs_interval``, …, ``num_obs``·``obs_interval`` with noise
    ``noise_std``, drawn with ``seed`` (see :func:`~.simulate`).
    """
    system = get_system(cell.get("system", CELL_KEYS["system"].default))
    interval = float(cell.get("obs_interval", system.obs_interval))
    num_obs = int(cell.get("num_obs", system.num_obs))
    times = interval * np.arange(1, num_obs + 1)
    noise = float(cell.get("noise_std", system.noise_std))
    return system, simulate(system, times=times, noise_std=noise, seed=int(cell.get("seed", 0)))
