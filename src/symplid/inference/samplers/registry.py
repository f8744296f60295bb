"""The sampler registry: every MCMC method ``sample`` can run, by name."""

from __future__ import annotations

from symplid.inference.samplers.dram import DRAMSettings
from symplid.inference.samplers.nuts import NUTSSettings
from symplid.registry import Registry

SAMPLERS: Registry = Registry("sampler")
"""Sampler name → its settings class (DRAM, the paper's; NUTS through BlackJAX)."""
SAMPLERS.register("dram", DRAMSettings)
SAMPLERS.register("nuts", NUTSSettings)
