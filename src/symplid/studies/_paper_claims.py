"""The paper's claims judged over the seeds of a results table (a pure function of it).

For each claim and each variant of the study (:mod:`._paper_study`): the fraction of seeds where
the claim holds with a Wilson 95 % interval, and the paired effect — one number per seed from
the two fits of the same data — as a median with a percentile-bootstrap 95 % interval
(:mod:`._claims_stats`, seeded: the same table gives the same numbers). The scales:

* ``hamiltonian``: difference of the relative H errors, leapfrog − RK2 (negative: leapfrog
  closer to the true H). Errors are fractions of H, so a difference of −0.005 is 0.5 points.
* ``process_noise``: ratio RK2 / leapfrog of the posterior-median process-noise variances
  (variances are positive and differ by orders of magnitude: a ratio is the natural scale).
* ``prediction``: ratio leapfrog / RK2 of the valid prediction horizons (the paper's 150 s
  against 20 s is a ratio of about 7).

A verdict per claim and variant: ``holds`` when the Wilson interval of the fraction lies above
one half (most seeds, beyond chance), ``fails`` when it lies below, ``mixed`` otherwise.
Calibration (:mod:`._paper_calibration`) is evaluated per variant and propagator.

A claim that does not apply to a variant (one fitted without a reference, or one that names
the claims it judges: :meth:`._paper_study.Variant.applicable_claims`) reads :data:`NOT_APPLICABLE`
with no count, fraction or effect, and the reason; it is never counted as failing.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from symplid.studies._claims_stats import LEVEL, bootstrap_median, wilson_interval
from symplid.studies._paper_calibration import evaluate_calibration

__all__ = [
    "CLAIMS",
    "NOT_APPLICABLE",
    "RATIO_THRESHOLD",
    "VERDICT_SPLIT",
    "evaluate_claims",
    "verdict",
]

#: The process-noise claim holds for a seed when RK2's variance is at least this many times
#: leapfrog's (the paper: "about an order of magnitude"; an independent reproduction: ≥ 5×).
RATIO_THRESHOLD = 5.0
#: A claim holds (fails) in a variant when the Wilson interval of its fraction lies above
#: (below) this.
VERDICT_SPLIT = 0.5

#: The three claims: the metric compared per seed, how the claim reads, the paired effect.
CLAIMS: dict[str, dict[str, str]] = {
    "hamiltonian": {
        "metric": "hamiltonian_rel_error",
        "statement": "the learned H is closer to the true H with leapfrog than with RK2",
        "paper": "true H 0.1227; MAP H 0.1219 (0.7 %) with leapfrog, 0.1211 (1.3 %) with RK2",
        "effect": "difference",
        "effect_label": "relative H error, leapfrog − RK2",
    },
    "process_noise": {
        "metric": "process_noise_median",
        "statement": "the process noise is at least 5 times smaller with leapfrog",
        "paper": "about an order of magnitude smaller with leapfrog",
        "effect": "ratio",
        "effect_label": "process-noise variance, RK2 / leapfrog",
    },
    "prediction": {
        "metric": "prediction_horizon_s",
        "statement": "the leapfrog MAP model predicts validly for longer than the RK2 one",
        "paper": "about 150 s with leapfrog against about 20 s with RK2",
        "effect": "ratio",
        "effect_label": "valid prediction horizon, leapfrog / RK2",
    },
}


def verdict(ci: Sequence[float] | None) -> str:
    """``holds`` / ``fails`` / ``mixed`` from the Wilson interval of a fraction."""
    if ci is None:
        return "undecided"
    if ci[0] > VERDICT_SPLIT:
        return "holds"
    if ci[1] < VERDICT_SPLIT:
        return "fails"
    return "mixed"


def _match(table: Any, setting: Mapping[str, Any], integrator: str) -> Any:
    """Rows of one setting and propagator. A run setting of :data:`_DEFAULTS` that the setting
    leaves out stands at its default; a cell with no value for it (a table without its column,
    or a cell run before another cell set it) was run with the default."""
    import pandas as pd

    mask = (table["integrator"] == integrator).to_numpy(dtype=bool, copy=True)
    for key, value in {**_DEFAULTS, **setting}.items():
        if key not in table.columns:
            if _DEFAULTS.get(key, _NO_DEFAULT) != value:
                return table.iloc[0:0]
            continue
        hit = (table[key] == value).to_numpy(dtype=bool, copy=True)
        if _DEFAULTS.get(key, _NO_DEFAULT) == value:
            hit |= pd.isna(table[key]).to_numpy(dtype=bool)
        mask &= hit
    return table[mask]


#: Run settings that a cell may lack (a table without the column, or a cell of a variant that
#: leaves it out), and the value such a cell was run with.
_DEFAULTS: dict[str, Any] = {"model.process_noise_per": "gap", "priors.process_var": "variances"}
_NO_DEFAULT = object()
#: What a claim that does not apply to a variant reads (:meth:`._paper_study.Variant.
#: applicable_claims`): no reference was fitted, or its metric does not exist there.
NOT_APPLICABLE = "n/a"


def evaluate_claims(
    table: Any,
    variants: Sequence[Any],
    *,
    symplectic: str = "leapfrog",
    seed: int = 0,
) -> dict[str, Any]:
    """Per claim and variant: the holds-fraction with its Wilson interval and the paired effect.

    Parameters
    ----------
    table
        A results table (pandas): ``seed``, ``integrator``, ``status``, the setting columns of
        the variants, the metrics of :data:`CLAIMS` and (optional) the calibration columns.
        Only rows with status ``"ok"`` count.
    variants
        :class:`~._paper_study.Variant` objects (``name``, ``setting()``, ``reference``,
        ``propagators()``).
    symplectic
        The propagator whose claims are judged against each variant's reference.
    seed
        Seed of the bootstrap.

    Returns
    -------
    dict
        ``{"symplectic", "level", "ratio_threshold", "verdict_split", "variants": [...],
        "claims": {name: {..., "per_variant": [...]}}, "calibration": [...]}``.

    Raises
    ------
    ValueError
        A missing column, or two ok rows for the same variant, seed and propagator.
    """
    missing = sorted({"seed", "integrator", "status"} - set(table.columns))
    missing += [s["metric"] for s in CLAIMS.values() if s["metric"] not in table.columns]
    if missing:
        raise ValueError(f"the results table has no column {', '.join(missing)}")
    ok = table[table["status"] == "ok"]
    result: dict[str, Any] = {
        "symplectic": symplectic,
        "level": LEVEL,
        "ratio_threshold": RATIO_THRESHOLD,
        "verdict_split": VERDICT_SPLIT,
        "variants": [],
        "claims": {name: {**spec, "per_variant": []} for name, spec in CLAIMS.items()},
        "calibration": [],
    }
    for i, v in enumerate(variants):
        _evaluate_variant(result, table, ok, v, symplectic, seed + 97 * i)
    return result


def _evaluate_variant(result: dict[str, Any], table: Any, ok: Any, v: Any, symplectic: str,
                      seed: int) -> None:
    """Add one variant's pairs, claims and calibration to ``result``."""
    setting = v.setting()
    applies = _applicable(v)
    judged = (symplectic, v.reference) if v.reference is not None else (symplectic,)
    done = table[table["status"] != "pending"]  # a cell not run yet is no seed of the variant
    seeds_all = set().union(*(set(_match(done, setting, i)["seed"]) for i in judged))
    sym = _unique(_match(ok, setting, symplectic), v.name, symplectic)
    if v.reference is None:
        ref, paired = None, []
    else:
        ref = _unique(_match(ok, setting, v.reference), v.name, v.reference)
        paired = sorted(set(sym.index) & set(ref.index))
    unpaired = len(seeds_all) - len(paired) if v.reference is not None else 0
    result["variants"].append({"name": v.name, "reference": v.reference,
                               "seeds": len(seeds_all), "pairs": len(paired),
                               "unpaired": unpaired, "claims": list(applies)})
    for j, (name, spec) in enumerate(CLAIMS.items()):
        if name not in applies or ref is None:
            entry = _not_applicable(v.reference)
        else:
            a = _numbers(sym.loc[paired, spec["metric"]])
            b = _numbers(ref.loc[paired, spec["metric"]])
            entry = _judge(name, a, b, np.asarray(paired), seed + j)
        result["claims"][name]["per_variant"].append(
            {"variant": v.name, "reference": v.reference, "unpaired": unpaired, **entry}
        )
    for integ in v.propagators():
        rows = _match(ok, setting, integ)
        if len(rows):
            cal = evaluate_calibration(rows, f"{v.name}, {integ}")
            result["calibration"].append({"variant": v.name, "integrator": integ, **cal})


def _applicable(v: Any) -> tuple[str, ...]:
    """The claims judged in variant ``v`` (all of them for an object without
    ``applicable_claims`` that has a reference)."""
    if getattr(v, "reference", None) is None:
        return ()
    method = getattr(v, "applicable_claims", None)
    return tuple(CLAIMS) if method is None else tuple(method())


def _not_applicable(reference: str | None) -> dict[str, Any]:
    """The entry of a claim that does not apply: no count, no fraction, verdict *n/a*."""
    why = ("no reference propagator is fitted in this variant (calibration only)"
           if reference is None else "the claim's metric does not exist in this variant")
    return {"n": 0, "undecided": 0, "holds": 0, "fraction": None, "fraction_ci": None,
            "verdict": NOT_APPLICABLE, "applies": False, "why": why,
            "median_symplectic": None, "median_reference": None,
            "effect": bootstrap_median([]),
            "per_seed": {"seed": [], "symplectic": [], "reference": [], "effect": []}}


def _unique(rows: Any, variant: str, integrator: str) -> Any:
    dup = rows.duplicated(["seed"])
    if dup.any():
        raise ValueError(
            f"variant {variant}: more than one ok row for seed {rows[dup].iloc[0]['seed']} "
            f"and integrator {integrator!r}"
        )
    return rows.set_index("seed")


def _numbers(column: Any) -> np.ndarray:
    import pandas as pd

    return pd.to_numeric(column, errors="coerce").to_numpy(float)


def _judge(name: str, sym: np.ndarray, ref: np.ndarray, seeds: np.ndarray,
           boot_seed: int) -> dict[str, Any]:
    """One claim over paired seeds: symplectic values ``sym``, reference values ``ref``."""
    finite = np.isfinite(sym) & np.isfinite(ref)
    if CLAIMS[name]["effect"] == "ratio":
        finite &= (sym > 0) & (ref > 0)
    s, r = sym[finite], ref[finite]
    n = int(finite.sum())
    out: dict[str, Any] = {"n": n, "undecided": int((~finite).sum()), "applies": True}
    if name == "hamiltonian":
        holds, effect = s < r, s - r
    elif name == "process_noise":
        effect = r / s
        holds = effect >= RATIO_THRESHOLD
        smaller = int((effect > 1).sum())
        out["smaller"] = smaller
        out["fraction_smaller"] = smaller / n if n else None
        ci = wilson_interval(smaller, n)
        out["fraction_smaller_ci"] = list(ci) if ci else None
    else:
        holds, effect = s > r, s / r
        out["ties"] = int((s == r).sum())
    out["holds"] = int(holds.sum())
    out["fraction"] = out["holds"] / n if n else None
    ci = wilson_interval(out["holds"], n)
    out["fraction_ci"] = list(ci) if ci else None
    out["verdict"] = verdict(ci)
    out["median_symplectic"] = float(np.median(s)) if n else None
    out["median_reference"] = float(np.median(r)) if n else None
    out["effect"] = bootstrap_median(effect, seed=boot_seed)
    out["per_seed"] = {
        "seed": [int(x) for x in seeds[finite]],
        "symplectic": s.tolist(),
        "reference": r.tolist(),
        "effect": effect.tolist(),
    }
    return out
