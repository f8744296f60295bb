"""A fit's run files: the draws streamed chunk by chunk, the summary, and a run saved as
finished or as interrupted (with the chains' state for ``symplid fit --resume``).

:class:`FitOutcome` is what :func:`symplid.workflow._fit.fit` produced, the same content as
the run folder in memory; :func:`save_run` writes it, and :func:`fit_summary` is the digest
``summary.json`` holds (MAP, posterior quantiles, convergence, what ended the sampling).
"""

from __future__ import annotations

import hashlib
import json
import math
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from symplid.inference._diagnostics import summary as diagnostics_summary
from symplid.io._chunks import ChunkWriter
from symplid.model._data import Observations
from symplid.model._statespace import HamiltonianModel
from symplid.sampling import InterruptedInBurnIn, draws_array
from symplid.workflow._interrupts import deferred_interrupts
from symplid.workflow._model_builder import model_description
from symplid.workflow._plan import ModelPlan
from symplid.workflow._results import RunFolder
from symplid.workflow._settings import Settings

__all__ = ["FitOutcome", "chunk_sink", "fit_summary", "run_fingerprint", "save_burn_in",
           "save_run"]


@dataclass
class FitOutcome:
    """What :func:`~symplid.workflow._fit.fit` produced (the same content as the run folder, in
    memory)."""

    settings: Settings
    data: Observations
    model: HamiltonianModel
    posterior: Any
    map_result: Any
    idata: Any = None
    summary: dict[str, Any] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    interrupted: bool = False
    standardised_scale: float | None = None
    """The position scale a of ``model.standardise`` (None: fitted in the data's units)."""
    diagnostics: dict[str, Any] | None = None
    """The MAP-level sensitivity checks (:func:`~symplid.workflow._sensitivity.sensitivity_checks`;
    None with ``map.sensitivity = false``), as saved in ``diagnostics.json``."""
    learning_step: dict[str, Any] | None = None
    """How ``model.dt = "auto"`` chose the step (:func:`~symplid.workflow._step_size.choose_step`;
    None for a given dt)."""
    map_refound: tuple[dict[str, float], ...] = ()
    """Each time the chains climbed above the MAP and it was searched again from there
    (:mod:`symplid.workflow._mode_watch`; empty when they never did)."""
    plan: ModelPlan | None = None
    """The run's model, built once (:class:`~symplid.workflow._plan.ModelPlan`): what the
    report and the held-out scores after the fit build on (None: a resumed run)."""


def chunk_sink(folder: RunFolder, first_index: int = 0, attrs: bool = True,
               elapsed: float = 0.0) -> ChunkWriter:
    """The sink that streams a run's draws to ``folder`` chunk by chunk
    (:mod:`symplid.io._chunks`), writing the draws' attributes (``sampler_attrs.json``) when
    sampling begins (``attrs``; a continued run has them already, and ``elapsed`` seconds
    of sampling)."""

    def begin(values: dict[str, Any]) -> None:
        folder.write_json(RunFolder.SAMPLER_ATTRS, values)

    return ChunkWriter(folder.file(RunFolder.CHUNKS), first_index, begin if attrs else None,
                       elapsed, run=run_fingerprint(folder))


def run_fingerprint(folder: RunFolder) -> str:
    """What the run's chunk files carry to be told from another run's: a digest of its
    ``settings.toml`` and ``data.csv`` (the seed, the model, the sampler, the data)."""
    digest = hashlib.sha256()
    for name in (RunFolder.SETTINGS, RunFolder.DATA):
        path = folder.file(name)
        digest.update(path.read_bytes() if path.exists() else b"")
        digest.update(b"\0")
    return digest.hexdigest()[:16]


def save_burn_in(folder: RunFolder, settings: Settings, stop: InterruptedInBurnIn) -> None:
    """A run stopped in its burn-in keeps the chains' state and the draws' attributes, so
    that ``fit --resume`` can continue it (there are no draws yet)."""
    from symplid.sampling._resume import checkpoint_arrays

    with deferred_interrupts():
        folder.write_npz(RunFolder.SAMPLER_STATE, **checkpoint_arrays(stop.checkpoint))
        folder.write_json(RunFolder.SAMPLER_ATTRS, stop.attrs)
        folder.mark_interrupted(
            f"in the burn-in, after {stop.checkpoint.iterations_done:,} of "
            f"{settings.sampler.iterations_cap:,} iterations per chain (no draws kept yet)")


def save_run(folder: RunFolder | None, outcome: FitOutcome, checkpoint: Any = None,
             warn: bool = False) -> FitOutcome:
    """Summarise the draws of ``outcome`` and write them: a finished run, or an interrupted
    one with its sampler state (``checkpoint``) for ``fit --resume``. SIGINT and SIGTERM wait
    until the files are written."""
    idata, settings = outcome.idata, outcome.settings
    with deferred_interrupts():  # a second Ctrl-C must not lose the draws the first kept
        interrupted = bool(idata.attrs.get("interrupted", False)) if idata is not None else False
        table = diagnostics_summary(idata, show=False, warn=warn and not interrupted,
                                    columns="convergence")  # only R-hat and ESS are read
        summary = {"model": model_description(settings.model),  # as written: first
                   **fit_summary(outcome.posterior, outcome.map_result, idata, table)}
        summary["timings"] = outcome.timings
        if outcome.learning_step is not None:
            summary["learning_step"] = outcome.learning_step
        if outcome.map_refound:
            summary["map_refound"] = list(outcome.map_refound)
        if outcome.standardised_scale is not None:
            summary["standardised_scale"] = outcome.standardised_scale
        summary["interrupted"] = interrupted
        if interrupted:
            summary["iterations_done"] = int(idata.attrs.get("iterations", 0))
        outcome.summary, outcome.interrupted = summary, interrupted
        if folder is not None:
            folder.write_posterior(idata)
            folder.write_summary(summary)
            if interrupted:
                if checkpoint is not None:
                    from symplid.sampling._resume import checkpoint_arrays

                    folder.write_npz(RunFolder.SAMPLER_STATE, **checkpoint_arrays(checkpoint))
                folder.mark_interrupted(
                    f"after {summary['iterations_done']:,} of "
                    f"{settings.sampler.iterations_cap:,} iterations per chain (the draws "
                    "made so far are in posterior.nc)"
                )
            else:
                folder.finish(required=("settings.toml", "data.csv", "map.json", "posterior.nc"))
    return outcome


def fit_summary(posterior, map_result, idata, table=None) -> dict[str, Any]:
    """A JSON-ready digest of a fit: MAP, posterior quantiles, convergence and acceptance."""

    names = list(posterior.param_names)
    out: dict[str, Any] = {
        "param_names": names,
        "map": dict(zip(names, np.asarray(map_result.theta).tolist(), strict=True)),
        "map_log_posterior": float(map_result.log_posterior),
        "log_evidence": float(map_result.log_evidence),
        "log_evidence_laplace": float(getattr(map_result, "log_evidence_laplace",
                                              map_result.log_evidence)),
        "evidence_method": str(getattr(map_result, "evidence_method", "laplace")),
        "map_optima": len(getattr(map_result, "optima", ())) or 1,
        "map_optima_spread": float(getattr(map_result, "optima_spread", 0.0)),
    }
    if idata is None:
        return out
    draws = draws_array(idata)  # (chain, draw, param)
    flat = draws.reshape(-1, draws.shape[-1])
    q = np.quantile(flat, [0.025, 0.5, 0.975], axis=0)
    out["posterior"] = {
        name: {"q025": q[0, i], "median": q[1, i], "q975": q[2, i], "mean": flat[:, i].mean()}
        for i, name in enumerate(names)
    }
    stats = idata.sample_stats
    for key in ("acceptance_rate", "accepted"):
        if key in stats:
            out["acceptance_rate"] = float(np.asarray(stats[key]).mean())
            break
    if table is not None:
        with warnings.catch_warnings():  # all NaN on very short chains: NaN, said in words
            warnings.simplefilter("ignore", RuntimeWarning)
            out["rhat_max"] = float(np.nanmax(table["r_hat"].to_numpy()))
            out["ess_min"] = float(np.nanmin(table["ess_bulk"].to_numpy()))
            if "ess_tail" in table:
                out["ess_tail_min"] = float(np.nanmin(table["ess_tail"].to_numpy()))
    # Chains restarted at the end of the burn-in (sampling.restart); 0: none.
    out["restarted_chains"] = len(idata.attrs.get("restarted_chains", None) or [])
    out.update(_budget_summary(idata))
    return out


def _budget_summary(idata) -> dict[str, Any]:
    """What ended the sampling (``stopped_by``: ``"target"``, the cap ``"iterations"`` or
    ``"wall time"``, ``"fixed budget"``, ``"interrupted"``), the iterations per chain and,
    for a budget set by the answer, its targets and burn-in
    (:mod:`~symplid.sampling._budget`), and when a cap ended it, the iterations per chain the
    targets would have needed at the rate seen (``projected_iterations``)."""
    attrs = idata.attrs
    out: dict[str, Any] = {"stopped_by": str(attrs.get("stopped_by", "fixed budget")),
                           "iterations": int(attrs.get("iterations", 0))}
    if "budget" in attrs:
        record = json.loads(attrs["budget"])
        out["burn_in"] = int(record["burn_in"])
        out["targets"] = {k: record["targets"][k] for k in ("ess_bulk", "ess_tail", "rhat")}
        projected = record.get("projected_iterations")
        if out["stopped_by"] in ("iterations", "wall time") and projected is not None \
                and math.isfinite(projected):
            out["projected_iterations"] = float(projected)
    return out
