"""A MAP the sampler climbs above was no maximum: find it again from the sampler's best point.

The sampler starts from the MAP (Section II-B.2) on the premise that it is the posterior's
highest point. On data that alias the motion (gaps as long as a swing) the log posterior has
many modes, the MAP search can end in a low one whatever its starts, and the chains, spread
from there, climb to a higher one during their burn-in: DRAM then mixes between modes it was
never tuned for and the run ends unconverged, or converged on a posterior whose MAP, Laplace
evidence and sensitivity checks all describe another mode.

:func:`mode_watch` is the runner's callback (``RunOptions.callback``) that watches the
highest point the chains have visited (``ChunkReport.best``); when it lies more than
:data:`MODE_MARGIN` nats above the MAP's log posterior (no draw of a chain started at a
maximum can rise above it by more than rounding), it stops the run with
:class:`HigherModeFound`. The fit then searches the MAP again from that point and samples
afresh from the new MAP (at most :data:`MAX_REFINDS` times); the first MAP is recorded in the
run's summary (``map_refound``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

MODE_MARGIN = 1.0
"""Nats by which a visited point must exceed the MAP's log posterior to count as higher."""
MAX_REFINDS = 2
"""How many times one fit searches its MAP again from a higher point."""


class HigherModeFound(Exception):
    """The chains visited a point of log posterior ``log_posterior`` above the MAP's
    ``map_log_posterior`` by more than :data:`MODE_MARGIN` (θ ``theta``)."""

    def __init__(self, log_posterior: float, theta: np.ndarray, map_log_posterior: float):
        super().__init__(f"the chains reached log π = {log_posterior:.4g}, above the MAP's "
                         f"{map_log_posterior:.4g}")
        self.log_posterior = float(log_posterior)
        self.theta = np.asarray(theta, dtype=float)
        self.map_log_posterior = float(map_log_posterior)


def mode_watch(map_log_posterior: float,
               margin: float = MODE_MARGIN) -> Callable[[Any], None]:
    """The runner callback that raises :class:`HigherModeFound` after the first chunk whose
    best visited point (``report.best``) is more than ``margin`` nats above the MAP."""

    def watch(report: Any) -> None:
        best = getattr(report, "best", None)
        if best is not None and best[0] > map_log_posterior + margin:
            raise HigherModeFound(best[0], best[1], map_log_posterior)

    return watch


def refound_record(found: HigherModeFound, new_log_posterior: float) -> dict[str, float]:
    """What ``summary.json["map_refound"]`` says of one search made again."""
    return {"first_map_log_posterior": found.map_log_posterior,
            "chains_log_posterior": found.log_posterior,
            "map_log_posterior": float(new_log_posterior)}


def refound_line(records: list[dict[str, float]]) -> str:
    """One sentence for the fit's line: the MAP found again, and by how much it rose."""
    first, last = records[0], records[-1]
    times = "" if len(records) == 1 else f" ({len(records)} times)"
    return (f"the chains climbed above the MAP (log π {first['first_map_log_posterior']:.2f} "
            f"→ {first['chains_log_posterior']:.2f}), so the MAP was searched again from "
            f"there{times}: log π {last['map_log_posterior']:.2f}")


__all__ = ["MAX_REFINDS", "MODE_MARGIN", "HigherModeFound", "mode_watch", "refound_line",
           "refound_record"]
