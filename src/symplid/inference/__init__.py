"""Inference (layer 4): MAP, Laplace, samplers (DRAM, NUTS), predictions, diagnostics."""

__all__ = []
