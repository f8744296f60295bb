"""The sampling runner: chains of any registered sampler's kernel, run to a result.

The kernels (DRAM, NUTS, the registry :data:`~symplid.inference.samplers.SAMPLERS`) are
:mod:`symplid.inference.samplers`; this layer runs them. :func:`run_chains` drives a kernel in
compiled chunks over several chains (:mod:`._chunk`, sized by :mod:`._pacing` so that a stop is
obeyed within about a second); between chunks the draws go to a sink, a callback runs, stuck
chains are restarted at the end of the burn-in (:mod:`._restart`) and a run without a fixed
budget checks its :class:`Targets` (:mod:`._budget`); :func:`sample` puts it together from
the MAP (:mod:`._starts`: the chains' starting points) and returns ArviZ ``InferenceData``;
:mod:`._resume` continues an interrupted run. How the chains run is one :class:`RunOptions`;
its default progress bar is :mod:`._progress`'s.
"""

from symplid.sampling._api import (
    InterruptedInBurnIn,
    SamplerCheckpoint,
    draws_array,
    sample,
)
from symplid.sampling._budget import STOPPED_BY, TargetsOutOfReach
from symplid.sampling._options import RunOptions, Targets
from symplid.sampling._run import ChainRun, ChunkReport, SamplingInterrupted, run_chains
from symplid.sampling._starts import overdispersed_starts

__all__ = [
    "STOPPED_BY",
    "ChainRun",
    "ChunkReport",
    "InterruptedInBurnIn",
    "RunOptions",
    "SamplerCheckpoint",
    "SamplingInterrupted",
    "Targets",
    "TargetsOutOfReach",
    "draws_array",
    "overdispersed_starts",
    "run_chains",
    "sample",
]
