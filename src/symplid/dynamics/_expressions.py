"""Reading a user's expression safely: the text checked character by character and token by
token, then SymPy's parser with only the allowed names in reach.

Used by :mod:`symplid.dynamics._user_models`, which turns the parsed expression into a potential
or a Hamiltonian (and re-exports the names of this module that users meet). Everything refused
here is refused in one line (:class:`UserModelError`) that quotes at most
:data:`QUOTE_LIMIT` characters of the text (:func:`quoted`): a name that is not a coordinate, a
declared parameter or one of :data:`FUNCTIONS`; any token but numbers, names and
``+ - * / ^ ( ) ,``; a character that only looks like an ASCII one (a Unicode minus, a
fullwidth letter, ``×``, ``²``: Python would fold some of them into another name); more than
``max_size`` tokens (:data:`MAX_EXPRESSION_SIZE`); a division by zero or a value that is
infinite, undefined or not real wherever the coordinates are (:func:`parse_expression` names
the part of the text that is); a declared parameter the expression does not use.
"""

from __future__ import annotations

import io
import re
import tokenize
import unicodedata
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

__all__ = [
    "CONSTANTS",
    "COORDINATE",
    "FUNCTIONS",
    "MAX_EXPRESSION_SIZE",
    "QUOTE_LIMIT",
    "Expression",
    "UserModelError",
    "first_line",
    "parse_expression",
    "quoted",
]

#: Functions an expression may call (SymPy's name on the right).
FUNCTIONS = {
    "exp": "exp", "log": "log", "sqrt": "sqrt", "sin": "sin", "cos": "cos", "tan": "tan",
    "sinh": "sinh", "cosh": "cosh", "tanh": "tanh", "asin": "asin", "acos": "acos",
    "atan": "atan", "abs": "Abs", "atan2": "atan2",
}
#: Constants an expression may name.
CONSTANTS = ("pi",)

#: The most tokens (numbers, names, operators) an expression may have by default
#: (``model.max_expression_size``): compile time grows faster than the size.
MAX_EXPRESSION_SIZE = 1000
#: The most characters of an expression an error message quotes.
QUOTE_LIMIT = 200

#: A coordinate's name: ``q1``.., ``p1``.. (group 1 the letter, group 2 the index).
COORDINATE = re.compile(r"^([qp])([1-9][0-9]*)$")
_OPERATORS = {"+", "-", "*", "/", "**", "^", "(", ")", ","}
#: Characters that look like an ASCII operator, and what to type instead (NFKC folds the
#: others that look like ASCII, such as fullwidth letters and digits).
_LOOKALIKES = {"\u2212": "-", "\u2010": "-", "\u2011": "-", "\u2012": "-", "\u2013": "-",
               "\u2014": "-", "\u00d7": "*", "\u00b7": "*", "\u2219": "*", "\u22c5": "*",
               "\u2217": "*", "\u00f7": "/", "\u2215": "/", "\u00b2": "^2", "\u00b3": "^3"}


class UserModelError(ValueError):
    """A user model that cannot be used: one line saying what is wrong and where."""


@dataclass(frozen=True)
class Expression:
    """A parsed expression: the SymPy object and what it uses."""

    expr: Any
    positions: tuple[int, ...]  # 1-based indices of the q's used
    momenta: tuple[int, ...]
    parameters: tuple[str, ...]


def quoted(text: str, limit: int = QUOTE_LIMIT) -> str:
    """``repr(text)``, or for a text longer than ``limit`` its start and end around ``…``
    with its length: what an error line may quote of an expression."""
    if len(text) <= limit:
        return repr(text)
    head, tail = text[: (2 * limit) // 3], text[-(limit // 3):]
    return f"{head!r} … {tail!r} ({len(text):,} characters)"


def _check_characters(text: str, key: str) -> None:
    """Refuse a non-ASCII character that looks like an ASCII one, or is no letter or digit
    of a name (a Greek letter may name a parameter)."""
    for at, ch in enumerate(text):
        if ch.isascii():
            continue
        folded = unicodedata.normalize("NFKC", ch)
        instead = _LOOKALIKES.get(ch) or (folded if folded != ch and folded.isascii() else "")
        what = f"{ch!r} (U+{ord(ch):04X} {unicodedata.name(ch, 'unnamed character')})"
        where = f"at character {at + 1} of {quoted(text)}"
        if instead:
            raise UserModelError(f"{key}: {what} {where} looks like {instead.strip()!r} but is "
                                 f"not it; type {instead.strip()!r}")
        if folded != ch or not (ch.isalpha() or ch.isdigit()):
            raise UserModelError(f"{key}: {what} {where} is not allowed in an expression; "
                                 "use numbers, + - * / ^ ( ) and names")


def _check_tokens(text: str, names: Sequence[str], key: str,
                  max_size: int = MAX_EXPRESSION_SIZE) -> None:
    """Refuse anything but numbers, the allowed operators and the allowed names, and more
    than ``max_size`` tokens."""
    allowed = set(names) | set(FUNCTIONS) | set(CONSTANTS)
    _check_characters(text, key)
    try:
        tokens = list(tokenize.generate_tokens(io.StringIO(text).readline))
    except (tokenize.TokenError, IndentationError, SyntaxError) as err:
        raise UserModelError(f"{key}: cannot read the expression {quoted(text)} "
                             f"({err})") from None
    size = sum(tok.type in (tokenize.NAME, tokenize.NUMBER, tokenize.OP) for tok in tokens)
    if size > max_size:
        raise UserModelError(f"{key}: the expression has {size:,} tokens, more than the limit "
                             f"of {max_size:,} (model.max_expression_size): its likelihood "
                             "would take very long to compile; write it with fewer terms, or "
                             "raise the limit")
    previous = None
    for tok in tokens:
        if tok.type in (tokenize.NEWLINE, tokenize.NL, tokenize.ENDMARKER, tokenize.INDENT,
                        tokenize.DEDENT):
            continue
        if tok.type == tokenize.NAME:
            if not (tok.string in allowed or COORDINATE.match(tok.string)):
                declared = ", ".join(names) or "none"
                raise UserModelError(
                    f"{key}: unknown symbol {tok.string!r} in {quoted(text)}: not a coordinate "
                    f"(q1.., p1..), a function ({', '.join(FUNCTIONS)}) or a parameter "
                    f"declared in [model.parameters] (declared: {declared})")
        elif tok.type == tokenize.OP and tok.string in _OPERATORS:
            if tok.string == "(" and previous is not None and previous.type == tokenize.NAME \
                    and previous.string not in FUNCTIONS:
                raise UserModelError(f"{key}: {previous.string!r} is not a function "
                                     f"({', '.join(FUNCTIONS)}) in {quoted(text)}")
        elif tok.type != tokenize.NUMBER or tok.string[-1] in "jJ":
            raise UserModelError(f"{key}: {tok.string!r} is not allowed in an expression "
                                 f"({quoted(text)}); use numbers, + - * / ^ ( ) and names")
        previous = tok


def _sympy_parse(text: str, names: Sequence[str], evaluate: bool = True) -> Any:
    """SymPy's parser on checked ``text``, with only the allowed names in reach."""
    import sympy
    from sympy.parsing.sympy_parser import convert_xor, parse_expr, standard_transformations

    coords = set(re.findall(r"\b[qp][1-9][0-9]*\b", text))
    local = {n: sympy.Symbol(n, real=True) for n in [*names, *coords]}
    glob: dict[str, Any] = {"__builtins__": {}, "Integer": sympy.Integer,
                            "Float": sympy.Float, "Rational": sympy.Rational,
                            "Symbol": sympy.Symbol, "pi": sympy.pi}
    if not evaluate:  # the parser then writes the operators as SymPy's classes
        glob |= {"Add": sympy.Add, "Mul": sympy.Mul, "Pow": sympy.Pow}
    glob |= {name: getattr(sympy, fn) for name, fn in FUNCTIONS.items()}
    return parse_expr(text, local_dict=local, global_dict=glob,
                      transformations=(*standard_transformations, convert_xor),
                      evaluate=evaluate)


def first_line(err: BaseException, limit: int = 120) -> str:
    """``Type: message`` of an exception, its first line, at most ``limit`` characters."""
    lines = str(err).strip().splitlines()
    text = lines[0] if lines else ""
    text = text if len(text) <= limit else text[:limit] + " …"
    return f"{type(err).__name__}: {text}" if text else type(err).__name__


def _not_finite_or_real(expr: Any) -> bool:
    """Whether ``expr`` holds an infinite or undefined number, or a number that is not real."""
    import sympy

    if expr.has(sympy.zoo, sympy.oo, -sympy.oo, sympy.nan):
        return True
    return any(node.is_number and node.is_extended_real is False
               for node in sympy.preorder_traversal(expr))


def _undefined_cause(text: str, names: Sequence[str]) -> str:
    """What makes the expression infinite, undefined or complex: the innermost part of the
    text as written (parsed without evaluation) whose value is."""
    import sympy

    try:
        raw = _sympy_parse(text, names, evaluate=False)
    except Exception:  # the evaluated parse succeeded; keep the general answer
        return "it has an infinite, undefined or complex value"
    for node in sympy.postorder_traversal(raw):
        if not isinstance(node, sympy.Expr):
            continue
        value = node.doit()
        if not _not_finite_or_real(value):
            continue
        written = sympy.sstr(node, order="none")
        if isinstance(node, sympy.Pow) and node.exp.is_negative and node.base.doit() == 0:
            base = sympy.sstr(node.base, order="none")
            return f"division by zero in {written}" + ("" if node.base.is_Number
                                                       else f" ({base} is 0)")
        if value.has(sympy.nan):
            return f"an undefined value: {written} is not a number"
        if value.has(sympy.zoo, sympy.oo, -sympy.oo):
            return f"an undefined value: {written} is infinite"
        return f"a value that is not real: {written} is {sympy.sstr(value)}"
    return "it has an infinite, undefined or complex value"


def parse_expression(text: str, names: Sequence[str], key: str = "model.potential",
                     require_all: bool = True, max_size: int = MAX_EXPRESSION_SIZE
                     ) -> Expression:
    """Read ``text`` safely into a SymPy expression (module docstring).

    ``require_all``: every name of ``names`` must appear (else only those that do are kept).
    ``max_size``: the most tokens the text may have.

    Raises
    ------
    UserModelError
        For a lookalike or other non-ASCII character, an unknown symbol, a forbidden token,
        more than ``max_size`` tokens, a division by zero or a value that is undefined or not
        real, a declared parameter it does not use, or text that is not an expression.
    """
    import sympy

    _check_tokens(text, names, key, max_size)
    try:
        expr = _sympy_parse(text, names)
    except Exception as err:  # SymPy raises many kinds for malformed text
        raise UserModelError(f"{key}: cannot read the expression {quoted(text)} "
                             f"({first_line(err)})") from None
    if not isinstance(expr, sympy.Expr):
        raise UserModelError(f"{key}: {quoted(text)} is not a scalar expression")
    if _not_finite_or_real(expr):
        raise UserModelError(f"{key}: {quoted(text)} cannot be used: "
                             f"{_undefined_cause(text, names)}")
    used = {s.name for s in expr.free_symbols}
    unused = [n for n in names if n not in used]
    if not require_all:
        names = [n for n in names if n in used]
    elif unused:
        raise UserModelError(f"{key}: the declared parameter(s) {', '.join(unused)} do not "
                             f"appear in {quoted(text)}; remove them from [model.parameters]")
    q = tuple(sorted(int(n[1:]) for n in used if n.startswith("q") and COORDINATE.match(n)))
    p = tuple(sorted(int(n[1:]) for n in used if n.startswith("p") and COORDINATE.match(n)))
    return Expression(expr, q, p, tuple(names))
