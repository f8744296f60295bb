"""Independent reference filters in plain NumPy, for cross-checking ``symplid.filters``.

Nothing here imports symplid: these are second implementations written from the textbook
formulas, so that agreement with the JAX filter means something.

* :func:`kalman_loglik`: the exact Kalman filter for a linear(-affine) Gaussian state-space
  model with one transition matrix per observation gap (irregular gaps) and missing values.
* :func:`numpy_ukf_loglik`: a plain vectorised unscented Kalman filter with the library's
  conventions (scaled sigma points from lower-Cholesky columns, process noise added once per gap
  after all substeps, or once per substep; linear observation update; jitter on the predicted
  covariance). Also used as the NumPy baseline of ``benchmarks/likelihood.py``.
* :func:`numpy_leapfrog` and :func:`polynomial_gradient`: a vectorised NumPy leapfrog step
  (eqs 5–6) and the gradient of a polynomial potential from its exponent table.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

LOG_2PI = math.log(2.0 * math.pi)

StepFn = Callable[[np.ndarray, float], np.ndarray]


def kalman_update(
    mean: np.ndarray, cov: np.ndarray, y: np.ndarray, H: np.ndarray, R: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float]:
    """Exact Gaussian update with a linear observation y = Hx + η, η ~ N(0, R).

    NaN components of ``y`` are dropped (their rows of H and rows/columns of R removed).
    Returns the filtered mean and covariance and log p(y | past).
    """
    mask = ~np.isnan(y)
    H_o = H[mask]
    R_o = R[np.ix_(mask, mask)]
    y_pred = H_o @ mean
    S = H_o @ cov @ H_o.T + R_o
    S = 0.5 * (S + S.T)
    chol = np.linalg.cholesky(S)
    innovation = y[mask] - y_pred
    z = np.linalg.solve(chol, innovation)
    loglik = -0.5 * (z @ z) - np.sum(np.log(np.diag(chol))) - 0.5 * mask.sum() * LOG_2PI
    # K = P Hᵀ S⁻¹ through the Cholesky factor (no explicit inverse).
    cross = cov @ H_o.T
    gain = np.linalg.solve(S, cross.T).T
    new_mean = mean + gain @ innovation
    new_cov = cov - gain @ S @ gain.T
    return new_mean, 0.5 * (new_cov + new_cov.T), float(loglik)


def kalman_loglik(
    x0: np.ndarray,
    P0: np.ndarray,
    transitions: Sequence[np.ndarray],
    Q: np.ndarray | Sequence[np.ndarray],
    H: np.ndarray,
    R: np.ndarray,
    ys: np.ndarray,
    offsets: Sequence[np.ndarray] | None = None,
) -> float:
    """Exact log marginal likelihood of a linear Gaussian state-space model.

    ``x_k = F_k x_{k−1} + c_k + ξ_k`` with ξ_k ~ N(0, Q), ``y_k = H x_k + η_k`` with
    η_k ~ N(0, R), x_0 ~ N(x0, P0). One transition matrix ``F_k`` (and optional offset
    ``c_k``) per observation gap, so irregular gaps are expressed by different ``F_k``. ``Q``
    is one matrix for every gap or a sequence of one per gap. NaN entries of ``ys`` are
    missing and dropped from their update.
    """
    Qs = [np.asarray(Q, dtype=float)] * len(transitions) if np.ndim(Q) == 2 else list(Q)
    mean = np.asarray(x0, dtype=float)
    cov = np.asarray(P0, dtype=float)
    ys = np.asarray(ys, dtype=float)
    total = 0.0
    for k, F in enumerate(transitions):
        mean = F @ mean
        if offsets is not None:
            mean = mean + offsets[k]
        cov = F @ cov @ F.T + Qs[k]
        mean, cov, ll = kalman_update(mean, cov, ys[k], H, R)
        total += ll
    return total


# --------------------------------------------------------------------------- the NumPy UKF
def unscented_weights(
    n: int, alpha: float, beta: float, kappa: float
) -> tuple[np.ndarray, np.ndarray, float]:
    """Van der Merwe's scaled unscented weights (Wm, Wc) and the spread sqrt(n + λ)."""
    lam = alpha**2 * (n + kappa) - n
    wm = np.full(2 * n + 1, 0.5 / (n + lam))
    wc = wm.copy()
    wm[0] = lam / (n + lam)
    wc[0] = wm[0] + 1.0 - alpha**2 + beta
    return wm, wc, math.sqrt(n + lam)


def sigma_points(mean: np.ndarray, cov: np.ndarray, spread: float) -> np.ndarray:
    """``(2n+1, n)`` points: m, then m + spread·L[:, i], then m − spread·L[:, i] (L lower)."""
    cols = spread * np.linalg.cholesky(cov).T  # row i = column i of L
    return np.concatenate([mean[None], mean + cols, mean - cols])


def _unscented_moments(
    points: np.ndarray, wm: np.ndarray, wc: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    mean = wm @ points
    centred = points - mean
    return mean, (wc[:, None] * centred).T @ centred


def numpy_ukf_loglik(
    step: StepFn,
    x0: np.ndarray,
    P0: np.ndarray,
    num_steps: Sequence[int],
    step_sizes: Sequence[float],
    ys: np.ndarray,
    Q: np.ndarray,
    R: np.ndarray,
    H: np.ndarray | None = None,
    alpha: float = 1.0,
    beta: float = 2.0,
    kappa: float = 0.0,
    jitter: float = 0.0,
    process_noise_per: str = "gap",
) -> float:
    """UKF log marginal likelihood (seed paper Theorem 1) in plain vectorised NumPy.

    Parameters
    ----------
    step
        ``step(points, h) -> points``: one integrator step of size ``h`` applied to every row
        of a ``(2n+1, n)`` array of states at once.
    x0, P0
        Mean and covariance of the state at the time before the first gap.
    num_steps, step_sizes
        Number and size of the substeps of each gap (``⌈gap/dt⌉`` and ``gap/⌈gap/dt⌉``).
    ys
        Observations ``(num_gaps, d_y)``; NaN = missing (dropped from that update).
    Q, R
        Process-noise covariance (added once per gap, or once per substep when
        ``process_noise_per="step"``) and observation-noise covariance.
    H
        Linear observation matrix ``(d_y, n)``; identity (full state) when None.
    alpha, beta, kappa
        Scaled unscented transform settings.
    jitter
        ``jitter·I`` added to the predicted covariance after symmetrising (after every
        prediction, so after every substep when ``process_noise_per="step"``), as the library
        does; the filtered covariance gets none.

    Returns
    -------
    float
        The log-likelihood; −∞ when a covariance is not positive definite or a value is not
        finite.
    """
    if process_noise_per not in ("gap", "step"):
        raise ValueError(f"process_noise_per must be 'gap' or 'step', got {process_noise_per!r}")
    mean = np.asarray(x0, dtype=float)
    cov = np.asarray(P0, dtype=float)
    n = mean.shape[0]
    H = np.eye(n) if H is None else np.asarray(H, dtype=float)
    ys = np.asarray(ys, dtype=float)
    wm, wc, spread = unscented_weights(n, alpha, beta, kappa)
    eye = np.eye(n)

    def predict_once(mean, cov, num, h):
        points = sigma_points(mean, cov, spread)
        for _ in range(num):
            points = step(points, h)
        mean, cov = _unscented_moments(points, wm, wc)
        cov = cov + Q
        return mean, 0.5 * (cov + cov.T) + jitter * eye

    total = 0.0
    with np.errstate(all="ignore"):
        try:
            for k in range(len(num_steps)):
                num, h = int(num_steps[k]), float(step_sizes[k])
                if process_noise_per == "gap":
                    mean, cov = predict_once(mean, cov, num, h)
                else:
                    for _ in range(num):
                        mean, cov = predict_once(mean, cov, 1, h)
                if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))):
                    return -math.inf
                mean, cov, ll = kalman_update(mean, cov, ys[k], H, R)
                total += ll
        except np.linalg.LinAlgError:
            return -math.inf
    return total if math.isfinite(total) else -math.inf


# --------------------------------------------------------------------------- NumPy dynamics
def polynomial_gradient(
    exponents: np.ndarray, coefficients: np.ndarray
) -> Callable[[np.ndarray], np.ndarray]:
    """∂U/∂q for U(q) = Σ_m c_m Π_i q_i^{e_mi}, vectorised over rows of ``q`` ``(k, d)``.

    ``exponents`` is the ``(num_terms, d)`` exponent table of the basis.
    """
    exponents = np.asarray(exponents, dtype=int)
    coefficients = np.asarray(coefficients, dtype=float)
    d = exponents.shape[1]
    # For coordinate j: d/dq_j of q^e = e_j q^(e − δ_j); terms with e_j = 0 drop out.
    per_coord = []
    for j in range(d):
        keep = exponents[:, j] > 0
        e = exponents[keep].copy()
        c = coefficients[keep] * e[:, j]
        e[:, j] -= 1
        per_coord.append((c, e))

    def grad(q: np.ndarray) -> np.ndarray:
        q = np.atleast_2d(q)
        out = np.empty_like(q)
        for j, (c, e) in enumerate(per_coord):
            # (k, 1, d) ** (terms, d) -> (k, terms, d) -> product over d
            monomials = np.prod(q[:, None, :] ** e[None, :, :], axis=-1)
            out[:, j] = monomials @ c
        return out

    return grad


def numpy_leapfrog(
    grad: Callable[[np.ndarray], np.ndarray], inv_mass: np.ndarray | None = None
) -> StepFn:
    """A vectorised leapfrog step in the integer-step form of eqs (5)–(6).

    ``grad(q)`` maps ``(k, d)`` positions to ``(k, d)`` gradients of U; the returned
    ``step(x, h)`` advances ``(k, 2d)`` states by one step of size ``h``.
    """
    minv = None if inv_mass is None else np.asarray(inv_mass, dtype=float)

    def velocity(p: np.ndarray) -> np.ndarray:
        return p if minv is None else p @ minv.T

    def step(x: np.ndarray, h: float) -> np.ndarray:
        d = x.shape[-1] // 2
        q, p = x[:, :d], x[:, d:]
        g = grad(q)
        q_next = q + h * velocity(p) - 0.5 * h * h * velocity(g)
        p_next = p - 0.5 * h * (g + grad(q_next))
        return np.concatenate([q_next, p_next], axis=1)

    return step


def numpy_substeps(times: np.ndarray, dt: float, t0: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """⌈gap/dt⌉ (with a 1e-9 relative tolerance) equal substeps per gap, eq. (14)."""
    gaps = np.diff(np.concatenate([[t0], np.asarray(times, dtype=float)]))
    num = np.maximum(np.ceil(gaps / dt * (1.0 - 1e-9)), 1).astype(int)
    return num, gaps / num
