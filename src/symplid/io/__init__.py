"""Input and output (layer 5): data files (CSV, NPZ) with located, one-line errors."""

from symplid.io._datafiles import (
    Layout,
    column_names,
    observation_kind,
    observation_layout,
    positions_only,
    read_observations,
    write_observations,
)
from symplid.io._trajectories import (
    as_list,
    num_trajectories,
    read_trajectories,
    write_trajectories,
)

__all__ = [
    "Layout",
    "as_list",
    "column_names",
    "num_trajectories",
    "observation_kind",
    "observation_layout",
    "positions_only",
    "read_observations",
    "read_trajectories",
    "write_observations",
    "write_trajectories",
]
