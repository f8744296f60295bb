"""Large programs saved as traced and lowered, so a later process skips tracing and lowering.

The persistent compilation cache (:func:`symplid.runtime.enable_compilation_cache`) keeps
XLA's compiled code, but JAX can only look a program up there after it has traced the Python
function and lowered it to StableHLO, in every process. For the filter's value-and-gradient
of a MAP search, its Hessian and a sampler's chunk that is most of a warm fit's fixed cost
(about 0.5 s, 0.5 s and 0.4 s each for a one-parameter user model, per posterior). A program
made by :func:`saved_jit` is therefore exported once (``jax.export``: the lowered StableHLO
with its calling convention) and written to the folder ``programs`` of the compilation
cache; a later process reads it back and runs ``jax.jit(exported.call)``, which lowers in
milliseconds and finds its compiled code in the persistent cache.

**The key.** A saved program is found by a SHA-256 of everything that determines it:

* the installed symplid's source (:func:`source_digest`: every ``.py`` and compiled
  extension of the package, so an edited checkout never reuses a stale program), the
  versions of JAX, jaxlib and the libraries that shape a trace, the platform and the JAX
  settings read while tracing (64-bit floats, matmul precision, the random number
  generator);
* the **name** its caller gives (which program: ``"map-hessian"``; a JAX transformation
  keeps the name and module of the function it transforms, so the name tells them apart),
  the function's module and qualified name, and the **identity** its caller gives: what
  the program closes over. The workflow gives a posterior the identity of its run
  (:func:`mark`: the full settings, a user's expression among them, and a digest of the
  data's values), and each program adds its own static settings (the search space's bounds,
  the sampler's settings, the chunk's length); a program without an identity is never saved;
* the shapes, dtypes and structure of its arguments.

Two runs with the same key trace the same function of the same closure, so they lower to
the same program. What cannot be exported (a custom call of the compiled likelihood kernel,
a host callback: ``jax.export`` refuses both) is compiled as usual, and the refusal is
remembered next to the saved programs so it is not tried again.

**Safety.** A saved file that cannot be read back (truncated, corrupt, another format) is
ignored and written again; nothing here raises into a fit. The results are those of the
same ``jax.jit(exported.call)`` whether its program was just exported or read back, so a fit
gives the same numbers with the file and without it.

**Turning it off.** ``SYMPLID_SAVED_PROGRAMS=off`` (or no compilation cache:
``SYMPLID_CACHE_DIR=off``, or a library user who never enabled it) makes :func:`saved_jit`
a plain ``jax.jit``. Saving needs the ``flatbuffers`` package (JAX's serialisation format);
without it, the same.

This module imports nothing from symplid above the base layer.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib.metadata
import importlib.util
import os
import sys
import threading
from collections.abc import Callable, Hashable
from pathlib import Path
from typing import Any

__all__ = [
    "OPT_OUT_ENV",
    "folder",
    "identity_of",
    "mark",
    "program_key",
    "saved_jit",
    "source_digest",
]

#: ``SYMPLID_SAVED_PROGRAMS=off`` turns saved programs off (plain ``jax.jit``).
OPT_OUT_ENV = "SYMPLID_SAVED_PROGRAMS"
#: The subfolder of the compilation cache that holds the saved programs.
SUBFOLDER = "programs"
#: The format of a saved program's key: a change of what a key holds starts afresh.
KEY_VERSION = "symplid-saved-program-1"
#: Libraries whose version can change a trace (what a user's expression becomes, a kernel).
TRACE_LIBRARIES = ("jax", "jaxlib", "numpy", "scipy", "sympy", "blackjax", "equinox")
#: JAX settings that are read while tracing or lowering.
TRACE_SETTINGS = ("jax_enable_x64", "jax_default_matmul_precision", "jax_default_prng_impl",
                  "jax_threefry_partitionable", "jax_numpy_rank_promotion",
                  "jax_numpy_dtype_promotion")

_IDENTITY = "_symplid_program_identity"
_LOCK = threading.Lock()


# ----------------------------------------------------------------------------- identities
def mark(owner: Any, identity: Hashable | None) -> Any:
    """Give ``owner`` (a posterior, a sampler's step) the ``identity`` of what its programs
    close over; ``None`` leaves it unmarked (its programs are never saved). Returns ``owner``.
    An object without a ``__dict__`` cannot be marked and is left as it is."""
    with contextlib.suppress(AttributeError, TypeError):
        vars(owner)[_IDENTITY] = None if identity is None else digest(identity)
    return owner


def identity_of(owner: Any) -> str | None:
    """The identity :func:`mark` gave ``owner`` (a hex digest), or None."""
    try:
        return vars(owner).get(_IDENTITY)
    except TypeError:
        return None


def digest(*parts: Any) -> str:
    """SHA-256 of the ``repr`` of ``parts``, NumPy arrays by dtype, shape and bytes."""
    h = hashlib.sha256()
    _feed(h, parts)
    return h.hexdigest()


def _feed(h: Any, value: Any) -> None:
    if hasattr(value, "__array__") and hasattr(value, "dtype") and hasattr(value, "shape"):
        import numpy as np

        array = np.ascontiguousarray(np.asarray(value))
        h.update(f"array{array.dtype.str}{array.shape}".encode())
        h.update(array.tobytes())
    elif isinstance(value, list | tuple):
        h.update(f"{type(value).__name__}[{len(value)}](".encode())
        for item in value:
            _feed(h, item)
        h.update(b")")
    else:
        h.update(repr(value).encode())
        h.update(b";")


# ----------------------------------------------------------------------------- the key
@functools.cache
def source_digest() -> str:
    """SHA-256 over the installed symplid package: every ``.py`` file and compiled extension,
    by path and content (computed once per process, a few milliseconds)."""
    root = Path(__file__).resolve().parent
    h = hashlib.sha256()
    for path in sorted(p for p in root.rglob("*") if p.suffix in (".py", ".so", ".pyd")):
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


@functools.cache
def _environment() -> tuple[Any, ...]:
    import jax

    versions = []
    for name in TRACE_LIBRARIES:
        try:
            versions.append((name, importlib.metadata.version(name)))
        except importlib.metadata.PackageNotFoundError:
            versions.append((name, None))
    return (KEY_VERSION, source_digest(), tuple(versions), jax.default_backend(),
            sys.version_info[:2])


def _settings() -> tuple[Any, ...]:
    import jax

    return tuple((name, str(getattr(jax.config, name, None))) for name in TRACE_SETTINGS)


def signature(args: tuple, kwargs: dict) -> tuple[Any, ...]:
    """The structure and the abstract values of a call's arguments as JAX sees them:
    ``(treedef, ((shape, dtype, weak), ...))``; a Python scalar is the weakly typed scalar
    JAX makes of it, so ``f(0)`` and ``f(jnp.asarray(0))`` have one signature and one program,
    as they have one trace. A few microseconds: it is computed at every call."""
    import jax

    leaves, tree = jax.tree.flatten((args, kwargs))
    return (tree, tuple(map(_abstract, leaves)))


def _abstract(leaf: Any) -> tuple[Any, ...]:
    shape = getattr(leaf, "shape", None)
    if shape is None:  # a Python scalar: weakly typed, but for a bool
        import jax
        import numpy as np

        dtype = jax.dtypes.canonicalize_dtype(np.asarray(leaf).dtype)
        return ((), dtype, not isinstance(leaf, bool))
    return (tuple(shape), leaf.dtype, bool(getattr(leaf, "weak_type", False)))


def program_key(fn: Callable, name: str, identity: Hashable, sig: tuple[Any, ...],
                options: Any = None) -> str:
    """The key of the program of ``fn`` (given ``name``, closing over ``identity``) for
    arguments of signature ``sig`` (:func:`signature`), lowered with compiler ``options``."""
    where = (getattr(fn, "__module__", None), getattr(fn, "__qualname__", None))
    tree, leaves = sig
    return digest(_environment(), _settings(), name, where, identity, str(tree), leaves,
                  repr(options))


# ----------------------------------------------------------------------------- the folder
def folder() -> Path | None:
    """Where saved programs live (the compilation cache's ``programs``), or None when they
    are off: ``SYMPLID_SAVED_PROGRAMS=off``, no compilation cache, or no ``flatbuffers``."""
    if os.environ.get(OPT_OUT_ENV, "").strip().lower() in ("off", "0", "false", "no"):
        return None
    if "jax" not in sys.modules or importlib.util.find_spec("flatbuffers") is None:
        return None
    import jax

    cache = jax.config.jax_compilation_cache_dir
    return Path(cache) / SUBFOLDER if cache else None


# ----------------------------------------------------------------------------- the program
def saved_jit(fn: Callable, name: str, identity: Hashable | None,
              compiler_options: dict[str, Any] | None = None) -> Callable:
    """``jax.jit(fn)``, its program saved and read back as the module docstring says.

    ``name`` and ``identity`` (``None``: never saved) enter the key; so do the arguments'
    signature, one saved program per signature. A call with keyword arguments is fine.
    """
    return _SavedJit(fn, name, identity, compiler_options)


class _SavedJit:
    """A jitted function whose program, per argument signature, is exported and saved."""

    def __init__(self, fn: Callable, name: str, identity: Hashable | None,
                 options: dict[str, Any] | None) -> None:
        import jax

        self._fn, self._name, self._identity, self._options = fn, name, identity, options
        self._plain = jax.jit(fn, compiler_options=options) if options else jax.jit(fn)
        self._programs: dict[tuple[Any, ...], Callable] = {}
        self._last: tuple[tuple[Any, ...], Callable] | None = None

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        if self._identity is None:
            return self._plain(*args, **kwargs)
        sig = signature(args, kwargs)
        if self._last is None or self._last[0] != sig:
            program = self._programs.get(sig)
            if program is None:
                where = folder()  # asked once per signature: a program keeps its choice
                program = self._programs[sig] = (
                    self._plain if where is None else self._resolve(where, sig, args, kwargs))
            self._last = (sig, program)
        return self._last[1](*args, **kwargs)

    def lower(self, *args: Any, **kwargs: Any) -> Any:
        """The program lowered as ``jax.jit`` lowers it (saved or not, it is this program):
        what a caller inspects, e.g. that data reach it as an argument, not as constants."""
        return self._plain.lower(*args, **kwargs)

    def _jit(self, fn: Callable, **options: Any) -> Callable:
        import jax

        if self._options:
            options["compiler_options"] = self._options
        return jax.jit(fn, **options)

    def _resolve(self, where: Path, sig: tuple[Any, ...], args: tuple, kwargs: dict) -> Callable:
        """The saved program of this signature: read back, else exported and written; the
        plain jitted function when it cannot be exported."""
        key = program_key(self._fn, self._name, self._identity, sig, self._options)
        path, refused = where / f"{key}.exported", where / f"{key}.refused"
        if refused.exists():
            return self._plain
        _register_named_tuples((args, kwargs))
        exported = _read(path)
        if exported is None:
            exported = _export(self._plain, args, kwargs)
            blob = None if exported is None else _serialized(exported)
            if blob is None:
                _write(refused, b"")
                return self._plain
            _write(path, blob)
            # run what later processes will read back: the program read from its bytes (no
            # source locations), which the compilation cache then knows under their key
            exported = _deserialized(blob)
            if exported is None:
                return self._plain
        return _on_one_device(self._jit, exported.call, self._name)


def _on_one_device(jit: Callable, call: Callable, name: str) -> Callable:
    """``call`` jitted with every argument placed on the default device, under ``name`` (the
    program's name in JAX's logs and profiles).

    Lowering an exported call writes its arguments' placement into the program: arrays a
    computation left on the device and arrays made in Python would otherwise give two
    programs (the sampler's first chunk and the next), the second compiled again because the
    compilation cache does not know it. The arguments are passed flat (keyword ones too), so
    that one placement covers them all."""
    import jax

    device = jax.sharding.SingleDeviceSharding(jax.devices()[0])

    def flat(tree: Any, *leaves: Any) -> Any:
        args, kwargs = jax.tree.unflatten(tree, leaves)
        return call(*args, **kwargs)

    flat.__name__ = flat.__qualname__ = name.replace("-", "_")

    programs: dict[Any, Callable] = {}

    def run(*args: Any, **kwargs: Any) -> Any:
        leaves, tree = jax.tree.flatten((args, kwargs))
        program = programs.get(tree)
        if program is None:
            program = programs[tree] = jit(functools.partial(flat, tree),
                                           in_shardings=device)
        return program(*leaves)

    return run


def _read(path: Path) -> Any:
    """The exported program saved at ``path``, or None (absent, unreadable, corrupt)."""
    try:
        blob = path.read_bytes()
    except OSError:
        return None
    return _deserialized(blob)


def _deserialized(blob: bytes) -> Any:
    """The exported program of ``blob``, or None when it does not read back."""
    from jax import export

    try:
        return export.deserialize(bytearray(blob))
    except Exception:  # a truncated or corrupt file: ignored, written again
        return None


def _export(jitted: Callable, args: tuple, kwargs: dict) -> Any:
    """``jax.export`` of ``jitted`` at these arguments, or None when it cannot be exported
    (a custom call without a stability guarantee, a host callback, ...)."""
    from jax import export

    try:
        return export.export(jitted)(*args, **kwargs)
    except Exception:
        return None


def _serialized(exported: Any) -> bytes | None:
    """``exported.serialize()``, or None when it cannot be (a pytree node of its outputs that
    JAX cannot name in a file)."""
    try:
        return bytes(exported.serialize())
    except Exception:
        return None


def _register_named_tuples(tree: Any) -> None:
    """Make the named tuples among the nodes of ``tree`` (a sampler's state: ``DRAMState``)
    serialisable, each under its module and qualified name: the same name in every process,
    so that a saved program's argument structure reads back (once per type and process)."""
    import jax
    from jax import export

    pending = [jax.tree.structure(tree)]
    while pending:
        node = pending.pop()
        data = node.node_data()
        if data is not None and _is_named_tuple(data[0]) and data[0] not in _NAMED:
            _NAMED.add(data[0])
            with contextlib.suppress(ValueError):  # registered already (by JAX or earlier)
                export.register_namedtuple_serialization(
                    data[0], serialized_name=f"{data[0].__module__}.{data[0].__qualname__}")
        pending.extend(node.children())


_NAMED: set[type] = set()


def _is_named_tuple(kind: type) -> bool:
    return isinstance(kind, type) and issubclass(kind, tuple) and hasattr(kind, "_fields")


def _write(path: Path, blob: bytes) -> None:
    """Write ``blob`` to ``path`` atomically (a temporary file renamed); a failure to write
    (a read-only cache) only means the program is not saved."""
    with _LOCK, contextlib.suppress(OSError):
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
        tmp.write_bytes(blob)
        os.replace(tmp, path)
