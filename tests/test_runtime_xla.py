"""XLA flags set by ``import symplid``, and the compiled programs they give.

* ``import symplid`` puts the small-loop threshold into ``XLA_FLAGS`` before JAX starts,
  merged with the user's flags (bare tokens last: XLA stops parsing at the first one),
  not at all with ``SYMPLID_XLA_FLAGS=off``, and with a one-line warning when too late.
* The optimised HLO shows that the filter's loops and a DRAM chunk compile to one kernel
  (a ``call`` marked ``xla_cpu_small_call``, no ``while`` left in the entry computation), so
  that a future JAX or a new custom call in the loop body cannot silently undo it.
"""

from __future__ import annotations

import dataclasses
import os
import re
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from symplid import runtime
from symplid.inference.samplers import dram

SRC = str(Path(__file__).resolve().parents[1] / "src")
SHOW_FLAGS = "import os, symplid; print(os.environ.get('XLA_FLAGS', '<unset>'))"


def _python(code: str, **env: str) -> subprocess.CompletedProcess:
    environ = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "SYMPLID_XLA_FLAGS")}
    environ["PYTHONPATH"] = SRC + os.pathsep + environ.get("PYTHONPATH", "")
    environ.update(env)
    return subprocess.run(
        [sys.executable, "-c", code], env=environ, capture_output=True, text=True, check=True
    )


# ------------------------------------------------------------------------- the environment


def test_import_sets_the_small_loop_flag():
    out = _python(SHOW_FLAGS).stdout.strip()
    assert out == runtime.small_loop_flag()


def test_import_merges_with_the_users_flags_bare_token_last():
    user = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1 --xla_dump_to=/x"
    out = _python(SHOW_FLAGS, XLA_FLAGS=user).stdout.split()
    assert out[-1] == "intra_op_parallelism_threads=1"
    assert set(out[:-1]) == {
        "--xla_cpu_multi_thread_eigen=false",
        "--xla_dump_to=/x",
        runtime.small_loop_flag(),
    }


def test_users_own_threshold_wins():
    user = "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=5"
    assert _python(SHOW_FLAGS, XLA_FLAGS=user).stdout.strip() == user


def test_opt_out_leaves_xla_flags_alone():
    assert _python(SHOW_FLAGS, SYMPLID_XLA_FLAGS="off").stdout.strip() == "<unset>"
    out = _python(SHOW_FLAGS, SYMPLID_XLA_FLAGS="off", XLA_FLAGS="--a=1 b").stdout.strip()
    assert out == "--a=1 b"


def test_one_line_warning_when_jax_started_first():
    result = _python("import jax; jax.devices(); import symplid")
    lines = [line for line in result.stderr.splitlines() if "XlaFlagsWarning" in line]
    assert len(lines) == 1 and "import symplid first" in lines[0]
    quiet = _python("import jax; jax.devices(); import symplid", SYMPLID_XLA_FLAGS="off")
    assert "XlaFlagsWarning" not in quiet.stderr


def test_merge_rules():
    merge = runtime.merge_xla_flags
    assert merge(None, "--a=1") == "--a=1"
    assert merge("b --c=2", "--a=1") == "--c=2 --a=1 b"  # a bare token goes last
    assert merge("--a=0", "--a=1") == "--a=0"  # the user's value wins
    extra = "--xla_backend_extra_options"
    assert merge(f"{extra}=k=1", f"{extra}=j=2,k=3") == f"{extra}=k=1,j=2"
    assert merge("x y x", "--a=1") == "--a=1 x y"


def test_single_thread_flags_keep_the_bare_token_last(monkeypatch):
    monkeypatch.delenv("SYMPLID_XLA_FLAGS", raising=False)
    tokens = runtime.single_thread_xla_flags().split()
    assert tokens[-1] == "intra_op_parallelism_threads=1"
    assert "--xla_cpu_multi_thread_eigen=false" in tokens
    assert runtime.small_loop_flag() in tokens
    monkeypatch.setenv("SYMPLID_XLA_FLAGS", "off")
    assert runtime.small_loop_flag() not in runtime.single_thread_xla_flags().split()


# ------------------------------------------------------------------------- the compiled HLO

needs_flag = pytest.mark.skipif(
    runtime.SMALL_LOOP_OPTION not in os.environ.get("XLA_FLAGS", ""),
    reason="XLA_FLAGS without the small-loop threshold (SYMPLID_XLA_FLAGS=off)",
)


def _one_kernel(compiled_text: str) -> bool:
    """No ``while`` runs loop by loop from the entry computation: each is a small call."""
    entry = compiled_text[compiled_text.index("\nENTRY") :]
    return (
        re.search(r"\swhile\(", entry) is None
        and 'xla_cpu_small_call="true"' in compiled_text
    )


@needs_flag
def test_filter_loop_compiles_to_one_kernel(hh_model, small_data, small_x0, small_P0,
                                            small_theta):
    reference = dataclasses.replace(hh_model, backend="jax")  # the JAX tier, not the kernel
    loglik = reference.log_likelihood_fn(small_data, small_x0, small_P0)
    text = jax.jit(loglik).lower(jnp.asarray(small_theta)).compile().as_text()
    assert "custom-call(" not in text and re.search(r"\sdot\(", text) is None
    assert _one_kernel(text)


@needs_flag
def test_filter_gradient_compiles_to_one_kernel(hh_model, small_data, small_x0, small_P0,
                                                small_theta):
    # the JAX tier's gradient (the compiled tier's is the kernel's adjoint, no XLA loop at all)
    reference = dataclasses.replace(hh_model, backend="jax")
    loglik = reference.log_likelihood_fn(small_data, small_x0, small_P0)
    text = jax.jit(jax.grad(loglik)).lower(jnp.asarray(small_theta)).compile().as_text()
    assert " scatter(" not in text, "a scatter (e.g. the transpose of jnp.diagonal) in the loop"
    assert _one_kernel(text)


@needs_flag
def test_dram_chunk_compiles_to_one_kernel():
    dim = 11
    scales = jnp.linspace(0.5, 2.0, dim)

    def logdensity(x):
        return -0.5 * jnp.sum((x / scales) ** 2)

    step = dram.build_kernel(logdensity)
    state = dram.init(jnp.zeros(dim), logdensity, jnp.eye(dim))

    def chunk(state, key):
        keys = jax.random.split(key, 10)
        return jax.lax.scan(lambda s, k: (step(k, s)[0], None), state, keys)[0]

    text = jax.jit(chunk).lower(state, jax.random.key(0)).compile().as_text()
    assert "custom-call(" not in text, "a LAPACK call in DRAM's loop body"
    assert re.search(r"\sdot\(", text) is None, "a dot in DRAM's loop body"
    assert _one_kernel(text)
    out = jax.jit(chunk)(state, jax.random.key(0))
    assert np.all(np.isfinite(np.asarray(out.position)))
