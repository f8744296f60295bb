"""Build script for the optional compiled likelihood kernel (everything else is in pyproject.toml).

The kernel is an XLA FFI handler (``csrc/ukf_kernel.cc``) and one numerical kernel per
instruction set (``csrc/ukf_kernel_avx512.cc``, ``_avx2.cc``, ``_baseline.cc``), compiled with
the system C++ compiler against the FFI headers that ship with ``jaxlib``. The four translation
units are compiled in parallel, one compiler process per core. The extension is optional: when
``jaxlib`` or a compiler is missing, or the compilation fails, the package installs without it
and symplid uses its JAX implementation of the likelihood. ``SYMPLID_BUILD_KERNEL=0`` skips it.
"""

from __future__ import annotations

import os
import sys
from concurrent.futures import ThreadPoolExecutor

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext
from setuptools.command.build_py import build_py

SOURCES = [  # the slowest to compile first (setuptools sorts them by name; the build does not)
    "csrc/ukf_kernel_avx512.cc",
    "csrc/ukf_kernel_baseline.cc",
    "csrc/ukf_kernel_avx2.cc",
    "csrc/ukf_adjoint_fast.cc",
    "csrc/ukf_adjoint.cc",
    "csrc/ukf_kernel.cc",
]
HEADERS = ["csrc/ukf_kernel.h", "csrc/ukf_kernel_impl.h", "csrc/ukf_adjoint.h",
           "csrc/ukf_basis.h"]
# Installed as package data (symplid/csrc) beside the built-in kernel's sources: a user
# model's unit is compiled from them on first use (symplid/model/_user_kernel.py).
USER_SOURCES = ["csrc/ukf_adjoint_update.h", "csrc/ukf_user.h", "csrc/ukf_user_math.h"]


def _ffi_include_dir() -> str | None:
    """The XLA FFI headers of the installed jaxlib (``jax.ffi.include_dir()``), if any."""
    try:
        import jaxlib
    except ImportError:
        return None
    folder = os.path.join(os.path.dirname(jaxlib.__file__), "include")
    return folder if os.path.isfile(os.path.join(folder, "xla", "ffi", "api", "ffi.h")) else None


def _jobs(count: int) -> int:
    """Compiler processes to run at once: one per usable core, at most one per source."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(count, cores))


class ParallelBuildExt(build_ext):
    """``build_ext`` that compiles an extension's sources in parallel (one compiler process
    per source, as many at once as there are cores), then links them as usual.

    A failed compilation raises the compiler's error from the source that failed, so an
    optional extension is skipped exactly as with the serial build.
    """

    def build_extension(self, ext: Extension) -> None:
        compiler = self.compiler
        serial = compiler.compile

        def compile_parallel(sources, *args, **kwargs):
            if len(sources) < 2:
                return serial(sources, *args, **kwargs)
            rank = {os.path.normpath(src): i for i, src in enumerate(SOURCES)}
            sources = sorted(sources, key=lambda src: rank.get(os.path.normpath(src), len(rank)))
            pool = ThreadPoolExecutor(_jobs(len(sources)))
            try:
                parts = [pool.submit(serial, [src], *args, **kwargs) for src in sources]
                return [obj for part in parts for obj in part.result()]
            finally:  # after a failure, start no further source
                pool.shutdown(wait=True, cancel_futures=True)

        compiler.compile = compile_parallel
        try:
            super().build_extension(ext)
        finally:
            del compiler.compile  # back to the class's method


class BuildPyWithSources(build_py):
    """``build_py`` that also copies the kernel's C++ sources into the package
    (``symplid/csrc``), from which user models' units are compiled at run time."""

    def run(self) -> None:
        super().run()
        target = os.path.join(self.build_lib, "symplid", "csrc")
        self.mkpath(target)
        for source in SOURCES + HEADERS + USER_SOURCES:
            if not source.endswith(("_avx512.cc", "_avx2.cc", "_baseline.cc", "_fast.cc")):
                self.copy_file(source, target)


def _extensions() -> list[Extension]:
    if os.environ.get("SYMPLID_BUILD_KERNEL", "1").strip().lower() in ("0", "no", "false"):
        print("symplid: SYMPLID_BUILD_KERNEL=0, the compiled kernel is skipped")
        return []
    include = _ffi_include_dir()
    if include is None:
        print("symplid: jaxlib's FFI headers not found; the compiled kernel is skipped")
        return []
    if sys.platform == "win32":
        args = ["/O2", "/std:c++17"]
    else:
        # No -march=native: the kernel holds AVX-512, AVX2 and baseline variants and picks one
        # at run time. Floating-point contraction on (fused multiply-adds where the processor
        # has them): the variants agree with each other and the JAX tier to rounding.
        # No debug information (-g0 overrides the -g of Python's own flags): on the kernel's
        # unrolled loops it made the compiler take 1.7 times as long.
        args = ["-O3", "-g0", "-std=c++17", "-fno-math-errno", "-ffp-contract=fast"]
    return [
        Extension(
            "symplid._ukf_kernel",
            sources=SOURCES,
            depends=HEADERS,
            include_dirs=[include],
            language="c++",
            extra_compile_args=args,
            optional=True,
        )
    ]


setup(ext_modules=_extensions(),
      cmdclass={"build_ext": ParallelBuildExt, "build_py": BuildPyWithSources})
