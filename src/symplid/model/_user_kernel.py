"""The compiled kernel for a user's U(q; θ): a unit generated, compiled and cached on first use.

The built-in kernel (:mod:`symplid.model._kernel`) knows the polynomial potentials of eq. (13)
at build time. For a user's expression (:mod:`symplid.dynamics._user_models`, a potential
with the quadratic kinetic energy ½pᵀM⁻¹p) this module writes the force and the derivatives
the adjoint needs as C++ (:mod:`symplid.model._user_force`), compiles them with the kernel's
own filter, propagators and adjoint (``csrc/ukf_user.h``) into a shared library, and loads it
as a pair of XLA FFI targets. The filter is the built-in kernel's; only the force is the
user's.

* **Compiler**: ``SYMPLID_CXX`` names it; else the one ``pip install`` compiled the package
  with (``$CXX``, else the C++ compiler Python was built with), else ``c++``. Where none is
  found, or the compilation fails, the JAX tier runs the model and one note per process says
  why.
* **Cache**: ``SYMPLID_KERNEL_CACHE``, else ``$XDG_CACHE_HOME/symplid/kernels`` (by default
  ``~/.cache/symplid/kernels``), one ``.so`` per key: a hash of the canonical expression,
  the parameters' order, d, the generated code, the instruction set, the compiler and its
  flags, the package's version and the kernel's sources. The library is written under a
  temporary name and renamed into place (atomic), under a lock file, so that two processes
  that need the same unit at once compile it once and never load half a file.
* **Instruction set**: the built-in kernel's (:func:`symplid.model._kernel.instruction_set`;
  ``SYMPLID_KERNEL_ISA`` narrows it), one unit per instruction set.
"""

from __future__ import annotations

import contextlib
import ctypes
import hashlib
import importlib.metadata
import os
import shlex
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from symplid._compiled import cached
from symplid.model._user_force import ForceCode, UnsupportedExpression, force_code

__all__ = [
    "UserUnit",
    "cache_dir",
    "compiler",
    "find_unit",
    "unit_reason",
]

# Per instruction set: the compiler's target flags and whether a vector is one of many
# registers (the value kernel's fast propagation).
_ISA_FLAGS = {
    "avx512": (["-mavx512f", "-mavx512vl", "-mavx512dq", "-mavx2", "-mfma"], 1),
    "avx2": (["-mavx2", "-mfma"], 0),
    "baseline": ([], 0),
}
# -O2: the Kepler unit compiled in 12.3 CPU-s against -O3's 22.5 and ran as fast (11.9 µs a
# value both; benchmarks/user_kernel.py --flags); no debug information, contraction as the
# package's build.
_OPT_FLAGS = ["-O2", "-g0", "-std=c++17", "-fno-math-errno", "-ffp-contract=fast", "-fPIC",
              "-shared", "-Wl,-Bsymbolic"]
_SOURCES = ("ukf_kernel.h", "ukf_kernel_impl.h", "ukf_basis.h", "ukf_adjoint.h",
            "ukf_adjoint.cc", "ukf_adjoint_update.h", "ukf_kernel.cc", "ukf_user.h",
            "ukf_user_math.h")


@dataclass(frozen=True)
class UserUnit:
    """A loaded user unit: its FFI targets (registered with XLA) and its shared library."""

    key: str
    path: Path
    value_target: str
    gradient_target: str
    isa: str


class _Units:
    """The process's loaded units by key and the notes already given (XLA's registry of FFI
    targets is per process, so this one is too)."""

    found: ClassVar[dict[str, UserUnit | str]] = {}  # by expression: the unit, or why none
    by_key: ClassVar[dict[str, UserUnit]] = {}
    noted: ClassVar[set[str]] = set()


def compiler() -> str | None:
    """The C++ compiler of user units (module docstring), as a path; None where none is found."""
    setting = os.environ.get("SYMPLID_CXX", "").strip()
    if setting:
        return shutil.which(shlex.split(setting)[0])
    # as setuptools picks the package's compiler: $CXX, else the one Python was built with
    named = [os.environ.get("CXX", "").strip(), (sysconfig.get_config_var("CXX") or "").strip()]
    for candidate in [shlex.split(n)[0] for n in named if n] + ["c++", "g++"]:
        found = shutil.which(candidate)
        if found:
            return found
    return None


def cache_dir() -> Path:
    """The folder of compiled user units (module docstring)."""
    setting = os.environ.get("SYMPLID_KERNEL_CACHE", "").strip()
    if setting:
        return Path(setting).expanduser()
    base = os.environ.get("XDG_CACHE_HOME", "").strip() or str(Path.home() / ".cache")
    return Path(base) / "symplid" / "kernels"


def _source_dir() -> Path | None:
    """The kernel's C++ sources: installed beside the package (``symplid/csrc``) or, in a
    source checkout, the repository's ``csrc``."""
    package = Path(__file__).resolve().parent.parent
    for folder in (package / "csrc", package.parent.parent / "csrc"):
        if all((folder / name).is_file() for name in _SOURCES):
            return folder
    return None


def _unit_text(code: ForceCode, isa: str) -> str:
    many = _ISA_FLAGS[isa][1]
    return (
        f"// A user model's unit, generated by symplid: {code.canonical}\n"
        '#include "ukf_kernel.h"\n#include "ukf_user_math.h"\n\n'
        "namespace symplid {\nnamespace user_force {\nnamespace um = ::symplid::user_math;\n\n"
        f"{code.source}\n}}  // namespace user_force\n}}  // namespace symplid\n\n"
        "#define SYMPLID_USER_FORCE ::symplid::user_force::Force\n"
        f'#define SYMPLID_USER_ISA "{isa}"\n#define SYMPLID_MANY_REGISTERS {many}\n'
        '#include "ukf_user.h"\n'
    )


def _package_version() -> str:
    try:
        return importlib.metadata.version("symplid")
    except importlib.metadata.PackageNotFoundError:  # a source tree on the path
        return "source"


def _key(code: ForceCode, isa: str, cxx: str, sources: Path) -> str:
    digest = hashlib.sha256()
    for part in (code.canonical, _unit_text(code, isa), isa, cxx, " ".join(_OPT_FLAGS),
                 _package_version(), _compiler_version(cxx)):
        digest.update(part.encode() + b"\0")
    for name in _SOURCES:
        digest.update((sources / name).read_bytes())
    return digest.hexdigest()[:24]


def _compiler_version(cxx: str) -> str:
    try:
        out = subprocess.run([cxx, "--version"], capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.SubprocessError):
        return ""
    return out.stdout.splitlines()[0] if out.stdout else ""


def _include_dir() -> str:
    import jax

    return str(jax.ffi.include_dir())


def _compile(cxx: str, text: str, sources: Path, isa: str, target: Path) -> str | None:
    """Compile ``text`` into ``target`` atomically; the compiler's last error line or None.
    Links the vector math library where there is one (retried without it where not)."""
    flags = _ISA_FLAGS[isa][0]
    with tempfile.TemporaryDirectory(dir=target.parent, prefix=".build-") as tmp:
        unit = Path(tmp) / "unit.cc"
        unit.write_text(text)
        out = Path(tmp) / "unit.so"
        error = ""
        for mvec in ((True, False) if sys.platform.startswith("linux") else (False,)):
            command = [cxx, *_OPT_FLAGS, *flags, f"-I{sources}", f"-I{_include_dir()}",
                       *(["-DSYMPLID_USER_MVEC=1"] if mvec else []), str(unit), "-o", str(out),
                       *(["-lmvec", "-lm"] if mvec else ["-lm"])]
            run = subprocess.run(command, capture_output=True, text=True)
            if run.returncode == 0:
                os.replace(out, target)  # atomic: a reader sees no file or the whole one
                return None
            error = (run.stderr.strip().splitlines() or ["failed"])[-1]
        return error


@contextlib.contextmanager
def _locked(path: Path):
    """An exclusive lock on ``path`` (POSIX; elsewhere none: the rename stays atomic)."""
    try:
        import fcntl
    except ImportError:  # not POSIX
        yield
        return
    with open(path, "a+") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def _build(code: ForceCode, isa: str) -> Path | str:
    """The unit's compiled library (built now if it is not cached), or why there is none."""
    cxx = compiler()
    if cxx is None:
        named = os.environ.get("SYMPLID_CXX", "").strip()
        return (f"the compiler SYMPLID_CXX={named!r} was not found" if named
                else "no C++ compiler was found (set SYMPLID_CXX)")
    sources = _source_dir()
    if sources is None:
        return "the kernel's C++ sources are not installed"
    key = _key(code, isa, cxx, sources)
    folder = cache_dir()
    target = folder / f"user_{key}.so"
    if target.is_file():
        return target
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with _locked(folder / f"user_{key}.lock"):
            if target.is_file():  # another process built it while this one waited
                return target
            error = _compile(cxx, _unit_text(code, isa), sources, isa, target)
    except OSError as err:
        return f"cannot write the unit to {str(folder)!r} ({err})"
    return target if error is None else f"its compilation failed ({error})"


def _load(path: Path, isa: str) -> UserUnit:
    """The unit at ``path``, its FFI targets registered (once per process and key: XLA
    refuses a second handler under a registered name)."""
    import jax

    key = path.stem
    if key in _Units.by_key:
        return _Units.by_key[key]
    handle = ctypes.CDLL(str(path))
    value_target, gradient_target = f"symplid_{key}", f"symplid_{key}_grad"
    jax.ffi.register_ffi_target(
        value_target, jax.ffi.pycapsule(handle.SymplidUkfLogLikelihood), platform="cpu")
    jax.ffi.register_ffi_target(
        gradient_target, jax.ffi.pycapsule(handle.SymplidUkfLogLikelihoodGradient),
        platform="cpu")
    _Units.by_key[key] = unit = UserUnit(key, path, value_target, gradient_target, isa)
    return unit


def _note(reason: str) -> None:
    if reason not in _Units.noted:
        _Units.noted.add(reason)
        print(f"symplid: the user model's compiled kernel is not used: {reason}; "
              "the JAX tier runs it", file=sys.stderr)


def find_unit(potential: Any, isa: str) -> UserUnit | str:
    """The loaded unit of a user potential for instruction set ``isa`` (compiled and cached
    on first use), or one line saying why there is none (noted once per process on stderr).
    The answer is kept on the potential (:func:`symplid._compiled.cached`)."""
    key = ("user_unit", isa, os.environ.get("SYMPLID_CXX", ""))
    return cached(potential, key, lambda: _find_unit(potential, isa))


def _find_unit(potential: Any, isa: str) -> UserUnit | str:
    expr = getattr(potential, "expression", None)
    if expr is None:
        return "the potential has no expression (a Python function: the JAX tier runs it)"
    if potential.num_params < 1:
        return "the potential has no parameters"
    try:
        code = force_code(expr, potential.dim, potential.param_names)
    except UnsupportedExpression as err:
        return f"the expression cannot be compiled: {err}"
    ident = f"{code.canonical}|{isa}|{os.environ.get('SYMPLID_CXX', '')}"
    if ident not in _Units.found:
        _Units.found[ident] = _built_and_loaded(code, isa)
    return _Units.found[ident]


def _built_and_loaded(code: ForceCode, isa: str) -> UserUnit | str:
    """The unit of ``code`` built (or found in the cache) and loaded, or why not (noted)."""
    built = _build(code, isa)
    if isinstance(built, str):
        _note(built)
        return built
    try:
        return _load(built, isa)
    except (OSError, AttributeError, RuntimeError, ValueError) as err:
        reason = f"the compiled unit cannot be loaded ({err})"
        _note(reason)
        return reason


def unit_reason(potential: Any, isa: str) -> str | None:
    """Why a user potential has no compiled unit (None when it has one, built now if needed)."""
    found = find_unit(potential, isa)
    return found if isinstance(found, str) else None
