"""The sampling runner: chains of any registered sampler's kernel, run to a result.

The kernels (DRAM, NUTS, the registry :data:`~symplid.inference.samplers.SAMPLERS`) are
:mod:`symplid.inference.samplers`; this layer runs them. :func:`run_chains` drives a kernel in
compiled chunks over several chains (:mod:`.chunk`, sized by :mod:`.pacing` so that a stop is
obeyed within about a second); between chunks the draws go to a sink, a callback runs, stuck
chains are restarted at the end of the burn-in (:mod:`.restart`) and a run without a fixed
budget checks its :class:`Targets` (:mod:`.budget`); :func:`sample` puts it together from
the MAP (:mod:`.starts`: the chains' starting points) and returns ArviZ ``InferenceData``;
:mod:`.resume` continues an interrupted run. How the chains run is one :class:`RunOptions`;
its default progress bar is :mod:`.progress`'s.
"""

from symplid.sampling.api import (
    InterruptedInBurnIn,
    SamplerCheckpoint,
    draws_array,
    sample,
)
from symplid.sampling.budget import STOPPED_BY
from symplid.sampling.options import RunOptions, Targets
from symplid.sampling.run import ChainRun, ChunkReport, SamplingInterrupted, run_chains
from symplid.sampling.starts import overdispersed_starts

__all__ = [
    "STOPPED_BY",
    "ChainRun",
    "ChunkReport",
    "InterruptedInBurnIn",
    "RunOptions",
    "SamplerCheckpoint",
    "SamplingInterrupted",
    "Targets",
    "draws_array",
    "overdispersed_starts",
    "run_chains",
    "sample",
]
