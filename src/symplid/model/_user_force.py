"""C++ for a user's U(q; θ): the force policy of a compiled user unit (``csrc/ukf_user.h``).

From the SymPy expression of U (:mod:`symplid.dynamics._user_models`) it writes one C++
struct, ``Force``, whose member templates run for one lane (``double``) and for a vector of
eight (``Vec``):

* ``add``: the force ∂U/∂q_j (what the leapfrog kicks of eqs 5–6 and the Runge–Kutta stages
  of eq. 14 read), common subexpressions computed once;
* ``adjoint``: for the gradient's reverse sweep through a kick p −= κ∇U(q), the
  Hessian–vector product ∇²U(q) v and, per parameter, v · ∂∇U/∂θ_t.

The derivatives are SymPy's, so they are exact; integer powers become products
(``pown``), half-integer ones a square root and products, and the functions those of
``csrc/ukf_user_math.h``. Nothing of the user's text reaches the compiler but the
expression tree that SymPy parsed from it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

__all__ = ["ForceCode", "UnsupportedExpression", "canonical", "canonical_text", "force_code"]

# SymPy function name → the name in csrc/ukf_user_math.h (namespace um).
_FUNCTIONS = {
    "exp": "exp", "log": "log", "sin": "sin", "cos": "cos", "tan": "tan", "sinh": "sinh",
    "cosh": "cosh", "tanh": "tanh", "asin": "asin", "acos": "acos", "atan": "atan",
    "Abs": "abs", "sign": "sign",
}


class UnsupportedExpression(ValueError):
    """An expression the code generator cannot write as C++ (the JAX tier runs it)."""


@dataclass(frozen=True)
class ForceCode:
    """The generated force policy: its C++ and what it was generated from."""

    source: str
    dim: int
    num_params: int
    canonical: str  # the expression, parameter order and dimension, as one text


def canonical(expr: Any) -> Any:
    """The expression in SymPy's canonical form (its automatic ordering of sums and products:
    ``(1 - cos(q1))*k`` and ``k*(1 - cos(q1))`` are one form): the code is generated from it,
    and the compiled unit's cache key is a hash of it. Not expanded: an expansion splits
    ``exp(a + b)`` into products of exponentials and powers of sums into many terms, which
    the generated code would then evaluate one by one."""
    return expr


def canonical_text(expr: Any, dim: int, names: Sequence[str]) -> str:
    """The canonical expression (``sympy.srepr``), the parameters in θ's order and d as one
    text: the same model gives the same text."""
    import sympy

    return f"d={dim};params={','.join(names)};U={sympy.srepr(canonical(expr))}"


def _balanced(parts: list[str], op: str) -> str:
    """``parts`` joined by ``op`` as a balanced tree: the compiler may not reassociate
    floating-point sums and products, so the dependent chain is what is written."""
    if len(parts) == 1:
        return parts[0]
    half = len(parts) // 2
    return f"({_balanced(parts[:half], op)} {op} {_balanced(parts[half:], op)})"


class _Printer:
    """C++ for SymPy expressions over named variables of the lane type T. Sums and products
    are balanced trees; in a product the factors that depend on θ alone come first (the
    compiler hoists them out of the substep loop), and a denominator is one reciprocal,
    computed beside the numerator rather than after it."""

    def __init__(self, names: dict[Any, str], static: set[Any]) -> None:
        self.names = names
        self.static = static  # symbols whose values do not change along a gap (θ)

    def _is_static(self, e: Any) -> bool:
        return e.is_number or e.free_symbols <= self.static

    def __call__(self, e: Any) -> str:
        import sympy

        if e in self.names:
            return self.names[e]
        if e.is_number:
            value = complex(sympy.N(e, 20))
            if value.imag != 0.0:
                raise UnsupportedExpression(f"a complex constant {e}")
            return repr(float(value.real))
        if isinstance(e, sympy.Add):
            return _balanced([self(a) for a in e.args], "+")
        if isinstance(e, sympy.Mul):
            return self._mul(e)
        if isinstance(e, sympy.Pow):
            return self._pow(e.base, e.exp)
        if isinstance(e, sympy.atan2):
            return f"um::atan2({self(e.args[0])}, {self(e.args[1])})"
        name = type(e).__name__
        if name in _FUNCTIONS and len(e.args) == 1:
            return f"um::{_FUNCTIONS[name]}({self(e.args[0])})"
        raise UnsupportedExpression(f"{name} ({e}) has no compiled form")

    def _mul(self, e: Any) -> str:
        import sympy

        static, dynamic, bottom = [], [], []
        for a in e.args:
            if isinstance(a, sympy.Pow) and a.exp.is_number and a.exp.is_negative:
                (static if self._is_static(a) else bottom).append(
                    self(a) if self._is_static(a) else self._pow(a.base, -a.exp))
            else:
                (static if self._is_static(a) else dynamic).append(self(a))
        if bottom:
            dynamic.append(f"(1.0 / {_balanced(bottom, '*')})")
        parts = ([_balanced(static, "*")] if static else []) + (
            [_balanced(dynamic, "*")] if dynamic else [])
        return _balanced(parts, "*") if parts else "1.0"

    def _pow(self, base: Any, exp: Any) -> str:
        import sympy

        b = self(base)
        if exp.is_Integer:
            n = int(exp)
            if n == 0:
                return "1.0"
            power = f"um::pown<{abs(n)}>({b})"
            return power if n > 0 else f"(1.0 / {power})"
        if exp.is_Rational and exp.q == 2:
            n = int(exp.p)
            root = f"um::sqrt({b})"
            whole = abs(n) // 2
            text = root if whole == 0 else f"(um::pown<{whole}>({b}) * {root})"
            return text if n > 0 else f"(1.0 / {text})"
        if exp.is_number:
            return f"um::pow({b}, {self(sympy.Float(exp, 20))})"
        return f"um::exp({self(exp)} * um::log({b}))"


def _block(outputs: Sequence[Any], targets: Sequence[str], names: dict[Any, str],
           params: Sequence[Any]) -> str:
    """C++ statements assigning ``outputs`` to ``targets``, common subexpressions once."""
    import sympy

    replacements, reduced = sympy.cse(list(outputs), symbols=sympy.numbered_symbols("_cse"))
    names = dict(names)
    printer = _Printer(names, set(params))
    lines = []
    for k, (sym, value) in enumerate(replacements):
        text = printer(value)
        names[sym] = f"t{k}"
        if printer._is_static(value):
            printer.static.add(sym)
        lines.append(f"    const T t{k} = T{{}} + {text};")
    lines += [f"    {target} = T{{}} + {printer(value)};"
              for target, value in zip(targets, reduced, strict=True)]
    return "\n".join(lines)


def force_code(expr: Any, dim: int, names: Sequence[str]) -> ForceCode:
    """The force policy of U(q; θ) = ``expr`` in ``q1..q{dim}`` and the parameters ``names``
    (θ's order).

    Raises
    ------
    UnsupportedExpression
        For a function or constant without a compiled form (the JAX tier runs the model).
    """
    import sympy

    expr = canonical(expr)
    qs = [sympy.Symbol(f"q{i + 1}", real=True) for i in range(dim)]
    cs = [sympy.Symbol(n, real=True) for n in names]
    vs = [sympy.Symbol(f"_v{i + 1}", real=True) for i in range(dim)]
    known = set(qs) | set(cs)
    stray = [s for s in expr.free_symbols if s not in known]
    if stray:
        raise UnsupportedExpression(f"unknown symbols {', '.join(map(str, stray))}")
    force = [sympy.diff(expr, q) for q in qs]
    hv = [sum((sympy.diff(force[j], qs[i]) * vs[j] for j in range(dim)), sympy.Integer(0))
          for i in range(dim)]
    pv = [sum((sympy.diff(force[j], c) * vs[j] for j in range(dim)), sympy.Integer(0))
          for c in cs]
    base = {q: f"x[{i}]" for i, q in enumerate(qs)} | {c: f"c{t}" for t, c in enumerate(cs)}
    params = "\n".join(f"    const auto c{t} = coef({t});" for t in range(len(cs)))
    add_body = _block(force, [f"acc[{i}]" for i in range(dim)], base, cs)
    adjoint_body = _block(
        [*hv, *pv],
        [f"hv[{i}]" for i in range(dim)] + [f"pv[{t}]" for t in range(len(cs))],
        base | {v: f"v[{i}]" for i, v in enumerate(vs)}, cs,
    )
    source = f"""struct Force {{
  static constexpr int D = {dim};
  static constexpr int kTerms = {len(cs)};
  static constexpr bool kTabled = false;
  static constexpr bool kScalarLane = false;

  // acc = dU/dq(x)
  template <bool INIT, class T, class Coef>
  SYMPLID_INLINE static void add(const T (&x)[D], const Coef& coef, T (&acc)[D]) {{
    static_assert(!INIT, "a user's force is never scaled into a kick's table");
{params}
{add_body}
  }}

  // hv = d2U/dq2(x) v; pv[t] = v . d(dU/dq)/d(theta_t)
  template <class T, class Coef>
  SYMPLID_INLINE static void adjoint(const T (&x)[D], const Coef& coef, const T (&v)[D],
                                     T (&hv)[D], T* pv) {{
{params}
{adjoint_body}
    (void)pv;
  }}
}};
"""
    return ForceCode(source, dim, len(cs), canonical_text(expr, dim, names))
