"""The cost of a run's report (``symplid report``, the end of ``symplid fit``), against a
baseline tree in the same run.

Workload: the report of a finished fit of the examples' Kepler and Lotka–Volterra models
(``examples/user_models``, data by its ``simulate_data.py``, the examples' own budgets: 4
chains of 9,000 kept draws), or of the run folders given with ``--runs``. The fits are made
once, by this tree, untimed (``symplid fit ... --no-report``).

Each tree (this checkout's ``src``, and ``--baseline SRC``: another checkout's ``src``
folder) reports on its own copy of each run folder in its own child process, pinned to the
same two cores, the trees taking turns; the child enables the compilation cache as the
command line does (a cache of the tree's own, filled by one untimed report first), then
times ``--repeats`` reports. Reported per run and tree (minimum over the repeats): the wall
and CPU seconds of the whole report, of building the figures (``report_figures``: the
posterior predictive paths included) and of writing them (``save_atomically``: layout,
drawing, PNG encoding), the ratio baseline / this tree, and per figure the share of pixels
that differ from the baseline's PNG. The machine may be shared: the load average is printed;
compare the ratios and the CPU seconds.

The paper's four figures (``symplid reproduce``, which writes no trace or pair plot) are timed
the same way, drawn and saved from arrays of a reproduction's shapes (200 s stored every 0.1 s,
100 sample paths per approach, 4 × 100,000 process-noise draws; ``--no-paper`` leaves them out).

Run: ``python benchmarks/report_figures.py [--baseline OLD/src] [--repeats 3]
[--runs RUN ...] [--systems kepler lotka-volterra] [--no-paper]``.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
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
CONFIGS = {"kepler": "kepler.toml", "lotka-volterra": "lotka_volterra.toml"}

CHILD = r"""
import json, sys, time
from symplid import runtime
runtime.enable_compilation_cache()
from symplid.workflow import _run_tools
run, repeats = sys.argv[1], int(sys.argv[2])
spent = {}
def timed(name):
    inner = getattr(_run_tools, name)
    def wrapper(*args, **kwargs):
        wall, cpu = time.perf_counter(), time.process_time()
        try:
            return inner(*args, **kwargs)
        finally:
            w, c = spent.get(name, (0.0, 0.0))
            spent[name] = (w + time.perf_counter() - wall, c + time.process_time() - cpu)
    setattr(_run_tools, name, wrapper)
timed("report_figures")
timed("save_atomically")
_run_tools.report_run(run)  # untimed: imports, the cache filled
rows = []
for _ in range(repeats):
    spent.clear()
    wall, cpu = time.perf_counter(), time.process_time()
    _run_tools.report_run(run)
    rows.append({"wall": time.perf_counter() - wall, "cpu": time.process_time() - cpu,
                 "build": spent["report_figures"][0], "build_cpu": spent["report_figures"][1],
                 "save": spent["save_atomically"][0], "save_cpu": spent["save_atomically"][1]})
print("BENCH " + json.dumps(rows))
"""

# The paper's four figures (``symplid reproduce``) from arrays of a reproduction's shapes:
# 200 s stored every 0.1 s, 100 sample paths per approach, 4 × 100,000 process-noise draws.
PAPER = r"""
import json, sys, time
from pathlib import Path
import numpy as np
from symplid.plotting import (Curves, plot_hamiltonians, plot_phase_portraits,
                              plot_process_noise, plot_trajectory_bands)
out, repeats = Path(sys.argv[1]), int(sys.argv[2])
rng = np.random.default_rng(0)
t = np.linspace(0.0, 200.0, 2001)
orbit = np.column_stack([np.cos(t), np.sin(1.3 * t), -np.sin(t), 1.3 * np.cos(1.3 * t)]) * 0.4
def approach(label, scale):  # smooth sample paths that drift apart, as the models' do
    rate = 1.0 + 0.02 * scale * rng.standard_normal((100, 1))
    paths = 0.4 * scale * np.cos(rate * t)
    return (Curves(label, t, orbit[:, 0] * scale, samples=paths,
                   lower=np.quantile(paths, 0.025, 0), upper=np.quantile(paths, 0.975, 0)),
            Curves(label, t, 0.1227 + 0.001 * np.sin(t) * scale,
                   samples=0.1227 + 1e-3 * rng.standard_normal((100, 1))
                   + 2e-4 * np.sin(rate * t)))
(lf_q, lf_h), (rk_q, rk_h) = approach("leapfrog", 1.0), approach("RK2", 1.05)
noise = {"leapfrog": np.exp(rng.normal(np.log(5e-6), 0.4, (4, 100_000))),
         "RK2": np.exp(rng.normal(np.log(1e-4), 0.4, (4, 100_000)))}
figures = {
    "fig1_phase_portraits": lambda p: plot_phase_portraits(
        {"learned with leapfrog": orbit * 1.01, "learned with RK2": orbit * 0.98}, orbit,
        orbit[:1000:50, :2] + 0.02, path=p),
    "fig2_hamiltonians": lambda p: plot_hamiltonians(
        [lf_h, rk_h], (t, np.full_like(t, 0.1227)),
        [Curves("RK2 by RK2", t, 0.1227 + 1e-4 * t)], t_data_end=100.0, path=p),
    "fig3_trajectories": lambda p: plot_trajectory_bands(
        [lf_q, rk_q], truth=(t, orbit[:, 0]), data=(t[:1000:50], orbit[:1000:50, 0]),
        t_data_end=100.0, path=p),
    "fig4_process_noise": lambda p: plot_process_noise(
        noise, {"leapfrog": 5e-6, "RK2": 1e-4}, path=p),
}
for name, draw in figures.items():
    draw(out / f"{name}.png")  # untimed: imports, fonts
rows = []
for _ in range(repeats):
    wall, cpu = time.perf_counter(), time.process_time()
    for name, draw in figures.items():
        draw(out / f"{name}.png")
    rows.append({"wall": time.perf_counter() - wall, "cpu": time.process_time() - cpu})
print("BENCH " + json.dumps(rows))
"""


def two_cores() -> list[int] | None:
    """The first two cores this process may use (None where affinity is not available)."""
    if not hasattr(os, "sched_getaffinity"):
        return None
    return sorted(os.sched_getaffinity(0))[:2]


def child(src: Path, args: list[str], cores: list[int] | None, cache: Path,
          script: str | None = None) -> subprocess.CompletedProcess:
    """``python -c script args`` (or ``python -m symplid.cli args``) with ``src`` first on
    the path, the compilation cache in ``cache``, pinned to ``cores``."""
    path = os.pathsep.join(filter(None, (str(src), os.environ.get("PYTHONPATH"))))
    env = dict(os.environ, PYTHONPATH=path, SYMPLID_CACHE_DIR=str(cache))
    command = ["-c", script] if script is not None else ["-m", "symplid.cli"]
    proc = subprocess.run([sys.executable, *command, *args], env=env, capture_output=True,
                          text=True, check=False,
                          preexec_fn=None if cores is None else
                          (lambda: os.sched_setaffinity(0, set(cores))))
    if proc.returncode != 0:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        raise SystemExit(f"{src}: {' '.join(args[:2])} failed: {' | '.join(tail)}")
    return proc


def fit(system: str, folder: Path, cores: list[int] | None) -> Path:
    """A finished run of ``system``'s example (no report), fitted by this tree."""
    spec = importlib.util.spec_from_file_location("simulate_data", EXAMPLES / "simulate_data.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    data = folder / f"{system}.csv"
    module.write_csv(system, data, 0)
    out = folder / f"run-{system}"
    print(f"fitting {system} (untimed) ...", flush=True)
    child(SRC, ["fit", str(data), "--config", str(EXAMPLES / CONFIGS[system]), "--out",
                str(out), "--no-progress", "--no-report"], cores, folder / "cache-fit")
    return out


def report(src: Path, run: Path, copy: Path, repeats: int, cores: list[int] | None,
           cache: Path) -> dict:
    """The best of ``repeats`` reports on a copy of ``run`` by the tree ``src``."""
    shutil.rmtree(copy, ignore_errors=True)
    shutil.copytree(run, copy)
    proc = child(src, [str(copy), str(repeats)], cores, cache, CHILD)
    line = next(x for x in proc.stdout.splitlines() if x.startswith("BENCH "))
    rows = json.loads(line[6:])
    best = {key: min(r[key] for r in rows) for key in rows[0]}
    return {**best, "load": os.getloadavg()[0]}


def paper(src: Path, folder: Path, repeats: int, cores: list[int] | None, cache: Path) -> dict:
    """The best of ``repeats`` drawings of the paper's four figures by the tree ``src``."""
    shutil.rmtree(folder, ignore_errors=True)
    (folder / "figures").mkdir(parents=True)
    proc = child(src, [str(folder / "figures"), str(repeats)], cores, cache, PAPER)
    line = next(x for x in proc.stdout.splitlines() if x.startswith("BENCH "))
    rows = json.loads(line[6:])
    return {"wall": min(r["wall"] for r in rows), "cpu": min(r["cpu"] for r in rows),
            "load": os.getloadavg()[0], "folder": folder}


def differing_pixels(a: Path, b: Path) -> str:
    """The share of pixels that differ between two PNGs (or that their sizes differ)."""
    from PIL import Image

    x = np.asarray(Image.open(a).convert("RGBA"), dtype=int)
    y = np.asarray(Image.open(b).convert("RGBA"), dtype=int)
    if x.shape != y.shape:
        return f"size {x.shape[1]}×{x.shape[0]} → {y.shape[1]}×{y.shape[0]}"
    return f"{100 * np.mean(np.any(x != y, axis=-1)):.2f} %"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, help="another checkout's src folder")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--systems", nargs="+", choices=sorted(CONFIGS),
                        default=sorted(CONFIGS))
    parser.add_argument("--runs", nargs="+", type=Path, help="finished run folders to report on "
                        "(instead of fitting the systems' examples)")
    parser.add_argument("--no-paper", action="store_true",
                        help="leave out the paper's four figures")
    args = parser.parse_args()
    trees = {"this tree": SRC}
    if args.baseline is not None:
        trees = {"baseline": args.baseline.resolve(), **trees}
    cores = two_cores()
    with tempfile.TemporaryDirectory(prefix="symplid-report-bench-") as tmp:
        tmp_path = Path(tmp)
        runs = ({p.name: p.resolve() for p in args.runs} if args.runs else
                {s: fit(s, tmp_path, cores) for s in args.systems})
        results: dict[tuple[str, str], dict] = {}
        for name, run in runs.items():
            for tree, src in trees.items():
                copy = tmp_path / tree.replace(" ", "-") / name
                results[name, tree] = report(src, run, copy, args.repeats, cores,
                                             tmp_path / f"cache-{tree.replace(' ', '-')}")
                results[name, tree]["folder"] = copy
        if not args.no_paper:
            for tree, src in trees.items():
                results["paper figures", tree] = paper(
                    src, tmp_path / tree.replace(" ", "-") / "paper", args.repeats, cores,
                    tmp_path / f"cache-{tree.replace(' ', '-')}")
        print_table(results, trees, args.repeats, cores)


def print_table(results: dict, trees: dict, repeats: int, cores: list[int] | None) -> None:
    print(f"\nreport of a finished run: minimum of {repeats} repeats per tree, pinned to cores "
          f"{cores}; seconds (wall / CPU)")
    head = f"{'run':<16} {'tree':<10} {'report':>13} {'build figures':>15} {'save figures':>15}"
    print(head + f" {'ratio':>12} {'load':>5}")
    for (name, tree), r in results.items():
        base = results.get((name, "baseline"))
        ratio = ("" if base is None or tree == "baseline" else
                 f"{base['wall'] / r['wall']:.2f}/{base['cpu'] / r['cpu']:.2f}")
        parts = (f"{r['build']:7.2f}/{r['build_cpu']:7.2f} {r['save']:7.2f}/{r['save_cpu']:7.2f}"
                 if "build" in r else f"{'':>15} {'':>15}")
        print(f"{name:<16} {tree:<10} {r['wall']:6.2f}/{r['cpu']:6.2f} {parts} {ratio:>12} "
              f"{r['load']:5.1f}")
    if "baseline" not in trees:
        return
    print("\npixels that differ from the baseline's figure")
    for name in dict.fromkeys(n for n, _ in results):
        this, base = results[name, "this tree"]["folder"], results[name, "baseline"]["folder"]
        for png in sorted((base / "figures").glob("*.png")):
            share = differing_pixels(png, this / "figures" / png.name)
            print(f"  {name:<16} {png.name:<16} {share}")


if __name__ == "__main__":
    main()
