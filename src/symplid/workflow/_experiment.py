"""What a sweep needs to know of an experiment, and the registry of experiments.

An experiment (the paper's Hénon–Heiles study first) owns the keys of its sweep cells, the
function that runs one cell, the metrics it returns and how they are drawn. The generic sweep
(:mod:`symplid.workflow._sweep`) reads all of it from here and knows nothing of any one
experiment: a spec names its experiment (``experiment = "paper"``), and its cells are the
experiment's keys plus any dotted run setting (``"sampler.gamma" = 0.02``).

The sweep takes its experiment as an object (``run_sweep(spec, out, experiment=...)``).
The registry below maps a spec's ``experiment = "..."`` to one; the core registers nothing in
it. The studies beside the library (:mod:`symplid.studies`: ``"paper"``, ``"baselines"``)
are registered by :func:`symplid.studies.register_studies`, which the command line calls
before it reads a spec; a user registers their own::

    from symplid.workflow._experiment import EXPERIMENTS, Experiment

    EXPERIMENTS.register("mine", Experiment("mine", keys, "mypkg.cells:run_cell"))
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from symplid._registry import Registry
from symplid.workflow._validate import Spec

__all__ = ["EXPERIMENTS", "Experiment"]

CellFn = Callable[[dict[str, Any]], Mapping[str, Any]]


@dataclass(frozen=True)
class Experiment:
    """A named study whose cells a sweep can run.

    Parameters
    ----------
    name
        The registry name (``experiment = "..."`` in a sweep spec).
    keys
        The short keys of a cell, in table-column order, each with its :class:`Spec` (type,
        default, range, choices, doc; ``setting`` names the dotted run setting it stands for).
        A ``None`` default is filled by ``defaults``.
    run_cell
        ``run_cell(cell: dict) -> dict`` of metrics, or ``"module:function"``.
    metrics
        The metrics drawn by default (one figure each), in order.
    figures
        ``figures(table, folder, settings) -> {metric: path}``; ``None``: the generic
        :func:`symplid.plotting._sweep.plot_sweep` of ``metrics``.
    description
        One line for listings.
    defaults
        ``defaults(given) -> {key: value}`` for keys whose default depends on other keys (e.g.
        a system's noise level), called with the values given for a cell.
    base_settings
        ``base_settings(cell) -> nested dict``: the run settings every cell starts from, before
        the keys with a ``setting`` and the dotted keys are applied.
    renamed
        Old short key → new short key; the old one is read with a ``FutureWarning``.
    """

    name: str
    keys: Mapping[str, Spec]
    run_cell: str | CellFn
    metrics: tuple[str, ...] = ()
    figures: Callable[..., Mapping[str, Any]] | None = None
    description: str = ""
    defaults: Callable[[Mapping[str, Any]], Mapping[str, Any]] | None = None
    base_settings: Callable[[Mapping[str, Any]], dict[str, Any]] | None = None
    renamed: Mapping[str, str] = field(default_factory=dict)

    @property
    def mapped(self) -> dict[str, str]:
        """Dotted run setting → the short key that sets it."""
        return {spec.setting: key for key, spec in self.keys.items() if spec.setting}


EXPERIMENTS: Registry[Experiment] = Registry("experiment")
"""Experiments by name: none built in; filled by :func:`symplid.studies.register_studies`
(``"paper"``, ``"baselines"``) and by users."""
