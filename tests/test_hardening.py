"""Issue 13: every hole a fuzzing campaign and a new user's first afternoon found, with the
exact input from the issue.  Each path ends in one clean ``error:`` line (deck errors name
file, line and key path; command-line errors the option), the documented exit code (0 ok,
1 analysis failed, 2 deck/usage), no traceback, no stray warning line, a bounded message."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import textwrap
import time
import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from mbsim.cli import main
from mbsim.deck import load_deck
from mbsim.output import read_result
from mbsim.output.hdf5 import check_finite, remove_stale_temporaries, write_result
from mbsim.result import Result

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT / "models"
SLIDER = (MODELS / "slider_crank.yaml").read_text()
GOVERNOR = (MODELS / "governor.yaml").read_text()
DRIVER = "function: pi/2 + omega*t"  # the slider-crank's crank driver, mutated below


def cli(*args):
    res = CliRunner().invoke(main, [str(a) for a in args])
    assert res.exception is None or isinstance(res.exception, SystemExit), res.exception
    return res


def one_error(res, code: int, *needles: str) -> str:
    """The run ended with exit ``code`` and exactly one stderr line, an ``error:`` line that
    holds every needle; returns it."""
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("error: ")]
    assert res.exit_code == code, (res.exit_code, res.stderr)
    assert len(errors) == 1 and all(ln.startswith(("error: ", "warning: ")) for ln in lines), \
        res.stderr
    assert "Traceback" not in res.output and "RuntimeWarning" not in res.stderr
    for n in needles:
        assert n in errors[0], (n, errors[0])
    return errors[0]


def deck(tmp_path, text, name="deck.yaml") -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


# -- deck: nesting, tags, magnitudes, limits --------------------------------------------------
@pytest.mark.parametrize("depth", [400, 3000, 100_000])
def test_deep_nesting_is_a_limit_not_a_recursion_error(tmp_path, depth):
    # issue: `[[[[...1...]]]]` 400 deep -> RecursionError at deck/tree.py:51; libyaml's C
    # composer would even crash (segfault) at 10^5 levels, so depth is checked first
    p = deck(tmp_path, SLIDER + f"\nzz: {'[' * depth}1{']' * depth}\n")
    line = SLIDER.count("\n") + 2
    one_error(cli("check", p), 2, f"deck.yaml:{line}:", "nesting depth", "MBSIM_MAX_DEPTH")


def test_python_tag_on_a_list_is_refused(tmp_path):
    # issue: `title: !!python/object/apply:os.system ["..."]` was silently read as a list
    p = deck(tmp_path, SLIDER.replace("title:", 'title: !!python/object/apply:os.system '
                                      '["echo hacked"]\nold_title:', 1))  # fmt: skip
    one_error(cli("check", p), 2, "deck.yaml:", "unsupported YAML tag", "python/object/apply")


def test_point_at_minus_1e308_is_a_clean_assembly_error(tmp_path, capfd):
    # issue: LinAlgError 'SVD did not converge' at analyses/assembly.py:91, and LAPACK's
    # '** On entry to DLASCL' on stdout
    p = deck(tmp_path, SLIDER.replace("crank: {P: [0.0, 0.08, 0.0]}",
                                      "crank: {P: [-1e308, 0.08, 0.0]}"))  # fmt: skip
    res = cli("check", p)
    one_error(res, 1, "deck.yaml", "overflowed", "B")
    assert "DLASCL" not in capfd.readouterr().out


@pytest.mark.parametrize("edit, item", [
    (("gravity: [0, 0, -9.81]", "gravity: [0, 0, -1e308]"), "body"),
    (("inertia: [0.004, 0.0004, 0.004]", "inertia: [1e308, 1e308, 1e308]"), "rod"),
])  # fmt: skip
def test_overflow_during_run_is_a_clean_error(tmp_path, edit, item):
    # issue: ValueError (infs or NaNs) at equations.py:208 (gravity 1e308) and
    # analyses/initial.py:102 (inertia 1e308) during `run`
    p = deck(tmp_path, SLIDER.replace(*edit))
    out = tmp_path / "x.h5"
    one_error(cli("run", p, "-m", "dynamic", "--t-end", "0.02", "-o", out), 1, "overflowed", item)


def test_spring_point_at_1e300_is_a_clean_error(tmp_path):
    # issue: a spring point at 1e300 -> ValueError at equations.py:208
    p = deck(tmp_path, GOVERNOR.replace("points: {spindle: [0.0, 0.0, 0.0], collar: [0.0, 0.0, "
                                        "0.0]}", "points: {spindle: [0.0, 1e300, 0.0], collar: "
                                        "[0.0, 0.0, 0.0]}"))  # fmt: skip
    assert p.read_text() != GOVERNOR
    res = cli("run", p, "-m", "dynamic", "--t-end", "0.02", "-o", tmp_path / "g.h5")
    one_error(res, 1, "overflowed")


def test_equilibrium_overflow_is_caught_by_the_api_safety_net(tmp_path):
    p = deck(tmp_path, SLIDER.replace("gravity: [0, 0, -9.81]", "gravity: [0, 0, -1e308]"))
    one_error(cli("run", p, "-m", "equilibrium", "-o", tmp_path / "e.h5"), 1, "overflowed")


def test_atol_zero_is_refused_at_load(tmp_path):
    # issue: `analysis: dynamic: atol: 0` on the compressor hung
    p = deck(tmp_path, (MODELS / "compressor.yaml").read_text().replace(
        "atol: 1.0e-8,", "atol: 0,"))  # fmt: skip
    one_error(cli("check", p), 2, "analysis.dynamic.atol", "atol must be > 0")
    for opt, value in (("--atol", "0"), ("--rtol", "nan"), ("--rtol", "1"), ("--atol", "-1")):
        one_error(cli("run", MODELS / "compressor.yaml", "-m", "dynamic", opt, value,
                      "-o", tmp_path / "c.h5"), 2, opt)  # fmt: skip
    assert not (tmp_path / "c.h5").exists()


def test_kinematic_1e6_over_1e6_is_refused_before_allocating(tmp_path):
    # issue: `kinematic: {t_end: 1e6, step: 1e-6}` -> numpy _ArrayMemoryError (7.28 TiB)
    p = deck(tmp_path, SLIDER + "\nanalysis:\n  kinematic: {t_end: 1.0e+6, step: 1.0e-6}\n")
    if "\nanalysis:" in SLIDER:  # the deck already has a section: set it instead
        p = deck(tmp_path, SLIDER)
        res = cli("run", p, "-m", "kinematic", "--set", "analysis.kinematic.t_end=1e6",
                  "--set", "analysis.kinematic.step=1e-6", "-o", tmp_path / "k.h5")
    else:
        res = cli("run", p, "-m", "kinematic", "-o", tmp_path / "k.h5")
    one_error(res, 2, "output times", "1e+12 > 1000000", "MBSIM_MAX_OUTPUTS")
    one_error(cli("run", MODELS / "slider_crank.yaml", "-m", "kinematic", "--t-end", "1e6",
                  "--step", "1e-6", "-o", tmp_path / "k.h5"), 2, "--step", "MBSIM_MAX_OUTPUTS")


@pytest.mark.parametrize("option, value", [("--step", "0"), ("--t-end", "-1"),
                                           ("--step", "-0.01")])
def test_bad_time_options_are_usage_errors(tmp_path, option, value):
    # issue: --step 0 -> ZeroDivisionError (kinematic.py:22); --t-end -1 and --step -0.01
    # "completed" with one output, exit 0
    out = tmp_path / "k.h5"
    one_error(cli("run", MODELS / "slider_crank.yaml", "-m", "kinematic", option, value,
                  "-o", out), 2, option)  # fmt: skip
    assert not out.exists()


@pytest.mark.parametrize("option, value", [("--step", "0"), ("--rtol", "2"),
                                           ("--accuracy", "-1")])
def test_bad_sweep_options_are_usage_errors_before_any_case(tmp_path, option, value):
    # the same for every case: refused once, exit 2, no case run and no folder made (before:
    # every case "failed" with the same message, exit 1)
    out = tmp_path / "sw"
    one_error(cli("sweep", MODELS / "governor.yaml", "-m", "dynamic", "--param", "k=1000,2000",
                  option, value, "-o", out), 2, option)  # fmt: skip
    assert not out.exists()


def test_limits_name_the_variable_and_can_be_raised(tmp_path, monkeypatch):
    table = "{table: {t: [0, 1, 2, 3], value: [0, 1, 2, 3]}}"
    p = deck(tmp_path, SLIDER.replace(DRIVER, f"function: {table}"))
    monkeypatch.setenv("MBSIM_MAX_TABLE_POINTS", "3")
    one_error(cli("check", p), 2, "table.t", "4 > 3", "MBSIM_MAX_TABLE_POINTS")
    monkeypatch.setenv("MBSIM_MAX_TABLE_POINTS", "4")
    assert load_deck(p).drivers["crank"].function.kind == "table"  # raised: accepted
    poly = "{polynomial: [1.5707963, 1, 2, 3]}"
    monkeypatch.setenv("MBSIM_MAX_POLYNOMIAL_TERMS", "3")
    one_error(cli("check", deck(tmp_path, SLIDER.replace(DRIVER, f"function: {poly}"))), 2,
              "polynomial", "MBSIM_MAX_POLYNOMIAL_TERMS")
    monkeypatch.setenv("MBSIM_MAX_DECK_BYTES", "1000")
    one_error(cli("check", MODELS / "slider_crank.yaml"), 2, "deck file size", "> 1000")
    monkeypatch.delenv("MBSIM_MAX_DECK_BYTES")
    monkeypatch.setenv("MBSIM_MAX_PARAMETERS", "2")
    one_error(cli("check", MODELS / "slider_crank.yaml"), 2, "parameters", "4 > 2")


def test_a_1e5_element_study_mode_is_rejected_quickly_with_a_short_message(tmp_path):
    # issue: a 1.2 MB deck whose study case `mode` is a 100 000-element list took 18 s
    modes = "[" + ", ".join(["kinematic"] * 99_999) + "]"
    p = deck(tmp_path, textwrap.dedent(f"""
        bodies:
          ground: {{ground: true}}
          b: {{mass: 1, inertia: [1, 1, 1]}}
        studies:
          s: {{cases: [{{label: a, mode: {modes}}}]}}
    """))
    # (its CPU time: python benchmarks/deck_limits.py; the message was built from every item)
    res = cli("check", p)
    line = one_error(res, 2, "studies.s.cases[0].mode", "expected mode")
    assert len(line) < 600


def test_a_1mb_body_name_is_not_echoed(tmp_path):
    # issue: a 1 MB body name gave a 1 MB error line
    name = "b" * 10**6
    p = deck(tmp_path, SLIDER.replace("bodies: [ground, crank]", f"bodies: [ground, {name}]"))
    line = one_error(cli("check", p), 2)
    assert len(line) < 600


@pytest.mark.parametrize("formula", ["9**9**9", "exp(exp(exp(exp(10))))", "sqrt(-1)"])
def test_overflowing_formulas_print_no_runtime_warning(tmp_path, formula):
    p = deck(tmp_path, SLIDER.replace(DRIVER, f"function: '{formula}'"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a RuntimeWarning would fail the test
        one_error(cli("check", p), 2, "drivers.crank.function", "expected a finite number")


# -- formula units ----------------------------------------------------------------------------
def test_degrees_in_a_formula(tmp_path):
    # issue: '30*deg + omega*t' -> "'deg' is a function"; deg(30) converted radians to degrees
    # (1718.9) and the run completed with a wrong crank angle
    p = deck(tmp_path, SLIDER.replace(DRIVER, "function: 'pi/2 + 30*deg + omega*t'"))
    f = load_deck(p).drivers["crank"].function
    theta0 = f.data["expr"]({"t": 0.0})
    assert theta0 == pytest.approx(math.pi / 2 + math.pi / 6, rel=1e-15)  # 30 deg = pi/6 rad
    for text, needles in [
        ("deg(30) + omega*t", ("'deg' is the constant pi/180", "30*deg", "deg2rad")),
        ("'360 deg * t'", ("'360*deg*t'",)),
        ("2*pie", ("did you mean 'pi'",)),
    ]:
        one_error(cli("check", deck(tmp_path, SLIDER.replace(DRIVER, f"function: {text}"))), 2,
                  "drivers.crank.function", *needles)
    assert "unknown unit 't'" not in cli("check", deck(tmp_path, SLIDER.replace(
        DRIVER, "function: '360 deg * t'"))).stderr  # fmt: skip


# -- YAML structure, assembly -----------------------------------------------------------------
def test_misindented_yaml_names_both_lines(tmp_path):
    lines = SLIDER.split("\n")
    k = next(i for i, ln in enumerate(lines) if ln.startswith("    type: rotation"))
    lines[k] = "     type: rotation"  # one space too many
    one_error(cli("check", deck(tmp_path, "\n".join(lines))), 2,
              f"deck.yaml:{k + 2}:", f"lines {k + 1} and {k + 2}", "indentation")


def test_check_of_a_deck_that_cannot_assemble(tmp_path):
    # issue: "Newton iteration did not converge ... worst constraints" but never "the loop
    # cannot close", and `check` printed nothing, not even the residuals at the estimates.
    # A rod of 0.15 m cannot reach from the crank pin (0.1 m off the slider's line, 0.2 m up).
    res = cli("check", MODELS / "slider_crank.yaml", "--set", "parameters.ell=0.15",
              "--set", "parameters.xC=0.2")
    one_error(res, 1, "the loop ground - crank - rod - slider - ground (through A, B, C, T) "
              "cannot close")  # fmt: skip
    assert "deck estimates: max |Phi| = " in res.stdout  # printed before the error line
    assert "B spherical" in res.stdout and "C spherical" in res.stdout
    # the four-bar with its coupler 4 m instead of 12.2 (Table 12.3.1): Newton does not
    # converge (the other failure path); the loop is still named
    fb = (MODELS / "four_bar.yaml").read_text()
    short = fb.replace("link2: [0, 6.1, 0]}", "link2: [0, 2.0, 0]}").replace(
        "link2: {P: [0, -6.1, 0], Q: [0.70926, -6.1, -0.70495]}",
        "link2: {P: [0, -2.0, 0], Q: [0.70926, -2.0, -0.70495]}")  # fmt: skip
    assert short.count("2.0, 0") == 3
    res = cli("check", deck(tmp_path, short))
    one_error(res, 1, "the loop ground - link1 - link2 - link3 - ground (through A, B, C, D) "
              "cannot close")  # fmt: skip
    assert "deck estimates: max |Phi|" in res.stdout


# -- command line ------------------------------------------------------------------------------
def test_option_errors_name_the_deck_file(tmp_path):
    # issue: --integrator dopri and --method stedy printed `<deck>` instead of the file name
    for mode, opt, value in (("dynamic", "--integrator", "dopri"),
                             ("equilibrium", "--method", "stedy")):
        line = one_error(cli("run", MODELS / "slider_crank.yaml", "-m", mode, opt, value,
                             "-o", tmp_path / "x.h5"), 2, "slider_crank.yaml")
        assert "<deck>" not in line


@pytest.mark.parametrize("args", [["run", "--bogus"], ["run"], ["plot"],
                                  ["run", "x.yaml", "-m", "sideways"], ["nosuchcommand"]])
def test_click_usage_errors_are_one_line(args):
    one_error(cli(*args), 2, "mbsim")


def test_verbose_and_quiet_work_before_and_after_the_command(tmp_path):
    # issue: -v/-vv logged nothing of mbsim's (only h5py debug noise) and were refused after
    # the subcommand; -q still printed `plot -> ...`
    for args in (["-v", "run", MODELS / "slider_crank.yaml", "-m", "kinematic"],
                 ["run", MODELS / "slider_crank.yaml", "-m", "kinematic", "-v"]):
        res = cli(*args, "--t-end", "0.05", "-o", tmp_path / "v.h5")
        assert res.exit_code == 0, res.stderr
        assert "mbsim.analyses.assembly" in res.stderr and "Newton iteration" in res.stderr
        assert "output_steps" in res.stderr  # the analysis' statistics at the end
        assert "h5py" not in res.stderr
    res = cli("run", MODELS / "slider_crank.yaml", "-m", "kinematic", "--t-end", "0.05",
              "-o", tmp_path / "q.h5", "-q", "--plot")
    assert res.exit_code == 0 and res.stdout == "" and res.stderr == ""
    assert (tmp_path / "q.png").exists()
    res = cli("-q", "check", MODELS / "four_bar.yaml")  # no own -q: stdout and warnings go
    assert res.exit_code == 0 and res.stdout == "" and res.stderr == ""
    res = cli("check", MODELS / "nosuch.yaml", "-q")
    one_error(res, 2, "no such deck file")


# -- output: path, disk full, stale temporaries, SIGTERM, NaN ----------------------------------
@pytest.mark.parametrize("kind", ["missing folder", "file as folder", "folder"])
def test_unwritable_output_is_refused_before_the_analysis(tmp_path, kind, monkeypatch):
    # issue: traceback, exit 1, discovered only after the whole analysis had run
    import mbsim.api

    def never(*a, **k):
        raise AssertionError("the analysis ran although the output cannot be written")

    monkeypatch.setattr(mbsim.api, "run_model", never)
    (tmp_path / "afile").write_text("x")
    out = {"missing folder": tmp_path / "nonexistent_dir" / "x.h5",
           "file as folder": tmp_path / "afile" / "x.h5", "folder": tmp_path}[kind]
    res = cli("run", MODELS / "slider_crank.yaml", "-m", "kinematic", "--step", "1e-4",
              "-o", out)  # fmt: skip
    one_error(res, 2, str(out))


def test_disk_full_keeps_the_earlier_file(tmp_path):
    # issue: h5py RuntimeError traceback, then a segmentation fault (exit 139) on a full
    # 64 KB tmpfs.  Simulated with a file-size limit (RLIMIT_FSIZE, SIGXFSZ ignored: a write
    # past it fails with EFBIG) in a subprocess; the earlier file must stay as it was.
    old = tmp_path / "x.h5"
    with h5py.File(old, "w") as f:  # an earlier HDF5 file (run -o refuses any other kind)
        f.attrs["note"] = "earlier results"
    earlier = old.read_bytes()
    code = textwrap.dedent(f"""
        import resource, signal, sys
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (20000, 20000))
        from mbsim.cli import main
        sys.argv = ["mbsim", "run", {str(MODELS / 'slider_crank.yaml')!r}, "-m", "kinematic",
                    "--t-end", "0.2", "-o", {str(old)!r}]
        main()
    """)
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert p.returncode == 1, (p.returncode, p.stderr)
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), p.stderr
    assert "cannot write the results" in lines[0] and "File too large" in lines[0]
    assert old.read_bytes() == earlier
    assert sorted(f.name for f in tmp_path.iterdir()) == ["x.h5"]  # no temporary left


def test_stale_temporaries_of_dead_runs_are_removed(tmp_path):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()  # its pid is free now (reuse within the test is very unlikely)
    stale = tmp_path / f".x.h5.tmp-{dead.pid}"
    live = tmp_path / f".y.h5.tmp-{os.getpid()}"
    other = tmp_path / ".notes.tmp-abc"
    for f in (stale, live, other):
        f.write_bytes(b"partial")
    res = cli("run", MODELS / "slider_crank.yaml", "-m", "kinematic", "--t-end", "0.05",
              "-o", tmp_path / "x.h5", "-q")  # fmt: skip
    assert res.exit_code == 0, res.stderr
    assert not stale.exists() and live.exists() and other.exists()
    assert remove_stale_temporaries(tmp_path) == []  # nothing left to remove


def test_a_sweep_removes_stale_temporaries_of_dead_runs(tmp_path):
    # issue: kill -9 during the write leaves .X.h5.tmp-PID files that nothing cleaned (sweep)
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    stale = tmp_path / f".case.h5.tmp-{dead.pid}"
    stale.write_bytes(b"partial")
    res = cli("sweep", MODELS / "slider_crank.yaml", "-m", "kinematic", "--param", "ell=0.3",
              "--t-end", "0.02", "-o", tmp_path, "-j", "1", "-q")  # fmt: skip
    assert res.exit_code == 0, res.stderr
    assert not stale.exists() and (tmp_path / "ell=0.3.h5").exists()


def test_a_sweep_removes_result_spools_of_dead_sweeps(tmp_path):
    # issue 13's note: a sweep killed with kill -9 left its .spool-* folder (pickled case
    # results) for good; the next sweep in the folder removes those of dead processes only
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    stale = tmp_path / f".spool-{dead.pid}-abc123"
    live = tmp_path / f".spool-{os.getpid()}-def456"
    for d in (stale, live):
        d.mkdir()
        (d / "case1.pkl").write_bytes(b"pickled")
    res = cli("sweep", MODELS / "slider_crank.yaml", "-m", "kinematic", "--param", "ell=0.3",
              "--t-end", "0.02", "-o", tmp_path, "-j", "1", "-q")  # fmt: skip
    assert res.exit_code == 0, res.stderr
    assert not stale.exists() and live.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".spool-")
                and p != live]  # the sweep's own spool is gone too


def _sigterm_run(deck, mode, out, *options):
    """Start `mbsim -v run DECK -m MODE -o OUT OPTIONS`, SIGTERM it 1 s after its analysis has
    started (the -v log line); returns (exit code, stderr, seconds from SIGTERM to exit)."""
    p = subprocess.Popen([sys.executable, "-m", "mbsim", "-v", "run", str(deck), "-m", mode,
                          *options, "-o", str(out), "--no-progress"],
                         stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True)  # fmt: skip
    for line in p.stderr:
        if f"{mode} analysis of" in line:
            break
    time.sleep(1.0)
    t0 = time.monotonic()
    p.terminate()  # SIGTERM
    _, err = p.communicate(timeout=60)
    return p.returncode, err, time.monotonic() - t0


def test_sigterm_on_run_keeps_the_outputs_reached(tmp_path):
    # issue: SIGTERM on `run` left no partial file (Ctrl-C did).  A kinematic run of 2*10^5
    # outputs (minutes); SIGTERM once it has started.
    out = tmp_path / "k.h5"
    code, err, _ = _sigterm_run(MODELS / "slider_crank.yaml", "kinematic", out,
                                "--t-end", "200", "--step", "0.001")
    assert code == 1, err
    assert "interrupted" in err and "marked incomplete" in err
    r = read_result(out)
    assert r.status == "incomplete" and 1 < len(r.t) < 200_001


def test_sigterm_on_a_dynamic_run_stops_it_without_the_error_estimate(tmp_path):
    # a SIGTERM (timeout, a batch system) during a long dynamic run used to end the run and
    # then start its error estimate's companion integration, as long again (found with
    # `timeout 120 mbsim run models/compressor.yaml --mode dynamic --integrator genalpha`,
    # still running 10 min later)
    out = tmp_path / "d.h5"
    code, err, seconds = _sigterm_run(MODELS / "governor.yaml", "dynamic", out,
                                      "--t-end", "5e3", "--step", "0.01")
    assert seconds < 20, "the run went on after SIGTERM"
    assert code == 1, err
    assert "interrupted" in err and "marked incomplete" in err
    r = read_result(out)
    assert r.status == "incomplete" and 1 < len(r.t) < 500_001
    with h5py.File(out) as f:  # no estimate: NaN, and why
        assert np.isnan(f.attrs["error_estimate"])
        assert "interrupted" in f.attrs["error_estimate_reason"]
        summary = json.loads(f["summary"].asstr()[()])
    assert summary["error_estimate"]["method"].startswith("not computed")


def test_a_complete_result_never_holds_nan(tmp_path):
    r = Result(mode="dynamic", t=np.linspace(0, 1, 5))
    r.add("bodies/a/r", np.column_stack([np.zeros(5), np.ones(5), [0, 0, np.inf, 0, 0]]), "m")
    check_finite(r)
    assert r.status == "incomplete" and "bodies.a.r" in r.message and "t = 0.5 s" in r.message
    write_result(r, tmp_path / "r.h5")
    with h5py.File(tmp_path / "r.h5") as f:
        assert f.attrs["status"] == "incomplete"
    ok = Result(mode="dynamic", t=np.linspace(0, 1, 5))
    ok.add("bodies/a/r", np.ones((5, 3)), "m")
    check_finite(ok)
    assert ok.complete


# -- plot, export, compare ---------------------------------------------------------------------
@pytest.fixture(scope="module")
def results(tmp_path_factory):
    d = tmp_path_factory.mktemp("res")
    for name, t_end in (("a", "0.1"), ("b", "0.05")):
        res = CliRunner().invoke(main, ["run", str(MODELS / "slider_crank.yaml"), "-m",
                                        "inverse", "--t-end", t_end, "-o", str(d / f"{name}.h5"),
                                        "-q"])  # fmt: skip
        assert res.exit_code == 0, res.stderr
    with h5py.File(d / "index.h5", "w") as f:  # as a sweep writes next to its cases
        f["cases"] = np.arange(2)
    return d


def test_plot_of_a_sweep_folder_skips_the_index(results, tmp_path):
    # issue: `mbsim plot DIR/*.h5 -y ...` failed on every sweep folder (index.h5), with an h5py
    # error that did not name the file
    files = sorted(str(p) for p in results.glob("*.h5"))
    res = cli("plot", *files, "-y", "drivers.crank.torque", "-o", tmp_path / "p.png")
    assert res.exit_code == 0, res.stderr
    assert "skipping" in res.stderr and "index.h5" in res.stderr
    assert (tmp_path / "p.png").exists()
    one_error(cli("plot", results / "index.h5", "-y", "x"), 2, "index.h5", "sweep index")
    one_error(cli("export", results / "index.h5"), 2, "index.h5", "not a results file")
    one_error(cli("compare", results / "a.h5", results / "index.h5"), 2, "index.h5")


def test_plot_of_a_group_lists_its_channels(results, tmp_path):
    # issue: `plot -y drivers` -> "no channel 'drivers" (cut, no suggestion)
    line = one_error(cli("plot", results / "a.h5", "-y", "drivers", "-o", tmp_path / "p.png"),
                     2, "'drivers' is a group", "drivers.crank.torque")
    assert "'drivers'" in line


def test_compare_usage_errors_and_time_axes(results):
    # issue: `compare --channels bodies.slider.r.x` exited 1 ("missing in a and b", "DIFFER: 0
    # of 0") where a usage error is 2; different time axes printed one line per channel
    one_error(cli("compare", results / "a.h5", results / "a.h5", "--channels",
                  "bodies.slider.r.x"), 2, "component", "bodies.slider.r")  # fmt: skip
    one_error(cli("compare", results / "a.h5", results / "a.h5", "--channels", "bodies.slidr.r"),
              2, "did you mean bodies.slider.r")
    res = cli("compare", results / "a.h5", results / "b.h5")
    assert res.exit_code == 1
    problems = [ln for ln in res.stdout.splitlines() if ln.startswith("problem:")]
    assert problems == ["problem: time axes differ: 21 samples in a, 11 in b"], res.stdout
