"""Prior families over the entries of θ (Section IV), their registry and how they are read.

Which prior each parameter gets (the paper's Laplace(0, b = 10) on every coefficient and
HalfNormal(1) on every variance) is :class:`symplid.model._prior_spec.PriorSpec`.

Each prior is a small frozen dataclass with

* ``log_density(x)``: the elementwise log density, in JAX (``jit``/``vmap``/``grad``-able),
  normalised, and −∞ outside the support (with a finite gradient everywhere, never NaN);
* ``support``: ``(lower, upper)``, possibly infinite;
* ``sample(key, shape)``: draws with an explicit PRNG key;
* ``mean``, ``std`` and ``median``: used for starting points and test tolerances;
* ``to_dict()``: ``{"family": ..., parameters...}`` for settings files, read back by
  :func:`prior_from_dict`; the ``repr`` (``Laplace(loc=0.0, scale=10.0)``) is read back by
  :func:`parse_prior`.

Family names and keys are those of the settings file: ``laplace`` and ``normal`` (``loc``,
``scale``), ``half-normal`` (``scale``), ``uniform`` (``low``, ``high``), ``log-normal``
(``mu`` and ``sigma`` of log x; ``loc`` and ``scale`` are accepted as synonyms),
``log-uniform`` (``low``, ``high``: log x uniform between their logarithms).

To add a family: write a frozen dataclass subclass of :class:`Prior` with ``family``,
``log_density``, ``support``, ``sample``, ``mean``, ``std``, ``median``, and list it in
:data:`PRIOR_FAMILIES`.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from symplid._registry import Registry

Array = jax.Array

_LOG_2PI = math.log(2.0 * math.pi)

def _positive(name: str, value: float, family: str) -> float:
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{family} prior: {name} must be a finite number > 0, got {value!r}")
    return value


def _finite(name: str, value: float, family: str) -> float:
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{family} prior: {name} must be finite, got {value!r}")
    return value


class Prior:
    """Base class of the prior families (see the module docstring for the interface)."""

    family: ClassVar[str] = ""
    log_scale: ClassVar[bool] = False
    """Whether the family is a law of log x (log-normal, log-uniform): DRAM's default
    ``parameter_scale = "prior"`` moves such a parameter as log x."""

    def log_density(self, x: Array) -> Array:  # pragma: no cover - abstract
        raise NotImplementedError

    @property
    def support(self) -> tuple[float, float]:  # pragma: no cover - abstract
        raise NotImplementedError

    def sample(self, key: Array, shape: tuple[int, ...] = ()) -> Array:  # pragma: no cover
        raise NotImplementedError

    @property
    def mean(self) -> float:  # pragma: no cover - abstract
        raise NotImplementedError

    @property
    def std(self) -> float:  # pragma: no cover - abstract
        raise NotImplementedError

    @property
    def median(self) -> float:  # pragma: no cover - abstract
        raise NotImplementedError

    def to_dict(self) -> dict[str, Any]:
        """``{"family": ..., <parameter>: <float>, ...}`` (JSON- and TOML-ready)."""
        out: dict[str, Any] = {"family": self.family}
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            out[f.name] = float(getattr(self, f.name))
        return out

    def _inside(self, x: Array) -> Array:
        lo, hi = self.support
        inside = jnp.ones(jnp.shape(x), dtype=bool)
        if math.isfinite(lo):
            inside = inside & (x >= lo)
        if math.isfinite(hi):
            inside = inside & (x <= hi)
        return inside


@dataclass(frozen=True)
class Laplace(Prior):
    """Laplace(loc, scale): density exp(−|x − loc|/scale) / (2 scale); the paper's b = scale."""

    loc: float = 0.0
    scale: float = 10.0
    family: ClassVar[str] = "laplace"

    def __post_init__(self) -> None:
        object.__setattr__(self, "loc", _finite("loc", self.loc, self.family))
        object.__setattr__(self, "scale", _positive("scale", self.scale, self.family))

    def log_density(self, x: Array) -> Array:
        x = jnp.asarray(x, dtype=float)
        return -jnp.abs(x - self.loc) / self.scale - math.log(2.0 * self.scale)

    @property
    def support(self) -> tuple[float, float]:
        return (-math.inf, math.inf)

    def sample(self, key: Array, shape: tuple[int, ...] = ()) -> Array:
        return self.loc + self.scale * jax.random.laplace(key, shape, dtype=jnp.float64)

    @property
    def mean(self) -> float:
        return self.loc

    @property
    def std(self) -> float:
        return math.sqrt(2.0) * self.scale

    @property
    def median(self) -> float:
        return self.loc


@dataclass(frozen=True)
class Normal(Prior):
    """Normal(loc, scale) with standard deviation ``scale``."""

    loc: float = 0.0
    scale: float = 1.0
    family: ClassVar[str] = "normal"

    def __post_init__(self) -> None:
        object.__setattr__(self, "loc", _finite("loc", self.loc, self.family))
        object.__setattr__(self, "scale", _positive("scale", self.scale, self.family))

    def log_density(self, x: Array) -> Array:
        x = jnp.asarray(x, dtype=float)
        z = (x - self.loc) / self.scale
        return -0.5 * z * z - math.log(self.scale) - 0.5 * _LOG_2PI

    @property
    def support(self) -> tuple[float, float]:
        return (-math.inf, math.inf)

    def sample(self, key: Array, shape: tuple[int, ...] = ()) -> Array:
        return self.loc + self.scale * jax.random.normal(key, shape, dtype=jnp.float64)

    @property
    def mean(self) -> float:
        return self.loc

    @property
    def std(self) -> float:
        return self.scale

    @property
    def median(self) -> float:
        return self.loc


@dataclass(frozen=True)
class HalfNormal(Prior):
    """HalfNormal(scale): the law of ``|Z|``·scale, Z ~ N(0, 1); support [0, ∞)."""

    scale: float = 1.0
    family: ClassVar[str] = "half-normal"

    def __post_init__(self) -> None:
        object.__setattr__(self, "scale", _positive("scale", self.scale, self.family))

    def log_density(self, x: Array) -> Array:
        x = jnp.asarray(x, dtype=float)
        z = x / self.scale
        value = -0.5 * z * z - math.log(self.scale) + 0.5 * math.log(2.0 / math.pi)
        return jnp.where(x >= 0.0, value, -jnp.inf)

    @property
    def support(self) -> tuple[float, float]:
        return (0.0, math.inf)

    def sample(self, key: Array, shape: tuple[int, ...] = ()) -> Array:
        return self.scale * jnp.abs(jax.random.normal(key, shape, dtype=jnp.float64))

    @property
    def mean(self) -> float:
        return self.scale * math.sqrt(2.0 / math.pi)

    @property
    def std(self) -> float:
        return self.scale * math.sqrt(1.0 - 2.0 / math.pi)

    @property
    def median(self) -> float:
        return self.scale * 0.6744897501960817  # Φ⁻¹(3/4)


@dataclass(frozen=True)
class Uniform(Prior):
    """Uniform(low, high) on the closed interval [low, high]."""

    low: float = 0.0
    high: float = 1.0
    family: ClassVar[str] = "uniform"

    def __post_init__(self) -> None:
        low = _finite("low", self.low, self.family)
        high = _finite("high", self.high, self.family)
        if not low < high:
            raise ValueError(f"uniform prior: low ({low:g}) must be less than high ({high:g})")
        object.__setattr__(self, "low", low)
        object.__setattr__(self, "high", high)

    def log_density(self, x: Array) -> Array:
        x = jnp.asarray(x, dtype=float)
        value = jnp.full(jnp.shape(x), -math.log(self.high - self.low))
        return jnp.where(self._inside(x), value, -jnp.inf)

    @property
    def support(self) -> tuple[float, float]:
        return (self.low, self.high)

    def sample(self, key: Array, shape: tuple[int, ...] = ()) -> Array:
        return jax.random.uniform(
            key, shape, dtype=jnp.float64, minval=self.low, maxval=self.high
        )

    @property
    def mean(self) -> float:
        return 0.5 * (self.low + self.high)

    @property
    def std(self) -> float:
        return (self.high - self.low) / math.sqrt(12.0)

    @property
    def median(self) -> float:
        return self.mean


@dataclass(frozen=True)
class LogNormal(Prior):
    """LogNormal(mu, sigma): log x ~ N(mu, sigma²); support (0, ∞)."""

    mu: float = 0.0
    sigma: float = 1.0
    family: ClassVar[str] = "log-normal"
    log_scale: ClassVar[bool] = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "mu", _finite("mu", self.mu, self.family))
        object.__setattr__(self, "sigma", _positive("sigma", self.sigma, self.family))

    def log_density(self, x: Array) -> Array:
        x = jnp.asarray(x, dtype=float)
        positive = x > 0.0
        safe = jnp.where(positive, x, 1.0)  # keeps log and its gradient finite off the support
        log_x = jnp.log(safe)
        z = (log_x - self.mu) / self.sigma
        value = -0.5 * z * z - log_x - math.log(self.sigma) - 0.5 * _LOG_2PI
        return jnp.where(positive, value, -jnp.inf)

    @property
    def support(self) -> tuple[float, float]:
        return (0.0, math.inf)

    def sample(self, key: Array, shape: tuple[int, ...] = ()) -> Array:
        return jnp.exp(self.mu + self.sigma * jax.random.normal(key, shape, dtype=jnp.float64))

    @property
    def mean(self) -> float:
        return math.exp(self.mu + 0.5 * self.sigma**2)

    @property
    def std(self) -> float:
        s2 = self.sigma**2
        return math.sqrt(math.expm1(s2)) * math.exp(self.mu + 0.5 * s2)

    @property
    def median(self) -> float:
        return math.exp(self.mu)


@dataclass(frozen=True)
class LogUniform(Prior):
    """LogUniform(low, high): log x uniform on [log low, log high]; density 1/(x log(high/low)).

    A scale-free prior for a variance whose order of magnitude is unknown: every decade of
    [low, high] holds the same mass, so a variance the data cannot tell from zero keeps no
    more mass near ``high`` than near ``low`` (unlike HalfNormal(1), whose mass at 1e-6…1e-4
    is all the data leave it). ``0 < low < high``.
    """

    low: float = 1e-8
    high: float = 1.0
    family: ClassVar[str] = "log-uniform"
    log_scale: ClassVar[bool] = True

    def __post_init__(self) -> None:
        low = _positive("low", self.low, self.family)
        high = _positive("high", self.high, self.family)
        if not low < high:
            raise ValueError(f"log-uniform prior: low ({low:g}) must be less than high ({high:g})")
        object.__setattr__(self, "low", low)
        object.__setattr__(self, "high", high)

    @property
    def _width(self) -> float:
        return math.log(self.high / self.low)

    def log_density(self, x: Array) -> Array:
        x = jnp.asarray(x, dtype=float)
        inside = self._inside(x)
        safe = jnp.where(inside, x, self.low)  # log and its gradient finite off the support
        return jnp.where(inside, -jnp.log(safe) - math.log(self._width), -jnp.inf)

    @property
    def support(self) -> tuple[float, float]:
        return (self.low, self.high)

    def sample(self, key: Array, shape: tuple[int, ...] = ()) -> Array:
        u = jax.random.uniform(key, shape, dtype=jnp.float64)
        return jnp.exp(math.log(self.low) + self._width * u)

    @property
    def mean(self) -> float:
        return (self.high - self.low) / self._width

    @property
    def std(self) -> float:
        second = (self.high**2 - self.low**2) / (2.0 * self._width)
        return math.sqrt(max(second - self.mean**2, 0.0))

    @property
    def median(self) -> float:
        return math.sqrt(self.low * self.high)


PRIOR_FAMILIES: Registry[type[Prior]] = Registry("prior family")
"""Family name → class, for :func:`prior_from_dict`, :func:`parse_prior` and settings.

A new family is a :class:`Prior` subclass (a frozen dataclass whose fields are its
parameters) registered here: ``PRIOR_FAMILIES.register("student-t", StudentT)``.
"""
PRIOR_FAMILIES.register("laplace", Laplace)
PRIOR_FAMILIES.register("normal", Normal, aliases=("gaussian",))
PRIOR_FAMILIES.register("half-normal", HalfNormal, aliases=("halfnormal",))
PRIOR_FAMILIES.register("uniform", Uniform)
PRIOR_FAMILIES.register("log-normal", LogNormal, aliases=("lognormal",))
PRIOR_FAMILIES.register("log-uniform", LogUniform, aliases=("loguniform",))

_SYNONYMS = {"log-normal": {"loc": "mu", "scale": "sigma"}}


def _family_key(name: str) -> str:
    return PRIOR_FAMILIES.canonical(name)


def prior_from_dict(spec: Mapping[str, Any]) -> Prior:
    """A prior from ``{"family": "laplace", "loc": 0, "scale": 10}`` (as written by ``to_dict``;
    ``"prior"`` in place of ``"family"``, as in a settings file's tables, is read the same).

    Missing parameters take the family's defaults; a key the family does not use is an error.
    """
    if isinstance(spec, Mapping) and "prior" in spec and "family" not in spec:
        spec = {("family" if k == "prior" else k): v for k, v in spec.items()}  # a settings table
    if not isinstance(spec, Mapping) or "family" not in spec:
        raise ValueError(f"a prior must be a table with a 'family' key, got {spec!r}")
    family = _family_key(spec["family"])
    cls = PRIOR_FAMILIES[family]
    names = [f.name for f in dataclasses.fields(cls)]  # type: ignore[arg-type]
    synonyms = _SYNONYMS.get(family, {})
    kwargs: dict[str, float] = {}
    for key, value in spec.items():
        if key == "family":
            continue
        name = synonyms.get(key, key)
        if name not in names:
            raise ValueError(
                f"{family} prior: unknown parameter {key!r} (it takes: {', '.join(names)})"
            )
        if isinstance(value, bool) or not isinstance(value, int | float | np.number):
            raise ValueError(f"{family} prior: {key} must be a number, got {value!r}")
        kwargs[name] = float(value)
    return cls(**kwargs)


_CALL = re.compile(r"^\s*([A-Za-z_\- ]+)\s*\((.*)\)\s*$")


def parse_prior(text: str) -> Prior:
    """A prior from text such as ``"laplace(0, 10)"`` or ``"HalfNormal(scale=1)"``.

    Positional arguments follow the dataclass field order (loc, scale / low, high / mu, sigma).
    The ``repr`` of every prior parses back to an equal prior.
    """
    match = _CALL.match(str(text))
    if not match:
        raise ValueError(f"cannot read a prior from {text!r}; write e.g. 'laplace(0, 10)'")
    raw = match.group(1).strip()
    # class names (HalfNormal, LogNormal) as well as family names
    family = _family_key(re.sub(r"(?<=[a-z])(?=[A-Z])", "-", raw))
    cls = PRIOR_FAMILIES[family]
    names = [f.name for f in dataclasses.fields(cls)]  # type: ignore[arg-type]
    spec: dict[str, Any] = {"family": family}
    args = [a.strip() for a in match.group(2).split(",") if a.strip()]
    for i, arg in enumerate(args):
        key, sep, value = arg.partition("=")
        if not sep:
            if i >= len(names):
                raise ValueError(f"too many arguments in {text!r}; {family} takes {names}")
            key, value = names[i], arg
        try:
            spec[key.strip()] = float(value)
        except ValueError:
            raise ValueError(f"cannot read the number {value.strip()!r} in {text!r}") from None
    return prior_from_dict(spec)


def as_prior(obj: Prior | Mapping[str, Any] | str, where: str = "prior") -> Prior:
    """A :class:`Prior` from a prior, a ``to_dict`` mapping or text (``where``: for errors)."""
    if isinstance(obj, Prior):
        return obj
    try:
        if isinstance(obj, Mapping):
            return prior_from_dict(obj)
        if isinstance(obj, str):
            return parse_prior(obj)
    except ValueError as err:
        raise ValueError(f"{where}: {err}") from None
    raise TypeError(f"{where}: expected a Prior, a mapping or a string, got {type(obj).__name__}")


__all__ = [
    "PRIOR_FAMILIES",
    "HalfNormal",
    "Laplace",
    "LogNormal",
    "LogUniform",
    "Normal",
    "Prior",
    "Uniform",
    "as_prior",
    "parse_prior",
    "prior_from_dict",
]
