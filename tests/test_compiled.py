"""Compiled programs live on their owner (``symplid._compiled``), not in module-level caches."""

from __future__ import annotations

import gc
import weakref

import numpy as np

import symplid
from symplid._compiled import cached, clear, jit_for
from symplid.model._simulate import true_trajectory


class Owner:
    pass


def test_cached_builds_once_per_key_and_clear_forgets():
    owner, built = Owner(), []

    def build():
        built.append(1)
        return len(built)

    assert cached(owner, "a", build) == 1
    assert cached(owner, "a", build) == 1
    assert cached(owner, ("b", 2), build) == 2
    clear(owner)
    assert cached(owner, "a", build) == 3


def test_jit_for_compiles_once_per_static_arguments():
    owner = Owner()

    def scaled(_owner, factor, x):
        return factor * x

    double = jit_for(owner, scaled, 2.0)
    assert double is jit_for(owner, scaled, 2.0)
    assert jit_for(owner, scaled, 3.0) is not double
    assert float(double(np.float64(1.5))) == 3.0


def test_a_potential_and_its_programs_are_freed_after_use():
    """Simulating compiles a program for the potential; dropping the potential frees both."""
    potential = symplid.Polynomial(dim=1, order=2)
    coefficients = np.array([0.0, 0.5])
    states = true_trajectory(potential, coefficients, [1.0, 0.0], [0.5, 1.0], dt=0.1)
    np.testing.assert_allclose(states[:, 0], np.cos([0.5, 1.0]), atol=2e-3)
    ref = weakref.ref(potential)
    del potential
    gc.collect()
    assert ref() is None, "something outside the potential keeps it (and its programs) alive"
