"""Draws streamed to a run folder, one file per compiled chunk of the sampler.

The sampler runs in chunks (:func:`symplid.sampling._run.run_chains`). After each,
:class:`ChunkWriter` writes ``draws/chunk-NNNNNN.npz`` through the one atomic writer
(:func:`symplid.io._files.write_with`: a temporary file and a rename), holding

* ``draw_<name>``: the draws the chunk kept, ``(num_chains, kept, ...)`` (none in the burn-in),
  ``theta`` and the sampler's statistics;
* the chains' states after the chunk (:func:`~symplid.sampling._resume.checkpoint_arrays`:
  ``leaf_<i>``, ``treedef``, ``iterations_done`` and, in a run that restarts stuck chains,
  ``monitor_<name>``), what ``fit --resume`` continues from;
* ``start`` and ``done`` (iterations per chain before and after it) and ``elapsed`` (sampling
  seconds so far);
* ``run``: the fingerprint of the run that wrote it (its settings and data), so that a chunk
  file copied in from another run is recognised.

A file is there whole or not at all, so a crash, a SIGKILL or the out-of-memory killer loses
at most the chunk being computed. The files are not flushed to the disk one by one (``fsync``
cost about 20 ms a chunk on a busy disk, as much as the rest of the write twenty times over):
the operating system writes them whatever happens to the process, and only a crash of the
whole system can leave the last ones empty or short, which :func:`read_chunks` detects.

:func:`read_chunks` gathers the chunks of a folder: they must follow one another from
iteration 0 (each ``start`` the ``done`` of the one before) and come from the run being read
(the same ``run``); the first that is unreadable (truncated, a disk fault), out of line or
another run's ends the run there, and its name is given back in one line
(:attr:`Chunks.note`).
"""

from __future__ import annotations

import contextlib
import re
import shutil
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from symplid.io._files import UNREADABLE, write_with

__all__ = ["CHUNKS_DIR", "ChunkWriter", "Chunks", "read_chunks", "remove_chunks"]

#: The folder of a run that holds the chunk files.
CHUNKS_DIR = "draws"
_NAME = re.compile(r"^chunk-(\d{6})\.npz$")
_DRAW = "draw_"
_RUN = "run"


def chunk_path(folder: Path, index: int) -> Path:
    """``<folder>/chunk-NNNNNN.npz``."""
    return folder / f"chunk-{index:06d}.npz"


class ChunkWriter:
    """A :data:`~symplid.sampling._run.ChunkSink` that writes each chunk to ``folder``.

    Parameters
    ----------
    folder
        The chunk folder (``<run>/draws``), made if missing.
    first_index
        Number of the first chunk written (a continued run goes on after its chunks).
    begin
        Called with the draws' attributes when the run starts (:func:`~symplid.sample`'s
        ``sink.begin``), e.g. to save them next to the chunks.
    elapsed
        Sampling seconds before this writer's first chunk (a continued run's).
    run
        The run's fingerprint, written into every chunk (``""``: none).
    """

    def __init__(self, folder: str | Path, first_index: int = 0,
                 begin: Any = None, elapsed: float = 0.0, run: str = "") -> None:
        self.folder, self.index, self._begin = Path(folder), int(first_index), begin
        self.elapsed, self.run = float(elapsed), str(run)

    def begin(self, attrs: Mapping[str, Any]) -> None:
        if self._begin is not None:
            self._begin(attrs)

    def __call__(self, draws: Mapping[str, np.ndarray], states: Any, start: int, done: int,
                 elapsed: float, monitor: Mapping[str, np.ndarray] | None = None) -> None:
        from symplid.sampling._api import SamplerCheckpoint
        from symplid.sampling._resume import checkpoint_arrays

        arrays = {f"{_DRAW}{name}": np.asarray(value) for name, value in draws.items()}
        arrays.update(checkpoint_arrays(SamplerCheckpoint(states, int(done),
                                                          None if monitor is None
                                                          else dict(monitor))))
        arrays.update(start=np.asarray(int(start)), done=np.asarray(int(done)),
                      elapsed=np.asarray(self.elapsed + float(elapsed)))
        if self.run:
            arrays[_RUN] = np.asarray(self.run)
        write_with(chunk_path(self.folder, self.index),
                   lambda buffer: np.savez(buffer, **arrays), durable=False)
        self.index += 1


@dataclass
class Chunks:
    """The chunks of a run read back (:func:`read_chunks`).

    Attributes
    ----------
    count
        Chunks read (in line, from iteration 0).
    draws
        ``name -> (num_chains, kept, ...)``: every chunk's draws, in order (empty in the
        burn-in).
    state
        The last chunk's state arrays (for ``resume_sampling``).
    iterations_done, elapsed
        Iterations per chain and sampling seconds after the last chunk.
    note
        One line naming the chunk file that was ignored (and those after it), or ``""``.
    """

    count: int = 0
    draws: dict[str, np.ndarray] = field(default_factory=dict)
    state: dict[str, np.ndarray] = field(default_factory=dict)
    iterations_done: int = 0
    elapsed: float = 0.0
    note: str = ""


def _load(path: Path) -> dict[str, np.ndarray]:
    with np.load(path) as stored:
        return {key: stored[key] for key in stored.files}


def _numbered(folder: Path) -> list[tuple[int, Path]]:
    if not folder.is_dir():
        return []
    found = [(int(m.group(1)), p) for p in folder.iterdir() if (m := _NAME.match(p.name))]
    return sorted(found)


def read_chunks(folder: str | Path, run: str = "") -> Chunks:
    """Gather the chunk files of ``folder`` (see the module docstring); an empty
    :class:`Chunks` when there are none. With ``run`` (the fingerprint the run's
    :class:`ChunkWriter` was given), a chunk written by another run ends them like a damaged
    one (a chunk of an older version, without a fingerprint, is read)."""
    folder = Path(folder)
    out, parts = Chunks(), {}
    for index, path in _numbered(folder):
        why, arrays = _checked(path, index, out, run)
        if why is None:
            for key, value in arrays.items():
                if key.startswith(_DRAW):
                    parts.setdefault(key[len(_DRAW):], []).append(value)
            out.state = {k: v for k, v in arrays.items() if not k.startswith(_DRAW)}
            out.count, out.iterations_done = out.count + 1, int(arrays["done"])
            out.elapsed = float(arrays["elapsed"])
            continue
        later = len(_numbered(folder)) - out.count - 1
        after = f" and the {later} after it" if later else ""
        out.note = (f"{path}: {why}; ignored{after}, the run continues from iteration "
                    f"{out.iterations_done:,}")
        break
    out.draws = {name: np.concatenate(values, axis=1) for name, values in parts.items()}
    return out


def _checked(path: Path, index: int, so_far: Chunks, run: str = "") -> tuple[str | None, dict]:
    """The chunk file's arrays, and why it cannot continue the chunks read so far (None: it
    can)."""
    if index != so_far.count:
        return f"chunk {so_far.count} is missing before it", {}
    try:
        if path.stat().st_size == 0:
            return "the file is empty", {}
        arrays = _load(path)
        start, done = int(arrays["start"]), int(arrays["done"])
    except UNREADABLE as err:
        return f"unreadable ({type(err).__name__})", {}
    if run and _RUN in arrays and str(arrays[_RUN]) != run:
        return "it was written by another run (other settings or data)", {}
    if start != so_far.iterations_done or done <= start:
        return (f"it covers iterations {start:,} to {done:,} but the chunks before end at "
                f"{so_far.iterations_done:,}"), {}
    arrays.pop(_RUN, None)
    return None, arrays


def remove_chunks(folder: str | Path, keep: int | None = None) -> None:
    """Remove the chunk files of ``folder`` (those numbered ``keep`` and after; all, and the
    folder itself, when ``keep`` is None)."""
    folder = Path(folder)
    if keep is None:
        with contextlib.suppress(FileNotFoundError):
            shutil.rmtree(folder)
        return
    for index, path in _numbered(folder):
        if index >= keep:
            path.unlink(missing_ok=True)
