"""A driven system identified three ways: symplid against the best linear model and PySINDy.

The classic nonlinear system-identification set-up: a forced Duffing oscillator
q̈ = −k1 q − k3 q³ − c q̇ + b u(t), (k1, k3, c, b) = (1, 0.5, 0.2, 1), excited by a multisine
(8 tones over 0.05–0.5 Hz, random phases), positions observed every 0.25 s with noise sd 0.05,
the input logged every 0.05 s (``examples/driven/driven_data.py``). Each method learns from
N noisy samples and then **simulates** the response to a new multisine (another seed) from
rest, 200 points over 50 s; the score is the RMSE of the simulated positions against the
noise-free truth (DOP853):

* **symplid**: the example's model (``examples/driven/duffing.toml``: U = k1 q²/2 + k3 q⁴/4,
  F = b u1 − c p1) fitted by the MAP and DRAM (``--draws``; 0: the MAP alone), its paths
  integrated from rest with the new input (posterior mean of the draws' positions);
* **ARX**: the best linear model, y_k = Σ a_i y_{k−i} + Σ b_j u_{k−j}, orders 1–6 each chosen
  by the simulation error on the last fifth of the training record, fitted by least squares
  and simulated on the new input;
* **PySINDy** with control (SINDYc): the state (q, q̇) from a smoothed finite difference of the
  noisy positions, a cubic polynomial library in (q, q̇, u), STLSQ; simulated from rest with
  the new input (``pip install -e '.[sindy]'``).

Run: ``python benchmarks/driven.py [--sizes 100 1000] [--draws 2000]``. Prints a table.
"""

from __future__ import annotations

import argparse
import importlib.util
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
GAP, NOISE, TEST_POINTS = 0.25, 0.05, 200


def _simulator():
    spec = importlib.util.spec_from_file_location(
        "driven_data", ROOT / "examples" / "driven" / "driven_data.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _truth_test(sim, seed: int):
    """(times, noise-free positions, input times, inputs) of the test record."""
    t_obs, _, t_in, u = sim.simulate("duffing", seed=seed, num=TEST_POINTS, noise=0.0)
    return t_obs, _, t_in, u


def _rmse(a: np.ndarray, b: np.ndarray) -> float:
    out = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    return float(np.sqrt(np.mean(out * out))) if np.all(np.isfinite(out)) else float("inf")


# ---------------------------------------------------------------------------- symplid
def fit_symplid(sim, train, draws: int, seed: int):
    """θ_Ψ draws (or the MAP) of the example's model on the training record."""
    from symplid.io._inputfiles import read_driven_csv
    from symplid.workflow._fit import build_model, build_posterior, find_map_for
    from symplid.workflow._settings import load_settings, resolve_for_data

    path = Path(f"/tmp/symplid_driven_{seed}_{len(train[0])}.csv")
    sim.write(path, *train)
    settings = load_settings(ROOT / "examples" / "driven" / "duffing.toml")
    obs = read_driven_csv(path, (), settings.inputs.interpolation)
    settings = resolve_for_data(settings, obs)
    model = build_model(settings, obs)
    posterior = build_posterior(settings, obs, model)
    result = find_map_for(settings, posterior)
    nd = model.num_dynamics_params
    if draws <= 0:
        return model, np.asarray(result.theta)[None, :nd]
    from symplid.sampling import sample

    idata = sample(posterior, method="dram", num_draws=draws, num_chains=2, seed=seed,
                   init=result, burn_in=draws)
    flat = np.concatenate([np.asarray(idata.posterior[n]).reshape(-1, 1)
                           for n in model.param_names[:nd]], axis=1)
    return model, flat[:: max(1, flat.shape[0] // 200)]


def simulate_symplid(model, params, t_obs, t_in, u) -> np.ndarray:
    from symplid.inference._driven import forced_paths
    from symplid.model._inputs import SampledInputs

    signal = SampledInputs(t_in, u, ("u1",), "cubic")
    x0 = np.zeros((params.shape[0], 2))
    times, paths = forced_paths(model, signal, params, x0, 0.0, float(t_obs[-1]), 0.01,
                                "yoshida4")
    index = np.searchsorted(times, t_obs - 1e-9)
    return paths[:, index, 0].mean(axis=0)


# ---------------------------------------------------------------------------- ARX
def _arx_design(y: np.ndarray, u: np.ndarray, na: int, nb: int) -> tuple[np.ndarray, np.ndarray]:
    start = max(na, nb)
    rows = [np.concatenate([y[k - na:k][::-1], u[k - nb:k][::-1]]) for k in range(start, y.size)]
    return np.asarray(rows), y[start:]


def _arx_simulate(coef: np.ndarray, u: np.ndarray, na: int, nb: int, num: int) -> np.ndarray:
    y = np.zeros(num)
    for k in range(num):
        past_y = np.array([y[k - i] if k - i >= 0 else 0.0 for i in range(1, na + 1)])
        past_u = np.array([u[k - j] if k - j >= 0 else 0.0 for j in range(1, nb + 1)])
        y[k] = coef @ np.concatenate([past_y, past_u])
        if not np.isfinite(y[k]) or abs(y[k]) > 1e6:
            y[k:] = np.inf
            break
    return y


def fit_arx(y: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, int, int]:
    """The (na, nb) of least simulation error on the last fifth, refitted on all."""
    cut = int(0.8 * y.size)
    best = (np.inf, 1, 1)
    for na in range(1, 7):
        for nb in range(1, 7):
            a, target = _arx_design(y[:cut], u[:cut], na, nb)
            coef = np.linalg.lstsq(a, target, rcond=None)[0]
            sim = _arx_simulate(coef, u, na, nb, y.size)
            err = _rmse(sim[cut:], y[cut:])
            best = min(best, (err, na, nb))
    _, na, nb = best
    a, target = _arx_design(y, u, na, nb)
    return np.linalg.lstsq(a, target, rcond=None)[0], na, nb


# ---------------------------------------------------------------------------- PySINDy
def fit_sindy(t: np.ndarray, y: np.ndarray, u: np.ndarray):
    import pysindy as ps

    q = y[:, None]
    x = np.hstack([q, ps.SmoothedFiniteDifference()(q, t)])
    model = ps.SINDy(feature_library=ps.PolynomialLibrary(degree=3),
                     optimizer=ps.STLSQ(threshold=0.02))
    model.fit(x, t=t, u=u[:, None])
    return model


def simulate_sindy(model, t_obs, t_in, u) -> np.ndarray:
    from scipy.interpolate import CubicSpline

    spline = CubicSpline(t_in, u)
    grid = np.concatenate([[0.0], t_obs])
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            x = model.simulate(np.zeros(2), grid, u=lambda s: np.atleast_1d(spline(s)))
        return x[1:, 0] if x.shape[0] == grid.size else np.full(t_obs.size, np.inf)
    except Exception:  # a learned model that blows up: scored as inf
        return np.full(t_obs.size, np.inf)


# ---------------------------------------------------------------------------- the table
def run(size: int, draws: int, seed: int = 0) -> dict[str, float]:
    sim = _simulator()
    train = sim.simulate("duffing", seed=seed, num=size)
    t_obs, y, t_in, u_dense = train
    u_obs = np.interp(t_obs, t_in, u_dense)
    test_t, test_y, test_tin, test_u = _truth_test(sim, seed + 7)
    out: dict[str, float] = {}
    start = time.perf_counter()
    model, params = fit_symplid(sim, train, draws, seed)
    out["symplid"] = _rmse(simulate_symplid(model, params, test_t, test_tin, test_u), test_y)
    out["symplid_s"] = time.perf_counter() - start
    start = time.perf_counter()
    coef, na, nb = fit_arx(y, u_obs)
    test_uobs = np.interp(test_t, test_tin, test_u)
    out["arx"] = _rmse(_arx_simulate(coef, test_uobs, na, nb, test_t.size), test_y)
    out["arx_orders"] = na * 10 + nb
    out["arx_s"] = time.perf_counter() - start
    try:
        start = time.perf_counter()
        sindy = fit_sindy(t_obs, y, u_obs)
        out["sindy"] = _rmse(simulate_sindy(sindy, test_t, test_tin, test_u), test_y)
        out["sindy_s"] = time.perf_counter() - start
    except ImportError:
        out["sindy"] = float("nan")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[100, 1000])
    parser.add_argument("--draws", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    print("| N | symplid RMSE | ARX RMSE (na, nb) | PySINDy RMSE | symplid s |")
    print("|---|---|---|---|---|")
    for size in args.sizes:
        r = run(size, args.draws, args.seed)
        orders = f"({int(r['arx_orders']) // 10}, {int(r['arx_orders']) % 10})"
        print(f"| {size} | {r['symplid']:.4f} | {r['arx']:.4f} {orders} | {r['sindy']:.4f} | "
              f"{r['symplid_s']:.0f} |", flush=True)


if __name__ == "__main__":
    main()
