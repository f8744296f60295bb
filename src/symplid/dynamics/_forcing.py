"""A generalised force F(q, p, u(t), t; θ_F): the driven, port-Hamiltonian form of eq. (3).

A driven or dissipative system adds a force to Hamilton's equations::

    q̇ = ∂H/∂p,    ṗ = −∂H/∂q + F(q, p, u(t), t; θ_F),

where H is any of the model's Hamiltonians, u(t) = (u1, …, um) are measured inputs (known,
not learned) and θ_F the force's own named parameters. Its power is
dH/dt = ∂H/∂p · F: the input power minus the dissipation. Linear friction −c·p1 is one case,
an input gain b·u1 another, ``"b*u1 - c*p1"`` both.

A :class:`Force` is the function ``F(q, p, u, t, params) -> (d,)`` of one point; it is made
from the user's expressions (:func:`user_force`, one per momentum, SymPy-parsed like a user
model by :func:`~symplid.dynamics._expressions.parse_expression`, so nothing of the text is
run as Python) or from a Python function in a file (``"file:force.py:F"``). The propagators
that keep their order with it are :mod:`symplid.dynamics._forced`.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import jax
import jax.numpy as jnp

from symplid.dynamics._expressions import (
    MAX_EXPRESSION_SIZE,
    UserModelError,
    first_line,
    parse_expression,
    quoted,
)
from symplid.dynamics._user_models import load_function

Array = jax.Array

__all__ = ["INPUT_NAME", "Force", "force_parameters", "input_names", "user_force"]

#: The name of the force's explicit time in an expression.
TIME = "t"
#: How an input is named in an expression and a data file: ``u1``, ``u2``, ….
INPUT_NAME = "u{}"

#: Newton iterations of the implicit half-kick, by how F depends on p (none: explicit).
_NEWTON = {"none": 0, "linear": 1, "nonlinear": 3}


def input_names(num_inputs: int) -> tuple[str, ...]:
    """``("u1", …, "um")``."""
    return tuple(INPUT_NAME.format(i + 1) for i in range(int(num_inputs)))


@dataclass(frozen=True)
class Force:
    """A generalised force ``fn(q, p, u, t, params) -> (d,)`` of one point.

    Parameters
    ----------
    fn
        ``q``, ``p`` of shape ``(d,)``, ``u`` of shape ``(m,)``, ``t`` a scalar, ``params`` of
        shape ``(len(names),)``; returns the force on each momentum, shape ``(d,)``.
    dim, num_inputs
        d and m.
    names
        The force's parameters θ_F, in θ's order (θ's ``force`` block).
    p_dependence
        ``"none"``, ``"linear"`` or ``"nonlinear"``: how F depends on p. It sets the Newton
        iterations of the implicit half-kick of :mod:`symplid.dynamics._forced` (0, 1, 3):
        exact for the first two, converged far below the step's error for the third.
    expressions
        The SymPy expressions of an expression force (None for a Python function).
    text
        What it was made from (the expressions, or ``file:PATH:NAME``). Two forces are equal
        when their text, dimension, inputs and parameters are: models built on equal forces
        share their compiled programs (:mod:`symplid.model._programs`).
    """

    fn: Callable[..., Array] = field(compare=False)
    dim: int
    num_inputs: int
    names: tuple[str, ...] = ()
    p_dependence: str = "nonlinear"
    expressions: Any = field(default=None, compare=False, repr=False)
    text: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "names", tuple(str(n) for n in self.names))
        if self.p_dependence not in _NEWTON:
            raise ValueError(f"p_dependence must be one of {', '.join(_NEWTON)}, "
                             f"got {self.p_dependence!r}")
        if self.dim < 1 or self.num_inputs < 0:
            raise ValueError("a force needs dim ≥ 1 and num_inputs ≥ 0")

    @property
    def num_params(self) -> int:
        """How many parameters θ_F holds."""
        return len(self.names)

    @property
    def param_names(self) -> tuple[str, ...]:
        """θ_F's names."""
        return self.names

    @property
    def newton_steps(self) -> int:
        """Newton iterations of the implicit half-kick (0 when F does not read p)."""
        return _NEWTON[self.p_dependence]

    def __call__(self, q: Array, p: Array, u: Array, t: Array, params: Array) -> Array:
        """F at one point ``(d,)`` or at points ``(d, N)`` (columns), ``u`` ``(m,)``."""
        q, p = jnp.asarray(q, dtype=float), jnp.asarray(p, dtype=float)
        u, params = jnp.asarray(u, dtype=float), jnp.asarray(params, dtype=float)

        def one(qi: Array, pi: Array) -> Array:
            return jnp.asarray(self.fn(qi, pi, u, t, params), dtype=float).reshape(self.dim)

        if q.ndim == 1:
            return one(q, p)
        flat_q, flat_p = q.reshape(q.shape[0], -1), p.reshape(p.shape[0], -1)
        out = jax.vmap(one, in_axes=(1, 1), out_axes=1)(flat_q, flat_p)
        return out.reshape(q.shape)


# ---------------------------------------------------------------------------- from text
def force_parameters(texts: str | Sequence[str], declared: Sequence[str]) -> tuple[str, ...]:
    """The declared parameters that force expressions name, in the order declared (a
    ``file:`` force takes every parameter not in H; the caller decides that)."""
    texts = [texts] if isinstance(texts, str) else list(texts)
    words = {w for text in texts for w in re.findall(r"[A-Za-z_][A-Za-z0-9_]*", text)}
    return tuple(n for n in declared if n in words)


def user_force(texts: str | Sequence[str], dim: int, names: Sequence[str], num_inputs: int,
               max_size: int = MAX_EXPRESSION_SIZE, key: str = "model.force") -> Force:
    """The force of expressions in q1..qd, p1..pd, u1..um, t and ``names``.

    ``texts`` is one expression per momentum (one text for d = 1), or ``"file:PATH:NAME"``
    naming ``F(q, p, u, t, params)`` written with ``jax.numpy`` (``params[name]``) that
    returns the d forces. The force's parameters are those of ``names`` that the expressions
    use (every one of ``names`` for a file).

    Raises
    ------
    UserModelError
        One line: an expression that cannot be read or uses an unknown symbol, one
        expression for a system of d ≠ 1 coordinates, an input u_j beyond ``num_inputs``.
    """
    names = tuple(str(n) for n in names)
    if isinstance(texts, str) and texts.strip().startswith("file:"):
        return _file_force(texts.strip(), dim, names, num_inputs, key)
    texts = [texts] if isinstance(texts, str) else [str(t) for t in texts]
    if len(texts) != dim:
        raise UserModelError(f"{key}: {len(texts)} expression(s) for a system of {dim} "
                             f"coordinates: give one force per momentum p1..p{dim}")
    inputs = input_names(num_inputs)
    allowed = (*names, *inputs, TIME)
    parsed = [parse_expression(t, allowed, key, require_all=False, max_size=max_size)
              for t in texts]
    for text, one in zip(texts, parsed, strict=True):
        top = max((*one.positions, *one.momenta), default=0)
        if top > dim:
            raise UserModelError(f"{key}: {quoted(text)} uses coordinate {top} but the "
                                 f"system has {dim} (q1..q{dim}, p1..p{dim})")
    used = {n for one in parsed for n in one.parameters}
    own = tuple(n for n in names if n in used)
    return _expression_force([one.expr for one in parsed], dim, own, num_inputs,
                             "; ".join(t.strip() for t in texts))


def _p_dependence(exprs: Sequence[Any], dim: int) -> str:
    """How the expressions depend on p1..pd (second derivatives zero: linear)."""
    import sympy

    ps = [sympy.Symbol(f"p{i + 1}", real=True) for i in range(dim)]
    if not any(e.has(p) for e in exprs for p in ps):
        return "none"
    second = [sympy.diff(e, a, b) for e in exprs for a in ps for b in ps]
    return "linear" if all(sympy.simplify(s) == 0 for s in second) else "nonlinear"


def _expression_force(exprs: list[Any], dim: int, names: tuple[str, ...], num_inputs: int,
                      text: str) -> Force:
    import sympy

    qs = [sympy.Symbol(f"q{i + 1}", real=True) for i in range(dim)]
    ps = [sympy.Symbol(f"p{i + 1}", real=True) for i in range(dim)]
    us = [sympy.Symbol(n, real=True) for n in input_names(num_inputs)]
    ts = sympy.Symbol(TIME, real=True)
    cs = [sympy.Symbol(n, real=True) for n in names]
    try:
        raw = sympy.lambdify([*qs, *ps, *us, ts, *cs], exprs, modules="jax", cse=True)
    except Exception as err:  # a construct SymPy cannot print for JAX
        raise UserModelError(f"model.force: cannot turn {quoted(text)} into a JAX function "
                             f"({first_line(err)})") from None

    def fn(q: Array, p: Array, u: Array, t: Array, params: Array) -> Array:
        args = (*(q[i] for i in range(dim)), *(p[i] for i in range(dim)),
                *(u[j] for j in range(num_inputs)), t, *(params[k] for k in range(len(names))))
        zero = 0.0 * q[0]  # a constant component still has the point's type
        return jnp.stack([jnp.asarray(v, dtype=float) + zero for v in raw(*args)])

    return Force(fn, dim, num_inputs, names, _p_dependence(exprs, dim), tuple(exprs), text)


def _file_force(spec: str, dim: int, names: tuple[str, ...], num_inputs: int,
                key: str) -> Force:
    """``F(q, p, u, t, params)`` from a file, traced once to check its shape."""
    raw = load_function(spec, key)

    def fn(q: Array, p: Array, u: Array, t: Array, params: Array) -> Array:
        mapping = {n: params[k] for k, n in enumerate(names)}
        return jnp.asarray(raw(q, p, u, t, mapping), dtype=float).reshape(dim)

    point = jax.ShapeDtypeStruct((dim,), jnp.float64)
    args = (point, point, jax.ShapeDtypeStruct((num_inputs,), jnp.float64),
            jax.ShapeDtypeStruct((), jnp.float64), jax.ShapeDtypeStruct((len(names),),
                                                                        jnp.float64))
    try:
        jax.eval_shape(fn, *args)
    except Exception as err:  # whatever the user's code raises under tracing
        raise UserModelError(f"{key}: {spec!r} is not a JAX-traceable function F(q, p, u, t, "
                             f"params) returning {dim} force(s): {first_line(err)}") from None
    return Force(fn, dim, num_inputs, names, "nonlinear", None, spec)
