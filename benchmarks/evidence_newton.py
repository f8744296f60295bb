"""The quadrature evidence's inner fits: Newton's method in the search coordinates against
L-BFGS-B, in the same process.

Workload: for each system, the MAP search of ``symplid fit`` (``find_map_for`` on the fit's
posterior, standardised as a fit standardises it) and the sensitivity check's refit with the
other process-noise model (``refit_map``), each run with the inner fits of the evidence's
quadrature (:mod:`symplid.inference.map._profile`) by the default rule (Newton's method in u,
L-BFGS-B where it does not apply) and forced to L-BFGS-B, the two taking turns,
``--repeats`` times each after one untimed run (compilation). Systems: the three examples of
``examples/user_models/`` (Kepler, Lotka–Volterra, a pendulum; data by its
``simulate_data.py``) and a Duffing oscillator that is not among them (U = ½ a q² + ¼ b q⁴,
a and b half-normal, the initial state learned, data with process noise: the state is kicked
by N(0, 0.03²) at each of 40 observations, observed with noise sd 0.05).

Reported per system and likelihood: the time of ``quadrature_evidence`` (its own clock,
``details["seconds"]``) and of the whole MAP phase, minimum over the repeats, for each rule
and their ratio; the value-and-gradient calls per inner fit (the joint mode's not counted),
how many inner fits ended in Newton's method, the nodes both rules share; the largest
difference in log evidence between the rules and the largest difference of g over the
grid's nodes (the nodes are the same: the centre and axes come from the joint mode before
any inner fit), and the quadrature's own error estimate. Pin to one core for steady figures
(``taskset -c 0``); the machine may be shared: the load average is printed, read the ratios.

Run: ``taskset -c 0 python benchmarks/evidence_newton.py [--repeats 3] [--systems kepler
duffing]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import os
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

HERE = Path(__file__).resolve().parent
EXAMPLES = HERE.parent / "examples" / "user_models"
SYSTEMS = ("kepler", "lotka-volterra", "pendulum", "duffing")
CONFIGS = {"kepler": "kepler.toml", "lotka-volterra": "lotka_volterra.toml",
           "pendulum": "pendulum.toml"}
RULES = ("L-BFGS-B", "Newton in u")

DUFFING = """# A Duffing oscillator, U = a q²/2 + b q⁴/4, position and momentum observed.
[model]
potential = "0.5*a*q1^2 + 0.25*b*q1^4"
dt = 0.05

[model.parameters]
a = { prior = "half-normal", scale = 5 }
b = { prior = "half-normal", scale = 5 }

[initial_state]
mode = "learned"
t0 = 0.0
"""


def duffing_csv(path: Path, seed: int = 0) -> None:
    """40 observations 0.25 apart of q̈ = −a q − b q³ (a = 1.5, b = 0.8) from (1.2, 0), the
    state kicked by N(0, 0.03²) at each observation time, observed with noise sd 0.05."""
    rng = np.random.default_rng(seed)
    x, t, rows = np.array([1.2, 0.0]), 0.0, []
    for _ in range(40):
        sol = solve_ivp(lambda _, z: [z[1], -1.5 * z[0] - 0.8 * z[0] ** 3], (t, t + 0.25), x,
                        method="DOP853", rtol=1e-11, atol=1e-12)
        t, x = t + 0.25, sol.y[:, -1] + 0.03 * rng.standard_normal(2)
        rows.append([t, *(x + 0.05 * rng.standard_normal(2))])
    np.savetxt(path, np.array(rows), delimiter=",", header="t,q1,p1", comments="")


def system_files(name: str, folder: Path) -> tuple[Path, Path]:
    """(settings file, data file) of ``name``, the data simulated into ``folder``."""
    data = folder / f"{name}.csv"
    if name == "duffing":
        duffing_csv(data)
        config = folder / "duffing.toml"
        config.write_text(DUFFING)
        return config, data
    spec = importlib.util.spec_from_file_location("simulate_data", EXAMPLES / "simulate_data.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.write_csv(name, data, 0)
    return EXAMPLES / CONFIGS[name], data


class Recorder:
    """Wraps the evidence's profile: g at every node, and each profile built (their counts)."""

    def __init__(self) -> None:
        from symplid.inference.map import _evidence

        self.module, self.original = _evidence, _evidence.Profile
        self.nodes, self.profiles = {}, []

    def __enter__(self) -> Recorder:
        recorder = self

        class Recording(self.original):
            def value(self, s, warm):
                g, nxt = super().value(s, warm)
                if not any(p is self for p in recorder.profiles):
                    recorder.profiles.append(self)
                recorder.nodes[tuple(np.round(s, 12))] = g
                return g, nxt

        self.module.Profile = Recording
        return self

    def __exit__(self, *exc) -> None:
        self.module.Profile = self.original


def one_run(search, lbfgsb_only: bool) -> dict:
    """One MAP search (``search()``) with the inner fits by the given rule."""
    from symplid.inference.map import _profile

    _profile._LBFGSB_ONLY = lbfgsb_only
    try:
        with Recorder() as rec:
            start = time.perf_counter()
            result = search()
            wall = time.perf_counter() - start
    finally:
        _profile._LBFGSB_ONLY = False
    details = result.evidence
    fits = rec.profiles[-1].calls if rec.profiles else {"newton": 0, "lbfgsb": 0}
    return {"map": wall, "evidence": details.get("seconds", float("nan")),
            "log_evidence": float(result.log_evidence), "nodes": rec.nodes,
            "calls": sum(p.fit_evaluations for p in rec.profiles),
            "num_nodes": details.get("nodes", 0),
            "newton": fits["newton"], "fits": fits["newton"] + fits["lbfgsb"],
            "error": details.get("error_estimate", float("nan"))}


def searches(name: str, folder: Path) -> dict:
    """{likelihood: the MAP search of the fit, the refit with the other process noise}."""
    from symplid.inference.map import without_process_var
    from symplid.io import read_observations
    from symplid.workflow._fit import find_map_for
    from symplid.workflow._plan import resolve_for_data
    from symplid.workflow._scaling import scaling_for
    from symplid.workflow._sensitivity import fit_posterior, refit_map
    from symplid.workflow._settings import load_settings

    config, data = system_files(name, folder)
    obs = read_observations(data)
    settings = resolve_for_data(load_settings(config), obs)
    scaling = scaling_for(settings, obs)
    posterior = fit_posterior(settings, obs, scaling, None)
    fit_settings = settings if scaling is None else scaling.settings(settings)
    result = find_map_for(fit_settings, posterior)  # compiles; the refit's start
    if scaling is not None:
        result = scaling.map_result(result, posterior.param_groups, obs)
    init = without_process_var(list(posterior.param_groups), result.theta)
    other = dataclasses.replace(settings, model=dataclasses.replace(
        settings.model, process_noise_per="none"))
    _, other_posterior = refit_map(other, obs, init)  # compiles
    return {"with Σ": lambda: find_map_for(fit_settings, posterior),
            "without Σ": lambda: refit_map(other, obs, init, posterior=other_posterior)[0]}


def compare(runs: dict[str, list[dict]]) -> dict:
    """Minimum times per rule, and the two rules' largest differences."""
    old, new = runs[RULES[0]], runs[RULES[1]]
    common = set(old[0]["nodes"]) & set(new[0]["nodes"])
    dg = max((abs(old[0]["nodes"][k] - new[0]["nodes"][k]) for k in common
              if np.isfinite(old[0]["nodes"][k])), default=float("nan"))
    return {
        "evidence": [min(r["evidence"] for r in runs[rule]) for rule in RULES],
        "map": [min(r["map"] for r in runs[rule]) for rule in RULES],
        "calls": [runs[rule][0]["calls"] / max(runs[rule][0]["fits"], 1) for rule in RULES],
        "newton": f"{new[0]['newton']}/{new[0]['fits']}",
        "nodes": f"{len(common)}/{len(old[0]['nodes'])}",
        "d_evidence": max(abs(a["log_evidence"] - b["log_evidence"]) for a in old for b in new),
        "dg": dg, "error": new[0]["error"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--systems", nargs="+", choices=SYSTEMS, default=list(SYSTEMS))
    args = parser.parse_args()
    rows = []
    warnings.simplefilter("ignore")  # the fits' own warnings (a variance on its floor)
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.systems:
            for likelihood, search in searches(name, Path(tmp)).items():
                runs: dict[str, list[dict]] = {rule: [] for rule in RULES}
                for _ in range(args.repeats):
                    for rule in RULES:
                        runs[rule].append(one_run(search, rule == RULES[0]))
                rows.append((name, likelihood, compare(runs)))
    print(f"load average at the end: {os.getloadavg()[0]:.2f} (1 min); "
          f"cores: {sorted(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity') else '?'}")
    print("| system | likelihood | evidence s (L-BFGS-B → Newton) | ratio | MAP s | ratio "
          "| vg calls/fit | Newton fits | nodes same | max Δ log Z | max Δ g | error est. |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, likelihood, c in rows:
        ev, mp, calls = c["evidence"], c["map"], c["calls"]
        print(f"| {name} | {likelihood} | {ev[0]:.2f} → {ev[1]:.2f} | {ev[1] / ev[0]:.2f} "
              f"| {mp[0]:.2f} → {mp[1]:.2f} | {mp[1] / mp[0]:.2f} "
              f"| {calls[0]:.1f} → {calls[1]:.1f} | {c['newton']} | {c['nodes']} "
              f"| {c['d_evidence']:.1e} | {c['dg']:.1e} | {c['error']:.1e} |")


if __name__ == "__main__":
    main()
