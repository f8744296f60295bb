"""The forced propagators keep their order: global error against SciPy's DOP853 (rtol 1e-13)
on a forced Duffing oscillator and a driven damped pendulum, slopes 2 and 4 in the step; with
F = 0 they are today's maps; the force's expressions are read like a user model's."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from symplid.dynamics._forced import bind_forced, forced_solve_gaps, with_force
from symplid.dynamics._forcing import user_force
from symplid.dynamics._integrators import INTEGRATORS, make_dynamics
from symplid.dynamics._user_models import UserModelError, build_user_model


def _signal(t):
    return np.sin(1.3 * t) + 0.5 * np.cos(2.1 * t)


def _duffing():
    pot = build_user_model("k1*q1^2/2 + k3*q1^4/4", "potential", 1, ("k1", "k3"))
    force = user_force("b*u1 - c*p1", 1, ("b", "c"), 1)
    k1, k3, b, c = 1.0, 0.5, 0.8, 0.1

    def rhs(t, x):
        q, p = x
        return [p, -k1 * q - k3 * q**3 + b * _signal(t) - c * p]

    return pot, force, np.array([k1, k3, b, c]), rhs


def _pendulum():
    """Pendulum H = p²/2 + k(1 − cos q) with a cubic drag (F nonlinear in p: Newton)."""
    pot = build_user_model("k*(1 - cos(q1))", "potential", 1, ("k",))
    force = user_force("b*u1 - c*p1 - d*p1^3 + e*t", 1, ("b", "c", "d", "e"), 1)
    k, b, c, d, e = 2.0, 0.7, 0.2, 0.05, 0.01

    def rhs(t, x):
        q, p = x
        return [p, -k * np.sin(q) + b * _signal(t) - c * p - d * p**3 + e * t]

    return pot, force, np.array([k, b, c, d, e]), rhs


def _errors(system, name, counts, span=4.0, x0=(1.0, 0.0)):
    pot, force, theta, rhs = system()
    ref = solve_ivp(rhs, (0.0, span), x0, method="DOP853", rtol=1e-13,
                    atol=1e-13).y[:, -1]
    integrator = with_force(name)
    nodes = np.asarray(integrator.nodes)
    dynamics = bind_forced(pot, force, jnp.asarray(theta))
    out = []
    for n in counts:
        h = span / n
        times = (np.arange(n)[:, None] + nodes[None, :]) * h
        xs = forced_solve_gaps(integrator, dynamics, jnp.asarray(x0), jnp.array([h]),
                               jnp.array([n]), times[None], _signal(times)[None, ..., None], n)
        out.append(np.abs(np.asarray(xs[-1]) - ref).max())
    return np.asarray(out)


@pytest.mark.parametrize("system", [_duffing, _pendulum], ids=["duffing", "pendulum"])
@pytest.mark.parametrize("name,order", [("leapfrog", 2), ("yoshida4", 4), ("rk4", 4),
                                        ("rk2-midpoint", 2)])
def test_forced_order(system, name, order):
    errors = _errors(system, name, (20, 40, 80, 160))
    slopes = np.log2(errors[:-1] / errors[1:])
    assert np.all(np.abs(slopes - order) < 0.15), (errors, slopes)


def test_unforced_forced_step_is_leapfrog_and_yoshida():
    """With F = 0 the forced step is today's step (to rounding: the same map)."""
    pot = build_user_model("k1*q1^2/2 + k3*q1^4/4", "potential", 1, ("k1", "k3"))
    zero = user_force("0*u1", 1, (), 1)
    theta = jnp.array([1.3, 0.4])
    q, p = jnp.array([[0.7, -1.1]]), jnp.array([[0.2, 0.5]])
    for name in ("leapfrog", "yoshida4", "rk4"):
        base = INTEGRATORS.get_entry(name)
        forced = with_force(name)
        h = 0.1
        times = jnp.asarray(forced.nodes) * h
        inputs = jnp.zeros((len(forced.nodes), 1))
        got = forced.forced_step(bind_forced(pot, zero, theta), q, p, h, times, inputs)
        want = base.step(make_dynamics(pot, theta), q, p, h)
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=0, atol=1e-15)


def test_force_reads_p_dependence_and_parameters():
    assert user_force("b*u1", 1, ("b", "c"), 1).p_dependence == "none"
    linear = user_force("b*u1 - c*p1*q1^2", 1, ("b", "c", "k"), 1)
    assert linear.p_dependence == "linear" and linear.names == ("b", "c")
    assert user_force("-c*p1^3", 1, ("c",), 0).p_dependence == "nonlinear"
    two = user_force(["u1 - c*p1", "-c*p2 + u2"], 2, ("c",), 2)
    value = two(jnp.array([0.0, 0.0]), jnp.array([1.0, 2.0]), jnp.array([3.0, 4.0]), 0.0,
                jnp.array([0.5]))
    np.testing.assert_allclose(np.asarray(value), [2.5, 3.0])


@pytest.mark.parametrize("texts,dim,inputs,match", [
    ("b*u2", 1, 1, "unknown symbol 'u2'"),
    ("b*x", 1, 1, "unknown symbol 'x'"),
    (["u1", "u1"], 1, 1, "2 expression"),
    ("b*q2", 1, 1, "coordinate 2"),
])
def test_force_errors_are_one_line(texts, dim, inputs, match):
    with pytest.raises(UserModelError, match=match) as err:
        user_force(texts, dim, ("b",), inputs)
    assert "\n" not in str(err.value)


def test_no_forced_form_for_tao():
    with pytest.raises(ValueError, match="no forced form"):
        with_force("tao")
