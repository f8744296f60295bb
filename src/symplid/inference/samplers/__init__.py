"""Posterior samplers: DRAM (the paper's), NUTS (BlackJAX), the registry and the chunked runner.

Each sampler is a pair of pure functions in the BlackJAX style, ``init`` and a ``step``
built by ``build_kernel(logdensity_fn, settings)``; :func:`run_chains` drives any such
kernel in compiled chunks over several chains, and :func:`sample` puts it all together and
returns ArviZ ``InferenceData``. How the chains are run is one :class:`RunOptions`; by
default the run lasts until the draws meet its :class:`Targets` (:mod:`.budget`).

Adding a sampler is one registration in :data:`SAMPLERS`: a :class:`SamplerSpec` with the
settings class and a ``build(posterior, settings, num_warmup, batch_logdensity)`` that returns
a :class:`SamplerKernel` (``init_states``, ``step``, ``record``, ``final_attrs``); see
:mod:`symplid.inference.samplers.registry`. ``sample``, the settings file, the command line
and the sweeps then offer it by name.
"""

from symplid.inference.samplers import dram, nuts
from symplid.inference.samplers.api import (
    InterruptedInBurnIn,
    SamplerCheckpoint,
    draws_array,
    sample,
)
from symplid.inference.samplers.budget import STOPPED_BY
from symplid.inference.samplers.dram import DRAMInfo, DRAMSettings, DRAMState
from symplid.inference.samplers.nuts import NUTSSettings, NUTSState
from symplid.inference.samplers.options import RunOptions, Targets
from symplid.inference.samplers.registry import SAMPLERS, SamplerKernel, SamplerSpec
from symplid.inference.samplers.run import ChainRun, ChunkReport, SamplingInterrupted, run_chains
from symplid.inference.samplers.starts import overdispersed_starts

__all__ = [
    "SAMPLERS",
    "STOPPED_BY",
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
    "dram",
    "draws_array",
    "nuts",
    "overdispersed_starts",
    "run_chains",
    "sample",
]
