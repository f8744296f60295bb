"""The result of :func:`~symplid.inference.map.find_map`: the MAP, the Hessian, the Laplace
approximation, each start's outcome, and their JSON form (``map.json``)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from symplid._jsonfloat import decode as _decode
from symplid._jsonfloat import encode_array as _json_list
from symplid._jsonfloat import encode_float as _json_float


class BoundWarning(UserWarning):
    """The MAP sits on a bound of θ."""


class MapConvergenceWarning(UserWarning):
    """No start of the MAP search reported convergence."""


class MultipleOptimaWarning(UserWarning):
    """The starts of the MAP search ended in different optima."""


@dataclass(frozen=True)
class Optimum:
    """One distinct end point of the MAP starts: its log posterior, θ and which starts
    (indices into ``MapResult.starts``) reached it."""

    log_posterior: float
    theta: np.ndarray
    starts: tuple[int, ...]

    def to_dict(self) -> dict[str, Any]:
        return {"log_posterior": _json_float(self.log_posterior),
                "theta": _json_list(self.theta), "starts": list(self.starts)}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Optimum:
        return cls(float(_decode(d["log_posterior"])),
                   np.asarray(_decode(d["theta"]), dtype=float),
                   tuple(int(k) for k in d["starts"]))


@dataclass(frozen=True)
class StartResult:
    """One start of :func:`find_map`.

    ``success`` means that L-BFGS-B reported convergence *and* the point is a maximum to within
    1e-3 in log posterior: the Newton decrement ½ gᵀH⁻¹g over the parameters no bound holds
    (``newton_decrement``; a parameter on a bound is left out only where the gradient points
    out of its range, the KKT sign condition) is below 1e-3 when the Hessian is computed;
    otherwise the largest projected-gradient component in the search space
    (``projected_gradient``) must be below 1e-3·max(1, |log π|). A run that stalls against a
    region where the filter fails is thus not counted as converged, whatever L-BFGS-B's
    message says.
    """

    start: np.ndarray
    theta: np.ndarray
    log_posterior: float
    success: bool
    message: str
    num_iterations: int
    num_evaluations: int
    seconds: float
    projected_gradient: float = math.nan
    newton_decrement: float = math.nan

    def to_dict(self) -> dict[str, Any]:
        return {
            "start": _json_list(self.start),
            "theta": _json_list(self.theta),
            "log_posterior": _json_float(self.log_posterior),
            "success": bool(self.success),
            "message": str(self.message),
            "num_iterations": int(self.num_iterations),
            "num_evaluations": int(self.num_evaluations),
            "seconds": float(self.seconds),
            "projected_gradient": _json_float(self.projected_gradient),
            "newton_decrement": _json_float(self.newton_decrement),
        }


@dataclass(frozen=True)
class MapResult:
    """The MAP point, the Hessian there and the Laplace approximation.

    Attributes
    ----------
    theta
        The MAP point, in the posterior's parameter order (``param_names``).
    log_posterior
        log π(θ*) + log L(θ*), the unnormalised log posterior at the MAP.
    success, message
        Whether the best point is a MAP to report: it converged, moved from its start, is a
        maximum, and its noise does not contradict the data (``failure`` empty); and
        L-BFGS-B's message for the best start.
    num_starts, starts
        How many starts were run, and each one's result (best first is *not* implied: in
        the order they were run).
    hessian
        ∇²(−log posterior) at the MAP, ``(d, d)``, by JAX autodiff (None when not computed).
    covariance
        The inverse Hessian, repaired to positive definite when needed (module docstring).
    covariance_repaired
        Whether the Hessian was not positive definite and had eigenvalues replaced.
    log_evidence
        log p(Y) by ``evidence_method`` (NaN when the Hessian was not computed):
        ``"quadrature"`` / ``"axis-quadrature"`` integrate the variances on their log scale
        (:mod:`symplid.inference.map._evidence`), ``"laplace"`` is the Laplace approximation.
    param_names
        Names of θ's entries.
    at_bounds
        Names of the parameters whose MAP value sits on a bound.
    seed, seconds
        The seed of the starts, and the wall time of the whole search (evidence included).
    log_evidence_laplace
        The Laplace approximation of log p(Y) (:mod:`symplid.inference.map._laplace`), kept for
        comparison; it is too low when a variance's posterior is skewed against zero.
    evidence_method, evidence
        How ``log_evidence`` was computed, and the details (nodes, timing, error estimate).
    optima
        The distinct optima the starts ended in, best first
        (:func:`~symplid.inference.map._starts.distinct_optima`); more than one means the log
        posterior has several local maxima within reach of the starts.
    failure
        Why the search failed ("" when it did not; :mod:`symplid.inference.map._checks`).
        Where the best point is no optimum, ``log_evidence`` is NaN.
    """

    theta: np.ndarray
    log_posterior: float
    success: bool
    message: str
    num_starts: int
    starts: tuple[StartResult, ...]
    hessian: np.ndarray | None
    covariance: np.ndarray | None
    covariance_repaired: bool
    log_evidence: float
    param_names: tuple[str, ...]
    at_bounds: tuple[str, ...] = ()
    seed: int = 0
    seconds: float = 0.0
    settings: dict[str, Any] = field(default_factory=dict)
    log_evidence_laplace: float = math.nan
    evidence_method: str = "laplace"
    evidence: dict[str, Any] = field(default_factory=dict)
    optima: tuple[Optimum, ...] = ()
    failure: str = ""

    @property
    def optima_spread(self) -> float:
        """Best minus worst log posterior over the distinct optima (0 for one optimum)."""
        if len(self.optima) < 2:
            return 0.0
        values = [o.log_posterior for o in self.optima]
        return float(max(values) - min(values))

    @property
    def std(self) -> np.ndarray | None:
        """Laplace standard deviations, √diag(covariance)."""
        if self.covariance is None:
            return None
        return np.sqrt(np.diag(self.covariance))

    @property
    def params(self) -> dict[str, float]:
        """``{name: MAP value}``."""
        return {n: float(v) for n, v in zip(self.param_names, self.theta, strict=True)}

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready dict; non-finite floats as ``"nan"``, ``"inf"``, ``"-inf"``."""
        return {
            "param_names": list(self.param_names),
            "theta": _json_list(self.theta),
            "params": {k: _json_float(v) for k, v in self.params.items()},
            "log_posterior": _json_float(self.log_posterior),
            "success": bool(self.success),
            "message": str(self.message),
            "num_starts": int(self.num_starts),
            "starts": [s.to_dict() for s in self.starts],
            "hessian": None if self.hessian is None else _json_list(self.hessian),
            "covariance": None if self.covariance is None else _json_list(self.covariance),
            "covariance_repaired": bool(self.covariance_repaired),
            "std": None if self.std is None else _json_list(self.std),
            "log_evidence": _json_float(self.log_evidence),
            "log_evidence_laplace": _json_float(self.log_evidence_laplace),
            "evidence_method": str(self.evidence_method),
            "evidence": dict(self.evidence),
            "optima": [o.to_dict() for o in self.optima],
            "failure": str(self.failure),
            "at_bounds": list(self.at_bounds),
            "seed": int(self.seed),
            "seconds": float(self.seconds),
            "settings": dict(self.settings),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> MapResult:
        """Inverse of :meth:`to_dict` (e.g. after reading ``map.json``)."""

        def arr(x: Any) -> np.ndarray | None:
            return None if x is None else np.asarray(_decode(x), dtype=float)

        starts = tuple(
            StartResult(
                arr(s["start"]),
                arr(s["theta"]),
                float(_decode(s["log_posterior"])),
                bool(s["success"]),
                str(s["message"]),
                int(s["num_iterations"]),
                int(s["num_evaluations"]),
                float(s["seconds"]),
                float(_decode(s.get("projected_gradient", "nan"))),
                float(_decode(s.get("newton_decrement", "nan"))),
            )
            for s in d.get("starts", [])
        )
        return cls(
            theta=arr(d["theta"]),
            log_posterior=float(_decode(d["log_posterior"])),
            success=bool(d["success"]),
            message=str(d["message"]),
            num_starts=int(d["num_starts"]),
            starts=starts,
            hessian=arr(d.get("hessian")),
            covariance=arr(d.get("covariance")),
            covariance_repaired=bool(d.get("covariance_repaired", False)),
            log_evidence=float(_decode(d.get("log_evidence", "nan"))),
            param_names=tuple(d["param_names"]),
            at_bounds=tuple(d.get("at_bounds", ())),
            seed=int(d.get("seed", 0)),
            seconds=float(d.get("seconds", 0.0)),
            settings=dict(d.get("settings", {})),
            log_evidence_laplace=float(_decode(d.get("log_evidence_laplace", "nan"))),
            evidence_method=str(d.get("evidence_method", "laplace")),
            evidence=dict(d.get("evidence", {})),
            optima=tuple(Optimum.from_dict(o) for o in d.get("optima", ())),
            failure=str(d.get("failure", "")),
        )

    def __repr__(self) -> str:
        lines = [
            f"MapResult(log_posterior={self.log_posterior:.6g}, success={self.success}, "
            f"starts={self.num_starts}, log_evidence={self.log_evidence:.6g})"
        ]
        if self.failure:
            lines.append(f"  failed: the best point {self.failure}")
        std = self.std
        for i, name in enumerate(self.param_names):
            sd = "" if std is None else f" ± {std[i]:.3g}"
            flag = "  (on a bound)" if name in self.at_bounds else ""
            lines.append(f"  {name:>14s} = {self.theta[i]: .6g}{sd}{flag}")
        return "\n".join(lines)


__all__ = [
    "BoundWarning",
    "MapConvergenceWarning",
    "MapResult",
    "MultipleOptimaWarning",
    "Optimum",
    "StartResult",
]
