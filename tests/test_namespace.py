"""The public namespaces' lazy tables (``symplid._namespace``): a namespace's names are the
objects of the modules its table names, ``__all__`` is the table, and importing a namespace
imports none of them (compared with the defining modules and, for the import, a fresh
interpreter's ``sys.modules``)."""

from __future__ import annotations

import importlib
import subprocess
import sys
import types

import pytest

import symplid
from symplid._namespace import lazy_attributes

FACADES = [n for n in symplid._NAMESPACES
           if not hasattr(importlib.import_module(f"symplid.{n}"), "__path__")
           and hasattr(importlib.import_module(f"symplid.{n}"), "_PUBLIC")]


def test_the_facades_are_tables():
    assert {"integrators", "priors", "samplers", "systems", "noise", "backends", "predict",
            "baselines"} <= set(FACADES)


@pytest.mark.parametrize("name", FACADES)
def test_a_facades_names_are_its_tables_objects(name):
    facade = importlib.import_module(f"symplid.{name}")
    assert list(facade.__all__) == list(facade._PUBLIC)
    for public, module in facade._PUBLIC.items():
        assert getattr(facade, public) is getattr(importlib.import_module(module), public)
    assert set(facade.__all__) <= set(dir(facade))
    assert "lazy_attributes" not in dir(facade)
    with pytest.raises(AttributeError, match="has no attribute 'nothing_here'"):
        facade.nothing_here


def test_importing_a_facade_imports_nothing_it_names():
    code = ("import sys, symplid.priors, symplid.samplers, symplid.integrators\n"
            "print(sorted(m for m in sys.modules if m.startswith(('jax', 'symplid.model'))))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "[]"


def test_lazy_attributes_on_a_module_of_its_own():
    module = types.ModuleType("probe")
    module.__getattr__, module.__dir__ = lazy_attributes(
        vars(module), {"sqrt": "math"}, {"json": "json"})
    import json
    import math
    assert module.sqrt is math.sqrt and module.json is json
    assert "sqrt" in vars(module)  # kept once found
    assert dir(module) == sorted({"__name__", "__doc__", "__package__", "__loader__",
                                  "__spec__", "__getattr__", "__dir__", "sqrt", "json"}
                                 & (set(vars(module)) | {"sqrt", "json"}))
    with pytest.raises(AttributeError):
        module.cos
