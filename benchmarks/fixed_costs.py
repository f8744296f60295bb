"""The cost of ``symplid reproduce`` end to end, against a baseline source tree in the same run.

Workload: ``symplid reproduce --out DIR --no-progress`` (the paper's experiment at its full
budget: two approaches, 4 chains × 200,000 DRAM iterations each, figures), with a warm
compilation cache (one untimed run per tree first, unless ``--no-warmup``).

Each tree (this checkout's ``src``, and ``--baseline SRC`` if given: another checkout's
``src`` folder, e.g. the last release's) runs in its own child process, restricted to the
same two cores (``taskset``-style affinity on the first two this process may use), the trees
taking turns, ``--repeats`` times each. Reported per tree: the wall time (minimum over the
repeats), the CPU time of the whole process tree (user + system, at that minimum), each
worker's MAP and DRAM seconds (from its ``summary.json``), and whether the printed table is
identical to the first tree's line for line (it must be: the numbers do not depend on how
the work is scheduled). The machine may be shared: read the ratios and the CPU seconds.

Run: ``python benchmarks/fixed_costs.py [--baseline ../other/src] [--repeats 2]``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
SRC = HERE.parent / "src"
TABLE_START = "this run"  # the header of the printed table
TABLE_END = "Run folder:"


def two_cores() -> list[int] | None:
    """The first two cores this process may use (None where affinity is not available)."""
    if not hasattr(os, "sched_getaffinity"):
        return None
    return sorted(os.sched_getaffinity(0))[:2]


def run_once(src: Path, out: Path, cores: list[int] | None) -> dict:
    """One ``symplid reproduce`` with ``src`` first on the path; wall, CPU, table, timings."""
    env = dict(os.environ, PYTHONPATH=str(src))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "symplid.cli", "reproduce", "--out", str(out),
                             "--no-progress"], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                            preexec_fn=None if cores is None else
                            (lambda: os.sched_setaffinity(0, set(cores))))
    stdout, _ = proc.communicate()
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"reproduce failed with {src} (exit {proc.returncode})")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    lines = stdout.splitlines()
    first = next(i for i, line in enumerate(lines) if TABLE_START in line)
    last = next(i for i, line in enumerate(lines) if line.startswith(TABLE_END))
    timings = {}
    for approach in ("leapfrog", "rk2"):
        summary = json.loads((out / approach / "summary.json").read_text())
        timings[approach] = summary.get("timings", {})
    return {"wall": wall, "cpu": cpu, "table": lines[first:last], "timings": timings}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, help="another checkout's src folder")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--no-warmup", action="store_true")
    args = parser.parse_args()
    trees = {"this tree": SRC}
    if args.baseline is not None:
        trees = {"baseline": args.baseline.resolve(), **trees}
    cores = two_cores()
    work = Path(tempfile.mkdtemp(prefix="symplid-fixed-costs-"))
    try:
        if not args.no_warmup:
            for name, src in trees.items():
                run_once(src, work / f"warm-{name.replace(' ', '-')}", cores)
        runs: dict[str, list[dict]] = {name: [] for name in trees}
        for k in range(args.repeats):
            for name, src in trees.items():  # the trees take turns
                out = work / f"{name.replace(' ', '-')}-{k}"
                runs[name].append(run_once(src, out, cores))
                shutil.rmtree(out, ignore_errors=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    report(runs, cores)


def report(runs: dict[str, list[dict]], cores: list[int] | None) -> None:
    reference = next(iter(runs.values()))[0]["table"]
    print(f"symplid reproduce, warm cache, cores {cores}; min wall over "
          f"{len(next(iter(runs.values())))} repeat(s)")
    print(f"{'tree':<10} {'wall s':>7} {'CPU s':>7} {'MAP s lf/rk2':>14} "
          f"{'DRAM s lf/rk2':>14}  table")
    best = {}
    for name, done in runs.items():
        b = min(done, key=lambda r: r["wall"])
        best[name] = b
        t = b["timings"]
        same = all(r["table"] == reference for r in done)
        print(f"{name:<10} {b['wall']:7.1f} {b['cpu']:7.1f} "
              f"{t['leapfrog'].get('map_s', 0):6.1f}/{t['rk2'].get('map_s', 0):<6.1f} "
              f"{t['leapfrog'].get('sampler_s', 0):6.1f}/{t['rk2'].get('sampler_s', 0):<6.1f}  "
              f"{'identical' if same else 'DIFFERS'}")
    if len(best) == 2:
        base, new = best["baseline"], best["this tree"]
        print(f"ratio this/baseline: wall {new['wall'] / base['wall']:.2f}, "
              f"CPU {new['cpu'] / base['cpu']:.2f}")
    print("\n".join(reference))


if __name__ == "__main__":
    main()
