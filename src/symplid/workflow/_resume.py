"""Continue an interrupted run folder (``symplid fit --resume``).

A run whose sampler was stopped by Ctrl-C, SIGTERM or SIGHUP is marked ``interrupted`` and
keeps its settings, data, MAP, draws and the chains' states (``sampler_state.npz``, see
:mod:`symplid.workflow._results`); a run killed outright keeps its draws and states in the
chunk files of ``draws/`` (:mod:`symplid.io._chunks`), which are preferred when present.
:func:`resume_fit` reloads them, runs the iterations left
(:func:`symplid.sampling._resume.resume_sampling`: on the whole run's key and chunk
grid, so the draws are those an uninterrupted run with the same seed makes) and saves the run
as :func:`symplid.workflow._fit.fit` does: a finished run, or interrupted again.

The settings are the run's own; settings given again (the same command line, a file) must
equal them, since a continuation under other settings would be neither run
(:func:`check_same_settings`; the ``[plots]`` section, which changes no result, is exempt and
stays the run's).
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

from symplid.inference.map import MapResult
from symplid.io._chunks import read_chunks, remove_chunks
from symplid.io._runfiles import flatten
from symplid.sampling import InterruptedInBurnIn, RunOptions
from symplid.sampling._resume import inference_data, resume_sampling
from symplid.workflow._fit import build_model, build_posterior
from symplid.workflow._fit_files import (
    FitOutcome,
    chunk_sink,
    run_fingerprint,
    save_burn_in,
    save_run,
)
from symplid.workflow._results import RunFolder, RunFolderError
from symplid.workflow._settings import Settings, SettingsError, settings_to_dict

__all__ = ["ChunkIgnoredWarning", "check_same_settings", "resume_fit"]


class ChunkIgnoredWarning(UserWarning):
    """A chunk file of draws could not continue the run (damaged, out of line) and was
    ignored; the run continues from the chunk before it."""


def check_same_settings(run: Settings, given: Settings, where: str | Path) -> None:
    """Refuse (one line) settings that differ from the interrupted run's own."""
    have, want = flatten(settings_to_dict(run)), flatten(settings_to_dict(given))
    changed = sorted(k for k in have.keys() | want.keys()
                     if have.get(k) != want.get(k) and not k.startswith("plots."))
    if changed:
        shown = ", ".join(f"{k} ({have.get(k)!r} in the run, {want.get(k)!r} given)"
                          for k in changed[:3])
        more = f" and {len(changed) - 3} more" if len(changed) > 3 else ""
        raise SettingsError(
            str(where), None,
            f"--resume continues the run as it was set up, but {shown}{more} changed; drop "
            "those options, or fit anew with --overwrite",
        )


def resume_fit(
    out: str | Path,
    progress: bool = True,
    warn: bool = False,
    status: Callable[[str], None] | None = None,
    expected: Callable[[Settings, Any], Settings | None] | None = None,
) -> FitOutcome:
    """Continue the interrupted run in ``out``; returns the outcome as :func:`fit` does.

    ``expected(settings, data)``, when given, returns the settings the caller asks for (or
    None: the run's own) given the run's; they must equal the run's
    (:func:`check_same_settings`). A finished run, or one that did not stop in sampling, is
    refused with a one-line :class:`~symplid.workflow._results.RunFolderError`; a failure
    while continuing leaves the interrupted run as it was, plus the chunks it finished (a
    kill too: the next ``--resume`` goes on from them).
    """
    folder = RunFolder(out, "c")
    try:
        return _resume(folder, out, progress, warn, status, expected)
    finally:  # saved or not, the folder's lock is given up (a refusal keeps the run as it was)
        folder.release()


def _resume(folder: RunFolder, out: str | Path, progress: bool, warn: bool,
            status: Callable[[str], None] | None,
            expected: Callable[[Settings, Any], Settings | None] | None) -> FitOutcome:
    settings, obs = folder.read_settings(), folder.read_data()
    if expected is not None:
        asked = expected(settings, obs)
        if asked is not None:
            check_same_settings(settings, asked, out)
    summary = folder.read_summary() if folder.file(RunFolder.SUMMARY).exists() else {}
    if settings.model.standardise == "on":
        raise RunFolderError(
            f"{out}: this run was fitted in standardised coordinates (model.standardise), "
            "which --resume does not continue yet; fit again with --overwrite"
        )
    idata, arrays, sink = _where_sampling_stopped(folder)
    if status is not None:
        status(f"resuming {out} at iteration {int(arrays['iterations_done']):,} of "
               f"{settings.sampler.iterations_cap:,} per chain (compiling first)...")
    model = build_model(settings, obs)
    posterior = build_posterior(settings, obs, model)
    map_result = MapResult.from_dict(folder.read_map())
    start = time.perf_counter()
    try:
        idata, checkpoint = resume_sampling(
            posterior, idata, arrays,
            options=RunOptions(progress=progress, return_state=True, sink=sink))
    except InterruptedInBurnIn as stop:
        save_burn_in(folder, settings, stop)
        raise
    timings = dict(summary.get("timings", {}))
    timings["sampler_s"] = float(timings.get("sampler_s", 0.0)) + time.perf_counter() - start
    timings["resumed"] = int(timings.get("resumed", 0)) + 1
    diagnostics = (folder.read_json(RunFolder.DIAGNOSTICS)
                   if folder.file(RunFolder.DIAGNOSTICS).exists() else None)  # the fit's own
    outcome = FitOutcome(settings, obs, model, posterior, map_result, idata, timings=timings,
                         diagnostics=diagnostics)
    return save_run(folder, outcome, checkpoint, warn)


def _where_sampling_stopped(folder: RunFolder) -> tuple[Any, dict[str, Any], Any]:
    """The draws so far (InferenceData, or their attributes alone before any draw), the
    chains' state arrays and the sink that goes on writing chunks.

    From the chunk files when there are (:mod:`symplid.io._chunks`: a run stopped, or killed
    outright, while sampling; a damaged last chunk is named in one warning line and written
    again); else from ``posterior.nc`` (or ``sampler_attrs.json``) and ``sampler_state.npz``,
    as a run stopped before its first chunk (or by an older version) left them.
    """
    chunks = read_chunks(folder.file(RunFolder.CHUNKS), run=run_fingerprint(folder))
    if chunks.note:
        warnings.warn(chunks.note, ChunkIgnoredWarning, stacklevel=3)
        remove_chunks(folder.file(RunFolder.CHUNKS), keep=chunks.count)  # made again
    if chunks.count:
        attrs = folder.read_json(RunFolder.SAMPLER_ATTRS)
        attrs.update(iterations=chunks.iterations_done, interrupted=1,
                     sampling_seconds=chunks.elapsed)
        idata = inference_data(chunks.draws, attrs) if chunks.draws else attrs
        return idata, chunks.state, chunk_sink(folder, chunks.count, attrs=False,
                                               elapsed=chunks.elapsed)
    arrays = folder.read_npz(RunFolder.SAMPLER_STATE)
    if "iterations_done" not in arrays:
        raise RunFolderError(f"{folder.file(RunFolder.SAMPLER_STATE)}: not a sampler state "
                             f"(no iterations_done); {folder.remedy}")
    if folder.file(RunFolder.POSTERIOR).exists():
        idata = folder.read_posterior()
    else:  # stopped in the burn-in: no draws yet, their attributes only
        idata = folder.read_json(RunFolder.SAMPLER_ATTRS)
    # Chunks go on from iteration 0 only (a state from an older version: none streamed).
    fresh = int(arrays["iterations_done"]) == 0
    return idata, arrays, chunk_sink(folder, attrs=False) if fresh else None
