"""Saved programs (:mod:`symplid._saved_programs`): read back bit for bit, never reused for
another program, a damaged file ignored, and a fit with them equal to a fit without.

A program read back must compute exactly what the program that was saved computes, and what
a plain ``jax.jit`` of the same function computes: the comparisons are of the bits. "Another
process" is simulated by a fresh :func:`saved_jit` (nothing kept in memory); that it really
read the file is checked by making a second export fail.
"""

from __future__ import annotations

import dataclasses
import importlib.util
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from symplid import _saved_programs as saved_programs
from symplid._saved_programs import program_key, saved_jit, signature

pytestmark = pytest.mark.skipif(importlib.util.find_spec("flatbuffers") is None,
                                reason="saving programs needs flatbuffers")

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "user_models"


@pytest.fixture
def folder(tmp_path, monkeypatch):
    """Saved programs on, in a folder of this test's own."""
    where = tmp_path / "programs"
    monkeypatch.delenv(saved_programs.OPT_OUT_ENV, raising=False)
    monkeypatch.setattr(saved_programs, "folder", lambda: where)
    return where


def _no_export(monkeypatch):
    """Make exporting fail: a program that works afterwards was read from its file."""
    def refuse(*_):
        raise AssertionError("exported again although a saved program was there")

    monkeypatch.setattr(saved_programs, "_export", refuse)


def _filter_like(theta, ys):
    """A small function with a loop, a gradient and a closure constant."""
    decay = jnp.asarray([0.9, 0.5])

    def step(x, y):
        x = decay * x + theta[0] * jnp.sin(x) + theta[1]
        return x, jnp.sum((y - x) ** 2)

    _, losses = jax.lax.scan(step, jnp.zeros(2), ys)
    return -jnp.sum(losses)


VG = jax.value_and_grad(_filter_like)
THETA = jnp.asarray([0.3, -0.1])
YS = jnp.asarray(np.random.default_rng(0).normal(size=(50, 2)))


def _bits(tree):
    return [np.asarray(leaf).tobytes() for leaf in jax.tree.leaves(tree)]


def test_read_back_is_bit_identical_to_the_saved_and_the_plain_program(folder, monkeypatch):
    first = saved_jit(VG, "vg", ("test", 1))(THETA, YS)
    assert len(list(folder.glob("*.exported"))) == 1
    _no_export(monkeypatch)
    again = saved_jit(VG, "vg", ("test", 1))(THETA, YS)  # another process: read back
    plain = jax.jit(VG)(THETA, YS)
    assert _bits(again) == _bits(first) == _bits(plain)
    # and at other arguments of the same signature
    other = (THETA + 0.5, YS * 2)
    assert _bits(saved_jit(VG, "vg", ("test", 1))(*other)) == _bits(jax.jit(VG)(*other))


def test_keyword_arguments_and_named_tuple_states_round_trip(folder, monkeypatch):
    class State(NamedTuple):
        position: jax.Array
        count: jax.Array

    def advance(state, key, *, data):
        noise = jax.random.normal(key, state.position.shape)
        return State(state.position + data * noise, state.count + 1)

    state, key = State(jnp.ones(3), jnp.zeros((), jnp.int32)), jax.random.key(1)
    saved = saved_jit(advance, "advance", ("test",))(state, key, data=jnp.float64(0.1))
    _no_export(monkeypatch)
    back = saved_jit(advance, "advance", ("test",))(state, key, data=jnp.float64(0.1))
    plain = jax.jit(advance)(state, key, data=jnp.float64(0.1))
    assert isinstance(back, State)
    assert _bits(back) == _bits(saved) == _bits(plain)


def test_another_name_identity_shape_dtype_options_or_source_is_another_key(monkeypatch):
    sig = signature((THETA, YS), {})
    base = program_key(VG, "vg", ("a",), sig)
    assert program_key(VG, "vg", ("a",), sig) == base  # the same program: the same key
    others = {
        "identity": program_key(VG, "vg", ("b",), sig),
        "name": program_key(VG, "hessian", ("a",), sig),
        "shape": program_key(VG, "vg", ("a",), signature((THETA, YS[:10]), {})),
        "dtype": program_key(VG, "vg", ("a",), signature((THETA.astype(jnp.float32), YS), {})),
        "structure": program_key(VG, "vg", ("a",), signature(((THETA,), YS), {})),
        "options": program_key(VG, "vg", ("a",), sig, {"xla_backend_optimization_level": 0}),
        "function": program_key(_bits, "vg", ("a",), sig),
    }
    monkeypatch.setattr(saved_programs, "_environment", lambda: ("another checkout",))
    others["source"] = program_key(VG, "vg", ("a",), sig)
    assert len({base, *others.values()}) == len(others) + 1, others


def test_a_python_scalar_and_a_weak_array_are_one_program(folder):
    """JAX traces ``f(0)`` and ``f(jnp.asarray(0))`` once: they are one saved program, and a
    strongly typed int32 another."""
    def step(x, count):
        return x + count

    program = saved_jit(step, "step", ("test",))
    x = jnp.ones(2)
    assert np.array_equal(program(x, 2), program(x, jnp.asarray(2)))
    assert len(list(folder.glob("*.exported"))) == 1
    assert signature((x, 2), {}) == signature((x, jnp.asarray(2)), {})
    assert signature((x, 2), {}) != signature((x, jnp.asarray(2, jnp.int32)), {})
    assert signature((x, 2.0), {}) != signature((x, 2), {})


def test_a_changed_closure_under_another_identity_is_not_reused(folder):
    """What the caller's identity stands for: the same function of another closure constant,
    under its own identity, runs its own program, never the first one's."""
    def scaled(factor):
        return lambda x: factor * x

    x = jnp.arange(3.0)
    assert np.array_equal(saved_jit(scaled(2.0), "scaled", ("factor", 2.0))(x), 2 * x)
    assert np.array_equal(saved_jit(scaled(3.0), "scaled", ("factor", 3.0))(x), 3 * x)
    assert len(list(folder.glob("*.exported"))) == 2


def test_a_truncated_or_corrupt_file_is_ignored_and_written_again(folder):
    expected = _bits(jax.jit(VG)(THETA, YS))
    saved_jit(VG, "vg", ("test",))(THETA, YS)
    (path,) = folder.glob("*.exported")
    good = path.read_bytes()
    for damaged in (good[: len(good) // 2], b"not a program", b""):
        path.write_bytes(damaged)
        assert _bits(saved_jit(VG, "vg", ("test",))(THETA, YS)) == expected
        assert path.read_bytes() == good  # recompiled and saved again


def test_off_unmarked_and_unexportable_programs_run_as_plain_jit(folder, monkeypatch):
    expected = _bits(jax.jit(VG)(THETA, YS))
    assert _bits(saved_jit(VG, "vg", None)(THETA, YS)) == expected  # no identity: not saved
    monkeypatch.setattr(saved_programs, "folder", lambda: None)  # off
    assert _bits(saved_jit(VG, "vg", ("test",))(THETA, YS)) == expected
    assert not folder.exists()

    monkeypatch.setattr(saved_programs, "folder", lambda: folder)

    def with_callback(x):  # a host callback cannot be exported
        y = jax.pure_callback(lambda v: np.asarray(v) * 2, jax.ShapeDtypeStruct(x.shape,
                                                                                 x.dtype), x)
        return y + 1

    assert np.array_equal(saved_jit(with_callback, "cb", ("test",))(jnp.ones(2)),
                          np.full(2, 3.0))
    assert len(list(folder.glob("*.refused"))) == 1  # remembered: not tried again
    _no_export(monkeypatch)
    assert np.array_equal(saved_jit(with_callback, "cb", ("test",))(jnp.ones(2)),
                          np.full(2, 3.0))


def test_the_environment_switch_turns_saving_off(monkeypatch, tmp_path):
    monkeypatch.delenv(saved_programs.OPT_OUT_ENV, raising=False)
    before = jax.config.jax_compilation_cache_dir
    assert before is None or saved_programs.folder() is not None
    jax.config.update("jax_compilation_cache_dir", str(tmp_path))  # nothing compiled here
    try:
        assert saved_programs.folder() == tmp_path / saved_programs.SUBFOLDER
        monkeypatch.setenv(saved_programs.OPT_OUT_ENV, "off")
        assert saved_programs.folder() is None
    finally:
        jax.config.update("jax_compilation_cache_dir", before)
    monkeypatch.delenv(saved_programs.OPT_OUT_ENV)
    assert (saved_programs.folder() is None) == (before is None)  # no cache: no saving


# ----------------------------------------------------------------------------- a whole fit
def _pendulum(tmp_path):
    from symplid.io import read_trajectories
    from symplid.workflow._settings import load_settings, settings_from_dict, settings_to_dict

    spec = importlib.util.spec_from_file_location("simulate_data",
                                                  EXAMPLES / "simulate_data.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    data = tmp_path / "pendulum.csv"
    module.write_csv("pendulum", data, 0)
    settings = settings_to_dict(load_settings(EXAMPLES / "pendulum.toml"))
    settings["sampler"].update(num_iterations=300, burn_in=100, num_chains=2)
    settings["map"].update(num_starts=2, sensitivity=False)
    obs = read_trajectories([data])
    return (obs[0] if isinstance(obs, list) else obs), settings_from_dict(settings)


def _fit(obs, settings):
    from symplid.workflow._fit import fit

    outcome = fit(obs, settings, progress=False)
    posterior = outcome.idata.posterior
    return (np.asarray(outcome.map_result.theta),
            np.stack([posterior[name].values for name in posterior.data_vars]))


@pytest.mark.slow
def test_a_fit_with_saved_programs_is_bit_identical_to_one_without(folder, monkeypatch,
                                                                    tmp_path):
    obs, settings = _pendulum(tmp_path)
    monkeypatch.setattr(saved_programs, "folder", lambda: None)
    without = _fit(obs, settings)
    monkeypatch.setattr(saved_programs, "folder", lambda: folder)
    saving = _fit(obs, settings)
    names = {p.name for p in folder.glob("*.exported")}
    assert len(names) >= 3  # the MAP's value and gradient, its Hessian, the chunk
    _no_export(monkeypatch)
    reading = _fit(obs, settings)
    assert {p.name for p in folder.iterdir()} == names  # all read back, none refused
    for a, b, c in zip(without, saving, reading, strict=True):
        assert a.tobytes() == b.tobytes() == c.tobytes()
    # another data set of the same shape is another identity: its own programs
    changed = dataclasses.replace(obs, values=obs.values + 1e-3)
    from symplid.workflow._building import program_identity

    def identity(*args):
        return saved_programs.digest(program_identity(*args))

    assert identity(settings, obs) == identity(settings, dataclasses.replace(obs))
    assert identity(settings, changed) != identity(settings, obs)
    other = dataclasses.replace(settings, model=dataclasses.replace(
        settings.model, potential="k*(1 - cos(q1)) + 0*q1"))
    assert identity(other, obs) != identity(settings, obs)
