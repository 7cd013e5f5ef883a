"""Issue 23, command-line hunt: option values out of their range are refused before any
work (exit 2, one ``error:`` line naming the option), or lowered with a ``warning:`` line
where a smaller value does the same work (``-j``)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from mbsim.cli_options import JOBS_PER_CPU
from tests.test_hardening import cli, one_error

ROOT = Path(__file__).resolve().parents[1]
SLIDER = ROOT / "models" / "slider_crank.yaml"


@pytest.mark.parametrize("args, needle", [
    (["--steps", "0"], "--steps"),          # was refused only after every adaptive run
    (["--steps", "nan"], "--steps"),
    (["--tolerances", ""], "--tolerances"),  # was a table without adaptive rows, exit 0
    (["--tolerances", "1"], "--tolerances"),
    (["--t-end", "0"], "--t-end"),          # was named 'analysis setting step'
    (["--t-end", "nan"], "--t-end"),
    (["--repeats", "0"], "--repeats"),      # was taken as 1
])
def test_bench_ladders_and_times_out_of_range_are_usage_errors(args, needle):
    one_error(cli("bench", SLIDER, *args), 2, needle)


def test_bench_unknown_output_channel_is_named_without_quotes():
    err = one_error(cli("bench", SLIDER, "--integrators", "rk4", "--steps", "0.01", "--t-end",
                        "0.05", "--outputs", "nope"), 2)
    assert err.endswith("no channel 'nope'"), err


@pytest.mark.parametrize("dpi", ["0", "-1", "nan", "1e9"])
def test_study_dpi_out_of_range_is_a_usage_error_before_any_case(tmp_path, dpi):
    out = tmp_path / "st"
    one_error(cli("study", SLIDER, "all", "--dpi", dpi, "-o", out), 2, "--dpi")
    assert not out.exists()


@pytest.mark.parametrize("command", ["study", "sweep"])
def test_jobs_zero_is_a_usage_error(tmp_path, command):
    args = ["all"] if command == "study" else ["--mode", "kinematic", "--param", "ell=0.3"]
    one_error(cli(command, SLIDER, *args, "-j", "0", "-o", tmp_path / "o"), 2, "--jobs")


def test_sweep_jobs_beyond_the_machine_is_lowered_not_forked(tmp_path):
    """-j 100000 on one case forked processes until the run was killed (a hang)."""
    res = cli("sweep", SLIDER, "--mode", "kinematic", "--param", "ell=0.3", "--t-end", "0.05",
              "-j", "100000", "-o", tmp_path / "sw")
    assert res.exit_code == 0, res.stderr
    cap = JOBS_PER_CPU * (os.cpu_count() or 1)
    assert f"warning: --jobs 100000 lowered to {cap}" in res.stderr
    assert "on up to 1 process(es)" in res.stdout  # never more processes than cases


@pytest.mark.parametrize("address", ["nonsense", "tcp://host", "tcp://a b:1"])
def test_sweep_scheduler_without_a_port_is_refused_at_once(tmp_path, address):
    """'nonsense' took 40 s and ended in a traceback from Dask's Client.__del__."""
    one_error(cli("sweep", SLIDER, "--mode", "kinematic", "--param", "ell=0.3", "--scheduler",
                  address, "-o", tmp_path / "sw"), 2, "--scheduler", "port")
    assert not (tmp_path / "sw").exists()


@pytest.fixture(scope="module")
def slider_result(tmp_path_factory):
    out = tmp_path_factory.mktemp("ranges") / "slider.h5"
    res = cli("run", SLIDER, "--mode", "kinematic", "--t-end", "0.05", "-o", out, "-q")
    assert res.exit_code == 0, res.stderr
    return out


@pytest.mark.parametrize("option, value", [("--rtol", "nan"), ("--atol", "nan"),
                                           ("--rtol", "inf"), ("--rtol", "-1")])
def test_compare_tolerance_not_finite_is_a_usage_error_not_differ(slider_result, option,
                                                                  value):
    """--rtol nan made every value 'differ': exit 1 and DIFFER on a file against itself."""
    res = cli("compare", slider_result, slider_result, option, value)
    one_error(res, 2, option)
    assert "DIFFER" not in res.stdout


def test_compare_worst_below_zero_is_a_usage_error(slider_result):
    one_error(cli("compare", slider_result, slider_result, "-n", "-3"), 2, "--worst")


def test_check_worst_below_zero_is_a_usage_error():
    """-n -2 printed all residuals but the last two (a Python slice)."""
    one_error(cli("check", SLIDER, "-n", "-2"), 2, "--worst")


def test_sweep_product_over_the_case_limit_is_refused_before_it_is_made(tmp_path):
    """300^4 cases: the product was built in memory until the kernel killed the sweep."""
    values = ",".join(f"{0.2 + i * 1e-4:.4f}" for i in range(300))
    res = cli("sweep", SLIDER, "--mode", "kinematic", "--param", f"ell={values}",
              "--param", f"omega={values}", "--param", f"w0={values}", "--param",
              f"xC={values}", "-o", tmp_path / "sw")
    one_error(res, 2, "number of sweep cases", "8100000000 > 100000", "MBSIM_MAX_CASES")
    assert not (tmp_path / "sw").exists()


@pytest.mark.parametrize("digits", [400, 5000])
def test_deck_integer_past_float_range_is_not_finite_not_a_traceback(tmp_path, digits):
    """mass: 999...9 (400 digits): OverflowError traceback converting it to float; 5000
    digits: ValueError past Python's 4300-digit limit."""
    deck = tmp_path / "deck.yaml"
    deck.write_text(SLIDER.read_text().replace("    mass: 0.12", f"    mass: {'9' * digits}"))
    one_error(cli("check", deck), 2, "deck.yaml:37: bodies.crank.mass",
              "expected a finite number")


@pytest.mark.parametrize("option, value", [("--t-end", "2"), ("--step", "0.1"),
                                           ("--integrator", "rk4"), ("--rtol", "1e-5")])
def test_settling_run_settings_without_method_settle_are_usage_errors(tmp_path, option, value):
    """--mode equilibrium (method steady on the governor) took --integrator rk4 and ran
    without it, exit 0: only the settling run (--method settle) uses them."""
    governor = ROOT / "models" / "governor.yaml"
    out = tmp_path / "e.h5"
    one_error(cli("run", governor, "--mode", "equilibrium", option, value, "-o", out), 2,
              option, "only with --method settle")
    assert not out.exists()


@pytest.mark.parametrize("command", ["run", "sweep"])
@pytest.mark.parametrize("tolerance", ["--rtol", "--atol"])
def test_accuracy_with_a_tolerance_is_a_usage_error(tmp_path, command, tolerance):
    """--accuracy 1e-6 --rtol 1e-3 ran at rtol 3e-9 (the accuracy's choice), --rtol
    dropped without a word."""
    sweep = ["--param", "ell=0.3"] if command == "sweep" else []
    one_error(cli(command, SLIDER, "--scene", "free", "--mode", "dynamic", *sweep,
                  "--accuracy", "1e-6", tolerance, "1e-3", "-o", tmp_path / "o"), 2,
              f"--accuracy and {tolerance}")
    assert not (tmp_path / "o").exists()
