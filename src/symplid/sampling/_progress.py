"""The runner's progress bar: one line per run, moved after every chunk.

:func:`~symplid.sampling._run.run_chains` draws it when ``RunOptions.progress`` is on (tqdm;
none otherwise); ``progress_position`` gives each process sampling at once its own line.
"""

from __future__ import annotations

from typing import Any

__all__ = ["progress_bar"]


def progress_bar(total: int, desc: str, enabled: bool, position: int | None = None,
                 initial: int = 0) -> Any:
    """A bar of ``total`` iterations from ``initial`` (a resumed run's), or None when not
    ``enabled``; the caller updates it by the iterations run and closes it."""
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit="it", unit_scale=True, dynamic_ncols=True,
                position=position, initial=initial)
