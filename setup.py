"""Build script for the optional compiled likelihood kernel (everything else is in pyproject.toml).

The kernel (``csrc/ukf_kernel.cc``) is an XLA FFI handler, compiled with the system C++
compiler against the FFI headers that ship with ``jaxlib``. The extension is optional: when
``jaxlib`` or a compiler is missing, or the compilation fails, the package installs without it
and symplid uses its JAX implementation of the likelihood.
"""

from __future__ import annotations

import os
import sys

from setuptools import Extension, setup


def _ffi_include_dir() -> str | None:
    """The XLA FFI headers of the installed jaxlib (``jax.ffi.include_dir()``), if any."""
    try:
        import jaxlib
    except ImportError:
        return None
    folder = os.path.join(os.path.dirname(jaxlib.__file__), "include")
    return folder if os.path.isfile(os.path.join(folder, "xla", "ffi", "api", "ffi.h")) else None


def _extensions() -> list[Extension]:
    include = _ffi_include_dir()
    if include is None:
        print("symplid: jaxlib's FFI headers not found; the compiled kernel is skipped")
        return []
    if sys.platform == "win32":
        args = ["/O2", "/std:c++17"]
    else:
        # No -march=native: the kernel holds AVX-512, AVX2 and baseline variants and picks one
        # at run time. No floating-point contraction, so all variants give the same numbers.
        args = ["-O3", "-std=c++17", "-fno-math-errno", "-ffp-contract=off"]
    return [
        Extension(
            "symplid._ukf_kernel",
            sources=["csrc/ukf_kernel.cc"],
            depends=["csrc/ukf_kernel_impl.h"],
            include_dirs=[include],
            language="c++",
            extra_compile_args=args,
            optional=True,
        )
    ]


setup(ext_modules=_extensions())
