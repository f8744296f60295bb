"""How fast a signal stops ``symplid fit``, and what streaming the draws to disk costs.

Two measurements on the paper's Hénon–Heiles data (``symplid simulate henon-heiles``) with the
default settings (cubic potential, 4 MAP starts, DRAM with 4 chains, chunks of
``sampler.chunk_size`` iterations):

``latency``
    A subprocess fit is sent SIGINT, SIGTERM and SIGHUP in turn, in the MAP phase (a delay
    after ``data.csv`` appears) and in sampling (a delay after the first chunk file appears);
    prints the seconds from the signal to the process's exit, min / median / max per phase,
    and the phase the run folder's marker says it stopped in.
``overhead``
    The same sampling run (after a warm-up that compiles) with the chunks written to a folder
    and without; prints the min over repeats of each and the relative difference. Run it on
    one core for a stable figure::

        taskset -c 0 python benchmarks/signals_and_chunks.py overhead

Not a test: run it by hand, e.g. ``python benchmarks/signals_and_chunks.py latency --repeats 5``.
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
CLI = [sys.executable, "-m", "symplid.cli"]


def _data(folder: Path) -> Path:
    path = folder / "hh.csv"
    subprocess.run([*CLI, "simulate", "henon-heiles", "--out", str(path)], check=True,
                   stdout=subprocess.DEVNULL)
    return path


def _wait_for(path: Path, fit: subprocess.Popen) -> None:
    while not path.exists():
        if fit.poll() is not None:
            raise RuntimeError(f"the fit ended (exit {fit.returncode}) before {path} appeared")
        time.sleep(0.005)


def _default_sigint() -> None:
    """SIGINT as in a terminal: a background job starts with it ignored, and a signal ignored
    when symplid starts stays ignored."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _one_stop(data: Path, out: Path, phase: str, signum: int, delay: float) -> tuple[float, str]:
    fit = subprocess.Popen([*CLI, "fit", str(data), "--out", str(out), "--x0",
                            "0.2,-0.25,0.3,-0.25", "--no-progress", "--no-report",
                            "--iterations", "200000", "--burn-in", "2000", "--dt", "0.25"],
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                           preexec_fn=_default_sigint)
    trigger = out / "data.csv" if phase == "map" else out / "draws" / "chunk-000000.npz"
    _wait_for(trigger, fit)
    time.sleep(delay)
    sent = time.perf_counter()
    fit.send_signal(signum)
    code = fit.wait()
    seconds = time.perf_counter() - sent
    marker = (out / ".incomplete").read_text().splitlines()[0]
    if code != 128 + signum:
        raise RuntimeError(f"exit {code} after signal {signum}: {marker}")
    return seconds, "sampling" if marker.startswith("interrupted:") else "before sampling"


def latency(repeats: int, phases: tuple[str, ...] = ("map", "sampling")) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        data = _data(folder)
        print("| signal sent in | stopped in | n | min s | median s | max s |")
        print("|---|---|---|---|---|---|")
        delays_of = {"map": (0.5, 1.0, 2.0, 3.0, 4.0), "sampling": (0.0, 0.1, 0.3, 0.6, 1.0)}
        for phase in phases:
            delays = delays_of[phase]
            found: dict[str, list[float]] = {}
            for k in range(repeats):
                signum = SIGNALS[k % len(SIGNALS)]
                seconds, where = _one_stop(data, folder / f"{phase}{k}", phase, signum,
                                           delays[k % len(delays)])
                found.setdefault(where, []).append(seconds)
            for where, values in found.items():
                print(f"| {phase} | {where} | {len(values)} | {min(values):.2f} | "
                      f"{statistics.median(values):.2f} | {max(values):.2f} |")


def overhead(repeats: int, iterations: int) -> None:
    import dataclasses

    import symplid
    from symplid.io._chunks import ChunkWriter
    from symplid.workflow._fit import build_model, build_posterior, find_map_for, sample_for
    from symplid.workflow._settings import Settings, resolve_for_data

    hh = symplid.get_system("henon-heiles")
    obs = symplid.simulate(hh, seed=0)
    base = Settings()
    base = dataclasses.replace(
        base, initial_state=dataclasses.replace(base.initial_state, x0=tuple(hh.initial_state)),
        model=dataclasses.replace(base.model, dt=0.25),  # the paper's step, not "auto"
        sampler=dataclasses.replace(base.sampler, num_iterations=iterations,
                                    burn_in=iterations // 2))
    settings = resolve_for_data(base, obs, "benchmark")
    posterior = build_posterior(settings, obs, build_model(settings, obs))
    map_fit = find_map_for(settings, posterior)
    times: dict[str, list[float]] = {"chunks off": [], "chunks on": []}
    with tempfile.TemporaryDirectory() as tmp:
        sample_for(settings, posterior, map_fit, progress=False)  # compiles
        for k in range(repeats):
            for label in times:
                sink = ChunkWriter(Path(tmp) / f"draws{k}") if label == "chunks on" else None
                idata = sample_for(settings, posterior, map_fit, progress=False, sink=sink)
                times[label].append(float(idata.attrs["sampling_seconds"]))
    off, on = min(times["chunks off"]), min(times["chunks on"])
    chunks = -(-iterations // settings.sampler.chunk_size)
    print(f"{iterations:,} iterations x {settings.sampler.num_chains} chains, {chunks} chunks "
          f"of {settings.sampler.chunk_size}; min of {repeats} (cores allowed: "
          f"{len(os.sched_getaffinity(0))})")
    print(f"chunks off: {off:.3f} s, chunks on: {on:.3f} s, overhead {100 * (on / off - 1):+.1f} %"
          f" ({1000 * (on - off) / chunks:.1f} ms per chunk)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", choices=("latency", "overhead"))
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--iterations", type=int, default=40_000)
    parser.add_argument("--phases", default="map,sampling", help="latency: map, sampling or both")
    args = parser.parse_args()
    if args.what == "latency":
        latency(args.repeats, tuple(args.phases.split(",")))
    else:
        overhead(args.repeats, args.iterations)


if __name__ == "__main__":
    main()
