"""Posterior samplers: DRAM (the paper's), NUTS, the registry and the chunked chain runner.

:func:`sample` runs a sampler named in :data:`SAMPLERS` (also ``symplid.sample``) and returns
ArviZ ``InferenceData``; :func:`draws_array` gives its draws as one array. Each sampler is a
pair of pure functions in the BlackJAX style (``init`` and a ``step``); a new one is one
registration of a :class:`SamplerSpec` whose ``build`` returns a :class:`SamplerKernel`, and
:func:`run_chains` drives it in compiled chunks over several chains. How the chains run is one
:class:`RunOptions`; without a fixed number of draws they run until the draws meet its
:class:`Targets` (bulk and tail ESS, R-hat) or a cap.
"""

from symplid.inference.samplers import (
    SAMPLERS,
    DRAMInfo,
    DRAMSettings,
    DRAMState,
    NUTSSettings,
    NUTSState,
    SamplerKernel,
    SamplerSpec,
)
from symplid.inference.samplers import dram as dram  # the old paths symplid.samplers.dram, .nuts
from symplid.inference.samplers import nuts as nuts
from symplid.sampling import (
    ChainRun,
    ChunkReport,
    InterruptedInBurnIn,
    RunOptions,
    SamplerCheckpoint,
    SamplingInterrupted,
    Targets,
    draws_array,
    overdispersed_starts,
    run_chains,
    sample,
)

__all__ = [
    "SAMPLERS",
    "ChainRun",
    "ChunkReport",
    "DRAMInfo",
    "DRAMSettings",
    "DRAMState",
    "InterruptedInBurnIn",
    "NUTSSettings",
    "NUTSState",
    "RunOptions",
    "SamplerCheckpoint",
    "SamplerKernel",
    "SamplerSpec",
    "SamplingInterrupted",
    "Targets",
    "draws_array",
    "overdispersed_starts",
    "run_chains",
    "sample",
]
