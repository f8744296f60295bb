"""Posterior samplers: DRAM (the paper's), NUTS (BlackJAX) and the chunked multi-chain runner.

Each sampler is a pair of pure functions in the BlackJAX style, ``init`` and a ``step``
built by ``build_kernel(logdensity_fn, settings)``; :func:`run_chains` drives any such
kernel in compiled chunks over several chains, and :func:`sample` puts it all together and
returns ArviZ ``InferenceData``.

Adding a sampler: write ``samplers/<name>.py`` with ``init``/``build_kernel`` (a
``step(rng_key, state) -> (state, info)``), then a ``_run_<name>`` in ``samplers/api.py``
that builds the chain states and says which state/info fields to record.
"""

from symplid.inference.samplers import dram, nuts
from symplid.inference.samplers.api import draws_array, overdispersed_starts, sample
from symplid.inference.samplers.dram import DRAMInfo, DRAMSettings, DRAMState
from symplid.inference.samplers.nuts import NUTSSettings, NUTSState
from symplid.inference.samplers.registry import SAMPLERS
from symplid.inference.samplers.run import ChainRun, ChunkReport, SamplingInterrupted, run_chains

__all__ = [
    "SAMPLERS",
    "ChainRun",
    "ChunkReport",
    "DRAMInfo",
    "DRAMSettings",
    "DRAMState",
    "NUTSSettings",
    "NUTSState",
    "SamplingInterrupted",
    "dram",
    "draws_array",
    "nuts",
    "overdispersed_starts",
    "run_chains",
    "sample",
]
