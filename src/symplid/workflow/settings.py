"""Run settings: nested frozen dataclasses with the paper's defaults, read from and written to TOML.

A settings file has one table per section; every key is optional and defaults to the value
used in the seed paper's Hénon–Heiles experiment (Section IV):

.. code-block:: toml

    seed = 0                      # seeds [map] and [sampler] unless they set their own

    [model]                       # the state-space model, eq. (7)
    order = 3                     # polynomial potential of total degree ≤ 3 (eqs 17–18)
    integrator = "leapfrog"       # any name in symplid.dynamics.integrators.INTEGRATORS
    dt = 0.25                     # learning step; each gap is split in ⌈gap/dt⌉ steps (eq. 14)
    process_noise_per = "gap"     # Σ added once per observation gap ("step": every substep)
    noise = "isotropic"           # Σ = θ_Σ I, Γ = θ_Γ I ("diagonal": one variance per component)
    observation = "auto"          # "full" / "positions"; "auto" follows the data file's columns
    mass = []                     # empty: M = I; else the diagonal of M
    alpha = 1.0                   # scaled unscented transform
    beta = 2.0
    kappa = 0.0
    jitter = 1e-12

    [initial_state]
    mode = "known"                # "known": X_0 ~ N(x0, p0_var I); "learned": x0 joins θ
    x0 = [0.2, -0.25, 0.3, -0.25] # (q1..qd, p1..pd); empty = centre the learned prior on y_1
    p0_var = 1e-16
    t0 = 0.0

    [priors.coefficients]         # one prior per group of θ
    family = "laplace"
    loc = 0.0
    scale = 10.0
    [priors.variances]
    family = "half-normal"
    scale = 1.0
    [priors.initial_state]        # used when initial_state.mode = "learned"
    family = "normal"
    loc = 0.0                     # an offset from the centre (x0, or the first observation)
    scale = 1.0

    [map]
    num_starts = 4
    seed = 0

    [sampler]
    method = "dram"               # or "nuts"
    num_samples = 200000          # iterations per chain, burn-in included
    burn_in = 100000
    num_chains = 4
    gamma = 0.01                  # DRAM second-stage scale
    adapt_start = 200
    thin = 1
    seed = 0

    [prediction]
    integrator = "leapfrog"
    dt = 0.01
    t_end = 200.0
    num_paths = 100

Prior families and their keys: ``laplace`` and ``normal`` and ``log-normal`` (``loc``,
``scale``; for log-normal these are μ and σ of log x), ``half-normal`` (``scale``), ``uniform``
(``low``, ``high``). A key that a family does not use is an error, so that what is written
is what is used.

Every problem raises :class:`SettingsError` with a one-line message ``"<source>: <key> ..."``
naming the file (or "command line") and the dotted key; a misspelt key gets the closest valid
key as a suggestion.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
import tomllib
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import tomli_w

from symplid.dynamics.integrators import INTEGRATORS, get_integrator

__all__ = [
    "InitialStateSettings",
    "MapSettings",
    "ModelSettings",
    "PredictionSettings",
    "PriorSettings",
    "PriorSpec",
    "SamplerSettings",
    "Settings",
    "SettingsError",
    "dump_settings",
    "load_settings",
    "merge_overrides",
    "parse_override",
    "resolve_for_data",
    "settings_from_dict",
    "settings_to_dict",
]


class SettingsError(ValueError):
    """A bad setting. The message names the source (file or "command line") and the key."""

    def __init__(self, source: str, key: str | None, message: str) -> None:
        self.source = source
        self.key = key
        text = f"{source}: {key} {message}" if key else f"{source}: {message}"
        super().__init__(text)


def _field(
    default: Any,
    *,
    choices: tuple[str, ...] | None = None,
    minimum: float | None = None,
    strict: bool = False,
    doc: str = "",
) -> Any:
    """A dataclass field with validation metadata (choices, lower bound, strict bound)."""
    metadata = {"choices": choices, "minimum": minimum, "strict": strict, "doc": doc}
    return field(default=default, metadata=metadata)


# ----------------------------------------------------------------------------- sections
@dataclass(frozen=True)
class ModelSettings:
    """The state-space model of eq. (7) and its unscented filter (Theorem 1)."""

    order: int = _field(3, minimum=1)
    integrator: str = _field("leapfrog")
    dt: float = _field(0.25, minimum=0.0, strict=True)
    process_noise_per: str = _field("gap", choices=("gap", "step"))
    noise: str = _field("isotropic", choices=("isotropic", "diagonal"))
    observation: str = _field("auto", choices=("auto", "full", "positions"))
    mass: tuple[float, ...] = _field(())
    alpha: float = _field(1.0, minimum=0.0, strict=True)
    beta: float = _field(2.0)
    kappa: float = _field(0.0)
    jitter: float = _field(1e-12, minimum=0.0)


@dataclass(frozen=True)
class InitialStateSettings:
    """The initial state X_0 ~ N(x0, p0_var·I) at time t0, known or learned with θ."""

    mode: str = _field("known", choices=("known", "learned"))
    x0: tuple[float, ...] = _field(())
    p0_var: float = _field(1e-16, minimum=0.0)
    t0: float = _field(0.0)


@dataclass(frozen=True)
class PriorSpec:
    """One prior family and its parameters (see the module docstring for which keys apply)."""

    family: str = _field(
        "normal", choices=("laplace", "normal", "half-normal", "log-normal", "uniform")
    )
    loc: float = _field(0.0)
    scale: float = _field(1.0, minimum=0.0, strict=True)
    low: float = _field(0.0)
    high: float = _field(1.0)


PRIOR_KEYS: dict[str, tuple[str, ...]] = {
    "laplace": ("loc", "scale"),
    "normal": ("loc", "scale"),
    "log-normal": ("loc", "scale"),
    "half-normal": ("scale",),
    "uniform": ("low", "high"),
}
_POSITIVE_FAMILIES = ("half-normal", "log-normal", "uniform")


@dataclass(frozen=True)
class PriorSettings:
    """Priors by group of θ: the paper's Laplace(0, 10) and half-normal(1) (Section IV)."""

    coefficients: PriorSpec = field(default_factory=lambda: PriorSpec("laplace", scale=10.0))
    variances: PriorSpec = field(default_factory=lambda: PriorSpec("half-normal", scale=1.0))
    initial_state: PriorSpec = field(default_factory=lambda: PriorSpec("normal", scale=1.0))


@dataclass(frozen=True)
class MapSettings:
    """The MAP search: bounded quasi-Newton from several seeded starts."""

    num_starts: int = _field(4, minimum=1)
    seed: int = _field(0, minimum=0)


@dataclass(frozen=True)
class SamplerSettings:
    """MCMC: DRAM with the paper's budget per chain (200,000 iterations, 100,000 burn-in)."""

    method: str = _field("dram", choices=("dram", "nuts"))
    num_samples: int = _field(200_000, minimum=1)
    burn_in: int = _field(100_000, minimum=0)
    num_chains: int = _field(4, minimum=1)
    gamma: float = _field(0.01, minimum=0.0, strict=True)
    adapt_start: int = _field(200, minimum=0)
    thin: int = _field(1, minimum=1)
    seed: int = _field(0, minimum=0)


@dataclass(frozen=True)
class PredictionSettings:
    """Predictions from the learned models: leapfrog at a fine dt to t_end (Figs 1–3)."""

    integrator: str = _field("leapfrog")
    dt: float = _field(0.01, minimum=0.0, strict=True)
    t_end: float = _field(200.0)
    num_paths: int = _field(100, minimum=0)


@dataclass(frozen=True)
class Settings:
    """Everything a run needs; the defaults are the paper's Hénon–Heiles experiment."""

    seed: int = _field(0, minimum=0)
    model: ModelSettings = field(default_factory=ModelSettings)
    initial_state: InitialStateSettings = field(default_factory=InitialStateSettings)
    priors: PriorSettings = field(default_factory=PriorSettings)
    map: MapSettings = field(default_factory=MapSettings)
    sampler: SamplerSettings = field(default_factory=SamplerSettings)
    prediction: PredictionSettings = field(default_factory=PredictionSettings)


_SEEDED_SECTIONS = ("map", "sampler")


# ----------------------------------------------------------------------------- dict <-> settings
def settings_to_dict(settings: Settings) -> dict[str, Any]:
    """Nested plain dict (tuples as lists); each prior lists only the keys its family uses."""
    return _to_dict(settings)


def _to_dict(obj: Any) -> dict[str, Any]:
    out: dict[str, Any] = {}
    keys = PRIOR_KEYS[obj.family] if isinstance(obj, PriorSpec) else None
    for f in dataclasses.fields(obj):
        if keys is not None and f.name != "family" and f.name not in keys:
            continue
        value = getattr(obj, f.name)
        if dataclasses.is_dataclass(value):
            out[f.name] = _to_dict(value)
        elif isinstance(value, tuple):
            out[f.name] = list(value)
        else:
            out[f.name] = value
    return out


def _all_keys(cls: type, prefix: str = "") -> list[str]:
    keys = []
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        name = f"{prefix}{f.name}"
        if dataclasses.is_dataclass(hints[f.name]):
            keys += _all_keys(hints[f.name], name + ".")
        else:
            keys.append(name)
    return keys


_VALID_KEYS = _all_keys(Settings)


def _suggest(key: str, section_keys: list[str]) -> str:
    """' (did you mean X?)' using difflib, first within the section, then anywhere."""
    leaf = key.rsplit(".", 1)[-1]
    prefix = key.rsplit(".", 1)[0] + "." if "." in key else ""
    close = difflib.get_close_matches(leaf, section_keys, n=1, cutoff=0.6)
    if close:
        return f"; did you mean '{prefix}{close[0]}'?"
    close = difflib.get_close_matches(key, _VALID_KEYS, n=1, cutoff=0.6)
    if not close:
        close = [k for k in _VALID_KEYS if k.rsplit(".", 1)[-1] == leaf][:1]
    if close:
        return f"; did you mean '{close[0]}'?"
    return f" (valid keys here: {', '.join(section_keys)})"


def settings_from_dict(data: Mapping[str, Any], source: str = "settings") -> Settings:
    """Build validated :class:`Settings` from a nested mapping (e.g. parsed TOML).

    Missing keys take the paper's defaults. ``map.seed`` and ``sampler.seed`` default to the
    top-level ``seed`` when it is given and they are not. ``source`` (a file name, or
    "command line") starts every error message.

    Raises
    ------
    SettingsError
        For an unknown (e.g. misspelt) key, with the closest valid key suggested; a value of the
        wrong type; a value out of range (dt ≤ 0, order < 1, a negative scale, ...); an unknown
        integrator; num_samples ≤ burn_in; a prior key its family does not use; ...
    """
    if not isinstance(data, Mapping):
        raise SettingsError(source, None, f"settings must be a table, got {type(data).__name__}")
    data = dict(data)
    if "seed" in data:
        for section in _SEEDED_SECTIONS:
            table = data.get(section, {})
            if isinstance(table, Mapping) and "seed" not in table:
                data[section] = {**table, "seed": data["seed"]}
    settings = _build(Settings, data, "", source)
    _check_cross(settings, source)
    return settings


def _build(cls: type, data: Mapping[str, Any], prefix: str, source: str) -> Any:
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    for key in data:
        if key not in fields:
            dotted = f"{prefix}{key}"
            raise SettingsError(
                source, None, f"unknown key '{dotted}'" + _suggest(dotted, list(fields))
            )
    if cls is PriorSpec:
        return _build_prior(data, prefix, source)
    kwargs = {}
    for name, f in fields.items():
        if name not in data:
            continue
        kwargs[name] = _convert(data[name], hints[name], f, f"{prefix}{name}", source)
    return cls(**kwargs)


def _build_prior(data: Mapping[str, Any], prefix: str, source: str) -> PriorSpec:
    fields = {f.name: f for f in dataclasses.fields(PriorSpec)}
    hints = typing.get_type_hints(PriorSpec)
    family = _convert(
        data.get("family", "normal"), str, fields["family"], f"{prefix}family", source
    )
    used = PRIOR_KEYS[family]
    for key in data:
        if key != "family" and key not in used:
            raise SettingsError(
                source,
                f"{prefix}{key}",
                f"is not used by the {family!r} prior (it takes: {', '.join(used)})",
            )
    kwargs = {"family": family}
    for key in used:
        if key in data:
            kwargs[key] = _convert(data[key], hints[key], fields[key], f"{prefix}{key}", source)
    spec = PriorSpec(**kwargs)
    if family == "uniform" and not spec.low < spec.high:
        raise SettingsError(
            source, f"{prefix}low", f"({spec.low:g}) must be less than {prefix}high ({spec.high:g})"
        )
    return spec


def _type_name(tp: Any) -> str:
    return {int: "an integer", float: "a number", str: "a string"}.get(tp, "a list of numbers")


def _convert(value: Any, tp: Any, f: dataclasses.Field, key: str, source: str) -> Any:
    """Check one value's type and range against its field; return it normalised."""
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, Mapping):
            raise SettingsError(source, key, f"must be a table ([{key}]), got {value!r}")
        return _build(tp, value, key + ".", source)
    meta = f.metadata
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise SettingsError(source, key, f"must be an integer, got {value!r}")
        out: Any = value
    elif tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise SettingsError(source, key, f"must be a number, got {value!r}")
        out = float(value)
        if not math.isfinite(out):
            raise SettingsError(source, key, f"must be finite, got {value!r}")
    elif tp is str:
        if not isinstance(value, str):
            raise SettingsError(source, key, f"must be a string, got {value!r}")
        out = value.strip().lower()
        if key.endswith("family"):
            out = out.replace("_", "-").replace("halfnormal", "half-normal")
            out = out.replace("lognormal", "log-normal")
        if key.endswith("integrator"):
            return _integrator_name(out, key, source)
    else:  # tuple[float, ...]
        if not isinstance(value, list | tuple) or any(
            isinstance(x, bool) or not isinstance(x, int | float) for x in value
        ):
            raise SettingsError(source, key, f"must be a list of numbers, got {value!r}")
        out = tuple(float(x) for x in value)
        if not all(math.isfinite(x) for x in out):
            raise SettingsError(source, key, f"must hold finite numbers, got {value!r}")
        return out
    choices = meta.get("choices")
    if choices and out not in choices:
        close = difflib.get_close_matches(str(out), choices, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise SettingsError(
            source, key, f"must be one of {', '.join(map(repr, choices))}, got {value!r}{hint}"
        )
    minimum = meta.get("minimum")
    if minimum is not None:
        if meta.get("strict") and not out > minimum:
            raise SettingsError(source, key, f"must be > {minimum:g}, got {value!r}")
        if not meta.get("strict") and not out >= minimum:
            raise SettingsError(source, key, f"must be ≥ {minimum:g}, got {value!r}")
    return out


def _integrator_name(name: str, key: str, source: str) -> str:
    try:
        return get_integrator(name).name
    except ValueError:
        close = difflib.get_close_matches(name.lower(), list(INTEGRATORS), n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise SettingsError(
            source,
            key,
            f"is {name!r}, not a known integrator{hint} (choose one of {', '.join(INTEGRATORS)})",
        ) from None


def _check_cross(s: Settings, source: str) -> None:
    """Checks that involve more than one key."""
    sampler = s.sampler
    if sampler.num_samples <= sampler.burn_in:
        raise SettingsError(
            source,
            "sampler.num_samples",
            f"({sampler.num_samples}) must be greater than sampler.burn_in ({sampler.burn_in}); "
            "num_samples counts every iteration, burn-in included",
        )
    if sampler.thin > sampler.num_samples - sampler.burn_in:
        raise SettingsError(
            source,
            "sampler.thin",
            f"({sampler.thin}) is larger than the {sampler.num_samples - sampler.burn_in} "
            "draws kept after burn-in",
        )
    if any(m <= 0 for m in s.model.mass):
        raise SettingsError(
            source, "model.mass", f"must hold positive numbers, got {list(s.model.mass)}"
        )
    if s.prediction.t_end <= s.initial_state.t0:
        raise SettingsError(
            source,
            "prediction.t_end",
            f"({s.prediction.t_end:g}) must be after initial_state.t0 ({s.initial_state.t0:g})",
        )
    variances = s.priors.variances
    if variances.family not in _POSITIVE_FAMILIES or (
        variances.family == "uniform" and variances.low < 0
    ):
        raise SettingsError(
            source,
            "priors.variances.family",
            f"must have positive support (half-normal, log-normal, or uniform with low ≥ 0), "
            f"got {variances.family!r}",
        )
    if s.priors.initial_state.family in _POSITIVE_FAMILIES:
        raise SettingsError(
            source,
            "priors.initial_state.family",
            f"must allow any real value (normal or laplace), got {s.priors.initial_state.family!r}",
        )
    if s.initial_state.x0 and len(s.initial_state.x0) % 2:
        raise SettingsError(
            source,
            "initial_state.x0",
            f"has {len(s.initial_state.x0)} numbers; it must be a full state (q1..qd, p1..pd)",
        )


# ----------------------------------------------------------------------------- files
def load_settings(path: str | os.PathLike) -> Settings:
    """Read and validate a TOML settings file; missing keys take the paper's defaults."""
    path = Path(path)
    if not path.exists():
        raise SettingsError(str(path), None, "no such settings file")
    if path.is_dir():
        raise SettingsError(str(path), None, "is a directory, not a settings file")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise SettingsError(str(path), None, "not a UTF-8 text file") from None
    except tomllib.TOMLDecodeError as err:
        raise SettingsError(str(path), None, f"not valid TOML: {err}") from None
    return settings_from_dict(data, source=str(path))


_HEADER = (
    "# symplid run settings: every value written out, so the run can be repeated exactly.\n"
    "# Read with symplid.workflow.settings.load_settings (or `symplid fit --config`).\n\n"
)


def dump_settings(settings: Settings, path: str | os.PathLike) -> Path:
    """Write every setting (defaults included) as TOML, atomically; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(_HEADER + tomli_w.dumps(settings_to_dict(settings)), encoding="utf-8")
    os.replace(tmp, path)
    return path


# ----------------------------------------------------------------------------- overrides
def parse_override(text: str, source: str = "command line") -> tuple[str, Any]:
    """Parse ``"model.dt=0.1"`` into ``("model.dt", 0.1)``.

    The value is read as a TOML value (numbers, booleans, ``[0.2, -0.25]``, quoted strings),
    falling back to the bare text as a string (``model.integrator=rk4``).
    """
    key, sep, raw = text.partition("=")
    key, raw = key.strip(), raw.strip()
    if not sep or not key:
        raise SettingsError(source, None, f"expected KEY=VALUE (e.g. model.dt=0.1), got {text!r}")
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw
    return key, value


def merge_overrides(
    settings: Settings, overrides: Mapping[str, Any], source: str = "command line"
) -> Settings:
    """Return ``settings`` with dotted keys replaced, e.g. ``{"model.dt": 0.1}``, re-validated.

    ``None`` values are skipped (an option the user did not give). Overriding the top-level
    ``seed`` also reseeds ``map.seed`` and ``sampler.seed`` unless they are overridden too.
    """
    data = settings_to_dict(settings)
    overrides = {k: v for k, v in overrides.items() if v is not None}
    if "seed" in overrides:
        for section in _SEEDED_SECTIONS:
            overrides.setdefault(f"{section}.seed", overrides["seed"])
    for key, value in overrides.items():
        parts = key.split(".")
        table = data
        for depth, part in enumerate(parts):
            if not isinstance(table, dict) or (
                part not in table and not _is_prior_key(parts, depth)
            ):
                section = list(table) if isinstance(table, dict) else []
                raise SettingsError(source, None, f"unknown key '{key}'" + _suggest(key, section))
            if depth == len(parts) - 1:
                if isinstance(table.get(part), dict):
                    raise SettingsError(source, key, "is a section; give one of its keys")
                table[part] = list(value) if isinstance(value, tuple) else value
            else:
                table = table[part]
        if len(parts) == 3 and parts[0] == "priors" and parts[2] == "family":
            # a new family: drop the old family's parameters so defaults apply
            group = data["priors"][parts[1]]
            for k in list(group):
                if k != "family" and f"priors.{parts[1]}.{k}" not in overrides:
                    del group[k]
    return settings_from_dict(data, source=source)


def _is_prior_key(parts: list[str], depth: int) -> bool:
    """Prior groups list only their family's keys; the others are still valid to set."""
    return (
        len(parts) == 3
        and depth == 2
        and parts[0] == "priors"
        and parts[2] in {f.name for f in dataclasses.fields(PriorSpec)}
    )


# ----------------------------------------------------------------------------- data
def resolve_for_data(settings: Settings, obs: Any, source: str = "settings") -> Settings:
    """Check the settings against a data set and fill what the data decide.

    ``model.observation = "auto"`` becomes ``"full"`` or ``"positions"`` from the data's columns
    (see :func:`symplid.io.observation_kind`). Checks that the observation kind matches the
    columns, that a known initial state has ``x0`` with 2d numbers, and that ``t0`` is before
    the first observation. The result is what a run folder records.
    """
    from symplid.io import observation_layout  # local: io does not need settings

    layout = observation_layout(obs)
    d = layout.dim
    model = settings.model
    observation = layout.kind if model.observation == "auto" else model.observation
    if observation != layout.kind:
        have = "only positions (q1..qd)" if layout.kind == "positions" else "positions and momenta"
        raise SettingsError(
            source,
            "model.observation",
            f'is {model.observation!r} but the data have {have}; use "auto"',
        )
    init = settings.initial_state
    if init.mode == "known" and not init.x0:
        raise SettingsError(
            source,
            "initial_state.x0",
            f"is empty but initial_state.mode is 'known': give x0 ({2 * d} numbers, "
            'q1..qd then p1..pd) or set mode = "learned"',
        )
    if init.x0 and len(init.x0) != 2 * d:
        raise SettingsError(
            source,
            "initial_state.x0",
            f"has {len(init.x0)} numbers but the data's system has a {2 * d}-dimensional "
            f"state (q1..q{d}, p1..p{d})",
        )
    if model.mass and len(model.mass) != d:
        raise SettingsError(source, "model.mass", f"has {len(model.mass)} numbers, expected {d}")
    first = float(obs.times[0])
    if not init.t0 < first:
        raise SettingsError(
            source,
            "initial_state.t0",
            f"({init.t0:g}) must be before the first observation time ({first:g})",
        )
    return dataclasses.replace(settings, model=dataclasses.replace(model, observation=observation))
