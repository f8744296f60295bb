"""Where a fit of a user's own model spends its time, against a baseline tree in the same run.

Workload: ``symplid fit DATA --config FILE --out RUN --no-progress`` for each system: the three
examples of ``examples/user_models/`` (Kepler, Lotka–Volterra, a pendulum; data by its
``simulate_data.py``) and an elastic pendulum (two parameters k and L, 30 observed positions,
simulated here by SciPy's DOP853). Each tree (this checkout's ``src``, and each ``--baseline
SRC``: another checkout's ``src`` folder, named by the folder above it; the option may be
given more than once) runs each fit in its own child process on the same two
cores, the trees taking turns: first **cold** (an empty compilation cache of its own), then
**warm** (the same cache again), then **new data** (the same cache, another data set of the
same shape: the noise drawn with another seed).

Reported per system, tree and cache: the phases (``parse``: the settings checked against the
data, the model's U or H built; ``compile``: JAX's tracing, lowering and XLA compilation,
summed over the whole fit, whichever phase asked for it, and its three parts (``XLA``:
XLA's compilation, or with a warm cache looking the program up and loading it); ``map``,
``refits`` (the dt/2 and process-noise sensitivity refits), ``sampling`` and ``report``
(predictions and figures), from the run's ``summary.json`` and the child's clock), the
whole wall time, the child's CPU seconds (user + system: the steadier figure on a shared
machine) and the load average when it ended, the smallest bulk ESS per second of
sampling, and the time to the target (R-hat ≤ 1.01 and ESS ≥ 400: the whole wall time when
the fit reached it, else "not reached"). Beside each baseline, the ratio of the wall times
and an estimate of the baseline's wall time at this tree's ESS (:func:`at_same_ess`), with
the ratio at the same ESS. Compile seconds overlap the phases that compile;
they are not added to them. The machine may be shared: the load average is printed,
compare the trees' ratios, not the seconds.

Run: ``python benchmarks/own_models.py [--baseline OLD/src ...] [--systems pendulum kepler]
[--iterations N --burn-in M] [--states cold "new data"]`` (the examples' own budgets without
``--iterations``).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
SRC = ROOT / "src"
EXAMPLES = ROOT / "examples" / "user_models"
SYSTEMS = ("kepler", "lotka-volterra", "pendulum", "elastic-pendulum")
STATES = ("cold", "warm", "new data")
CONFIGS = {"kepler": "kepler.toml", "lotka-volterra": "lotka_volterra.toml",
           "pendulum": "pendulum.toml"}

ELASTIC = """# An elastic pendulum in the plane: a mass on a spring of stiffness k (per unit
# mass) and rest length L under gravity, positions only.
[model]
potential = "0.5*k*(sqrt(q1^2 + q2^2) - L)^2 + 9.81*q2"
dt = 0.02

[model.parameters]
k = { prior = "half-normal", scale = 50 }
L = { prior = "half-normal", scale = 2 }

[initial_state]
mode = "learned"
t0 = 0.0

[sampler]
num_iterations = 4000
burn_in = 2000
num_chains = 2

[prediction]
t_end = 4.0
"""


def elastic_pendulum_csv(path: Path, seed: int = 0) -> None:
    """30 noisy positions of an elastic pendulum (k = 20, L = 1), DOP853 at tolerance 1e-11."""
    from scipy.integrate import solve_ivp

    k, length = 20.0, 1.0

    def rhs(_t, x):
        r = np.hypot(x[0], x[1])
        force = -k * (r - length) / r
        return [x[2], x[3], force * x[0], force * x[1] - 9.81]

    t = np.linspace(0.1, 3.0, 30)
    sol = solve_ivp(rhs, (0.0, 3.0), [0.6, -0.9, 0.0, 0.0], t_eval=t, method="DOP853",
                    rtol=1e-11, atol=1e-11)
    rng = np.random.default_rng(seed)
    q = sol.y[:2].T + 0.01 * rng.standard_normal((t.size, 2))
    rows = "\n".join(f"{ti:.6g},{a:.10g},{b:.10g}" for ti, (a, b) in zip(t, q, strict=True))
    path.write_text("t,q1,q2\n" + rows + "\n", encoding="utf-8")


def prepare(system: str, folder: Path, seed: int = 0) -> tuple[Path, Path]:
    """(data file, settings file) of ``system`` in ``folder``, its noise drawn with ``seed``."""
    data = folder / f"{system}-{seed}.csv"
    if system == "elastic-pendulum":
        elastic_pendulum_csv(data, seed)
        config = folder / "elastic_pendulum.toml"
        config.write_text(ELASTIC, encoding="utf-8")
        return data, config
    spec = importlib.util.spec_from_file_location("simulate_data", EXAMPLES / "simulate_data.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.write_csv(system, data, seed)
    config = folder / CONFIGS[system]
    shutil.copy(EXAMPLES / CONFIGS[system], config)
    return data, config


# ----------------------------------------------------------------------------- the child
CHILD = r"""
import json, sys, time
import jax
from jax import monitoring
compile_s = {"trace": 0.0, "lower": 0.0, "xla": 0.0}
EVENTS = {"/jax/core/compile/jaxpr_trace_duration": "trace",
          "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
          "/jax/core/compile/backend_compile_duration": "xla"}
def on_duration(name, secs, **_):
    if name in EVENTS:
        compile_s[EVENTS[name]] += secs
monitoring.register_event_duration_secs_listener(on_duration)
from symplid.cli import main
from symplid.io import read_trajectories
try:
    from symplid.workflow._settings import load_settings, resolve_for_data
except ImportError:  # a tree from before the modules were private
    from symplid.workflow.settings import load_settings, resolve_for_data
data, config, out, extra = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4:]
start = time.perf_counter()
resolve_for_data(load_settings(config), read_trajectories([data]), config)
parse = time.perf_counter() - start
start = time.perf_counter()
main(["fit", data, "--config", config, "--out", out, "--no-progress", "--no-report", *extra],
     standalone_mode=False)
fitted = time.perf_counter()
main(["report", out, "--no-progress"], standalone_mode=False)
done = time.perf_counter()
print("BENCH " + json.dumps({"parse": parse, "fit": fitted - start, "report": done - fitted,
                             "compile": sum(compile_s.values()), **compile_s}))
"""


def child_fit(child: str, src: Path, data: Path, config: Path, out: Path, cache: Path,
              extra: list[str], cores: list[int] | None) -> tuple[dict, dict]:
    """Run the script ``child`` (a fit) on the tree ``src`` in its own process, pinned to
    ``cores``; returns the clock it prints on its ``BENCH`` line and the run's summary."""
    # the tree's src first; what the caller put on the path (a package of its own) after it
    path = os.pathsep.join(filter(None, (str(src), os.environ.get("PYTHONPATH"))))
    env = dict(os.environ, PYTHONPATH=path, SYMPLID_CACHE_DIR=str(cache))
    used = resource.getrusage(resource.RUSAGE_CHILDREN)
    proc = subprocess.run([sys.executable, "-c", child, str(data), str(config), str(out),
                           *extra], env=env, capture_output=True, text=True,
                          preexec_fn=None if cores is None else
                          (lambda: os.sched_setaffinity(0, set(cores))), check=False)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    line = next((x for x in proc.stdout.splitlines() if x.startswith("BENCH ")), None)
    if proc.returncode != 0 or line is None:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        raise SystemExit(f"the fit failed with {src}: {' | '.join(tail)}")
    cpu = (after.ru_utime + after.ru_stime) - (used.ru_utime + used.ru_stime)
    return ({**json.loads(line[6:]), "cpu": cpu},
            json.loads((out / "summary.json").read_text()))


def run_child(src: Path, data: Path, config: Path, out: Path, cache: Path, extra: list[str],
              cores: list[int] | None) -> dict:
    clock, summary = child_fit(CHILD, src, data, config, out, cache, extra, cores)
    t = summary.get("timings", {})
    wall = clock["parse"] + clock["fit"] + clock["report"]
    ess = min(summary.get("ess_min", float("nan")),
              summary.get("ess_tail_min", summary.get("ess_min", float("nan"))))
    rhat = summary.get("rhat_max", float("nan"))
    sampling = t.get("sampler_s", float("nan"))
    reached = bool(rhat <= 1.01 and ess >= 400)
    return {"parse": clock["parse"], "compile": clock["compile"], "trace": clock["trace"],
            "lower": clock["lower"], "xla": clock["xla"], "map": t.get("map_s"),
            "refits": t.get("diagnostics_s", 0.0), "sampling": sampling,
            "report": clock["report"], "wall": wall, "cpu": clock["cpu"],
            "load": os.getloadavg()[0], "ess_per_s": ess / sampling,
            "target": wall if reached else None, "rhat": rhat, "ess": ess}


def two_cores() -> list[int] | None:
    if not hasattr(os, "sched_getaffinity"):
        return None
    return sorted(os.sched_getaffinity(0))[:2]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, action="append", default=[],
                        help="another checkout's src folder (again for more than one)")
    parser.add_argument("--systems", nargs="+", choices=SYSTEMS, default=list(SYSTEMS))
    parser.add_argument("--iterations", type=int, help="iterations per chain (with --burn-in)")
    parser.add_argument("--burn-in", type=int)
    parser.add_argument("--states", nargs="+", choices=STATES, default=list(STATES),
                        help="which runs (a cold run always comes first when asked)")
    args = parser.parse_args()
    extra = [] if args.iterations is None else ["--iterations", str(args.iterations)]
    extra += [] if args.burn_in is None else ["--burn-in", str(args.burn_in)]
    trees = {"this tree": SRC}
    baselines = {_tree_name(path, len(args.baseline)): path.resolve() for path in args.baseline}
    trees = {**baselines, **trees}
    cores = two_cores()
    print(f"load average before: {os.getloadavg()[0]:.2f}; cores {cores}")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for system in args.systems:
            data, config = prepare(system, folder)
            other, _ = prepare(system, folder, seed=1)
            caches = {name: folder / f"cache-{i}" for i, name in enumerate(trees)}
            for cache_state in (x for x in STATES if x in args.states):
                for name, src in trees.items():
                    out = folder / f"run-{system}-{name}-{cache_state}".replace(" ", "")
                    given = other if cache_state == "new data" else data
                    result = run_child(src, given, config, out, caches[name], extra, cores)
                    rows.append((system, name, cache_state, result))
                    print(_row(system, name, cache_state, result), flush=True)
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    _print_table(rows)


HEADER = ("| system | tree | cache | parse | compile (trace + lower + XLA) | MAP | refits "
          "| sampling | report | wall | CPU s | load | ESS/s | to target |")


def _row(system: str, tree: str, cache: str, r: dict) -> str:
    target = "not reached" if r["target"] is None else f"{r['target']:.1f}"
    return (f"| {system} | {tree} | {cache} | {r['parse']:.2f} | {r['compile']:.1f} "
            f"({r['trace']:.1f} + {r['lower']:.1f} + {r['xla']:.1f}) | "
            f"{r['map']:.1f} | {r['refits']:.1f} | {r['sampling']:.1f} | {r['report']:.1f} | "
            f"{r['wall']:.1f} | {r['cpu']:.1f} | {r['load']:.1f} | {r['ess_per_s']:.1f} | "
            f"{target} |")


def _print_table(rows: list[tuple[str, str, str, dict]]) -> None:
    print("\nseconds (compile overlaps the phases that compile)\n")
    print(HEADER)
    print("|---" * 14 + "|")
    for row in rows:
        print(_row(*row))
    by = {(s, t, c): r for s, t, c, r in rows}
    baselines = sorted({t for _, t, _, _ in rows if t != "this tree"})
    for system, tree, cache, r in rows:
        for name in baselines if tree == "this tree" else ():
            base = by.get((system, name, cache))
            if base is not None:
                same = at_same_ess(base, r["ess"])
                print(f"{system} ({cache}): wall this/{name} {r['wall'] / base['wall']:.2f}, "
                      f"CPU {r['cpu'] / base['cpu']:.2f}, "
                      f"compile {r['compile'] / max(base['compile'], 1e-9):.2f}; "
                      f"{name} at this tree's ESS {r['ess']:.0f} ≈ {same:.1f} s, "
                      f"this/{name} at the same ESS {r['wall'] / same:.2f}")


def at_same_ess(base: dict, ess: float) -> float:
    """The wall time the run ``base`` would have taken to the ESS ``ess`` (an estimate):
    its fixed costs (everything but sampling) plus its sampling time scaled by the share of
    its ESS that ``ess`` is. ESS grows in proportion to the draws kept, so this assumes the
    baseline's burn-in shrinks in proportion too: the estimate is low when it would not, and
    the ratio printed beside it is then in the baseline's favour."""
    share = min(1.0, ess / base["ess"]) if base["ess"] > 0 else 1.0
    return base["wall"] - base["sampling"] * (1.0 - share)


def _tree_name(src: Path, count: int) -> str:
    """``baseline`` for the one baseline, else the name of the checkout (the folder above
    its ``src``)."""
    return "baseline" if count == 1 else src.resolve().parent.name


if __name__ == "__main__":
    main()
