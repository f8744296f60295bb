"""JSON for floats that may be non-finite: ``nan``, ``inf`` and ``-inf`` as strings.

JSON has no NaN or infinity; writing them as the strings ``"nan"``, ``"inf"`` and ``"-inf"``
(rather than ``null``) keeps which one it was, and the files stay strict JSON. Used by
:class:`~symplid.inference.map.MapResult` (``map.json``) and the run files (``symplid.io``);
it sits below every layer that writes or reads them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

NONFINITE = {"nan": math.nan, "inf": math.inf, "-inf": -math.inf}


def encode_float(x: float) -> float | str:
    """A float, or ``"nan"``/``"inf"``/``"-inf"`` when it is not finite."""
    x = float(x)
    if math.isfinite(x):
        return x
    return "nan" if math.isnan(x) else ("inf" if x > 0 else "-inf")


def encode_array(a: Any) -> Any:
    """An array as nested lists of :func:`encode_float` values (a scalar as one value)."""
    a = np.asarray(a, dtype=float)
    if a.ndim == 0:
        return encode_float(a)
    return [encode_array(x) if a.ndim > 1 else encode_float(x) for x in a]


def decode(x: Any) -> Any:
    """Inverse of the encoders: the strings back to floats, through lists and mappings."""
    if isinstance(x, str):
        return NONFINITE.get(x, x)
    if isinstance(x, Mapping):
        return {k: decode(v) for k, v in x.items()}
    if isinstance(x, Sequence):
        return [decode(v) for v in x]
    return x


__all__ = ["NONFINITE", "decode", "encode_array", "encode_float"]
