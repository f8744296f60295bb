"""Potentials: basis order and size, term names, gradients, the named systems' coefficients."""

from __future__ import annotations

import math
from fractions import Fraction

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import symplid
from symplid.dynamics._potentials import monomial_exponents


def test_basis_order_d2_l3_matches_design():
    pot = symplid.Polynomial(dim=2, order=3)
    assert pot.param_names == (
        "q1", "q2", "q1^2", "q1*q2", "q2^2", "q1^3", "q1^2*q2", "q1*q2^2", "q2^3",
    )
    assert pot.exponents == (
        (1, 0), (0, 1), (2, 0), (1, 1), (0, 2), (3, 0), (2, 1), (1, 2), (0, 3),
    )


@pytest.mark.parametrize(
    ("dim", "order"), [(1, 1), (1, 4), (2, 1), (2, 3), (3, 2), (3, 4), (4, 3), (5, 2)]
)
def test_num_params_is_binomial(dim, order):
    pot = symplid.Polynomial(dim=dim, order=order)
    assert pot.num_params == math.comb(dim + order, order) - 1
    # Every monomial of degree 1..order appears exactly once, sorted by degree.
    degrees = [sum(e) for e in pot.exponents]
    assert degrees == sorted(degrees)
    assert len(set(pot.exponents)) == pot.num_params
    assert min(degrees) == 1 and max(degrees) == order


def test_within_degree_order_is_first_coordinate_highest():
    for e_list in (monomial_exponents(3, 3), monomial_exponents(4, 2)):
        for deg in range(1, 4):
            block = [e for e in e_list if sum(e) == deg]
            assert block == sorted(block, reverse=True)


def test_term_names_d3():
    pot = symplid.Polynomial(dim=3, order=3)
    names = pot.param_names
    assert names[:3] == ("q1", "q2", "q3")
    assert names[3:9] == ("q1^2", "q1*q2", "q1*q3", "q2^2", "q2*q3", "q3^2")
    assert "q1*q2*q3" in names and names[-1] == "q3^3"
    assert names.index("q1^2*q2") < names.index("q1*q2*q3") < names.index("q2^3")


@pytest.mark.parametrize(("dim", "order"), [(1, 1), (1, 5), (2, 3), (2, 4), (3, 3)])
def test_value_matches_monomial_sum(dim, order):
    pot = symplid.Polynomial(dim=dim, order=order)
    rng = np.random.default_rng(dim * 10 + order)
    c = rng.normal(size=pot.num_params)
    q = rng.normal(size=dim)
    expected = sum(cm * np.prod(q ** np.array(e)) for cm, e in zip(c, pot.exponents, strict=True))
    assert float(pot.value(jnp.asarray(q), jnp.asarray(c))) == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize(("dim", "order"), [(1, 1), (1, 4), (2, 2), (2, 3), (3, 3), (3, 4)])
def test_gradient_matches_autodiff_of_value(dim, order):
    pot = symplid.Polynomial(dim=dim, order=order)
    rng = np.random.default_rng(100 + dim * 10 + order)
    grad_of_value = jax.grad(pot.value)
    for _ in range(3):
        c = jnp.asarray(rng.normal(size=pot.num_params))
        q = jnp.asarray(rng.normal(size=dim))
        np.testing.assert_allclose(
            pot.gradient(q, c), grad_of_value(q, c), rtol=1e-12, atol=1e-12
        )


def test_function_potential_gradient_matches_analytic():
    def u(q, c):
        return c[0] * jnp.cosh(q[0]) + c[1] * q[0] * q[1] ** 2 + c[2] * jnp.sin(q[1])

    pot = symplid.FunctionPotential(u, dim=2, num_params=3, names=("cosh", "q1q2^2", "sin"))
    assert pot.param_names == ("cosh", "q1q2^2", "sin")
    c = np.array([0.7, -1.3, 0.4])
    rng = np.random.default_rng(5)
    for _ in range(4):
        q = rng.normal(size=2)
        analytic = np.array(
            [
                c[0] * np.sinh(q[0]) + c[1] * q[1] ** 2,
                2 * c[1] * q[0] * q[1] + c[2] * np.cos(q[1]),
            ]
        )
        np.testing.assert_allclose(pot.gradient(q, c), analytic, rtol=1e-12)
        assert float(pot.value(q, c)) == pytest.approx(float(u(q, c)), rel=1e-14)


def test_function_potential_validation():
    with pytest.raises(ValueError, match="names"):
        symplid.FunctionPotential(lambda q, c: c[0] * q[0], dim=1, num_params=1, names=("a", "b"))
    with pytest.raises(TypeError, match="callable"):
        symplid.FunctionPotential("not a function", dim=1, num_params=1)  # type: ignore[arg-type]


def test_henon_heiles_energy_at_initial_state(hh):
    # H = ½(0.3² + 0.25²) + ½·0.2² + ½·0.25² + 0.2²·(−0.25) − ⅓(−0.25)³, in exact arithmetic.
    q1, q2, p1, p2 = (Fraction(1, 5), Fraction(-1, 4), Fraction(3, 10), Fraction(-1, 4))
    exact = (p1**2 + p2**2) / 2 + (q1**2 + q2**2) / 2 + q1**2 * q2 - q2**3 / 3
    assert float(exact) == pytest.approx(0.12270833333, abs=1e-11)
    h = symplid.hamiltonian(hh.potential, hh.coefficients, hh.initial_state)
    assert float(h) == pytest.approx(float(exact), rel=1e-14)
    # The design's coefficient vector in the library's convention.
    np.testing.assert_array_equal(hh.coefficients, [0, 0, 0.5, 0, 0.5, 0, 1, 0, -1 / 3])


def test_hamiltonian_with_mass_and_batch():
    pot = symplid.Polynomial(2, 2)
    c = pot.coefficients_from({"q1^2": 1.0, "q2^2": 2.0})
    mass = np.array([[2.0, 0.5], [0.5, 1.0]])
    rng = np.random.default_rng(3)
    states = rng.normal(size=(5, 4))
    h = symplid.hamiltonian(pot, c, states, inv_mass=np.linalg.inv(mass))
    q, p = states[:, :2], states[:, 2:]
    kinetic = 0.5 * np.einsum("ki,ij,kj->k", p, np.linalg.inv(mass), p)
    expected = kinetic + q[:, 0] ** 2 + 2 * q[:, 1] ** 2
    np.testing.assert_allclose(h, expected, rtol=1e-13)


def test_coefficients_from_names_and_exponents():
    pot = symplid.Polynomial(2, 3)
    by_name = pot.coefficients_from({"q1^2*q2": 1.5, "q2": -2.0})
    by_exp = pot.coefficients_from({(2, 1): 1.5, (0, 1): -2.0})
    np.testing.assert_array_equal(by_name, by_exp)
    assert by_name[6] == 1.5 and by_name[1] == -2.0 and np.count_nonzero(by_name) == 2


def test_coefficients_from_errors():
    pot = symplid.Polynomial(2, 3)
    with pytest.raises(ValueError, match=r"unknown term 'q3'"):
        pot.coefficients_from({"q3": 1.0})
    with pytest.raises(ValueError, match=r"unknown term 'q2\^4'"):
        pot.coefficients_from({"q2^4": 1.0})
    with pytest.raises(ValueError, match=r"not in the basis"):
        pot.coefficients_from({(0, 4): 1.0})
    with pytest.raises(ValueError, match=r"not in the basis"):
        pot.coefficients_from({(0, 0): 1.0})  # the constant is not part of the basis


def test_polynomial_argument_errors():
    with pytest.raises(ValueError, match="dim"):
        symplid.Polynomial(0, 3)
    with pytest.raises(ValueError, match="order"):
        symplid.Polynomial(2, 0)
    pot = symplid.Polynomial(2, 3)
    with pytest.raises(ValueError, match="expected 9 coefficients"):
        pot.value(jnp.zeros(2), jnp.zeros(8))
    with pytest.raises(ValueError, match="dim=2"):
        pot.gradient(jnp.zeros(3), jnp.zeros(9))


def _random_points(dim, n, seed):
    return np.random.default_rng(seed).uniform(-1.5, 1.5, size=(n, dim))


def test_double_well_coefficients_match_formula():
    system = symplid.get_system("double-well")
    for q in _random_points(1, 20, 11):
        formula = -0.5 * q[0] ** 2 + 0.25 * q[0] ** 4
        value = float(system.potential.value(jnp.asarray(q), system.coefficients))
        assert value == pytest.approx(formula, rel=1e-12, abs=1e-14)


def test_fpu_chain_coefficients_match_formula():
    system = symplid.get_system("fpu-chain")
    n = system.dim
    alpha = 0.25
    for q in _random_points(n, 20, 12):
        ext = np.concatenate([[0.0], q, [0.0]])  # fixed ends q_0 = q_{n+1} = 0
        diff = np.diff(ext)
        formula = np.sum(0.5 * diff**2 + alpha / 3.0 * diff**3)
        value = float(system.potential.value(jnp.asarray(q), system.coefficients))
        assert value == pytest.approx(formula, rel=1e-12, abs=1e-14)


def test_harmonic_and_henon_heiles_match_formula():
    harmonic = symplid.get_system("harmonic")
    hh = symplid.get_system("henon-heiles")
    for q in _random_points(2, 20, 13):
        hh_formula = 0.5 * q[0] ** 2 + 0.5 * q[1] ** 2 + q[0] ** 2 * q[1] - q[1] ** 3 / 3
        assert float(hh.potential.value(jnp.asarray(q), hh.coefficients)) == pytest.approx(
            hh_formula, rel=1e-12, abs=1e-14
        )
        assert float(
            harmonic.potential.value(jnp.asarray(q[:1]), harmonic.coefficients)
        ) == pytest.approx(0.5 * q[0] ** 2, rel=1e-14)


def test_get_system_unknown_name():
    with pytest.raises(ValueError, match="unknown system 'kepler'"):
        symplid.get_system("kepler")
