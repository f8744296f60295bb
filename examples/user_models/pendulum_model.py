"""The pendulum's potential as a Python function: ``--potential pendulum_model.py:U``.

``q`` has shape (d,); ``params`` maps each name of ``[model.parameters]`` to its value.
Write it with ``jax.numpy`` so that symplid can differentiate it.
"""

import jax.numpy as jnp


def U(q, params):
    return params["k"] * (1.0 - jnp.cos(q[0]))
