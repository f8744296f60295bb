"""Input and output (layer 5): data files (CSV, NPZ) with located, one-line errors."""

from symplid.io.datafiles import (
    Layout,
    column_names,
    observation_kind,
    observation_layout,
    positions_only,
    read_observations,
    write_observations,
)

__all__ = [
    "Layout",
    "column_names",
    "observation_kind",
    "observation_layout",
    "positions_only",
    "read_observations",
    "write_observations",
]
