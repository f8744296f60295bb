"""Sharp edges of the defaults: each case was an error, a traceback or wrong advice before.

A learned initial state with data from t = 0, expression errors that name their real cause,
advice that names only what the model accepts, one prior syntax in every table, and a report
that describes a user's model as written.
"""

from __future__ import annotations

import numpy as np
import pytest

from csv_data import harmonic, write_csv
from symplid.io import read_observations
from symplid.workflow._settings import Settings, merge_overrides, resolve_for_data


# ----------------------------------------------------------------------------- t0 at the data
def test_learned_initial_state_with_data_from_t0_just_works(tmp_path):
    """The defaults (t0 = 0) with data whose first time is 0: the state sits at the first
    observation, and the posterior's density is finite there."""
    from symplid.workflow._building import build_model, build_posterior

    t = np.arange(0.0, 12.0)
    obs = read_observations(write_csv(tmp_path / "h.csv", t, harmonic(t)))
    learned = merge_overrides(Settings(), {"initial_state.mode": "learned", "model.order": 2,
                                           "model.dt": 0.25})
    resolved = resolve_for_data(learned, obs)
    assert resolved.initial_state.t0 == "first"
    posterior = build_posterior(resolved, obs, build_model(resolved, obs))
    assert posterior.t0 == [None]
    truth = {"c[q1^2]": 0.5, "process_var": 1e-4, "obs_var[q]": 4e-4, "obs_var[p]": 4e-4,
             "x0[0].q1": 1.0, "x0[0].p1": 0.0}
    theta = np.array([truth.get(n, 0.0) for n in posterior.param_names])
    assert np.isfinite(float(posterior.log_density(theta)))


def test_a_t0_before_the_data_is_kept_and_one_after_is_refused(tmp_path):
    t = np.arange(1.0, 12.0)
    obs = read_observations(write_csv(tmp_path / "h.csv", t, harmonic(t)))
    learned = merge_overrides(Settings(), {"initial_state.mode": "learned", "model.order": 2})
    assert resolve_for_data(learned, obs).initial_state.t0 == 0.0
    late = merge_overrides(learned, {"initial_state.t0": 2.0})
    with pytest.raises(ValueError, match="must be before the first observation time"):
        resolve_for_data(late, obs)


# ----------------------------------------------------------------------------- advice
NONSEPARABLE = "0.5*(1 + a*q1^2)*p1^2 + 0.5*q1^2"


def _resolved(tmp_path, overrides):
    from symplid.workflow._settings import settings_from_dict

    t = np.arange(0.0, 12.0)
    obs = read_observations(write_csv(tmp_path / "h.csv", t, harmonic(t)))
    return resolve_for_data(merge_overrides(settings_from_dict({
        "initial_state": {"mode": "learned"},
        "model": {"parameters": {"a": {"prior": "normal", "loc": 0.0, "scale": 1.0}}}
        if "model.hamiltonian" in overrides else {}}), {"model.dt": 0.25, **overrides}), obs), obs


@pytest.mark.parametrize(("overrides", "advice"), [
    ({"model.order": 2}, "use a smaller dt or yoshida4"),
    ({"model.order": 2, "model.damping": True}, "use a smaller dt or yoshida4"),
    ({"model.order": 2, "model.integrator": "yoshida4"}, "use a smaller dt"),
    ({"model.hamiltonian": NONSEPARABLE}, "use a smaller dt or tao4"),
    ({"model.hamiltonian": NONSEPARABLE, "model.integrator": "tao4"}, "use a smaller dt"),
])
def test_step_advice_names_only_what_the_model_accepts(tmp_path, overrides, advice):
    """The step-size warning's advice, and the model built with the integrator it names."""
    import dataclasses

    from symplid.workflow._building import build_model
    from symplid.workflow._sensitivity import sensitivity_lines, sensitivity_summary, step_advice

    settings, obs = _resolved(tmp_path, overrides)
    assert step_advice(settings, obs) == advice
    named = advice.rpartition(" or ")[2]
    if " or " in advice:
        build_model(dataclasses.replace(settings, model=dataclasses.replace(
            settings.model, integrator=named)), obs)
    step = {"dt": 0.25, "dt_refit": 0.125, "shifts": {"a": 1.0}, "flagged": ["a"],
            "advice": advice}
    noise = {"not_available": "skipped"}
    text = "\n".join([*sensitivity_lines({"threshold_sd": 0.3, "step_size": step,
                                          "process_noise": noise}),
                      *sensitivity_summary({"threshold_sd": 0.3, "step_size": step,
                                            "process_noise": noise})])
    assert text.count(advice) == 2
    if "yoshida4" not in advice:
        assert "yoshida4" not in text
    # a step the user set: the step chosen from the data is offered; a chosen one: not again
    assert text.count('model.dt = "auto"') == 2
    chosen = sensitivity_lines({"threshold_sd": 0.3, "step_size": {**step, "auto": True},
                                "process_noise": noise})
    assert advice in "\n".join(chosen) and '"auto"' not in "\n".join(chosen)


# ----------------------------------------------------------------------------- expressions
def _refusal(text: str, names=("k",), dim: int = 1, kind: str = "potential", **kwargs) -> str:
    from symplid.dynamics._user_models import UserModelError, build_user_model

    with pytest.raises(UserModelError) as info:
        build_user_model(text, kind, dim, list(names), **kwargs)
    message = str(info.value)
    assert "\n" not in message
    return message


@pytest.mark.parametrize(("text", "words"), [
    ("k*q1^2/(q1 - q1)", ["division by zero in 1/(q1 - q1)", "(q1 - q1 is 0)"]),
    ("k*q1^2 + 1/0", ["division by zero in 1/0"]),
    ("k*q1^2 + 0/0", ["division by zero"]),
    ("k*q1^2 + log(0)", ["log(0) is infinite"]),
    ("k*q1^2 + sqrt(-1)", ["not real", "sqrt(-1)"]),
    ("k*q1^2 + atan2(0, 0)", ["undefined value"]),
    ("k*q1^2 \u2212 q1", ["U+2212 MINUS SIGN", "character 8", "looks like '-'"]),
    ("k*q1^2 + \uff4b*q1", ["U+FF4B FULLWIDTH LATIN SMALL LETTER K", "looks like 'k'"]),
    ("k*q1\u00b2", ["looks like '^2'"]),
    ("k*q1^2 + 2\u00d7q1", ["looks like '*'"]),
    ("k*q1^2 + \u2603", ["U+2603", "is not allowed"]),
])
def test_expression_errors_name_the_real_cause(text, words):
    message = _refusal(text)
    for word in words:
        assert word in message, message
    assert "do not appear" not in message and "' ' is not allowed" not in message


def test_a_greek_parameter_name_is_still_a_name():
    import jax.numpy as jnp

    from symplid.dynamics._user_models import build_user_model

    pot = build_user_model("\u03b1*q1^2", "potential", 1, ["\u03b1"])
    assert float(pot.value(jnp.array([0.5]), jnp.array([2.0]))) == pytest.approx(0.5)


def test_a_lookalike_parameter_name_is_refused():
    from symplid.workflow._settings import settings_from_dict
    from symplid.workflow._validate import SettingsError

    with pytest.raises(SettingsError, match="read as 'k'"):
        settings_from_dict({"model": {"potential": "k*q1^2", "parameters": {
            "\uff4b": {"prior": "normal", "loc": 0, "scale": 1}}}})


def test_a_huge_expression_is_refused_in_one_short_line():
    """10,000 terms: refused by the size limit, quoting no more than ~200 characters; with the
    limit raised, the parser's own failure is quoted as briefly."""
    huge = " + ".join(["k*q1^2", *(f"{i}*q1^{i}" for i in range(2, 10_001))])
    assert len(huge) > 100_000
    message = _refusal(huge)
    assert "model.max_expression_size" in message and "limit of 1,000" in message
    assert len(message) < 500 and "characters" not in message
    bad = huge + " + x"
    for kwargs in ({}, {"max_size": 10**6}):
        message = _refusal(bad, **kwargs)
        assert len(message) < 500, message[:600]


def test_the_size_limit_is_a_setting(tmp_path):
    from symplid.workflow._settings import settings_from_dict
    from symplid.workflow._validate import SettingsError

    t = np.arange(0.0, 12.0)
    obs = read_observations(write_csv(tmp_path / "h.csv", t, harmonic(t)))
    small = settings_from_dict({"initial_state": {"mode": "learned"}, "model": {
        "potential": "k*q1^2 + k*q1^3 + k*q1^4",
        "parameters": {"k": {"prior": "normal", "loc": 0.0, "scale": 1.0}}}})
    resolve_for_data(small, obs)  # 17 tokens, under the default
    tight = merge_overrides(small, {"model.max_expression_size": 10})
    with pytest.raises(SettingsError, match="17 tokens, more than the limit of 10"):
        resolve_for_data(tight, obs)


CSE_MODELS = [
    ("-GM/sqrt(q1^2 + q2^2)", "potential", 2, ("GM",)),
    ("beta*exp(q1) - alpha*q1 + delta*exp(p1) - gamma*p1", "hamiltonian", 1,
     ("alpha", "beta", "gamma", "delta")),
    ("0.5*(1 + a*q1^2)*p1^2 + 0.5*q1^2", "hamiltonian", 1, ("a",)),
    ("k*(1 - cos(q1))", "potential", 1, ("k",)),
    ("k*exp(-(q1^2 + q2^2))*(q1^2 + q2^2) + sqrt(q1^2 + q2^2)*(q1^2 + q2^2)^2 "
     "+ c*(q1*p2 - q2*p1)^2 + 0.5*(p1^2 + p2^2)", "hamiltonian", 2, ("k", "c")),
]


@pytest.mark.parametrize(("text", "kind", "dim", "names"), CSE_MODELS)
def test_common_subexpressions_keep_value_and_gradient(text, kind, dim, names):
    """The code generated after SymPy's common subexpression elimination against SymPy's
    plain code generation of the same expression: values and gradients to 1e-12."""
    import jax
    import jax.numpy as jnp
    import sympy

    from symplid.dynamics._hamiltonians import is_hamiltonian
    from symplid.dynamics._user_models import build_user_model, parse_expression

    model = build_user_model(text, kind, dim, list(names))
    expr = parse_expression(text, list(names), require_all=True).expr
    qs = [sympy.Symbol(f"q{i + 1}", real=True) for i in range(dim)]
    ps = [sympy.Symbol(f"p{i + 1}", real=True) for i in range(dim)]
    cs = [sympy.Symbol(n, real=True) for n in names]
    plain = sympy.lambdify([*qs, *ps, *cs], expr, modules="jax")

    def reference(q, p, c):
        return plain(*q, *p, *c)

    def ours(q, p, c):
        if is_hamiltonian(model):
            return model.value(q, p, c)
        if kind == "hamiltonian":  # split into T(p) + U(q)
            return model.value(q, c) + model.kinetic(p, c)
        return model.value(q, c) + 0.0 * jnp.sum(p)

    rng = np.random.default_rng(3)
    for _ in range(3):
        q, p = jnp.asarray(rng.uniform(0.3, 1.2, dim)), jnp.asarray(rng.uniform(-1, 1, dim))
        c = jnp.asarray(rng.uniform(0.2, 1.5, len(names)))
        np.testing.assert_allclose(ours(q, p, c), reference(q, p, c), rtol=1e-12, atol=0)
        for arg in range(3 if kind == "hamiltonian" else 1):
            if arg == 1 and kind == "potential":
                continue
            got = jax.grad(ours, argnums=arg)(q, p, c)
            want = jax.grad(reference, argnums=arg)(q, p, c)
            np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize(("potential", "words"), [
    ("k*q1^2/(q1 - q1)", "division by zero in 1/(q1 - q1)"),
    ("k*q1^2 \u2212 q1", "U+2212 MINUS SIGN"),
])
def test_the_command_line_says_it_in_one_line_with_exit_2(tmp_path, potential, words):
    from click.testing import CliRunner

    from symplid.cli import main

    t = np.arange(0.0, 12.0)
    data = write_csv(tmp_path / "h.csv", t, harmonic(t))
    config = tmp_path / "m.toml"
    config.write_text('[model]\npotential = "k*q1^2"\n[model.parameters]\n'
                      'k = { prior = "half-normal", scale = 2 }\n'
                      '[initial_state]\nmode = "learned"\n', encoding="utf-8")
    result = CliRunner().invoke(main, ["fit", str(data), "--config", str(config), "--potential",
                                       potential, "--out", str(tmp_path / "r"), "--no-progress"],
                                catch_exceptions=False)
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("symplid: error:"), result.output
    assert words in lines[0]


# ----------------------------------------------------------------------------- prior syntax
def test_every_prior_table_takes_prior(tmp_path):
    """``[priors.GROUP]`` takes ``prior = ...`` as ``[model.parameters]`` does (a family with
    its keys, or text), is written that way, and reads back equal."""
    import tomllib

    from symplid.model._priors import HalfNormal, Laplace, Normal
    from symplid.workflow._settings import dump_settings, load_settings, settings_from_dict

    table = {"prior": "half-normal", "scale": 0.5}
    s = settings_from_dict({
        "priors": {"variances": table, "coefficients": {"prior": "laplace(0, 2)"}},
        "model": {"potential": "k*q1^2", "parameters": {"k": table}}})
    assert s.priors.variances == HalfNormal(0.5) and s.priors.coefficients == Laplace(0.0, 2.0)
    assert s.model.parameters[0].prior == HalfNormal(0.5)
    written = tomllib.loads(dump_settings(s, tmp_path / "s.toml").read_text())
    assert written["priors"]["variances"] == {"prior": "half-normal", "scale": 0.5}
    assert not any("family" in group for group in written["priors"].values()
                   if isinstance(group, dict))
    assert load_settings(tmp_path / "s.toml") == s
    assert merge_overrides(s, {"priors.initial_state.prior": "normal(0, 3)"}
                           ).priors.initial_state == Normal(0.0, 3.0)


def test_the_old_family_key_is_read_with_one_deprecation_line(tmp_path):
    from symplid.model._priors import HalfNormal, Normal
    from symplid.workflow._commandline import _merged_file
    from symplid.workflow._settings import settings_from_dict
    from symplid.workflow._validate import SettingsError

    with pytest.warns(FutureWarning, match=r"priors\.variances\.family is deprecated; use "
                                           r"priors\.variances\.prior"):
        s = settings_from_dict({"priors": {"variances": {"family": "half-normal",
                                                         "scale": 0.5}}})
    assert s.priors.variances == HalfNormal(0.5)
    with pytest.warns(FutureWarning, match=r"model\.parameters\.k\.family is deprecated"):
        s = settings_from_dict({"model": {"potential": "k*q1^2", "parameters": {
            "k": {"family": "normal", "loc": 1.0, "scale": 2.0}}}})
    assert s.model.parameters[0].prior == Normal(1.0, 2.0)
    with pytest.warns(FutureWarning, match=r"priors\.coefficients\.family is deprecated"):
        s = merge_overrides(Settings(), {"priors.coefficients.family": "normal"})
    assert s.priors.coefficients == Normal(0.0, 1.0)
    config = tmp_path / "old.toml"
    config.write_text('[priors.variances]\nfamily = "half-normal"\nscale = 0.25\n')
    with pytest.warns(FutureWarning, match="family is deprecated"):
        assert _merged_file(Settings(), config).priors.variances == HalfNormal(0.25)
    with pytest.raises(SettingsError, match=r"same setting; give only priors\.variances\.prior"):
        settings_from_dict({"priors": {"variances": {"family": "normal", "prior": "normal"}}})


# ----------------------------------------------------------------------------- the report
def test_model_description_says_what_was_written():
    from symplid.workflow._model_builder import model_description
    from symplid.workflow._settings import settings_from_dict

    def described(model):
        return model_description(settings_from_dict({"model": model,
                                                     "sampler": {"method": "nuts"}}).model)

    k = {"k": {"prior": "half-normal", "scale": 2.0}}
    assert described({"potential": "k*(1 - cos(q1))", "parameters": k}) == \
        "U(q) = k*(1 - cos(q1)) (parameters: k)"
    assert described({"hamiltonian": NONSEPARABLE, "parameters": {
        "a": {"prior": "normal", "loc": 0.0, "scale": 1.0}}}) == \
        f"H(q, p) = {NONSEPARABLE} (parameters: a)"
    assert described({"potential": "k*(1 - cos(q1))", "kinetic": "k*sqrt(1 + p1^2)",
                      "parameters": k}).endswith(", T(p) = k*sqrt(1 + p1^2) (parameters: k)")
    assert described({"order": 4}) == "polynomial U(q) of order 4"
    assert described({"order": 2, "damping": True}) == "polynomial U(q) of order 2, damped"
    assert "polynomial" not in described({"potential": "mlp"})
    huge = " + ".join(f"{i}*k*q1^{i}" for i in range(1, 500))
    text = described({"potential": huge, "parameters": k})
    assert len(text) < 300 and "characters)" in text


@pytest.mark.slow
def test_report_and_summary_describe_a_user_model_as_written(tmp_path):
    """A fit of a user's pendulum with the defaults (a learned initial state, data from
    t = 0): the report's header, summary.txt and the potential figure's title give the
    expression and its parameter, not a polynomial order."""
    from click.testing import CliRunner

    from symplid.cli import main

    t = np.arange(0.0, 12.0)
    data = write_csv(tmp_path / "h.csv", t, harmonic(t))
    config = tmp_path / "m.toml"
    config.write_text('[model]\npotential = "k*(1 - cos(q1))"\n[model.parameters]\n'
                      'k = { prior = "half-normal", scale = 2 }\n'
                      '[initial_state]\nmode = "learned"\n', encoding="utf-8")
    out = tmp_path / "run"
    result = CliRunner().invoke(main, [
        "fit", str(data), "--config", str(config), "--out", str(out), "--iterations", "400",
        "--dt", "0.25", "--burn-in", "200", "--chains", "2", "--no-progress",
        "--set", "map.sensitivity=false",
        "--set", "sampler.chunk_size=100"], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    written = "U(q) = k*(1 - cos(q1)) (parameters: k)"
    report = (out / "report.md").read_text(encoding="utf-8")
    assert "polynomial" not in report and "order 3" not in report
    assert written in report.splitlines()[2]  # the header
    assert f"![Potential U(q): {written}]" in report
    summary = (out / "summary.txt").read_text(encoding="utf-8")
    assert summary.splitlines()[0].split(None, 1) == ["model", written]


def test_a_run_written_with_family_keys_reads_without_a_warning(tmp_path):
    """A run folder's own settings.toml from before: the library wrote it, so no
    deprecation line when report or predict read it."""
    import warnings

    from symplid.model._priors import HalfNormal
    from symplid.workflow._results import RunFolder
    from symplid.workflow._settings import dump_settings

    run = tmp_path / "run"
    run.mkdir()
    path = dump_settings(Settings(), run / "settings.toml")
    path.write_text(path.read_text().replace('prior = "', 'family = "'))
    assert 'family = "half-normal"' in path.read_text()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        settings = RunFolder(run, "r").read_settings()
    assert settings.priors.variances == HalfNormal(1.0)
