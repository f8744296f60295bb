"""How soon a stop is obeyed while the sampler runs, and what the paced calls cost.

Each measurement runs once per source tree given (``--trees``: folders put first on
``PYTHONPATH``, e.g. this checkout's ``src`` and a baseline's), in the same run, so that the
figures compare on one machine under one load:

``latency``
    A subprocess ``symplid fit`` of a small oscillator (order 2, two chains, NUTS, one chunk of
    ``--chunk`` iterations) is sent SIGTERM ``--after`` seconds after sampling begins (its
    ``sampler_attrs.json`` appears); prints the seconds from the signal to the last chunk file
    (the iterations kept) and to the process's exit (saving included), and the iterations
    done.
``throughput``
    ``sample()`` with DRAM on the same posterior, compiled first, then timed (min over
    ``--repeats``): the cost of running a chunk as paced calls against one call.

Not a test: run it by hand, e.g.::

    python benchmarks/stop_by_time.py latency --trees src /tmp/main/src
    python benchmarks/stop_by_time.py throughput --trees src /tmp/main/src
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

FIT = ["--order", "2", "--x0", "1,0", "--chains", "2", "--no-progress", "--no-report",
       "--set", "map.num_starts=1", "--set", "map.sensitivity=false",
       "--set", "map.evidence=laplace"]
FIT += ["--dt", "0.25"]  # a fixed step: the workload of the measurements before "auto"

_THROUGHPUT = """
import sys, time
from symplid.io import read_observations
from symplid.inference.map import find_map
from symplid.sampling import sample
from symplid.workflow._fit import build_model, build_posterior
from symplid.workflow._settings import Settings, merge_overrides, resolve_for_data
obs = read_observations(sys.argv[1])
s = merge_overrides(Settings(), {"model.order": 2, "model.dt": 0.25,
                                 "initial_state.x0": [1.0, 0.0]}, source="b")
s = resolve_for_data(s, obs, "b")
post = build_posterior(s, obs, build_model(s, obs))
init = find_map(post, seed=0, num_starts=1)
budget = dict(num_draws=20000, burn_in=0, num_chains=4, seed=1, init=init)
import inspect
if "options" in inspect.signature(sample).parameters:  # the runner's options object
    from symplid.sampling import RunOptions
    budget["options"] = RunOptions(chunk_size=2000, progress=False)
else:  # a tree from before it
    budget.update(chunk_size=2000, progress=False)
sample(post, "dram", **budget)  # compiles
times = []
for _ in range(int(sys.argv[2])):
    start = time.perf_counter()
    sample(post, "dram", **budget)
    times.append(time.perf_counter() - start)
print(min(times))
"""


def _data(folder: Path) -> Path:
    t = np.arange(1, 13.0)
    rng = np.random.default_rng(0)
    q = np.cos(t) + 0.02 * rng.normal(size=t.size)
    p = -np.sin(t) + 0.02 * rng.normal(size=t.size)
    path = folder / "h.csv"
    path.write_text("t,q1,p1\n" + "".join(f"{a!r},{b!r},{c!r}\n" for a, b, c in
                                         zip(t.tolist(), q.tolist(), p.tolist(), strict=True)))
    return path


def _environment(tree: str) -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(Path(tree).resolve())}


def latency(tree: str, data: Path, folder: Path, chunk: int, after: float) -> str:
    out = folder / f"run-{abs(hash(tree))}"
    fit = subprocess.Popen([sys.executable, "-m", "symplid.cli", "fit", str(data), "--out",
                            str(out), "--method", "nuts", "--iterations", str(20 * chunk),
                            "--burn-in", "100", "--set", f"sampler.chunk_size={chunk}", *FIT],
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                           env=_environment(tree))
    attrs = out / "sampler_attrs.json"
    while not attrs.exists():
        if fit.poll() is not None:
            return f"ended before sampling (exit {fit.returncode})"
        time.sleep(0.01)
    time.sleep(after)
    fit.send_signal(signal.SIGTERM)
    sent_wall, sent = time.time(), time.perf_counter()
    fit.wait()
    exited = time.perf_counter() - sent
    chunks = sorted((out / "draws").glob("chunk-*.npz"))
    if not chunks:
        return f"exit {fit.returncode} after {exited:.1f} s, no chunk kept"
    with np.load(chunks[-1]) as last:
        done = int(last["done"])
    kept = chunks[-1].stat().st_mtime - sent_wall
    return (f"exit {fit.returncode}; last chunk written {kept:.1f} s after the signal, exit "
            f"after {exited:.1f} s; {done:,} iterations done")


def throughput(tree: str, data: Path, repeats: int) -> str:
    done = subprocess.run([sys.executable, "-c", _THROUGHPUT, str(data), str(repeats)],
                          capture_output=True, text=True, env=_environment(tree), check=True)
    seconds = float(done.stdout.split()[-1])
    return f"4 chains x 20,000 DRAM iterations: {seconds:.3f} s ({seconds / 80000 * 1e6:.2f} us/it)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("what", choices=["latency", "throughput"])
    parser.add_argument("--trees", nargs="+", required=True)
    parser.add_argument("--chunk", type=int, default=100_000)
    parser.add_argument("--after", type=float, default=5.0)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    print(f"load: {os.getloadavg()[0]:.1f} (1-minute average)")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        data = _data(folder)
        for tree in args.trees:
            if args.what == "latency":
                line = latency(tree, data, folder, args.chunk, args.after)
            else:
                line = throughput(tree, data, args.repeats)
            print(f"{tree}: {line}")
    print(f"load: {os.getloadavg()[0]:.1f} (1-minute average)")


if __name__ == "__main__":
    main()
