"""The command line end to end: reproduce --quick, simulate → fit → predict → report, bad input."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from symplid.cli import main

SUMMARY_KEYS = {
    "map_hamiltonian",
    "hamiltonian_rel_error",
    "process_noise_map",
    "process_noise_median",
    "process_noise_q025",
    "process_noise_q975",
    "prediction_horizon_s",
    "acceptance_rate",
    "rhat_max",
    "ess_min",
}
TINY_FIT = ["--iterations", "800", "--burn-in", "400", "--chains", "2", "--no-progress",
            "--no-report"]
TINY_FIT += ["--dt", "0.25"]  # a fixed step: the step search is test_step_size.py's
TINY_FIT += ["--set", "map.sensitivity=false"]  # the MAP refits: test_fit_diagnostics.py


def run(*args: str):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


@pytest.fixture(scope="module")
def paper_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("paper") / "run"
    result = run("reproduce", "--quick", "--out", out, "--no-progress")
    assert result.exit_code == 0, result.output
    return out


@pytest.mark.slow
def test_reproduce_quick_writes_every_file_and_key(paper_run):
    summary = json.loads((paper_run / "summary.json").read_text())
    assert summary["true_hamiltonian"] == pytest.approx(0.1227083333, rel=1e-8)
    for approach in ("leapfrog", "rk2"):
        assert set(summary[approach]) >= SUMMARY_KEYS
        assert (paper_run / approach / "posterior.nc").stat().st_size > 0
        assert (paper_run / approach / "map.json").exists()
        # Even a small budget learns H to a few per cent from 20 noisy points.
        assert summary[approach]["hamiltonian_rel_error"] < 0.05
        q = summary[approach]
        assert q["process_noise_q025"] <= q["process_noise_median"] <= q["process_noise_q975"]
    assert {"process_noise_ratio", "seed", "wall_time_s"} <= set(summary)
    # The paper's central contrast: RK2 needs more process noise than leapfrog.
    assert summary["process_noise_ratio"] > 1.0
    for name in (
        "fig1_phase_portraits",
        "fig2_hamiltonians",
        "fig3_trajectories",
        "fig4_process_noise",
    ):
        png = paper_run / "figures" / f"{name}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    report = (paper_run / "report.md").read_text()
    assert "figures/fig3_trajectories.png" in report
    assert not (paper_run / ".incomplete").exists()


@pytest.fixture(scope="module")
def harmonic_csv(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("data") / "harmonic.csv"
    result = run(
        "simulate",
        "harmonic",
        "--out",
        path,
        "--num-obs",
        "15",
        "--t-end",
        "15",
        "--noise-std",
        "0.02",
        "--seed",
        "3",
    )
    assert result.exit_code == 0, result.output
    return path


@pytest.mark.slow
def test_simulate_fit_predict_report(tmp_path, harmonic_csv):
    out = tmp_path / "fit"
    result = run("fit", harmonic_csv, "--out", out, "--order", "2", "--x0", "1,0", *TINY_FIT)
    assert result.exit_code == 0, result.output
    map_info = json.loads((out / "map.json").read_text())
    # U = ½q²: the q² coefficient is 0.5 and the linear one 0 within the noise.
    names = map_info["param_names"]
    theta = dict(zip(names, map_info["theta"], strict=True))
    assert theta["c[q1^2]"] == pytest.approx(0.5, abs=0.02)
    assert theta["c[q1]"] == pytest.approx(0.0, abs=0.02)

    result = run("predict", out, "--t-end", "30", "--num-paths", "10")
    assert result.exit_code == 0, result.output
    pred = np.load(out / "predictions.npz")
    assert pred["times"][-1] == pytest.approx(30.0)
    # The prediction follows cos(t) (x0 = (1, 0), unit frequency) to within the band.
    assert np.max(np.abs(pred["map_path"][:, 0] - np.cos(pred["times"]))) < 0.1

    result = run("report", out)
    assert result.exit_code == 0, result.output
    report = (out / "report.md").read_text()
    assert "figures/traces.png" in report and "figures/predictive.png" in report
    assert (out / "figures" / "traces.png").exists()


def test_same_seed_same_fit(tmp_path, harmonic_csv):
    outs = []
    for k in range(2):
        out = tmp_path / f"fit{k}"
        result = run(
            "fit",
            harmonic_csv,
            "--out",
            out,
            "--order",
            "2",
            "--x0",
            "1,0",
            "--dt",
            "0.25",
            "--iterations",
            "300",
            "--burn-in",
            "150",
            "--chains",
            "2",
            "--no-progress",
        )
        assert result.exit_code == 0, result.output
        assert re.search(r"log evidence -?\d+\.\d\d \((axis-)?quadrature; Laplace -?\d+\.\d\d\)",
                         result.output), result.output
        outs.append(out)
    a, b = (json.loads((o / "summary.json").read_text()) for o in outs)
    assert a["evidence_method"] in ("quadrature", "axis-quadrature") and a["map_optima"] >= 1
    a.pop("timings"), b.pop("timings")
    assert a == b
    maps = [_without_timings(json.loads((o / "map.json").read_text())) for o in outs]
    assert maps[0] == maps[1]


def _without_timings(obj):
    """Drop wall-clock entries, the only part of a run that may differ between two runs."""
    if isinstance(obj, dict):
        return {k: _without_timings(v) for k, v in obj.items() if "seconds" not in k}
    if isinstance(obj, list):
        return [_without_timings(v) for v in obj]
    return obj


# ----------------------------------------------------------------------------- bad input
def _expect_user_error(result, *words: str) -> None:
    assert result.exit_code == 2, result.output
    err = result.stderr.strip()
    assert err.count("\n") == 0, f"more than one line: {err!r}"
    assert err.startswith("symplid: error:"), err
    assert "Traceback" not in result.output
    for word in words:
        assert word in err, f"{word!r} not in {err!r}"


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


GOOD_CSV = "t,q1,p1\n1,0.5,0.1\n2,0.4,0.2\n3,0.1,0.3\n"


@pytest.mark.parametrize(
    ("content", "words"),
    [
        (None, ["no such file"]),
        ("", ["empty"]),
        ("t,q1,p1\n1,0.5,0.1\n2,abc,0.2\n", ["abc"]),
        ("t,q1,p1\n1,0.5,0.1\n1,0.4,0.2\n", ["increasing"]),
        ("t,q1,p1,p2\n1,0.5,0.1,0.3\n2,0.4,0.2,0.1\n", ["p2"]),
    ],
    ids=["missing", "empty", "text-in-number", "times-not-increasing", "p-without-q"],
)
def test_bad_data_files(tmp_path, content, words):
    path = tmp_path / "data.csv"
    if content is not None:
        path.write_text(content)
    out = tmp_path / "run"
    result = run("fit", path, "--out", out, "--x0", "1,0")
    _expect_user_error(result, *words)
    assert not out.exists() or (out / ".incomplete").exists() or not any(out.iterdir())


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--integrator", "leapfrogg"], ["leapfrogg"]),
        (["--dt", "0"], ["dt"]),
        (["--dt", "-1"], ["dt"]),
        (["--iterations", "100", "--burn-in", "100"], ["burn_in"]),
        (["--set", "model.orderr=3"], ["orderr"]),
    ],
    ids=["unknown-integrator", "dt-zero", "dt-negative", "burn-in", "misspelt-key"],
)
def test_bad_settings_on_the_command_line(tmp_path, args, words):
    data = _write(tmp_path, "data.csv", GOOD_CSV)
    out = tmp_path / "run"
    result = run("fit", data, "--out", out, "--x0", "1,0", *args)
    _expect_user_error(result, *words)
    assert not (out / "summary.json").exists()


def test_misspelt_key_in_settings_file_names_file_and_suggests(tmp_path):
    data = _write(tmp_path, "data.csv", GOOD_CSV)
    config = _write(tmp_path, "s.toml", '[model]\nintegratr = "leapfrog"\n')
    result = run("fit", data, "--out", tmp_path / "run", "--config", config)
    _expect_user_error(result, "s.toml", "integratr", "integrator")


def test_known_initial_state_needs_x0(tmp_path):
    data = _write(tmp_path, "data.csv", GOOD_CSV)
    result = run("fit", data, "--out", tmp_path / "run")
    _expect_user_error(result, "x0")


def test_reproduce_rejects_burn_in_not_below_iterations(tmp_path):
    result = run("reproduce", "--out", tmp_path / "r", "--iterations", "100", "--burn-in", "100")
    _expect_user_error(result, "burn-in")


def test_unknown_system_and_predict_on_missing_run(tmp_path):
    _expect_user_error(run("simulate", "pendulum", "--out", tmp_path / "d.csv"), "pendulum")
    _expect_user_error(run("predict", tmp_path / "nothing", "--t-end", "10"), "nothing")


def test_old_samples_option_still_works_with_a_warning(tmp_path):
    data = _write(tmp_path, "data.csv", GOOD_CSV)
    args = ["--x0", "1,0", "--samples", "100", "--burn-in", "100"]
    result = run("fit", data, "--out", tmp_path / "run", *args)
    # the warning is one line on stderr (as the command line prints warnings), then the error
    warning, error = result.stderr.strip().split("\n")
    assert warning == "symplid: warning: --samples is deprecated; use --iterations"
    assert result.exit_code == 2
    assert error.startswith("symplid: error: command line: sampler.num_iterations (100)")


def test_help_lists_the_registries():
    import symplid

    # click may wrap a line after a hyphen ("implicit-" / "midpoint"): undo that first
    text = re.sub(r"-\n\s+", "-", run("fit", "--help").output)
    for name in (*symplid.INTEGRATORS.names(), *symplid.samplers.SAMPLERS.names()):
        assert name in text
    assert "--iterations" in text and "--samples" not in text
    assert "midpoint" in run("reproduce", "--help").output
