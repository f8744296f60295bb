"""Posterior samplers: DRAM (the paper's), NUTS, the registry and the chunked chain runner.

:func:`sample` runs a sampler named in :data:`SAMPLERS` (also ``symplid.sample``) and returns
ArviZ ``InferenceData``; :func:`draws_array` gives its draws as one array. Each sampler is a
pair of pure functions in the BlackJAX style (``init`` and a ``step``); a new one is one
registration of a :class:`SamplerSpec` whose ``build`` returns a :class:`SamplerKernel`, and
:func:`run_chains` drives it in compiled chunks over several chains. How the chains run is one
:class:`RunOptions`; without a fixed number of draws they run until the draws meet its
:class:`Targets` (bulk and tail ESS, R-hat) or a cap.
"""

from symplid._namespace import lazy_attributes

#: The public names: name -> the module that defines it, imported on first use.
_PUBLIC = {
    "SAMPLERS": "symplid.inference.samplers",
    "ChainRun": "symplid.sampling",
    "ChunkReport": "symplid.sampling",
    "DRAMInfo": "symplid.inference.samplers",
    "DRAMSettings": "symplid.inference.samplers",
    "DRAMState": "symplid.inference.samplers",
    "InterruptedInBurnIn": "symplid.sampling",
    "NUTSSettings": "symplid.inference.samplers",
    "NUTSState": "symplid.inference.samplers",
    "RunOptions": "symplid.sampling",
    "SamplerCheckpoint": "symplid.sampling",
    "SamplerKernel": "symplid.inference.samplers",
    "SamplerSpec": "symplid.inference.samplers",
    "SamplingInterrupted": "symplid.sampling",
    "Targets": "symplid.sampling",
    "draws_array": "symplid.sampling",
    "overdispersed_starts": "symplid.sampling",
    "run_chains": "symplid.sampling",
    "sample": "symplid.sampling",
}
#: Modules that were reachable here before (old paths; not in ``__all__``).
_MODULES = {
    "dram": "symplid.inference.samplers._dram",
    "nuts": "symplid.inference.samplers._nuts",
}
__getattr__, __dir__ = lazy_attributes(globals(), _PUBLIC, _MODULES)

__all__ = [*_PUBLIC]
