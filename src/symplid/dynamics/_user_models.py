"""A user's own U(q; θ) or H(q, p; θ): an expression, or a JAX function in a Python file.

Two forms name a model (``model.potential`` / ``model.hamiltonian`` in the run settings):

* an **expression** in the coordinates ``q1..qd``, the momenta ``p1..pd`` and the declared
  parameters, e.g. ``"-GM/sqrt(q1^2 + q2^2)"`` or ``"beta*exp(q1) - alpha*q1 + delta*exp(p1)
  - gamma*p1"``. ``^`` is a power. The text is checked token by token first (names must be
  coordinates, declared parameters or the functions of :data:`FUNCTIONS`; no attributes,
  subscripts, strings or keywords), then read by SymPy's parser with a dictionary that holds
  only those names, and compiled to ``jax.numpy`` by ``sympy.lambdify`` after SymPy's common
  subexpression elimination (``cse=True``: each repeated subexpression is evaluated once, and
  traced and compiled once): nothing of the text is ever run as Python. Gradients and
  Hessians are JAX's.

  What is refused, in one line that quotes at most :data:`QUOTE_LIMIT` characters of the
  text: a character that only looks like an ASCII one (a Unicode minus ``−``, a fullwidth
  ``ｋ``, ``×``: Python would fold some of them into another name), a division by zero or a
  value that is undefined or not real wherever the coordinates are (``1/(q1 - q1)``,
  ``log(0)``, ``sqrt(-1)``), and an expression of more than ``max_size`` tokens
  (:data:`MAX_EXPRESSION_SIZE`, the setting ``model.max_expression_size``): the compile time
  of the likelihood grows faster than the size of the expression (on a loaded machine, 20 s
  for a polynomial of 30 monomials, 67 s for 60; 100 monomials took 8 minutes before common
  subexpressions were eliminated).
* a **Python file**, ``"file:model.py:U"``: ``U(q, params)`` (a potential) or
  ``H(q, p, params)`` (a Hamiltonian) written with ``jax.numpy``, where ``q`` and ``p`` have
  shape ``(d,)`` and ``params`` maps each declared parameter name to its value.

A Hamiltonian expression in which no term mixes q and p is split into T(p) + U(q)
(:class:`~symplid.dynamics._separable.SeparablePotential`): leapfrog and Yoshida's methods
integrate it explicitly. Otherwise it is a :class:`~symplid.dynamics._hamiltonians.
FunctionHamiltonian`, for the non-separable integrators. ``model.kinetic`` declares a T(p)
for a potential in the same two forms (``"quadratic"``: ½pᵀM⁻¹p).
"""

from __future__ import annotations

import importlib.util
import re
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import jax
import jax.numpy as jnp

from symplid.dynamics._expressions import (
    CONSTANTS,
    COORDINATE,
    FUNCTIONS,
    MAX_EXPRESSION_SIZE,
    QUOTE_LIMIT,
    Expression,
    UserModelError,
    first_line,
    parse_expression,
    quoted,
)
from symplid.dynamics._hamiltonians import FunctionHamiltonian
from symplid.dynamics._potentials import FunctionPotential
from symplid.dynamics._separable import SeparablePotential

Array = jax.Array

__all__ = [
    "CONSTANTS",
    "FUNCTIONS",
    "MAX_EXPRESSION_SIZE",
    "QUADRATIC",
    "QUOTE_LIMIT",
    "UserHamiltonian",
    "UserModelError",
    "UserPotential",
    "build_user_model",
    "is_user_model",
    "load_function",
    "parse_expression",
    "quoted",
]

#: The kinetic energy ½pᵀM⁻¹p (``model.kinetic``'s default).
QUADRATIC = "quadratic"

@dataclass(frozen=True)
class UserPotential(FunctionPotential):
    """A user's U(q; θ): its parameters form θ's ``parameters`` group (declared priors)."""

    parameter_group: ClassVar[str] = "parameters"
    #: The SymPy expression of U for an expression model (None for a Python function): the
    #: compiled user kernel generates its force from it (symplid.model._user_kernel).
    expression: Any = field(default=None, compare=False, repr=False)


@dataclass(frozen=True, eq=False)
class UserHamiltonian(FunctionHamiltonian):
    """A user's non-separable H(q, p; θ); its parameters form θ's ``parameters`` group."""

    parameter_group: ClassVar[str] = "parameters"


def is_user_model(text: Any) -> bool:
    """Whether ``text`` is a user model (``file:...`` or an expression) rather than the name of
    a registered family: anything but a bare name (letters, digits, ``-``, ``_``), so that a
    misspelt family name is answered with the family names."""
    if not isinstance(text, str):
        return False
    text = text.strip()
    return (text.startswith("file:") or not re.fullmatch(r"[A-Za-z][A-Za-z0-9_-]*", text)
            or bool(COORDINATE.match(text)))


def _to_jax(symbols: Sequence[Any], expr: Any) -> Callable:
    """``expr`` as a ``jax.numpy`` function of ``symbols`` by ``sympy.lambdify``, after SymPy's
    common subexpression elimination (``cse=True``: the generated code assigns each repeated
    subexpression once and reuses it, so JAX traces, differentiates and compiles it once)."""
    import sympy

    try:
        return sympy.lambdify(list(symbols), expr, modules="jax", cse=True)
    except Exception as err:  # a construct SymPy cannot print for JAX
        raise UserModelError(f"cannot turn {quoted(str(expr))} into a JAX function "
                             f"({first_line(err)})") from None


def _lambdified(expr: Any, dim: int, names: Sequence[str], of: str) -> Callable:
    """``f(x, params)`` of one point ``x`` (the q's or the p's, ``of``) by ``sympy.lambdify``."""
    import sympy

    xs = [sympy.Symbol(f"{of}{i + 1}", real=True) for i in range(dim)]
    ps = [sympy.Symbol(n, real=True) for n in names]
    raw = _to_jax([*xs, *ps], expr)

    def fn(x: Array, params: Array) -> Array:
        value = raw(*(x[i] for i in range(dim)), *(params[j] for j in range(len(names))))
        return jnp.asarray(value, dtype=float) + 0.0 * x[0]  # a constant still depends on x

    return fn


def _split(expr: Any) -> tuple[Any, Any] | None:
    """(U(q), T(p)) when no term of ``expr`` mixes q and p; None otherwise."""
    import sympy

    u, t = sympy.Integer(0), sympy.Integer(0)
    for term in sympy.Add.make_args(sympy.expand(expr)):
        kinds = {s.name[0] for s in term.free_symbols if COORDINATE.match(s.name)}
        if kinds == {"q", "p"}:
            return None
        if kinds == {"p"}:
            t += term
        else:
            u += term
    return u, t


def _check_dim(parsed: Expression, dim: int, key: str) -> None:
    top = max((*parsed.positions, *parsed.momenta), default=0)
    if top > dim:
        raise UserModelError(f"{key}: the expression uses coordinate {top} but the data's "
                             f"system has {dim} (q1..q{dim}, p1..p{dim})")


def _expression_model(text: str, kind: str, dim: int, names: tuple[str, ...],
                      kinetic: str, max_size: int) -> Any:
    key = f"model.{kind}"
    separate_t = kind == "potential" and kinetic != QUADRATIC
    parsed = parse_expression(text, names, key, require_all=not separate_t, max_size=max_size)
    _check_dim(parsed, dim, key)
    if kind == "potential":
        if parsed.momenta:
            raise UserModelError(f"{key}: a potential U(q) cannot use the momenta p1..; write "
                                 f"the whole H as model.hamiltonian")
        u = _lambdified(parsed.expr, dim, names, "q")
        if kinetic == QUADRATIC:
            return UserPotential(u, dim, len(names), names, expression=parsed.expr)
        t = kinetic_function(kinetic, dim, names, parsed.parameters, max_size)
        return SeparablePotential(u, t, dim, len(names), names)
    parts = _split(parsed.expr)
    if parts is not None:
        u, t = (_lambdified(e, dim, names, v) for e, v in zip(parts, "qp", strict=True))
        return SeparablePotential(u, t, dim, len(names), names)
    return _nonseparable(parsed.expr, dim, names)


def _nonseparable(expr: Any, dim: int, names: tuple[str, ...]) -> UserHamiltonian:
    import sympy

    qs = [sympy.Symbol(f"q{i + 1}", real=True) for i in range(dim)]
    ps = [sympy.Symbol(f"p{i + 1}", real=True) for i in range(dim)]
    cs = [sympy.Symbol(n, real=True) for n in names]
    raw = _to_jax([*qs, *ps, *cs], expr)

    def h(q: Array, p: Array, params: Array) -> Array:
        value = raw(*(q[i] for i in range(dim)), *(p[i] for i in range(dim)),
                    *(params[j] for j in range(len(names))))
        return jnp.asarray(value, dtype=float) + 0.0 * q[0]

    return UserHamiltonian(h, dim, len(names), names)


def kinetic_function(text: str, dim: int, names: tuple[str, ...],
                     used_by_u: Sequence[str] | None = None,
                     max_size: int = MAX_EXPRESSION_SIZE) -> Callable:
    """T(p, params) of ``model.kinetic``: an expression in p1..pd, or ``file:PATH:NAME``.

    ``used_by_u``: the parameters the potential's expression uses; every declared parameter
    must appear in U or in T. ``max_size``: the most tokens of the expression.
    """
    if text.startswith("file:"):
        return _checked_file_function(text, "kinetic", dim, names)
    parsed = parse_expression(text, names, "model.kinetic", require_all=False,
                              max_size=max_size)
    unused = [n for n in names if n not in parsed.parameters and n not in (used_by_u or ())]
    if used_by_u is not None and unused:
        raise UserModelError(f"model.potential: the declared parameter(s) {', '.join(unused)} "
                             "appear in neither U nor T; remove them from [model.parameters]")
    _check_dim(parsed, dim, "model.kinetic")
    if parsed.positions:
        raise UserModelError("model.kinetic: a kinetic energy T(p) cannot use the positions "
                             "q1..; write the whole H as model.hamiltonian")
    t = _lambdified(parsed.expr, dim, parsed.parameters, "p")
    index = [names.index(n) for n in parsed.parameters]
    return lambda p, params: t(p, params[jnp.asarray(index, dtype=int)] if index else params)


def load_function(spec: str, key: str) -> Callable:
    """The function that ``"file:PATH:NAME"`` (or ``"PATH:NAME"``) names, imported from PATH.

    Raises
    ------
    UserModelError
        When the file is missing, cannot be imported, or does not define a callable NAME.
    """
    body = spec[5:] if spec.startswith("file:") else spec
    path_text, sep, name = body.rpartition(":")
    if not sep or not path_text or not name.isidentifier():
        raise UserModelError(f"{key}: {spec!r} must read file:PATH:NAME (e.g. "
                             "file:model.py:U)")
    path = Path(path_text).expanduser()
    if not path.is_file():
        raise UserModelError(f"{key}: no such file {str(path)!r}")
    module_name = f"symplid_user_model_{abs(hash(str(path.resolve())))}"
    loader = importlib.util.spec_from_file_location(module_name, path)
    if loader is None or loader.loader is None:
        raise UserModelError(f"{key}: {str(path)!r} is not a Python file")
    module = importlib.util.module_from_spec(loader)
    try:
        loader.loader.exec_module(module)
    except Exception as err:  # the user's file: any error it raises is theirs
        raise UserModelError(f"{key}: importing {str(path)!r} failed: "
                             f"{type(err).__name__}: {err}") from None
    sys.modules.pop(module_name, None)
    fn = getattr(module, name, None)
    if not callable(fn):
        raise UserModelError(f"{key}: {str(path)!r} does not define a function {name!r}")
    return fn


def _as_mapping(names: tuple[str, ...], params: Array) -> dict[str, Array]:
    return {n: params[j] for j, n in enumerate(names)}


def _checked_file_function(spec: str, kind: str, dim: int, names: tuple[str, ...]
                           ) -> Callable:
    """The file's function as ``f(x, params_vector)``, traced once to check it."""
    fn = load_function(spec, f"model.{kind}")
    nargs = 3 if kind == "hamiltonian" else 2
    if nargs == 3:
        def wrapped(q: Array, p: Array, params: Array) -> Array:
            return jnp.asarray(fn(q, p, _as_mapping(names, params)), dtype=float).reshape(())
    else:
        def wrapped(x: Array, params: Array) -> Array:  # type: ignore[misc]
            return jnp.asarray(fn(x, _as_mapping(names, params)), dtype=float).reshape(())
    point = jax.ShapeDtypeStruct((dim,), jnp.float64)
    args = (point,) * (nargs - 1) + (jax.ShapeDtypeStruct((len(names),), jnp.float64),)
    try:
        jax.eval_shape(jax.grad(wrapped), *args)
    except Exception as err:  # whatever the user's code raises under tracing
        first = str(err).strip().splitlines()[0] if str(err).strip() else ""
        raise UserModelError(
            f"model.{kind}: {spec!r} is not a JAX-traceable scalar function of "
            f"({'q, p, params' if nargs == 3 else 'x, params'}) with params[name] for "
            f"{', '.join(names) or 'no parameters'}: {type(err).__name__}: {first}") from None
    return wrapped


def build_user_model(text: str, kind: str, dim: int, names: Sequence[str],
                     kinetic: str = QUADRATIC, max_size: int = MAX_EXPRESSION_SIZE) -> Any:
    """The potential or Hamiltonian of a user model (module docstring).

    Parameters
    ----------
    text
        The expression, or ``file:PATH:NAME``.
    kind
        ``"potential"`` (U(q)) or ``"hamiltonian"`` (H(q, p)).
    dim
        The data's number of coordinates d.
    names
        The declared parameters, in θ's order.
    kinetic
        T(p) for a potential: ``"quadratic"`` (½pᵀM⁻¹p), an expression or ``file:PATH:NAME``.
    max_size
        The most tokens an expression may have (:data:`MAX_EXPRESSION_SIZE`).

    Returns
    -------
    UserPotential, SeparablePotential or UserHamiltonian
    """
    names = tuple(str(n) for n in names)
    text = text.strip()
    if kind not in ("potential", "hamiltonian"):
        raise ValueError(f"kind must be 'potential' or 'hamiltonian', got {kind!r}")
    if not text.startswith("file:"):
        return _expression_model(text, kind, dim, names, kinetic, max_size)
    fn = _checked_file_function(text, kind, dim, names)
    if kind == "hamiltonian":
        return UserHamiltonian(fn, dim, len(names), names)
    if kinetic == QUADRATIC:
        return UserPotential(fn, dim, len(names), names)
    t = kinetic_function(kinetic, dim, names, max_size=max_size)
    return SeparablePotential(fn, t, dim, len(names), names)
