"""A stop asked for while the MAP's programs compile is obeyed at once (``symplid._stopping``).

XLA compiles in one C call that no signal can cut short; the MAP's first evaluation runs in a
worker thread (``first_call_waits``), so a stop requested meanwhile raises ``StopRequested``
within a poll interval, not when the compilation ends.
"""

from __future__ import annotations

import threading
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from symplid import _stopping as stopping
from symplid.inference.map import find_map


class _SlowToCompile:
    """A 1-D Gaussian written as a long unrolled chain of operations (seconds to compile)."""

    num_params = 1
    param_names = ("a",)
    param_groups = ("parameters",)
    lower = np.array([-np.inf])
    upper = np.array([np.inf])

    def log_density(self, theta):
        x = theta[0]
        acc = jnp.zeros(())
        for k in range(400):
            acc = acc + jnp.sin(x * (1.0 + 1e-4 * k)) * 1e-9
        return -0.5 * (x - 1.0) ** 2 + acc


def test_a_stop_during_the_map_compilation_is_obeyed_at_once():
    stopping.clear()
    jax.clear_caches()
    timer = threading.Timer(0.3, stopping.request, args=(2,))
    began = time.perf_counter()
    timer.start()
    try:
        with pytest.raises(stopping.StopRequested):
            find_map(_SlowToCompile(), init=np.array([0.0]), num_starts=1)
        waited = time.perf_counter() - began
    finally:
        timer.cancel()
        stopping.clear()
    assert waited < 0.3 + 1.0
