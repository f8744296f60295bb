"""Workflow (layer 6): settings, run folders, fit, compare, predictions of a run, sweeps on Dask."""

__all__ = []
