"""The cost of the MAP's data-driven start, against a baseline tree in the same run.

Workload: for each system, the posterior of ``symplid fit DATA --config FILE`` is built and its
MAP found (:func:`symplid.workflow._fit.find_map_for`: the whole MAP phase of a fit, its
homotopy starts included), in a child process of its own pinned to one core. Systems: the
Kepler, Lotka–Volterra and pendulum examples of ``examples/user_models/`` (data by their
``simulate_data.py``), the elastic pendulum of ``benchmarks/own_models.py`` (30 positions,
a fixed step) and a Hénon–Heiles orbit simulated here (40 noisy positions over t ∈ (0, 20],
two parameters ω² and λ, simulated by SciPy's DOP853).

Each tree (this checkout's ``src``, and ``--baseline SRC``: another checkout's ``src``) has a
compilation cache of its own; the first child per system and tree fills it (reported as
**cold**), then ``--repeats`` children run with it (**warm**: the minimum over them). Reported:
the seconds of :func:`~symplid.inference.map._data_start.data_start` (every call the MAP
phase makes, summed, and how many) and of the whole MAP phase, the compilation they caused
(JAX's trace + lower + XLA seconds, and the number of XLA programs), and the largest
relative difference between the trees' data starts θ and scales and their final MAP θ.
Each time is given as wall and CPU seconds (the process's user + system: the steadier figure
on a loaded machine). The machine may be shared: the load average is printed; read the
ratios.

Run: ``python benchmarks/data_start.py --baseline OLD/src [--repeats 3] [--systems kepler]``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SRC = HERE.parent / "src"
sys.path.insert(0, str(HERE))

from own_models import prepare  # noqa: E402  (the examples' data, written the same way)

SYSTEMS = ("kepler", "lotka-volterra", "pendulum", "elastic-pendulum", "henon-heiles")

HENON_HEILES = """# A Hénon–Heiles orbit, positions only (w = 1, lam = 1 simulated).
[model]
potential = "0.5*w*(q1^2 + q2^2) + lam*(q1^2*q2 - q2^3/3)"
dt = 0.1

[model.parameters]
w = { prior = "half-normal", scale = 5 }
lam = { prior = "normal", loc = 0, scale = 5 }

[initial_state]
mode = "learned"
t0 = 0.0
"""


def henon_heiles_csv(path: Path, seed: int = 0) -> None:
    """40 positions of a Hénon–Heiles orbit (w = 1, λ = 1, E ≈ 0.11), noise 0.01."""
    from scipy.integrate import solve_ivp

    def rhs(_t, x):
        q1, q2, p1, p2 = x
        return [p1, p2, -q1 - 2.0 * q1 * q2, -q2 - q1**2 + q2**2]

    t = np.linspace(0.5, 20.0, 40)
    sol = solve_ivp(rhs, (0.0, 20.0), [0.0, 0.1, 0.45, 0.1], t_eval=t, method="DOP853",
                    rtol=1e-11, atol=1e-12)
    q = sol.y[:2].T + 0.01 * np.random.default_rng(seed).standard_normal((t.size, 2))
    rows = "\n".join(f"{ti:.6g},{a:.10g},{b:.10g}" for ti, (a, b) in zip(t, q, strict=True))
    path.write_text("t,q1,q2\n" + rows + "\n", encoding="utf-8")


def system_files(system: str, folder: Path) -> tuple[Path, Path]:
    """(data file, settings file) of ``system`` in ``folder``."""
    if system != "henon-heiles":
        return prepare(system, folder)
    data, config = folder / "henon-heiles.csv", folder / "henon_heiles.toml"
    henon_heiles_csv(data)
    config.write_text(HENON_HEILES, encoding="utf-8")
    return data, config


CHILD = r"""
import json, sys, time
import numpy as np
from symplid import runtime
runtime.enable_compilation_cache()
from jax import monitoring
spent = {"trace": 0.0, "lower": 0.0, "xla": 0.0, "programs": 0}
EVENTS = {"/jax/core/compile/jaxpr_trace_duration": "trace",
          "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
          "/jax/core/compile/backend_compile_duration": "xla"}
def on_duration(name, secs, **_):
    if name in EVENTS:
        spent[EVENTS[name]] += secs
        spent["programs"] += EVENTS[name] == "xla"
monitoring.register_event_duration_secs_listener(on_duration)
from symplid.inference.map import _find
from symplid.io import read_trajectories
from symplid.workflow._building import build_model, build_posterior
from symplid.workflow._fit import find_map_for
from symplid.workflow._settings import load_settings, resolve_for_data
calls = {"seconds": 0.0, "cpu": 0.0, "count": 0, "compile": 0.0, "programs": 0, "theta": None,
         "scale": None}
inner = _find.data_start
def timed(*args, **kwargs):
    before = dict(spent)
    start, cpu = time.perf_counter(), time.process_time()
    found = inner(*args, **kwargs)
    calls["seconds"] += time.perf_counter() - start
    calls["cpu"] += time.process_time() - cpu
    calls["count"] += 1
    calls["compile"] += sum(spent[k] - before[k] for k in ("trace", "lower", "xla"))
    calls["programs"] += spent["programs"] - before["programs"]
    if found is not None and calls["theta"] is None:
        calls["theta"], calls["scale"] = found.theta.tolist(), found.scale.tolist()
    return found
_find.data_start = timed
data, config = sys.argv[1], sys.argv[2]
obs = read_trajectories([data])
settings = resolve_for_data(load_settings(config), obs, config)
posterior = build_posterior(settings, obs, build_model(settings, obs))
before = dict(spent)
start, cpu = time.perf_counter(), time.process_time()
result = find_map_for(settings, posterior)
seconds, cpu = time.perf_counter() - start, time.process_time() - cpu
print("BENCH " + json.dumps({
    "map": seconds, "map_cpu": cpu, "ds_cpu": calls["cpu"],
    "map_compile": sum(spent[k] - before[k] for k in ("trace", "lower", "xla")),
    "map_programs": spent["programs"] - before["programs"], "data_start": calls["seconds"],
    "calls": calls["count"], "ds_compile": calls["compile"], "ds_programs": calls["programs"],
    "start": calls["theta"], "scale": calls["scale"], "theta": np.asarray(result.theta).tolist(),
    "log_posterior": float(result.log_posterior)}))
"""


def run_child(src: Path, data: Path, config: Path, cache: Path) -> dict:
    """One MAP phase on the tree ``src`` in a child process on core 0 (``taskset -c 0``)."""
    env = dict(os.environ, PYTHONPATH=str(src), SYMPLID_CACHE_DIR=str(cache))
    pin = (lambda: os.sched_setaffinity(0, {0})) if hasattr(os, "sched_setaffinity") else None
    proc = subprocess.run([sys.executable, "-c", CHILD, str(data), str(config)], env=env,
                          capture_output=True, text=True, preexec_fn=pin, check=False)
    line = next((x for x in proc.stdout.splitlines() if x.startswith("BENCH ")), None)
    if proc.returncode != 0 or line is None:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        raise SystemExit(f"the MAP failed with {src}: {' | '.join(tail)}")
    return json.loads(line[6:])


def relative_difference(a: list | None, b: list | None) -> float:
    """max |a − b| / max(|b|, 1e-300) over finite entries; NaN when either is missing."""
    if a is None or b is None:
        return float("nan")
    x, y = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    ok = np.isfinite(x) & np.isfinite(y)
    both_nan = np.isnan(x) == np.isnan(y)
    if not np.all(both_nan):
        return float("inf")
    return float(np.max(np.abs(x - y)[ok] / np.maximum(np.abs(y[ok]), 1e-300), initial=0.0))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, required=True, help="another checkout's src")
    parser.add_argument("--systems", nargs="+", choices=SYSTEMS, default=list(SYSTEMS))
    parser.add_argument("--repeats", type=int, default=3, help="warm children per tree (min)")
    args = parser.parse_args()
    trees = {"baseline": args.baseline.resolve(), "this tree": SRC}
    print(f"load average before: {os.getloadavg()[0]:.2f}")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for system in args.systems:
            data, config = system_files(system, folder)
            runs: dict[str, list[dict]] = {name: [] for name in trees}
            for turn in range(1 + args.repeats):  # the trees take turns; the first is cold
                del turn
                for k, (name, src) in enumerate(trees.items()):
                    runs[name].append(run_child(src, data, config, folder / f"cache-{k}"))
            rows.append((system, runs))
            print(_rows(system, runs), flush=True)
    print(f"load average after: {os.getloadavg()[0]:.2f}\n")
    print(HEADER)
    print("|---" * 13 + "|")
    for system, runs in rows:
        print(_rows(system, runs))


HEADER = ("| system | tree | cache | data_start s (calls) | CPU s | its compile s (programs) | "
          "MAP phase s | CPU s | its compile s (programs) | data_start ratio (CPU) | "
          "MAP ratio (CPU) | start, scale rel. diff | MAP θ rel. diff |")


def _rows(system: str, runs: dict[str, list[dict]]) -> str:
    """The cold and warm rows of ``system``: minima over the runs, ratios to the baseline's."""
    base = runs["baseline"]
    lines = []
    for name, results in runs.items():
        for cache, chosen in (("cold", results[:1]), ("warm", results[1:])):
            if not chosen:
                continue
            ref = base[:1] if cache == "cold" else base[1:]
            low = {k: min(r[k] for r in chosen) for k in ("data_start", "ds_cpu", "map",
                                                          "map_cpu")}
            ratio = {k: low[k] / min(r[k] for r in ref) for k in low}
            r = min(chosen, key=lambda x: x["map"])
            diff_start = max(relative_difference(r["start"], ref[0]["start"]),
                             relative_difference(r["scale"], ref[0]["scale"]))
            diff_map = relative_difference(r["theta"], ref[0]["theta"])
            lines.append(
                f"| {system} | {name} | {cache} | {low['data_start']:.2f} ({r['calls']}) | "
                f"{low['ds_cpu']:.2f} | {r['ds_compile']:.2f} ({r['ds_programs']}) | "
                f"{low['map']:.2f} | {low['map_cpu']:.2f} | "
                f"{r['map_compile']:.2f} ({r['map_programs']}) | "
                f"{ratio['data_start']:.2f} ({ratio['ds_cpu']:.2f}) | "
                f"{ratio['map']:.2f} ({ratio['map_cpu']:.2f}) | {diff_start:.1e} | "
                f"{diff_map:.1e} |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
