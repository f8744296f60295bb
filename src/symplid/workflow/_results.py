"""Run folders: everything one run produced, written so that an unfinished run never looks done.

A run folder holds::

    settings.toml    every setting, defaults included (symplid.workflow._settings.dump_settings)
    data.csv         the data the run used (symplid.io.write_observations)
    map.json         the MAP point, its log posterior, the Hessian, ... (write_map)
    posterior.nc     the draws as ArviZ InferenceData (netCDF through h5netcdf)
    sampler_state.npz   only while interrupted: the chains' states, for ``fit --resume``
    sampler_attrs.json  only while sampling or interrupted: the attributes of the draws
    draws/chunk-NNNNNN.npz  only while sampling or interrupted: each compiled chunk's draws
                     and the chains' states after it (symplid.io._chunks), removed at the end
    summary.json     the run's numbers, and summary.txt, the same as a readable table
    figures/*.png
    report.md

Completeness rule (the marker)
------------------------------
Opening a folder for writing first writes a marker file ``.incomplete``; :meth:`RunFolder.finish`
removes it, last. A run that fails or is killed midway therefore leaves the marker behind, and
readers (``RunFolder(path, mode="r")``) refuse such a folder unless asked. A marker rather than
a temporary folder renamed at the end was chosen so that a long run's partial results (settings,
data, MAP, a partial chain) stay where the user looks for them, and so that ``predict`` and
``report`` can add files to an existing run (``mode="a"``) under the same rule. When used as a
context manager, a failure writes its one-line reason into the marker. Each file is itself
written to a hidden temporary name and renamed, so no file is ever half written.

An update of a finished run (``mode="a"``) never makes it unfinished: its marker says
``update started`` (readers ignore it, since every file is replaced atomically), and a failed
or interrupted update removes it again. A sampler stopped by Ctrl-C or SIGTERM leaves the
marker ``interrupted: ...`` (:meth:`RunFolder.mark_interrupted`): the draws made so far are in
``posterior.nc``, the chains' states in ``sampler_state.npz``, and readers refuse the run with a
one-line message that says what to do. The chunk files in ``draws/`` are written as the
sampler goes, so a run killed outright (SIGKILL, the out-of-memory killer, a third Ctrl-C) keeps
every finished chunk and can be continued too. ``mode="c"`` opens such a run to continue it
(``symplid fit --resume``): the marker stays as it is until the continuation saves (a failed or
killed continuation leaves the interrupted run as it was, resumable).

One writer at a time
--------------------
Modes ``"w"``, ``"a"`` and ``"c"`` hold an exclusive lock on ``.lock``
(:class:`symplid.io._files.FolderLock`) until the run is finished, marked or failed (or the
process ends, however it ends): a second writer is refused in one line naming the holder,
and a reader of an unfinished folder being written is told so.

Every file is read through one reader and written through one writer
(:mod:`symplid.io._files`): a damaged file is one line naming it and what to do
(:attr:`RunFolder.remedy`), a failing disk one line and no temporary file. The files' formats
(strict JSON with non-finite floats, netCDF attributes, the summary table) are
:mod:`symplid.io._runfiles`; their names are re-exported here.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import os
import shutil
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal

import numpy as np

from symplid.io import read_trajectories, write_trajectories
from symplid.io._chunks import CHUNKS_DIR, remove_chunks
from symplid.io._files import (
    FolderLock,
    FolderLockedError,
    StorageError,
    make_folder,
    read_with,
    write_bytes,
    write_fault,
    write_text,
    write_with,
)
from symplid.io._runfiles import (
    RunFolderError,
    format_summary,
    netcdf_bytes,
    numeric_arrays,
    read_json,
    restore_attrs,
    to_jsonable,
    write_json,
)
from symplid.model._data import DataError, Observations
from symplid.workflow._driven import read_run_inputs, write_run_inputs
from symplid.workflow._settings import Settings, dump_settings, load_settings

__all__ = [
    "RunFolder",
    "RunFolderError",
    "format_summary",
    "read_json",
    "to_jsonable",
    "write_json",
]


# ----------------------------------------------------------------------------- the folder
Mode = Literal["w", "a", "r", "c"]


class RunFolder:
    """One run's folder: write its files, mark it finished, read it back.

    Parameters
    ----------
    path
        The folder.
    mode
        ``"w"`` (default): a new run. The folder is created (parents too) and the
        ``.incomplete`` marker written before anything else. An existing non-empty folder is
        refused unless ``overwrite=True`` and it is a run folder (then its run files are
        removed first; other files are left alone).
        ``"r"``: read an existing, finished run; nothing can be written.
        ``"a"``: add to an existing, finished run (``predict``, ``report``): the marker is
        written again until :meth:`finish`.
        ``"c"``: continue an interrupted run (its marker says ``interrupted:``); anything else
        is refused with a one-line message (a finished run: "nothing to resume").
    overwrite
        Only for ``mode="w"``.
    allow_incomplete
        For ``"r"`` and ``"a"``: open a folder whose run did not finish (to inspect it).
    identity
        For ``mode="w"``: a file that marks an earlier run of the same kind where the folder
        has no ``settings.toml`` (``symplid reproduce`` writes ``config.json``), so that
        rerunning into it overwrites it like a run.

    Use it as a context manager to call :meth:`finish` on success and to record the error in
    the marker on failure::

        with RunFolder(out) as run:
            run.write_settings(settings)
            run.write_data(data)
            ...

    Raises
    ------
    RunFolderError
        (a :class:`~symplid.model._data.DataError`) when the folder cannot be used as asked, with a
        one-line message naming it.
    """

    MARKER = ".incomplete"
    SETTINGS = "settings.toml"
    DATA = "data.csv"
    MAP = "map.json"
    POSTERIOR = "posterior.nc"
    SUMMARY = "summary.json"
    SUMMARY_TEXT = "summary.txt"
    DIAGNOSTICS = "diagnostics.json"  # the MAP-level checks (symplid.workflow._sensitivity)
    REPORT = "report.md"
    FIGURES = "figures"
    SAMPLER_STATE = "sampler_state.npz"
    SAMPLER_ATTRS = "sampler_attrs.json"  # an unfinished run's draws' attributes
    CHUNKS = CHUNKS_DIR  # the draws streamed chunk by chunk (symplid.io._chunks)
    RUN_FILES = (SETTINGS, DATA, MAP, POSTERIOR, SUMMARY, SUMMARY_TEXT, DIAGNOSTICS, REPORT,
                 FIGURES, SAMPLER_STATE, SAMPLER_ATTRS, CHUNKS)
    UPDATE = "update"
    INTERRUPTED = "interrupted:"

    def __init__(
        self,
        path: str | os.PathLike,
        mode: Mode = "w",
        *,
        overwrite: bool = False,
        allow_incomplete: bool = False,
        identity: str | None = None,
    ) -> None:
        if mode not in ("w", "a", "r", "c"):
            raise ValueError(f"mode must be 'w', 'a', 'r' or 'c', got {mode!r}")
        self.path = Path(path)
        self.mode: Mode = mode
        self._finished = False
        self._identity = identity
        self._lock = FolderLock(self.path)
        if mode == "w":
            _check_parents(self.path)
            self._create(overwrite)
        elif mode == "c":
            self._check_existing(allow_incomplete=True)
            self._lock.acquire()
            self._check_resumable()
        else:
            self._check_existing(allow_incomplete)
            if mode == "a":
                self._lock.acquire()
                self._write_marker(f"{self.UPDATE} started")

    # ------------------------------------------------------------------ state
    def _create(self, overwrite: bool) -> None:
        path = self.path
        if path.exists() and not path.is_dir():
            raise RunFolderError(f"{path}: exists and is not a folder")
        # The lock first: of two commands started into one folder at the same instant, the
        # second is refused naming the first, not told that the folder (the first's files,
        # being written) "already exists" and may be overwritten.
        make_folder(path)
        self._lock.acquire()  # held until the run is finished, marked or failed
        try:
            overwriting = any(p.name != FolderLock.NAME for p in path.iterdir())
            if overwriting:
                self._check_overwrite(overwrite)
        except BaseException:
            self._lock.release()
            raise
        if overwriting:
            self._write_marker("run started (overwriting an earlier run)")
            try:
                for name in self.RUN_FILES:
                    target = path / name
                    if target.is_dir():
                        shutil.rmtree(target)
                    elif target.exists():
                        target.unlink()
            except OSError as err:
                raise write_fault(path, err) from None
        self._write_marker("run started")

    def _check_overwrite(self, overwrite: bool) -> None:
        """Refuse to write into a folder that is not empty, unless ``overwrite`` and it holds
        an earlier run."""
        path = self.path
        if not overwrite:
            raise RunFolderError(
                f"{path}: the folder already exists and is not empty; choose another "
                "output folder or allow overwriting"
            )
        if not self._looks_like_run():
            raise RunFolderError(
                f"{path}: not a run folder (no {self.SETTINGS} or {self.MARKER}); "
                "refusing to overwrite it"
            )

    def _looks_like_run(self) -> bool:
        """Whether the folder holds an earlier run: its settings, its marker, or the file that
        marks a run of another kind (``identity``, e.g. ``reproduce``'s ``config.json``)."""
        marks = (self.SETTINGS, self.MARKER, *((self._identity,) if self._identity else ()))
        return any((self.path / name).exists() for name in marks)

    def _check_existing(self, allow_incomplete: bool) -> None:
        path = self.path
        if not path.exists():
            raise RunFolderError(f"{path}: no such run folder")
        if not path.is_dir():
            raise RunFolderError(f"{path}: not a folder")
        if not self._looks_like_run():
            raise RunFolderError(f"{path}: not a run folder (no {self.SETTINGS})")
        if allow_incomplete or self.is_complete:
            return
        if self._lock.held_elsewhere() and self._lock.holder() != os.getpid():
            raise FolderLockedError(f"{path}: a symplid process is writing this run folder "
                                    "now; wait until it ends")
        reason = self.incomplete_reason or "unknown reason"
        if reason.startswith(self.UPDATE):
            return  # an update (predict, report) in progress or killed: the run is finished
        if reason.startswith(self.INTERRUPTED):
            raise RunFolderError(
                f"{path}: sampling was {reason}; continue it with 'symplid fit --resume --out "
                f"{path}', or fit again with --overwrite"
            )
        if self.has_chunks:  # killed while sampling: its finished chunks are kept
            raise RunFolderError(
                f"{path}: the run that wrote this folder did not finish ({reason}); continue it "
                f"with 'symplid fit --resume --out {path}', or fit again with --overwrite")
        raise RunFolderError(
            f"{path}: the run that wrote this folder did not finish ({reason}); run it again"
        )

    def _check_resumable(self) -> None:
        path = self.path
        if self.is_complete:
            raise RunFolderError(f"{path}: the run is finished; nothing to resume")
        reason = self.incomplete_reason or "unknown reason"
        stopped = reason.startswith(self.INTERRUPTED) and self.file(self.SAMPLER_STATE).exists()
        if not stopped and not self.has_chunks:  # killed while sampling: its chunks are kept
            raise RunFolderError(
                f"{path}: the run did not stop in sampling with its draws kept ({reason}); "
                "it cannot be resumed: fit again with --overwrite"
            )

    @property
    def has_chunks(self) -> bool:
        """True when the folder holds chunk files of draws (a run sampling, stopped or killed)."""
        folder = self.file(self.CHUNKS)
        return folder.is_dir() and any(folder.glob("chunk-*.npz"))

    def _write_marker(self, reason: str) -> None:
        stamp = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
        write_text(self.path / self.MARKER, f"{reason}\n{stamp} pid {os.getpid()}\n")

    @property
    def is_complete(self) -> bool:
        """True when the folder exists and carries no ``.incomplete`` marker."""
        return self.path.is_dir() and not (self.path / self.MARKER).exists()

    @property
    def incomplete_reason(self) -> str | None:
        """The first line of the marker (why the run is unfinished), or None when finished."""
        marker = self.path / self.MARKER
        if not marker.exists():
            return None
        return marker.read_text(encoding="utf-8").splitlines()[0].strip() or "unfinished"

    def finish(self, required: tuple[str, ...] = (SETTINGS, DATA)) -> None:
        """Mark the run finished by removing the marker, after checking ``required`` files."""
        self._check_writable()
        missing = [name for name in required if not (self.path / name).exists()]
        if missing:
            raise RuntimeError(f"{self.path}: cannot finish the run, missing {', '.join(missing)}")
        for name in (self.SAMPLER_STATE, self.SAMPLER_ATTRS):  # only an interrupted run's
            (self.path / name).unlink(missing_ok=True)
        remove_chunks(self.file(self.CHUNKS))  # gathered into posterior.nc
        (self.path / self.MARKER).unlink(missing_ok=True)
        self._finished = True
        self.release()

    def mark_interrupted(self, detail: str) -> None:
        """Mark a run whose sampler was stopped (Ctrl-C, SIGTERM): its files are written but
        the chains are short. Readers refuse it with a message that says what to do."""
        self._check_writable()
        self._write_marker(f"{self.INTERRUPTED} {detail}")
        self._finished = True
        self.release()

    def fail(self, reason: str) -> None:
        """Record why the run stopped (first line of the marker); the folder stays unfinished.

        For an update of a finished run (``mode="a"``) the marker is removed instead: the
        files it replaced were replaced atomically, so the run is still the finished run.
        """
        try:
            if self.mode in ("r", "c"):
                return  # "c": the interrupted run's files are untouched until it saves
            if self.mode == "a":
                with contextlib.suppress(OSError):
                    (self.path / self.MARKER).unlink(missing_ok=True)
                return
            first_line = (str(reason).strip().splitlines() or ["failed"])[0]
            # best effort: on a full or read-only disk the marker stays "run started"
            with contextlib.suppress(RunFolderError, StorageError):
                self._write_marker(f"failed: {first_line}")
        finally:
            self.release()

    def release(self) -> None:
        """Give up the folder's lock (:class:`~symplid.io._files.FolderLock`, taken by modes
        ``"w"``, ``"a"`` and ``"c"``): done by :meth:`finish`, :meth:`mark_interrupted` and
        :meth:`fail`, and by the end of the process whatever ends it."""
        self._lock.release()

    def __enter__(self) -> RunFolder:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if self.mode == "r" or self._finished:
            return
        if exc_type is None:
            self.finish()
        else:
            self.fail(f"{exc_type.__name__}: {exc}" if str(exc) else exc_type.__name__)
        # KeyboardInterrupt included: an update never leaves a finished run unfinished

    def _check_writable(self) -> None:
        if self.mode == "r":
            raise RuntimeError(f"{self.path}: opened read-only (mode='r')")
        if self._finished:
            raise RuntimeError(f"{self.path}: the run is already finished")

    def __repr__(self) -> str:
        state = "complete" if self.is_complete else "incomplete"
        return f"RunFolder({str(self.path)!r}, mode={self.mode!r}, {state})"

    # ------------------------------------------------------------------ paths
    def file(self, name: str) -> Path:
        """Path of a file in the folder."""
        return self.path / name

    @property
    def figures_dir(self) -> Path:
        return self.path / self.FIGURES

    def figure_path(self, name: str) -> Path:
        """``figures/<name>`` (``.png`` added when there is no extension); creates figures/."""
        make_folder(self.figures_dir)
        path = self.figures_dir / name
        return path if path.suffix else path.with_suffix(".png")

    def figures(self) -> list[Path]:
        """The figure files, sorted by name."""
        if not self.figures_dir.is_dir():
            return []
        return sorted(p for p in self.figures_dir.iterdir() if not p.name.startswith("."))

    # ------------------------------------------------------------------ writers
    def write_settings(self, settings: Settings) -> Path:
        """settings.toml: every setting, defaults included."""
        self._check_writable()
        return dump_settings(settings, self.file(self.SETTINGS))

    def write_data(self, obs: Observations | list[Observations]) -> Path:
        """data.csv: the observations the run used (several trajectories: with a
        ``trajectory`` column, :mod:`symplid.io._trajectories`)."""
        self._check_writable()
        write_run_inputs(self.path, obs)  # a driven run's sampled inputs, beside its data
        return write_trajectories(obs, self.file(self.DATA))

    def write_json(self, name: str, obj: Any) -> Path:
        """Any JSON file in the folder (see the module's JSON conventions)."""
        self._check_writable()
        return write_json(obj, self.file(name))

    def write_map(self, result: Any, **extra: Any) -> Path:
        """map.json from a MAP result (a mapping, dataclass or NamedTuple with ``theta``,
        ``log_posterior``, ``hessian``, ...), plus ``extra`` keys such as ``param_names``."""
        content = to_jsonable(result, "map")
        if not isinstance(content, dict):
            raise TypeError("the MAP result must be a mapping, a dataclass or a NamedTuple")
        content.update(to_jsonable(extra))
        return self.write_json(self.MAP, content)

    def write_posterior(self, idata: Any) -> Path:
        """posterior.nc from ArviZ InferenceData (attributes that netCDF cannot hold, such as
        lists, dictionaries, booleans or None, are stored as JSON text and restored by
        :meth:`read_posterior`); made in memory, then written atomically
        (:mod:`symplid.io._files`)."""
        self._check_writable()
        return write_bytes(self.file(self.POSTERIOR), netcdf_bytes(idata))

    def write_summary(self, summary: Mapping[str, Any], table: str | None = None) -> Path:
        """summary.json, and summary.txt: :func:`format_summary` plus an optional extra table
        (e.g. the text of ``arviz.summary``)."""
        path = self.write_json(self.SUMMARY, summary)
        text = format_summary(summary)
        if table:
            text += "\n" + table.rstrip() + "\n"
        write_text(self.file(self.SUMMARY_TEXT), text)
        return path

    def write_npz(self, name: str, **arrays: Any) -> Path:
        """A compressed NumPy archive in the folder, written atomically."""
        self._check_writable()
        return write_with(self.file(name), lambda buffer: np.savez_compressed(buffer, **arrays))

    def save_figure(self, figure: Any, name: str, dpi: int = 150) -> Path:
        """Save a matplotlib figure as ``figures/<name>`` (PNG unless ``name`` has a suffix)."""
        self._check_writable()
        path = self.figure_path(name)
        return write_with(path, lambda buffer: figure.savefig(
            buffer, format=path.suffix.lstrip(".") or "png", dpi=dpi, bbox_inches="tight"))

    def write_report(self, text: str) -> Path:
        """report.md (Markdown; refer to figures as ``figures/<name>.png``)."""
        self._check_writable()
        path = self.file(self.REPORT)
        write_text(path, text if text.endswith("\n") else text + "\n")
        return path

    # ------------------------------------------------------------------ readers
    @property
    def remedy(self) -> str:
        """What to do about a damaged file of this run (the end of the one-line error)."""
        if self.mode == "c":
            return "--resume is impossible: fit again with --overwrite"
        return "the run is damaged: fit it again (symplid fit ... --overwrite)"

    def _read(self, name: str, reader: Any) -> Any:
        """``reader(path)`` of the file ``name``; a missing, empty or unreadable file is one
        :class:`RunFolderError` line naming it and :attr:`remedy`."""
        path = self.file(name)
        if not path.exists():
            raise RunFolderError(f"{self.path}: this run has no {name}")
        return read_with(path, reader, self.remedy)

    def read_settings(self) -> Settings:
        """The run's settings. A run written before the prior tables took ``prior`` reads its
        ``family`` keys without a deprecation line: the file is the run's, not the user's."""
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", r".*\.family is deprecated", FutureWarning)
            return self._read(self.SETTINGS, _whole_settings)

    def read_data(self) -> Observations | list[Observations]:
        """The run's data: one :class:`Observations`, or a list for several trajectories; a
        driven run's with their inputs (:mod:`symplid.workflow._driven`)."""
        obs = self._read(self.DATA, lambda path: read_trajectories([path]))
        if not self.file(self.SETTINGS).exists():
            return obs
        return read_run_inputs(self.path, obs, self.read_settings())  # a driven run's inputs

    def read_json(self, name: str) -> Any:
        return self._read(name, lambda path: read_json(path, self.remedy))

    def read_map(self) -> dict[str, Any]:
        """map.json, with every list of numbers turned into a float array."""
        return numeric_arrays(self.read_json(self.MAP))

    def read_summary(self) -> dict[str, Any]:
        return self.read_json(self.SUMMARY)

    def read_report(self) -> str:
        return self._read(self.REPORT, lambda path: path.read_text(encoding="utf-8"))

    def read_npz(self, name: str) -> dict[str, np.ndarray]:
        """Every array of a NumPy archive in the folder (e.g. the sampler state)."""

        def load(path: Path) -> dict[str, np.ndarray]:
            with np.load(path) as stored:
                return {key: stored[key] for key in stored.files}

        return self._read(name, load)

    def read_posterior(self) -> Any:
        """posterior.nc as InferenceData, loaded into memory (the file is closed)."""
        return self._read(self.POSTERIOR, _load_posterior)


def _load_posterior(path: Path) -> Any:
    import arviz as az

    with az.rc_context({"data.load": "eager"}):
        idata = az.from_netcdf(str(path))
    for group in idata.groups():
        dataset = getattr(idata, group)
        dataset.attrs = restore_attrs(dict(dataset.attrs))
    if hasattr(idata, "attrs"):
        idata.attrs = restore_attrs(dict(idata.attrs))
    if not idata.groups():
        raise ValueError("no groups: not a posterior file")
    return idata


def _check_parents(path: Path) -> None:
    """A one-line error when a parent of ``path`` is a file (``--out afile/run``)."""
    for parent in reversed(path.parents):
        if parent.exists() and not parent.is_dir():
            raise RunFolderError(f"{path}: {parent} is a file, not a folder")




#: The sections every run's settings.toml has had (a run writes all of them, in this order);
#: ``[inputs]`` came later, so a run written before it lacks it.
_RUN_SECTIONS = ("model", "initial_state", "priors", "map", "sampler", "prediction", "plots")


def _whole_settings(path: Path) -> Settings:
    """A run's settings.toml, which must hold every section a run writes: a file cut short
    (it may still parse) is damaged, not a run with default settings."""
    import tomllib

    settings = load_settings(path)  # a file that is not TOML: its own one line
    with open(path, "rb") as handle:
        tables = tomllib.load(handle)
    missing = [name for name in _RUN_SECTIONS if name not in tables]
    if missing:
        raise DataError(f"{path}: incomplete, no [{missing[0]}] section (cut short?)")
    return settings
