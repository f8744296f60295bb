"""Posterior samplers' kernels: DRAM (the paper's), NUTS (BlackJAX) and their registry.

Each sampler is a pair of pure functions in the BlackJAX style, ``init`` and a ``step``
built by ``build_kernel(logdensity_fn, settings)``; nothing here runs a chain. The runner
(:mod:`symplid.sampling`: chunks, starting points, restarts of stuck chains, the stopping
rule, progress, resumption and :func:`symplid.sampling.sample`) drives any such kernel.

Adding a sampler is one registration in :data:`SAMPLERS`: a :class:`SamplerSpec` with the
settings class and a ``build(posterior, settings, num_warmup, batch_logdensity)`` that returns
a :class:`SamplerKernel` (``init_states``, ``step``, ``record``, ``final_attrs``); see
:mod:`symplid.inference.samplers._registry`. ``sample``, the settings file, the command line
and the sweeps then offer it by name.
"""

from symplid.inference.samplers import _dram as dram
from symplid.inference.samplers import _nuts as nuts
from symplid.inference.samplers._dram import DRAMInfo, DRAMSettings, DRAMState
from symplid.inference.samplers._nuts import NUTSSettings, NUTSState
from symplid.inference.samplers._registry import SAMPLERS, DataStep, SamplerKernel, SamplerSpec

__all__ = [
    "SAMPLERS",
    "DRAMInfo",
    "DRAMSettings",
    "DRAMState",
    "DataStep",
    "NUTSSettings",
    "NUTSState",
    "SamplerKernel",
    "SamplerSpec",
    "dram",
    "nuts",
]
