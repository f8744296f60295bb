"""Process-wide settings for symplid's own processes (CLI, workers, tests), in one place.

Nothing here runs at import: each setting is turned on by a call.

**Compilation cache.** JAX's persistent compilation cache.

Compiling the filter's gradient and Hessian for a MAP fit takes tens of seconds; the same
model structure compiles to the same program, so the second run of a command reuses the
compiled code from disk. The library never turns this on at import (it is a global JAX
setting); the command line and the worker processes it starts do.

The folder is ``$SYMPLID_CACHE_DIR``, else ``$XDG_CACHE_HOME/symplid/jax``, else
``~/.cache/symplid/jax``; ``SYMPLID_CACHE_DIR=off`` disables it.
"""

from __future__ import annotations

import os
import sys
import warnings
from pathlib import Path

import jax


def default_cache_dir() -> Path | None:
    """Where the cache lives, or None when disabled by ``SYMPLID_CACHE_DIR=off``."""
    explicit = os.environ.get("SYMPLID_CACHE_DIR")
    if explicit is not None:
        return None if explicit.strip().lower() in ("", "0", "off", "none") else Path(explicit)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "symplid" / "jax"


def enable_compilation_cache(path: str | Path | None = None) -> Path | None:
    """Turn on the persistent cache (every compilation kept); returns the folder used.

    Does nothing when a cache folder is already configured or the cache is disabled.
    """
    if jax.config.jax_compilation_cache_dir:
        return Path(jax.config.jax_compilation_cache_dir)
    folder = Path(path) if path is not None else default_cache_dir()
    if folder is None:
        return None
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None  # a read-only home: run without the cache
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return folder


def show_warning_line(message, category, filename, lineno, file=None, line=None) -> None:
    """Write a warning as one readable line (no source path): ``symplid: warning: ...``."""
    print(f"symplid: warning: {message}", file=sys.stderr if file is None else file)


def one_line_warnings() -> None:
    """Show every warning of this process as one line (the CLI and its worker processes)."""
    warnings.showwarning = show_warning_line
