"""Workflow (layer 7): settings, run folders, fit, compare, predictions of a run, sweeps on Dask.

The names below are the workflow's public surface, what the how-to pages use from Python: a
run's settings (:class:`Settings`, :func:`load_settings`, :func:`merge_overrides`), a fit
(:func:`fit`), a comparison of models (:func:`compare_models`, :func:`format_table`) and a
sweep (:func:`run_sweep`, :func:`load_results`, an :class:`Experiment` registered in
:data:`EXPERIMENTS`). The modules that define them are private; each name is imported when
first used.
"""

from symplid._namespace import lazy_attributes

#: The public names: name -> the module that defines it, imported on first use.
_PUBLIC = {
    "Settings": "symplid.workflow._settings_schema",
    "load_settings": "symplid.workflow._settings",
    "merge_overrides": "symplid.workflow._settings",
    "fit": "symplid.workflow._fit",
    "compare_models": "symplid.workflow._compare",
    "format_table": "symplid.workflow._compare_table",
    "run_sweep": "symplid.workflow._sweep",
    "load_results": "symplid.workflow._sweep_results",
    "EXPERIMENTS": "symplid.workflow._experiment",
    "Experiment": "symplid.workflow._experiment",
}
__getattr__, __dir__ = lazy_attributes(globals(), _PUBLIC)

__all__ = [*_PUBLIC]
