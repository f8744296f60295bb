"""Run settings: the paper's defaults, TOML round trips, overrides, and every error message."""

from __future__ import annotations

import dataclasses
import math
import tomllib
import warnings

import numpy as np
import pytest

import symplid
from symplid.model._priors import HalfNormal, Laplace, Normal, Uniform
from symplid.workflow._settings import (
    Settings,
    SettingsError,
    dump_settings,
    load_settings,
    merge_overrides,
    parse_override,
    resolve_for_data,
    settings_from_dict,
    settings_to_dict,
)


def _load_text(tmp_path, text: str, name: str = "run.toml") -> Settings:
    path = tmp_path / name
    path.write_text(text)
    return load_settings(path)


# ----------------------------------------------------------------------------- defaults
def test_defaults_are_the_papers_numbers():
    s = Settings()
    # Section IV of the paper: cubic potential, leapfrog, process noise once per gap. The
    # learning step, the noise layout and the standardisation default to "auto" (decided by
    # the data); the paper's experiment sets its dt = 0.25, one isotropic variance each for Σ
    # and Γ and no standardisation itself (see test_paper_settings_fix_the_auto_defaults).
    assert (s.model.order, s.model.integrator, s.model.dt) == (3, "leapfrog", "auto")
    assert (s.model.process_noise_per, s.model.noise, s.model.observation) == (
        "gap",
        "auto",
        "auto",
    )
    assert (s.model.observation_noise, s.model.standardise) == ("additive", "auto")
    assert (s.model.alpha, s.model.beta, s.model.kappa, s.model.jitter) == (1.0, 2.0, 0.0, 1e-12)
    assert s.model.mass == ()
    # Known initial state with covariance 1e-16 I at t0 = 0.
    assert (s.initial_state.mode, s.initial_state.p0_var, s.initial_state.t0) == (
        "known",
        1e-16,
        0.0,
    )
    # Laplace(0, b = 10) on the coefficients, half-normal(1) on the variances.
    assert s.priors.coefficients == Laplace(0.0, 10.0)
    assert s.priors.variances == HalfNormal(1.0)
    assert s.priors.initial_state.family == "normal"
    # DRAM until ESS ≥ 400 and R-hat ≤ 1.01, at most the paper's 200,000 iterations; γ =
    # 0.01, adaptation after 200. A fixed budget's burn-in is half of it (the paper's).
    assert (s.sampler.method, s.sampler.num_iterations, s.sampler.burn_in) == (
        "dram", "auto", "auto")
    assert (s.sampler.target_ess, s.sampler.target_rhat, s.sampler.max_iterations) == (
        400.0, 1.01, 200_000)
    assert s.sampler.num_draws is None and s.sampler.resolved_burn_in is None
    fixed = merge_overrides(s, {"sampler.num_iterations": 200_000})
    assert (fixed.sampler.resolved_burn_in, fixed.sampler.num_draws) == (100_000, 100_000)
    assert (s.sampler.gamma, s.sampler.adapt_start, s.sampler.num_chains) == (0.01, 200, 4)
    assert (s.sampler.thin, s.sampler.seed, s.seed) == (1, 0, 0)
    # Predictions with leapfrog at dt = 0.01 over 200 s, 100 posterior paths.
    assert (s.prediction.integrator, s.prediction.dt, s.prediction.t_end) == (
        "leapfrog",
        0.01,
        200.0,
    )
    assert s.prediction.num_paths == 100
    assert s.map.num_starts >= 1


def test_paper_settings_fix_the_auto_defaults(hh_data):
    """The paper's experiment (reproduce, its sweeps) does not depend on the "auto" rules."""
    from symplid.studies._paper import PaperConfig, paper_settings
    from symplid.studies._paper_cells import known_initial_state
    from symplid.workflow._settings import resolve_for_data
    from symplid.workflow._sweep_spec import cell_settings, sweep_spec_from_dict

    for approach in ("leapfrog", "rk2"):
        m = resolve_for_data(paper_settings(PaperConfig(), approach), hh_data).model
        assert (m.noise, m.standardise, m.observation_noise) == ("isotropic", "off", "additive")
        assert m.dt == 0.25  # the paper's step, where a user's fit chooses it ("auto")
    assert known_initial_state({})["model"] == {"noise": "isotropic", "standardise": "off"}
    cell = sweep_spec_from_dict({"base": {}, "sweep": {"grid": {"seed": [0]}}}).cells[0]
    assert cell.settings["dt"] == 0.25  # a paper sweep's cell too
    assert cell_settings(cell.settings).model.dt == 0.25
    # while a user's full-state file gets one variance per kind, positions-only one in all
    init = paper_settings(PaperConfig(), "leapfrog").initial_state
    default = resolve_for_data(Settings(initial_state=init), hh_data).model
    assert (default.noise, default.standardise) == ("per-kind", "off")
    positions = symplid.Observations(hh_data.times, hh_data.values[:, :2], ("q1", "q2"))
    assert resolve_for_data(Settings(initial_state=init), positions).model.noise == "isotropic"


def test_defaults_build_the_papers_model():
    """The defaults are accepted as they are by HamiltonianModel (no translation needed)."""
    m = Settings().model
    model = symplid.HamiltonianModel(
        symplid.Polynomial(dim=2, order=m.order),
        integrator=m.integrator,
        dt=0.25,  # the paper's (the default "auto" is chosen by the fit from the data)
        process_noise_per=m.process_noise_per,
        noise="isotropic",  # the paper's (the default "auto" is resolved from the data)
        observation_noise=m.observation_noise,
        alpha=m.alpha,
        beta=m.beta,
        kappa=m.kappa,
        jitter=m.jitter,
    )
    assert model.num_params == 11  # θ1..θ9, θ10 (process), θ11 (observation)


def test_empty_file_and_empty_dict_give_defaults(tmp_path):
    assert _load_text(tmp_path, "") == Settings()
    assert settings_from_dict({}) == Settings()


@pytest.mark.parametrize("name", sorted(symplid.INTEGRATORS))
def test_every_integrator_is_accepted(name):
    assert settings_from_dict({"model": {"integrator": name}}).model.integrator == name


def test_integrator_alias_is_resolved_to_its_name():
    s = settings_from_dict({"model": {"integrator": "RK2"}, "prediction": {"integrator": "verlet"}})
    assert s.model.integrator == "rk2-midpoint"
    assert s.prediction.integrator == "leapfrog"


# ----------------------------------------------------------------------------- round trips
def _custom() -> Settings:
    return settings_from_dict(
        {
            "seed": 11,
            "model": {"order": 4, "integrator": "rk2-heun", "dt": 0.1, "mass": [1, 2.5]},
            "initial_state": {"mode": "learned", "x0": [0.2, -0.25, 0.3, -0.25], "t0": -1},
            "priors": {
                "coefficients": {"prior": "normal", "loc": 0.5, "scale": 3.0},
                "variances": {"prior": "uniform", "low": 0.0, "high": 0.5},
                "initial_state": {"prior": "laplace", "scale": 0.3},
            },
            "sampler": {"method": "nuts", "num_iterations": 3000, "burn_in": 1000, "thin": 7},
            "prediction": {"dt": 1e-3, "t_end": 50, "num_paths": 0},
        }
    )


@pytest.mark.parametrize("make", [Settings, _custom])
def test_dump_then_load_is_equal(tmp_path, make):
    settings = make()
    path = dump_settings(settings, tmp_path / "sub" / "settings.toml")
    assert load_settings(path) == settings
    assert not list((tmp_path / "sub").glob(".*tmp"))


def test_dump_writes_every_key(tmp_path):
    path = dump_settings(Settings(), tmp_path / "settings.toml")
    written = tomllib.loads(path.read_text())

    def keys(table, prefix=""):
        out = set()
        for k, v in table.items():
            # an empty table (model.parameters of a named family) is written as its header
            out |= keys(v, f"{prefix}{k}.") if isinstance(v, dict) and v else {prefix + k}
        return out

    expected = {
        f"{section}.{f.name}"
        for section in ("model", "initial_state", "map", "sampler", "prediction", "plots",
                        "inputs")
        for f in dataclasses.fields(getattr(Settings(), section))
    }
    expected |= {"seed", "priors.coefficients.prior", "priors.coefficients.loc"}
    expected |= {"priors.coefficients.scale", "priors.variances.prior", "priors.variances.scale"}
    expected |= {"priors.initial_state.prior", "priors.initial_state.loc"}
    expected |= {"priors.initial_state.scale", "priors.damping.prior", "priors.damping.scale"}
    expected |= {"priors.process_var"}
    assert keys(written) == expected
    assert written["sampler"]["num_iterations"] == "auto"
    assert load_settings(path) == Settings()  # "auto" is read back as written


def test_custom_values_survive(tmp_path):
    s = _custom()
    assert s.model.mass == (1.0, 2.5) and s.initial_state.x0 == (0.2, -0.25, 0.3, -0.25)
    assert s.priors.variances == Uniform(0.0, 0.5)
    assert settings_to_dict(s)["priors"]["variances"] == {
        "prior": "uniform",
        "low": 0.0,
        "high": 0.5,
    }


def test_top_level_seed_seeds_the_sections(tmp_path):
    s = _load_text(tmp_path, "seed = 7\n[sampler]\nnum_chains = 2\n")
    assert (s.seed, s.map.seed, s.sampler.seed) == (7, 7, 7)
    s = _load_text(tmp_path, "seed = 7\n[sampler]\nseed = 3\n")
    assert (s.seed, s.map.seed, s.sampler.seed) == (7, 7, 3)


# ----------------------------------------------------------------------------- errors
MISSPELT = [
    ("[model]\nintergrator = 'rk4'\n", "unknown key 'model.intergrator'", "model.integrator"),
    (
        "[sampler]\nnum_iteration = 10\n",
        "unknown key 'sampler.num_iteration'",
        "sampler.num_iterations",
    ),
    ("[sampler]\nburnin = 10\n", "unknown key 'sampler.burnin'", "sampler.burn_in"),
    ("dt = 0.1\n", "unknown key 'dt'", "model.dt"),
    ("[modle]\ndt = 0.1\n", "unknown key 'modle'", "model"),
    (
        "[priors.coefficient]\nscale = 1\n",
        "unknown key 'priors.coefficient'",
        "priors.coefficients",
    ),
    ("[prediction]\ntend = 100\n", "unknown key 'prediction.tend'", "prediction.t_end"),
]


@pytest.mark.parametrize(("text", "what", "suggestion"), MISSPELT)
def test_misspelt_key_names_file_and_suggests(tmp_path, text, what, suggestion):
    with pytest.raises(SettingsError) as info:
        _load_text(tmp_path, text)
    message = str(info.value)
    assert message.startswith(str(tmp_path / "run.toml") + ": ")
    assert what in message
    assert message.endswith(f"; did you mean '{suggestion}'?")
    assert "\n" not in message


BAD_VALUES = [
    ("[model]\ndt = 0\n", "model.dt", "must be > 0"),
    ("[model]\ndt = -0.25\n", "model.dt", "must be > 0"),
    ("[model]\ndt = nan\n", "model.dt", "finite"),
    ("[model]\ndt = 'fast'\n", "model.dt", "must be a number"),
    ("[model]\norder = 0\n", "model.order", "≥ 1"),
    ("[model]\norder = 2.5\n", "model.order", "must be an integer"),
    ("[model]\nintegrator = 'leapfrg'\n", "model.integrator", "did you mean 'leapfrog'"),
    ("[model]\nintegrator = 'magic'\n", "model.integrator", "not a known integrator"),
    ("[model]\nnoise = 'diag'\n", "model.noise", "did you mean 'diagonal'"),
    ("[model]\nobservation = 'velocities'\n", "model.observation", "'auto', 'full'"),
    ("[model]\nmass = [1, -2]\n", "model.mass", "positive"),
    ("[model]\nmass = 'heavy'\n", "model.mass", "list of numbers"),
    ("model = 3\n", "model", "must be a table"),
    ("[initial_state]\nmode = 'guess'\n", "initial_state.mode", "'known', 'learned'"),
    ("[initial_state]\nx0 = [1, 2, 3]\n", "initial_state.x0", "full state"),
    ("[initial_state]\np0_var = -1e-16\n", "initial_state.p0_var", "≥ 0"),
    ("[priors.coefficients]\nscale = -10\n", "priors.coefficients.scale", "must be > 0"),
    ("[priors.variances]\nprior = 'half-normal'\nscale = 0\n", "priors.variances.scale", "> 0"),
    ("[priors.variances]\nprior = 'normal'\n", "priors.variances.prior", "positive support"),
    ("[priors.coefficients]\nprior = 'cauchy'\n", "priors.coefficients.prior", "one of"),
    ("[priors.coefficients]\nprior='laplace'\nhigh = 1\n", "priors.coefficients.high", "not used"),
    ("[priors.variances]\nprior='uniform'\nlow=2\nhigh=1\n", "priors.variances.low", "less than"),
    ("[priors.initial_state]\nprior='half-normal'\n", "priors.initial_state.prior", "any real"),
    (
        "[sampler]\nnum_iterations = 1000\nburn_in = 1000\n",
        "sampler.num_iterations",
        "greater than sampler.burn_in",
    ),
    ("[sampler]\nnum_iterations = 'many'\n", "sampler.num_iterations", "number or 'auto'"),
    (
        "[sampler]\nburn_in = 300000\n",
        "sampler.max_iterations",
        "greater than sampler.burn_in",
    ),
    ("[sampler]\nnum_iterations = 10\nburn_in = 10\n", "sampler.num_iterations", "greater than"),
    ("[sampler]\nnum_chains = true\n", "sampler.num_chains", "must be an integer"),
    ("[sampler]\nnum_chains = 0\n", "sampler.num_chains", "≥ 1"),
    ("[sampler]\ngamma = 0\n", "sampler.gamma", "> 0"),
    ("[sampler]\nmethod = 'gibbs'\n", "sampler.method", "'dram', 'nuts'"),
    ("[sampler]\nnum_iterations=20\nburn_in=10\nthin=11\n", "sampler.thin", "larger than the 10"),
    ("[prediction]\ndt = 0\n", "prediction.dt", "> 0"),
    ("[prediction]\nt_end = 0\n", "prediction.t_end", "after initial_state.t0"),
    ("[prediction]\nnum_paths = -1\n", "prediction.num_paths", "≥ 0"),
    ("[map]\nnum_starts = 0\n", "map.num_starts", "≥ 1"),
    ("seed = -1\n", "seed", "≥ 0"),
    ("seed = 1.5\n", "seed", "must be an integer"),
]


@pytest.mark.parametrize(("text", "key", "words"), BAD_VALUES)
def test_bad_value_names_file_and_key(tmp_path, text, key, words):
    with pytest.raises(SettingsError) as info:
        _load_text(tmp_path, text)
    err = info.value
    assert isinstance(err, ValueError)
    assert str(err).startswith(f"{tmp_path / 'run.toml'}: {key} ")
    assert err.key == key and err.source == str(tmp_path / "run.toml")
    assert words in str(err)
    assert "\n" not in str(err)


def test_unreadable_files(tmp_path):
    with pytest.raises(SettingsError, match="no such settings file"):
        load_settings(tmp_path / "missing.toml")
    with pytest.raises(SettingsError, match="not valid TOML"):
        _load_text(tmp_path, "[model\ndt = 0.1\n")
    with pytest.raises(SettingsError, match="is a directory"):
        load_settings(tmp_path)


# ----------------------------------------------------------------------------- overrides
def test_merge_overrides_sets_dotted_keys():
    s = merge_overrides(Settings(), {"model.dt": 0.1, "model.integrator": "rk2", "sampler.thin": 5})
    assert (s.model.dt, s.model.integrator, s.sampler.thin) == (0.1, "rk2-midpoint", 5)
    assert dataclasses.replace(s, model=Settings().model, sampler=Settings().sampler) == Settings()


def test_merge_overrides_skips_none_and_reseeds():
    s = merge_overrides(Settings(), {"seed": 9, "model.dt": None})
    assert (s.seed, s.map.seed, s.sampler.seed, s.model.dt) == (9, 9, 9, "auto")
    s = merge_overrides(Settings(), {"seed": 9, "sampler.seed": 2})
    assert (s.map.seed, s.sampler.seed) == (9, 2)


def test_merge_overrides_prior_family_change():
    s = merge_overrides(Settings(), {"priors.coefficients.prior": "normal"})
    assert s.priors.coefficients == Normal(0.0, 1.0)
    s = merge_overrides(
        Settings(), {"priors.variances.prior": "uniform", "priors.variances.high": 2.0}
    )
    assert s.priors.variances == Uniform(0.0, 2.0)


@pytest.mark.parametrize(
    ("overrides", "words"),
    [
        ({"model.intergrator": "rk4"}, "did you mean 'model.integrator'"),
        ({"dt": 0.1}, "did you mean 'model.dt'"),
        ({"model": 1}, "is a section"),
        ({"model.dt": -1.0}, "model.dt must be > 0"),
        ({"model.integrator": "rk3"}, "not a known integrator"),
        ({"sampler.num_iterations": 50, "sampler.burn_in": 60}, "greater than sampler.burn_in"),
    ],
)
def test_merge_overrides_errors_name_the_command_line(overrides, words):
    with pytest.raises(SettingsError) as info:
        merge_overrides(Settings(), overrides)
    assert str(info.value).startswith("command line: ")
    assert words in str(info.value)


def test_parse_override():
    assert parse_override("model.dt=0.1") == ("model.dt", 0.1)
    assert parse_override("sampler.num_chains = 2") == ("sampler.num_chains", 2)
    assert parse_override("model.integrator=rk4") == ("model.integrator", "rk4")
    assert parse_override('model.noise="diagonal"') == ("model.noise", "diagonal")
    assert parse_override("initial_state.x0=[0.2, -0.25]") == ("initial_state.x0", [0.2, -0.25])
    key, value = parse_override("model.dt=inf")
    assert key == "model.dt" and math.isinf(value)
    with pytest.raises(SettingsError, match="KEY=VALUE"):
        parse_override("model.dt")
    key, value = parse_override("model.dt=abc")
    with pytest.raises(SettingsError, match="must be a number"):
        merge_overrides(Settings(), {key: value})


# ----------------------------------------------------------------------------- against data
@pytest.fixture(scope="module")
def full_data():
    return symplid.Observations([1.0, 2.0], np.ones((2, 4)), ("q1", "q2", "p1", "p2"))


@pytest.fixture(scope="module")
def q_data():
    return symplid.Observations([1.0, 2.0], np.ones((2, 2)), ("q1", "q2"))


X0 = {"initial_state": {"x0": [0.2, -0.25, 0.3, -0.25]}}


def test_resolve_fills_observation_from_columns(full_data, q_data):
    s = settings_from_dict(X0)
    assert resolve_for_data(s, full_data).model.observation == "full"
    assert resolve_for_data(s, q_data).model.observation == "positions"
    resolved = resolve_for_data(s, q_data)
    assert dataclasses.replace(resolved, model=s.model) == s
    learned = settings_from_dict({"initial_state": {"mode": "learned"}})
    assert resolve_for_data(learned, q_data).initial_state.x0 == ()


@pytest.mark.parametrize(
    ("changes", "key", "words"),
    [
        ({"model": {"observation": "full"}}, "model.observation", "only positions"),
        ({"initial_state": {"x0": []}}, "initial_state.x0", "mode is 'known'"),
        ({"initial_state": {"x0": [1.0, 2.0]}}, "initial_state.x0", "4-dimensional"),
        ({"initial_state": {"x0": [0, 0, 0, 0], "t0": 1.5}}, "initial_state.t0", "before"),
        ({"model": {"mass": [1.0]}}, "model.mass", "expected 2"),
    ],
)
def test_resolve_errors(q_data, changes, key, words):
    data = {**X0, **changes}
    with pytest.raises(SettingsError) as info:
        resolve_for_data(settings_from_dict(data), q_data, source="run.toml")
    assert str(info.value).startswith(f"run.toml: {key} ")
    assert words in str(info.value)


def test_resolve_positions_setting_on_full_data(full_data):
    s = settings_from_dict({**X0, "model": {"observation": "positions"}})
    with pytest.raises(SettingsError, match="positions and momenta"):
        resolve_for_data(s, full_data)


# ----------------------------------------------------------------------------- renamed keys
def test_old_num_samples_key_is_read_with_a_future_warning(tmp_path):
    with pytest.warns(FutureWarning, match=r"sampler\.num_samples is deprecated; use sampler\."
                      r"num_iterations"):
        s = _load_text(tmp_path, "[sampler]\nnum_samples = 3000\nburn_in = 1000\n")
    assert (s.sampler.num_iterations, s.sampler.burn_in, s.sampler.num_draws) == (3000, 1000, 2000)
    with pytest.warns(FutureWarning, match="use sampler.num_iterations"):
        s = merge_overrides(Settings(), {"sampler.num_samples": 300_000})
    assert s.sampler.num_iterations == 300_000
    # Both names: refused, and without the deprecation warning first (one line, issue 23).
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(SettingsError, match="give only"):
            settings_from_dict({"sampler": {"num_samples": 10, "num_iterations": 10}})


def test_written_settings_use_the_new_key(tmp_path):
    fixed = merge_overrides(Settings(), {"sampler.num_iterations": 200_000})
    text = dump_settings(fixed, tmp_path / "s.toml").read_text()
    assert "num_iterations = 200000" in text and "num_samples" not in text


# ----------------------------------------------------------------------------- registries
@pytest.mark.parametrize(
    ("data", "key", "registry"),
    [
        ({"model": {"integrator": "magic"}}, "model.integrator", symplid.INTEGRATORS),
        ({"prediction": {"integrator": "magic"}}, "prediction.integrator", symplid.INTEGRATORS),
        ({"sampler": {"method": "gibbs"}}, "sampler.method", symplid.samplers.SAMPLERS),
        (
            {"priors": {"coefficients": {"prior": "cauchy"}}},
            "priors.coefficients.prior",
            symplid.model._priors.PRIOR_FAMILIES,
        ),
    ],
)
def test_unknown_names_list_the_registry(data, key, registry):
    with pytest.raises(SettingsError) as info:
        settings_from_dict(data, source="s.toml")
    message = str(info.value)
    assert message.startswith(f"s.toml: {key} must be one of ")
    assert f"not a known {registry.kind}" in message
    for name in registry.names():
        assert repr(name) in message


def test_a_registered_prior_family_is_a_setting():
    """A family registered from outside (here, this test) is read, written and used."""
    from symplid.model._priors import PRIOR_FAMILIES

    @dataclasses.dataclass(frozen=True)
    class Wide(Normal):
        family = "wide-normal"

    PRIOR_FAMILIES.register("wide-normal", Wide)
    try:
        s = settings_from_dict({"priors": {"coefficients": {"prior": "wide_normal", "scale": 3}}})
        assert s.priors.coefficients == Wide(0.0, 3.0)
        assert settings_from_dict(settings_to_dict(s)) == s
        assert s.priors.prior_spec(False).coefficients == Wide(0.0, 3.0)
    finally:
        PRIOR_FAMILIES.unregister("wide-normal")


def test_process_var_prior_setting_scales_a_log_uniform_to_the_data():
    """``priors.process_var = "log-uniform"``: Σ's prior is LogUniform(b·1e-8, b), b the mean
    sample variance of the data's components (computed here with NumPy); Γ keeps the
    variances' prior; the default keeps the paper's half-normal for both."""
    from symplid.model._priors import LogUniform
    from symplid.model._simulate import simulate
    from symplid.workflow._fit import build_model, build_posterior

    obs = simulate("harmonic", noise_std=0.05, seed=2)
    b = float(np.mean(np.var(obs.values, axis=0, ddof=1)))
    for choice, want in (("variances", HalfNormal(1.0)), ("log-uniform", LogUniform(b * 1e-8, b))):
        settings = merge_overrides(Settings(), {"model.order": 2, "initial_state.x0": [1.0, 0.0],
                                                "model.dt": 0.25, "priors.process_var": choice})
        posterior = build_posterior(settings, obs, build_model(settings, obs))
        groups = np.asarray(posterior.param_groups)
        sigma = [p for p, g in zip(posterior.priors, groups, strict=True) if g == "process_var"]
        gamma = [p for p, g in zip(posterior.priors, groups, strict=True) if g == "obs_var"]
        assert sigma and gamma
        for prior in sigma:
            assert type(prior) is type(want)
            assert prior.support == pytest.approx(want.support, rel=1e-12)
        assert all(prior == HalfNormal(1.0) for prior in gamma)
    with pytest.raises(SettingsError, match=r"priors\.process_var"):
        merge_overrides(Settings(), {"priors.process_var": "half-cauchy"})
