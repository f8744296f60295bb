"""A library of candidate terms for ``symplid discover``: which model holds them all, and the
model of a chosen subset.

Two kinds of library:

* **a polynomial** of order N in q (the settings' ``model.potential = "polynomial"`` with
  ``model.order``, or ``order=N``): the terms are the monomials of eq. (13) in the library's
  basis order, and the library is the polynomial family itself, so the search runs on the
  compiled likelihood kernel;
* **a list of terms**, each an expression in the coordinates (``"q1^2"``, ``"cos(q1)"``,
  ``"q1^2*q2"``; momenta too, ``"p1^2"``, which makes the library a whole Hamiltonian):
  the library is the user model ``c1*(term1) + c2*(term2) + …`` whose coefficients ``c1``,
  ``c2``, … take the coefficients' prior (``priors.coefficients``, the paper's Laplace(0, 10)
  unless the settings say otherwise).

A chosen subset becomes a user model of its terms alone (:meth:`TermLibrary.subset_settings`),
which ``symplid fit`` then fits fully: sampler, report and predictions.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Sequence
from dataclasses import dataclass

from symplid.dynamics._potentials import Polynomial
from symplid.dynamics._user_models import UserModelError, parse_expression
from symplid.workflow._settings import Settings, merge_overrides
from symplid.workflow._validate import SettingsError

__all__ = ["LibraryError", "TermLibrary", "parse_terms", "term_library"]


class LibraryError(ValueError):
    """A library that cannot be built from what was given: one line saying why."""


_MOMENTUM = re.compile(r"\bp[1-9][0-9]*\b")


def parse_terms(text: str | Sequence[str]) -> list[str]:
    """Terms from ``"q1^2, q1^4, cos(q1)"`` (commas inside brackets belong to the term) or
    a list of strings; blanks are stripped, repeats refused.

    Raises
    ------
    LibraryError
        For an empty term or list, or a term given twice.
    """
    if isinstance(text, str):
        parts, depth, word = [], 0, []
        for ch in text:
            depth += (ch == "(") - (ch == ")")
            if ch == "," and depth == 0:
                parts.append("".join(word))
                word = []
            else:
                word.append(ch)
        parts.append("".join(word))
    else:
        parts = [str(t) for t in text]
    terms = [t.strip() for t in parts]
    if not terms or any(not t for t in terms):
        raise LibraryError(f"terms: expected e.g. 'q1^2, q1^4, cos(q1)', got {text!r}")
    seen = {t for t in terms if terms.count(t) > 1}
    if seen:
        raise LibraryError(f"terms: {sorted(seen)[0]!r} is given twice")
    return terms


@dataclass(frozen=True)
class TermLibrary:
    """The terms, the settings of the model that holds them all, and where their
    coefficients sit in θ (the first ``len(names)`` entries for both kinds)."""

    names: tuple[str, ...]
    settings: Settings  # the whole library's model
    kind: str  # "polynomial" or "terms"
    base: Settings  # the settings given, for the chosen subset's model

    @property
    def size(self) -> int:
        return len(self.names)

    def subset_settings(self, included: Sequence[bool]) -> Settings:
        """The settings of the model with the ``included`` terms alone: a user model whose
        coefficients are named after the library's (``c1``, ``c2``, … by position)."""
        chosen = [j for j, keep in enumerate(included) if keep]
        if not chosen:
            raise ValueError("the chosen subset has no term: there is no model to fit")
        return _expression_settings(self.base, [self.names[j] for j in chosen],
                                    [f"c{j + 1}" for j in chosen])


def _expression_settings(base: Settings, terms: Sequence[str], names: Sequence[str]) -> Settings:
    """``base`` with the user model Σ name·(term), each name with the coefficients' prior."""
    expression = " + ".join(f"{n}*({t})" for n, t in zip(names, terms, strict=True))
    prior = base.priors.coefficients.to_dict()
    prior["prior"] = prior.pop("family")
    whole_h = _has_momentum(terms)
    key = "model.hamiltonian" if whole_h else "model.potential"
    overrides = {key: expression, "model.standardise": "off",
                 **{f"model.parameters.{n}": dict(prior) for n in names}}
    return merge_overrides(base, overrides, source="terms")


def _has_momentum(terms: Sequence[str]) -> bool:
    """Whether a term names a momentum (the library is then a whole Hamiltonian)."""
    return any(_MOMENTUM.search(t) for t in terms)


def _check_term(term: str, dim: int) -> None:
    """A term is an expression in q1..qd (and p1..pd) alone, and uses at least one of them."""
    try:
        parsed = parse_expression(term, (), key="terms")
    except UserModelError as err:
        raise LibraryError(f"term {term!r}: {err}") from None
    used = parsed.positions + parsed.momenta
    if not used:
        raise LibraryError(f"term {term!r} is a constant: it does not change the dynamics")
    if max(used) > dim:
        raise LibraryError(f"term {term!r} names a coordinate beyond the data's {dim} "
                           "degree(s) of freedom")


def term_library(settings: Settings, dim: int, terms: str | Sequence[str] | None = None,
                 order: int | None = None) -> TermLibrary:
    """The library of ``terms`` (a list or comma-separated text), or else of the polynomial
    of ``order`` (default: ``settings.model.order``) in ``dim`` coordinates.

    Raises
    ------
    LibraryError
        For both ``terms`` and ``order``, a term that is not an expression in q1..qd (and
        p1..pd), or settings whose model is neither the polynomial family nor replaceable.
    """
    if terms is not None and order is not None:
        raise LibraryError("give either terms or a polynomial order, not both")
    if terms is None:
        m = settings.model
        if m.potential != "polynomial" or m.hamiltonian != "separable":
            raise LibraryError(
                f"model.potential is {m.potential!r}: a library is a polynomial (give an "
                "order) or a list of terms (give terms)")
        order = m.order if order is None else int(order)
        if order < 1:
            raise LibraryError(f"order: {order} is not a polynomial order (orders are ≥ 1)")
        model = dataclasses.replace(m, order=order, standardise="off")
        library = dataclasses.replace(settings, model=model)
        names = Polynomial(dim, order).param_names
        return TermLibrary(tuple(names), library, "polynomial", library)
    parsed = parse_terms(terms)
    for term in parsed:
        _check_term(term, dim)
    try:
        library = _expression_settings(settings, parsed, [f"c{j + 1}" for j in
                                                          range(len(parsed))])
    except SettingsError as err:
        raise LibraryError(str(err)) from None
    return TermLibrary(tuple(parsed), library, "terms", settings)
