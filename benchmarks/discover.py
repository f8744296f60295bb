"""Which terms? ``symplid discover`` against PySINDy's sequential thresholding.

For each case and each data seed, both methods are given the same noisy observations and the
same library of terms, and each returns a set of terms with coefficients:

* ``hh20``: Hénon–Heiles (the paper's eq. 15), the paper's 20 full-state observations 5 s
  apart with noise sd 0.05, the 9-term cubic library; true terms ½q1², ½q2², q1²q2, −⅓q2³;
* ``hh200``: the same trajectory observed 200 times (0.5 s apart);
* ``well``: the quartic double well U = −½q² + ¼q⁴, 30 observations 1 s apart, sd 0.05,
  the 6-term library q … q⁶;
* ``pendulum``: U = 1 − cos q from q = 2.5 rad, recorded by SciPy's DOP853 (rtol = atol =
  1e-12), 40 observations 0.5 s apart, sd 0.02, the library q², q⁴, q⁶, cos q.

**symplid**: :func:`symplid.workflow._discover.discover` (leapfrog, dt 0.25 — 0.1 for the
pendulum —, known x0, isotropic observation noise, Laplace(0, 10) coefficients, beta-binomial
prior over subsets); its set is the most probable subset, its coefficients that subset's MAP.

**PySINDy** (the ``sindy`` extra): the momenta's time derivatives by its
``FiniteDifference`` (second order, irregular times allowed), then its ``STLSQ``
(sequential thresholded least squares, its default threshold 0.1 and ridge 0.05) regresses
ṗ_i on −∂φ_j/∂q_i, the forces of the same library's terms φ_j: SINDy is told that the system
is Hamiltonian and separable, which it does not know by itself, so the comparison gives it
the same library. A term is in its set when any of its force columns has a non-zero
coefficient; its coefficient is their mean.

A method recovers a seed when its set equals the true set exactly; the coefficient error is
‖ĉ − c‖ / ‖c‖ over the library (a term left out counts as 0). The table gives, per case and
method, the recovery rate over the seeds, the median coefficient error and the mean time;
``--csv`` keeps one row per case, seed and method.

Run: ``nice python benchmarks/discover.py --seeds 5 --cases hh20,well,pendulum --csv b.csv``
(symplid: 10–40 fits per seed; PySINDy: milliseconds); ``--table-only b.csv`` rebuilds the
table.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from symplid import runtime

runtime.limit_threads()
runtime.enable_compilation_cache()  # as the command line does: a seed reuses the programs

import symplid  # noqa: E402
from symplid.workflow._discover import discover  # noqa: E402
from symplid.workflow._settings import Settings, merge_overrides  # noqa: E402


@dataclass(frozen=True)
class Case:
    """One benchmark problem: its data, library and truth."""

    name: str
    terms: tuple[str, ...]  # the library, as expressions in q1..qd
    truth: dict[str, float]  # the true coefficients of U (others 0)
    x0: tuple[float, ...]
    dt: float
    order: int | None  # a polynomial library (the compiled kernel), else the terms


HH_TERMS = ("q1", "q2", "q1^2", "q1*q2", "q2^2", "q1^3", "q1^2*q2", "q1*q2^2", "q2^3")
HH_TRUTH = {"q1^2": 0.5, "q2^2": 0.5, "q1^2*q2": 1.0, "q2^3": -1.0 / 3.0}
HH_X0 = tuple(float(x) for x in symplid.get_system("henon-heiles").initial_state)
"""The paper's initial state, which ``symplid.simulate`` starts the data from."""

CASES = {
    "hh20": Case("hh20", HH_TERMS, HH_TRUTH, HH_X0, 0.25, 3),
    "hh200": Case("hh200", HH_TERMS, HH_TRUTH, HH_X0, 0.25, 3),
    "well": Case("well", ("q1", "q1^2", "q1^3", "q1^4", "q1^5", "q1^6"),
                 {"q1^2": -0.5, "q1^4": 0.25}, (0.5, 0.6), 0.25, 6),
    "pendulum": Case("pendulum", ("q1^2", "q1^4", "q1^6", "cos(q1)"), {"cos(q1)": -1.0},
                     (2.5, 0.0), 0.1, None),
}


def data_for(case: Case, seed: int) -> symplid.Observations:
    """The noisy observations of ``case`` for data seed ``seed`` (module docstring)."""
    if case.name == "pendulum":
        from scipy.integrate import solve_ivp

        times = 0.5 * np.arange(1, 41)
        sol = solve_ivp(lambda t, x: [x[1], -np.sin(x[0])], (0.0, times[-1]), list(case.x0),
                        method="DOP853", t_eval=times, rtol=1e-12, atol=1e-12)
        noise = np.random.default_rng(seed).normal(0.0, 0.02, sol.y.T.shape)
        return symplid.Observations(times, sol.y.T + noise, ("q1", "p1"))
    system = symplid.get_system("henon-heiles" if case.name.startswith("hh") else "double-well")
    times = 0.5 * np.arange(1, 201) if case.name == "hh200" else None
    return symplid.simulate(system, times=times, seed=seed)


def truth_vector(case: Case) -> np.ndarray:
    return np.array([case.truth.get(t, 0.0) for t in case.terms])


# ----------------------------------------------------------------------------- the methods
def run_symplid(case: Case, obs: symplid.Observations, num_starts: int) -> dict:
    settings = merge_overrides(Settings(), {
        "initial_state.x0": list(case.x0), "model.noise": "isotropic", "model.dt": case.dt,
        "map.num_starts": num_starts})
    t0 = time.perf_counter()
    found = discover(obs, settings, terms=None if case.order else list(case.terms),
                     order=case.order, progress=False)
    chosen = set(found.chosen)
    coef = np.array([row["coefficient"] for row in found.search.coefficients()])
    return {"chosen": chosen, "coef": coef, "seconds": time.perf_counter() - t0,
            "fits": found.search.num_fits,
            "inclusion": found.table["inclusion_probability"].to_numpy(),
            "cos_margin": _cos_margin(case, found.search)}


def _cos_margin(case: Case, search) -> float:
    """log evidence of the best visited subset with cos q minus that of the best without it
    (polynomials only); NaN when the library has no cos q."""
    if "cos(q1)" not in case.terms:
        return math.nan
    j = case.terms.index("cos(q1)")
    with_cos = [f.log_evidence for f in search.fits if f.included[j]]
    without = [f.log_evidence for f in search.fits if not f.included[j]]
    return max(with_cos) - max(without) if with_cos and without else math.nan


def _forces(terms: Sequence[str], dim: int):
    """−∂φ_j/∂q_i of every term as NumPy functions of q (shape (dim, n)): [i][j]."""
    import sympy

    qs = sympy.symbols(f"q1:{dim + 1}", real=True)
    local = {f"q{i + 1}": q for i, q in enumerate(qs)}
    exprs = [sympy.sympify(t.replace("^", "**"), locals=local) for t in terms]
    return [[sympy.lambdify([qs], -sympy.diff(e, q), "numpy") for e in exprs] for q in qs]


def run_sindy(case: Case, obs: symplid.Observations) -> dict:
    try:
        import pysindy as ps
    except ImportError:
        raise SystemExit("benchmarks/discover.py: PySINDy is missing; install the benchmark "
                         "extra: pip install -e '.[sindy]'") from None
    t0 = time.perf_counter()
    x, t = np.asarray(obs.values), np.asarray(obs.times)
    d = x.shape[1] // 2
    p_dot = ps.FiniteDifference(order=2)._differentiate(x, t)[:, d:]
    forces = _forces(case.terms, d)
    m = len(case.terms)
    xi = np.zeros((d, m))
    for i in range(d):
        columns = np.stack([np.broadcast_to(np.asarray(f(x[:, :d].T), dtype=float), (len(t),))
                            for f in forces[i]], axis=1)
        active = np.any(columns != 0.0, axis=0)
        optimizer = ps.STLSQ()  # its defaults: threshold 0.1, alpha 0.05
        optimizer.fit(columns[:, active], p_dot[:, i])
        xi[i, active] = np.ravel(optimizer.coef_)
    nonzero = xi != 0.0
    coef = np.array([xi[nonzero[:, j], j].mean() if nonzero[:, j].any() else 0.0
                     for j in range(m)])
    chosen = {case.terms[j] for j in range(m) if nonzero[:, j].any()}
    return {"chosen": chosen, "coef": coef, "seconds": time.perf_counter() - t0, "fits": 0,
            "inclusion": None, "cos_margin": math.nan}


# ----------------------------------------------------------------------------- the table
def rows_for(case: Case, seeds: Sequence[int], num_starts: int, csv_path: Path | None,
             methods: Sequence[str]) -> list[dict]:
    rows, truth, true_set = [], truth_vector(case), set(case.truth)
    for seed in seeds:
        obs = data_for(case, seed)
        for method in methods:
            out = (run_symplid(case, obs, num_starts) if method == "symplid"
                   else run_sindy(case, obs))
            row = {"case": case.name, "seed": seed, "method": method,
                   "recovered": out["chosen"] == true_set,
                   "chosen": " + ".join(t for t in case.terms if t in out["chosen"]),
                   "coef_error": float(np.linalg.norm(out["coef"] - truth)
                                       / np.linalg.norm(truth)),
                   "seconds": out["seconds"], "fits": out["fits"],
                   **_inclusion_margins(case, out["inclusion"]),
                   "cos_over_polynomials": out["cos_margin"]}
            rows.append(row)
            print(f"{case.name} seed {seed} {method}: {row['chosen']} "
                  f"(error {row['coef_error']:.3g}, {row['seconds']:.1f} s, inclusion: true "
                  f"≥ {row['min_true_inclusion']:.3f}, others ≤ "
                  f"{row['max_other_inclusion']:.3f}; cos q over the best polynomial: "
                  f"{row['cos_over_polynomials']:.2f} nats)", flush=True)
            if csv_path is not None:
                _append(csv_path, row)
    return rows


def _inclusion_margins(case: Case, inclusion: np.ndarray | None) -> dict:
    """The smallest inclusion probability of a true term and the largest of another (the
    issue's test: > 0.9 and < 0.5); NaN for a method without probabilities."""
    if inclusion is None:
        return {"min_true_inclusion": math.nan, "max_other_inclusion": math.nan}
    true = np.array([t in case.truth for t in case.terms])
    return {"min_true_inclusion": float(inclusion[true].min()),
            "max_other_inclusion": float(inclusion[~true].max()) if (~true).any() else 0.0}


def _append(path: Path, row: dict) -> None:
    new = not path.exists()
    with path.open("a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(row))
        if new:
            writer.writeheader()
        writer.writerow(row)


def read_rows(path: Path) -> list[dict]:
    """The rows that ``--csv`` wrote, with their numbers read back."""
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    for row in rows:
        row["recovered"] = row["recovered"] == "True"
        for key in ("coef_error", "seconds", "fits", "min_true_inclusion",
                    "max_other_inclusion", "cos_over_polynomials"):
            row[key] = float(row[key])
    return rows


def table(rows: list[dict]) -> str:
    lines = ["| case | method | seeds | exact recovery | inclusion > 0.9 / < 0.5 | "
             "median coefficient error | mean fits | mean time (s) |",
             "|---|---|---|---|---|---|---|---|"]
    keys = sorted({(r["case"], r["method"]) for r in rows},
                  key=lambda k: (list(CASES).index(k[0]), k[1]))
    for case, method in keys:
        sel = [r for r in rows if r["case"] == case and r["method"] == method]
        hits = sum(bool(r["recovered"]) for r in sel)
        clear = sum(r["min_true_inclusion"] > 0.9 and r["max_other_inclusion"] < 0.5
                    for r in sel)
        clear_text = "–" if method != "symplid" else f"{clear}/{len(sel)}"
        lines.append(
            f"| {case} | {method} | {len(sel)} | {hits}/{len(sel)} | {clear_text} | "
            f"{np.median([r['coef_error'] for r in sel]):.3g} | "
            f"{np.mean([r['fits'] for r in sel]):.1f} | "
            f"{np.mean([r['seconds'] for r in sel]):.2f} |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=20, help="data seeds 0..N-1")
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--cases", default=",".join(CASES))
    parser.add_argument("--methods", default="symplid,sindy")
    parser.add_argument("--num-starts", type=int, default=2,
                        help="MAP starts of the whole library's fit")
    parser.add_argument("--csv", type=Path, default=None, help="append one row per fit here")
    parser.add_argument("--table-only", type=Path, nargs="+", default=None, metavar="CSV",
                        help="print the table of these CSV files (from --csv), fit nothing")
    args = parser.parse_args(argv)
    if args.table_only:
        rows = {(r["case"], r["seed"], r["method"]): r  # a repeated fit: the last row
                for path in args.table_only for r in read_rows(path)}
        print(table(list(rows.values())))
        return 0
    names = [c.strip() for c in args.cases.split(",")]
    unknown = [n for n in names if n not in CASES]
    if unknown:
        print(f"unknown case(s) {unknown}; choose from {', '.join(CASES)}", file=sys.stderr)
        return 2
    methods = [m.strip() for m in args.methods.split(",")]
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    rows: list[dict] = []
    for name in names:
        rows += rows_for(CASES[name], seeds, args.num_starts, args.csv, methods)
    print(table(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
