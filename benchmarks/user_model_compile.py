"""The compile time of a user's expression model, against a baseline source tree in the same run.

Workload: a potential of ``N`` distinct monomial terms in two coordinates,
``k*q1^2 + k*q2^2 + Σ c_ij q1^i q2^j`` (fixed tiny numbers c_ij, total degree 3..),
declared with one parameter ``k``; 20 full-state observations of a harmonic oscillator; the
posterior's ``value_and_grad`` (leapfrog, dt = 0.25). Timed per size: reading the expression
(SymPy: parse, split, code generation), and the first call of the jitted value and gradient
(tracing plus XLA's compilation), with the child's peak resident memory. The value and
gradient at a fixed θ are printed, so that the trees can be compared to the last digit.

Each tree (this checkout's ``src``, and ``--baseline SRC`` if given) runs in its own child
process, one per size, the trees taking turns. The machine may be shared: read the ratios.

Run: ``python benchmarks/user_model_compile.py [--baseline ../main/src] [--sizes 30,100]``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
SRC = HERE.parent / "src"


def expression(size: int) -> str:
    """``k*q1^2 + k*q2^2`` and ``size - 2`` more distinct monomials of degree 3 and above."""
    terms = ["k*q1^2", "k*q2^2"]
    degree = 3
    while len(terms) < size:
        for i in range(degree + 1):
            if len(terms) == size:
                break
            c = 1e-4 / (1 + len(terms))
            terms.append(f"{c:.6g}*q1^{degree - i}*q2^{i}")
        degree += 1
    return " + ".join(terms)


def child(size: int) -> dict:
    """One measurement in this process (run by the parent with a tree's ``src`` first)."""
    import jax
    import numpy as np

    jax.config.update("jax_enable_x64", True)
    import resource

    import symplid
    from symplid.workflow._building import build_model, build_posterior
    from symplid.workflow._settings import resolve_for_data, settings_from_dict

    t = np.arange(1.0, 21.0)
    values = np.column_stack([np.cos(t), 0.5 * np.sin(t), -np.sin(t), 0.5 * np.cos(t)])
    obs = symplid.Observations(t, values, ("q1", "q2", "p1", "p2"))
    settings = resolve_for_data(settings_from_dict({
        "initial_state": {"x0": [1.0, 0.0, 0.0, 0.5]},
        "model": {"potential": expression(size), "dt": 0.25,
                  "parameters": {"k": {"prior": "half-normal", "scale": 2.0}}}}), obs)
    start = time.perf_counter()
    model = build_model(settings, obs)
    posterior = build_posterior(settings, obs, model)
    parse = time.perf_counter() - start
    fn = posterior.value_and_grad()
    theta = np.array([0.5, 1e-3, 1e-3, 1e-3][: posterior.num_params])
    start = time.perf_counter()
    value, grad = fn(theta)
    jax.block_until_ready(grad)
    compile_s = time.perf_counter() - start
    start = time.perf_counter()
    for _ in range(5):
        jax.block_until_ready(fn(theta)[1])
    call = (time.perf_counter() - start) / 5
    return {"size": size, "parse_s": parse, "compile_s": compile_s, "call_ms": 1e3 * call,
            "value": float(value), "grad": [float(g) for g in np.asarray(grad)],
            "max_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def measure(src: Path, size: int) -> dict:
    env = dict(os.environ, PYTHONPATH=str(src))
    out = subprocess.run([sys.executable, __file__, "--child", str(size)], env=env,
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, help="another checkout's src folder")
    parser.add_argument("--sizes", default="30,100", help="numbers of terms, comma-separated")
    parser.add_argument("--child", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child is not None:
        print(json.dumps(child(args.child)))
        return
    trees = {"this": SRC} | ({"baseline": args.baseline} if args.baseline else {})
    print(f"load: {os.getloadavg()[0]:.2f}")
    print("| size | tree | parse (s) | value+grad first call (s) | later call (ms) | "
          "peak RSS (MB) | value |")
    print("|---:|---|---:|---:|---:|---:|---:|")
    for size in (int(s) for s in args.sizes.split(",")):
        results = {name: measure(src, size) for name, src in trees.items()}
        for name, r in results.items():
            print(f"| {size} | {name} | {r['parse_s']:.2f} | {r['compile_s']:.2f} | "
                  f"{r['call_ms']:.2f} | {r['max_rss_mb']:.0f} | {r['value']:.12g} |")
        if "baseline" in results:
            a, b = results["this"], results["baseline"]
            diff = max(abs(x - y) / max(abs(y), 1e-300) for x, y in
                       zip([a["value"], *a["grad"]], [b["value"], *b["grad"]], strict=True))
            print(f"|  | ratio this/baseline | {a['parse_s'] / b['parse_s']:.2f} | "
                  f"{a['compile_s'] / b['compile_s']:.2f} | {a['call_ms'] / b['call_ms']:.2f} |"
                  f"  | max rel. diff {diff:.1e} |")
    print(f"load: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
