"""Input and output traps (issue 23, item 7): each one the exact command a user typed, ending
in one ``error:`` line with the documented exit code (0 ok, 1 failed part-way with what was
done kept, 2 deck or usage error), no traceback."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest
from click.testing import CliRunner

from mbsim.cli import main
from mbsim.sweep import read_index

ROOT = Path(__file__).resolve().parents[1]
SLIDER = ROOT / "models" / "slider_crank.yaml"


def cli(*args):
    res = CliRunner().invoke(main, [str(a) for a in args])
    assert res.exception is None or isinstance(res.exception, SystemExit), repr(res.exception)
    return res



def small_sweep(out):
    """`mbsim sweep` of two short kinematic cases of the slider-crank on one process."""
    return cli("sweep", SLIDER, "--mode", "kinematic", "--param", "ell=0.3,0.27",
               "--t-end", "0.02", "-j", "1", "-o", out)


def one_error(res, code: int, *needles: str) -> str:
    """Exit ``code``, exactly one ``error:`` line on stderr (other lines only warnings),
    holding every needle; returns it."""
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("error: ")]
    assert res.exit_code == code, (res.exit_code, res.stderr, res.stdout)
    assert len(errors) == 1, res.stderr
    assert all(ln.startswith(("error: ", "warning: ")) for ln in lines), res.stderr
    assert "Traceback" not in res.output
    for n in needles:
        assert n in errors[0], (n, errors[0])
    return errors[0]


def slider_with(tmp_path, old: str, new: str, name: str = "deck.yaml") -> Path:
    text = SLIDER.read_text()
    assert old in text
    p = tmp_path / name
    p.write_text(text.replace(old, new, 1))
    return p


# -- YAML types in numeric fields ----------------------------------------------------------------
@pytest.mark.parametrize("value, says", [
    ("2001-12-14", "got a date 2001-12-14"),
    ("2001-12-14 21:59:43", "got a date 2001-12-14 21:59:43"),
    ("!!timestamp 2001-01-01", "got a date"),
    ("null", "got nothing"),
    ("true", "got true"),
    ("!!set {a, b}", "unsupported YAML tag"),
    ("!!binary aGVsbG8=", "unsupported YAML tag"),
])  # fmt: skip
def test_non_numeric_yaml_types_in_a_numeric_field_are_deck_errors(tmp_path, value, says):
    deck = slider_with(tmp_path, "    mass: 0.12", f"    mass: {value}")
    res = cli("check", deck)
    line = SLIDER.read_text().splitlines().index("    mass: 0.12") + 1  # the crank's mass
    one_error(res, 2, str(deck), f":{line}:", "bodies.crank.mass", says)


def test_a_date_given_with_set_is_a_deck_error():
    res = cli("check", SLIDER, "--set", "bodies.crank.mass=2001-12-14")
    one_error(res, 2, "bodies.crank.mass", "got a date 2001-12-14", "(value from --set)")


@pytest.mark.parametrize(
    "path", ["analysis.dynamic.t_end", "bodies.crank.r[0]", "drivers.crank.function"]
)
def test_a_date_in_a_setting_vector_or_function_is_a_deck_error(path):
    res = cli("check", SLIDER, "--set", f"{path}=2001-12-14")
    one_error(res, 2, path, "got a date 2001-12-14")


def test_a_date_given_with_sweep_param_fails_its_case_only(tmp_path):
    out = tmp_path / "sw"
    res = cli(
        "sweep",
        SLIDER,
        "--mode",
        "kinematic",
        "--param",
        "bodies.crank.mass=0.12,2001-12-14",
        "--t-end",
        "0.02",
        "-j",
        "1",
        "-o",
        out,
    )
    one_error(res, 1, "1 of 2 case(s) not complete")
    rows = {r["bodies.crank.mass"]: r for r in read_index(out / "index.csv")}
    assert rows["0.12"]["status"] == "complete"
    assert rows["2001-12-14"]["status"] == "failed"
    assert "got a date 2001-12-14" in rows["2001-12-14"]["message"]


def test_binary_in_a_text_field_is_refused():
    res = cli("check", SLIDER, "--set", "title=!!binary aGVsbG8=")
    one_error(res, 2, "unsupported YAML tag", "binary")


# -- sweeps on a full or read-only disk ----------------------------------------------------------
@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EROFS])
def test_sweep_whose_index_cannot_be_written_keeps_the_case_files(tmp_path, monkeypatch, code):
    import mbsim.sweep

    def full(path, write):
        raise OSError(code, os.strerror(code), str(path))

    monkeypatch.setattr(mbsim.sweep, "_atomic", full)
    out = tmp_path / "sw"
    res = small_sweep(out)
    one_error(res, 1, "cannot write the index", os.strerror(code), "2 case file(s) written")
    assert sorted(p.name for p in out.glob("*.h5")) == ["ell=0.27.h5", "ell=0.3.h5"]


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EROFS])
def test_sweep_into_a_folder_that_takes_no_file_runs_nothing(tmp_path, monkeypatch, code):
    import builtins

    real_open = builtins.open

    def refuse(file, *a, **k):
        if ".write-probe-" in str(file):
            raise OSError(code, os.strerror(code), str(file))
        return real_open(file, *a, **k)

    monkeypatch.setattr(builtins, "open", refuse)
    out = tmp_path / "sw"
    res = small_sweep(out)
    one_error(res, 2, f"output folder {out}", os.strerror(code))
    assert not list(out.glob("*.h5"))


# -- the -o template -----------------------------------------------------------------------------
@pytest.mark.parametrize("template, says", [
    ("{mode.__class__.__init__.__globals__}", "only plain names"),
    ("{mode.__class__}.h5", "only plain names"),
    ("{ell[0]}.h5", "only plain names"),
    ("{mode!r}.h5", "no conversions"),
    ("{mode:>2000000000}.h5", "format '>2000000000' not allowed"),
    ("{ell:{mode}}.h5", "not allowed"),
    ("{xyz}.h5", "unknown field 'xyz'; available: deck, ell, mode, omega, scene, w0, xC"),
    ("{}.h5", "unknown field"),
    ("a{.h5", "write {{ and }} for braces"),
    ("{mode:.3f}.h5", "Unknown format code"),
])  # fmt: skip
def test_output_template_takes_only_plain_documented_fields(tmp_path, template, says):
    res = cli("run", SLIDER, "--mode", "kinematic", "--t-end", "0.01", "-o", tmp_path / template)
    one_error(res, 2, "output name template", says)
    assert not list(tmp_path.iterdir())


def test_output_template_fields_and_short_formats(tmp_path):
    res = cli(
        "run",
        SLIDER,
        "--mode",
        "kinematic",
        "--t-end",
        "0.01",
        "--set",
        "parameters.ell=0.27",
        "-o",
        tmp_path / "{deck}_{mode}_{ell:.3f}{scene}.h5",
    )
    assert res.exit_code == 0, res.output
    assert (tmp_path / "slider_crank_kinematic_0.270.h5").is_file()


# -- every command checks its output path before its work ----------------------------------------
@pytest.fixture(scope="module")
def slider_h5(tmp_path_factory):
    out = tmp_path_factory.mktemp("res") / "s.h5"
    res = cli("run", SLIDER, "--mode", "kinematic", "--t-end", "0.05", "-o", out, "-q")
    assert res.exit_code == 0, res.output
    return out


def _never(*a, **k):
    raise AssertionError("the work ran although the output path is bad")


@pytest.mark.parametrize("args, module, fn, says", [
    (["bench", SLIDER, "--integrators", "rk4", "-o", "{d}/nofolder/wp.png"],
     "mbsim.analyses.bench", "work_precision", "-o: output {d}/nofolder/wp.png: the folder"),
    (["bench", SLIDER, "-o", "{d}/wp.txt"], "mbsim.analyses.bench", "work_precision",
     "-o: cannot save a figure as '.txt'"),
    (["export", "{h5}", "--csv", "{d}/nofolder/x.csv"], "mbsim.output", "read_result",
     "--csv: output {d}/nofolder/x.csv: the folder {d}/nofolder does not exist"),
    (["plot", "{h5}", "bodies.crank.r", "-o", "{d}/nofolder/p.png"], "mbsim.output",
     "read_result", "-o: output {d}/nofolder/p.png: the folder {d}/nofolder does not exist"),
    (["plot", "{h5}", "bodies.crank.r", "--data", "{d}/nofolder/p.csv"], "mbsim.output",
     "read_result", "--data: output {d}/nofolder/p.csv: the folder"),
    (["animate", "{h5}", "-o", "{d}/nofolder/a.gif"], "mbsim.animate", "animate_file",
     "-o: output {d}/nofolder/a.gif: the folder {d}/nofolder does not exist"),
    (["run", SLIDER, "--mode", "kinematic", "-o", "{d}/nofolder/r.h5"], "mbsim.api",
     "run_model", "output {d}/nofolder/r.h5: the folder"),
    (["study", SLIDER, "inverse_rod_length", "-o", "{h5}/x"], "mbsim.study", "run_study",
     "output folder {h5}/x: cannot write there"),
])  # fmt: skip
def test_every_command_checks_its_output_path_first(
    tmp_path, slider_h5, monkeypatch, args, module, fn, says
):
    import importlib

    monkeypatch.setattr(importlib.import_module(module), fn, _never)
    fill = {"d": tmp_path, "h5": slider_h5}
    res = cli(*[str(a).format(**fill) for a in args])
    one_error(res, 2, says.format(**fill))


# -- limits enforced while parsing ---------------------------------------------------------------
def _deck_with(text: str, tmp_path, name="deck.yaml") -> Path:
    p = tmp_path / name
    p.write_text(SLIDER.read_text() + text)
    return p


def test_a_compact_million_point_table_is_refused_while_parsing(tmp_path, monkeypatch):
    """The 8.9 MB deck of the issue (a driver table of 10^6 points, flow style) ends in the
    item limit's error at the table's line; composing it took 17 s and 730 MB before
    (benchmarks/deck_limits.py measures the refusal: about 0.2 s of parsing)."""
    import yaml

    def never(*a, **k):
        raise AssertionError("the deck was composed although it is over a limit")

    monkeypatch.setattr(yaml, "compose", never)
    n = 10**6
    text = SLIDER.read_text().replace(
        "function: pi/2 + omega*t",
        "function: {table: {t: ["
        + ",".join(map(str, range(n)))
        + "], value: ["
        + ",".join("1" for _ in range(n))
        + "]}}",
    )
    p = tmp_path / "table.yaml"
    p.write_text(text)
    line = text[: text.index("{table")].count("\n") + 1
    one_error(
        cli("check", p),
        2,
        f"table.yaml:{line}: drivers.crank.function.table.t: number of entries of one list",
        "MBSIM_MAX_ITEMS",
    )


@pytest.mark.parametrize("nesting", [
    "".join(f"\n{'  ' * i}- " for i in range(1, 3000)),  # block lists, 3000 deep
    "{a: " * 3000 + "1" + "}" * 3000,  # flow mappings (PyYAML 6.0.4's scanner refuses them)
])  # fmt: skip
def test_nesting_limit_is_mbsims_own_in_block_and_flow_style(tmp_path, nesting):
    p = _deck_with(f"\nzz: {nesting}\n", tmp_path)
    one_error(cli("check", p), 2, "deck.yaml:", "zz", "nesting depth", "MBSIM_MAX_DEPTH")


def test_brackets_inside_quotes_and_comments_do_not_count_as_nesting(tmp_path):
    from mbsim.deck.tree import _flow_too_deep

    deep = "[" * 100
    text = f"zz: ['{deep}', \"\\\"{deep}\", don't, 'it''s{deep}']  # {deep}\n"
    assert _flow_too_deep(text, 64) is None
    assert _flow_too_deep(text + "yy: " + deep, 64) == 2
    p = _deck_with("\n" + text, tmp_path)
    one_error(cli("check", p), 2, "unknown key 'zz'")


def test_values_in_all_are_limited(tmp_path, monkeypatch):
    monkeypatch.setenv("MBSIM_MAX_NODES", "1000")
    p = _deck_with("\nzz: [" + ",".join(["1"] * 1000) + "]\n", tmp_path)
    one_error(cli("check", p), 2, "number of values in the deck", "MBSIM_MAX_NODES")
    monkeypatch.setenv("MBSIM_MAX_NODES", "100000")
    one_error(cli("check", p), 2, "unknown key 'zz'")


def test_a_set_value_is_limited_too():
    res = cli("check", SLIDER, "--set", "bodies.crank.r=" + "[" * 100 + "]" * 100)
    line = one_error(res, 2, "bodies.crank.r", "nesting depth", "(+120 characters)")
    assert len(line) < 400


# -- formulas: long sums and products are flat, nesting has a clean limit ------------------------
def test_a_sum_of_4999_terms_under_the_length_limit_is_read(tmp_path):
    formula = "0.3" + "+0" * 4998  # 9 999 characters, 4 999 terms
    assert len(formula) < 10_000
    res = cli("check", SLIDER, "--set", f"parameters.ell={formula}")
    assert res.exit_code == 0, res.output


@pytest.mark.parametrize(
    "formula", ["-" * 3000 + "1", "2**" * 1000 + "1", "1 if t else " * 500 + "0"]
)
def test_deep_formula_nesting_is_a_clean_limit(formula):
    res = cli("check", SLIDER, "--set", f"parameters.ell={formula}")
    one_error(res, 2, "parameters.ell", "nested deeper than 100 levels")


# -- parameters ----------------------------------------------------------------------------------
def test_9990_chained_parameters_are_each_evaluated_once(tmp_path, monkeypatch):
    """q_i: q_(i-1) + 1 for i < 9990 (the issue's 172 kB deck took 22 s in `check`; its CPU
    time: python benchmarks/deck_limits.py): the values are right and each formula is
    parsed once."""
    import mbsim.deck.values
    from mbsim.deck import load_deck

    n = 9990
    head, rest = SLIDER.read_text().split("parameters:\n", 1)
    lines = ["  q_0: 1"] + [f"  q_{i}: q_{i - 1} + 1" for i in range(1, n)]
    p = tmp_path / "chain.yaml"
    p.write_text(head + "parameters:\n" + "\n".join(lines) + "\n" + rest)
    calls = []
    real = mbsim.deck.values.parse_expression

    def counted(text, *a, **k):
        calls.append(text)
        return real(text, *a, **k)

    monkeypatch.setattr(mbsim.deck.values, "parse_expression", counted)
    spec = load_deck(p)
    assert spec.parameters["q_9989"] == n
    chained = [c for c in calls if c.startswith("q_")]
    assert len(chained) == len(set(chained)) == n - 1


# -- unknown analysis settings -------------------------------------------------------------------
def test_a_misspelt_setting_in_the_deck_is_an_error_with_a_suggestion(tmp_path):
    deck = slider_with(tmp_path, "analysis:\n", "analysis:\n  dynamic: {t_ned: 0.5}\n")
    line = deck.read_text().split("\n").index("  dynamic: {t_ned: 0.5}") + 1
    one_error(
        cli("check", deck),
        2,
        f"deck.yaml:{line}:",
        "analysis.dynamic.t_ned",
        "unknown setting 't_ned' of the dynamic analysis; did you mean t_end?",
    )


def test_a_misspelt_setting_given_with_set_or_sweep_param_is_an_error(tmp_path):
    one_error(
        cli(
            "run",
            SLIDER,
            "--mode",
            "kinematic",
            "--set",
            "analysis.kinematic.stepp=0.1",
            "-o",
            tmp_path / "x.h5",
        ),
        2,
        "analysis.kinematic.stepp",
        "did you mean step?",
    )
    res = cli(
        "sweep",
        SLIDER,
        "--mode",
        "kinematic",
        "--param",
        "analysis.kinematic.t_ennd=0.1,0.2",
        "-o",
        tmp_path / "sw",
    )
    one_error(res, 2, "cannot --param analysis.kinematic.t_ennd", "did you mean t_end?")
    assert not (tmp_path / "sw").exists()


def test_a_misspelt_setting_of_run_model_is_a_usage_error():
    from mbsim.api import load_model, run_model
    from mbsim.errors import UsageError

    spec, model = load_model(SLIDER)
    with pytest.raises(
        UsageError, match="unknown setting 't_ennd' of the inverse analysis; did you mean t_end"
    ):
        run_model(model, "inverse", {"t_ennd": 1}, deck=spec)


def test_an_option_of_another_mode_is_a_usage_error(tmp_path):
    one_error(
        cli("run", SLIDER, "--mode", "kinematic", "--integrator", "rk4", "-o", tmp_path / "x.h5"),
        2,
        "--integrator does not apply to --mode kinematic",
    )
    one_error(
        cli(
            "sweep",
            SLIDER,
            "--mode",
            "kinematic",
            "--param",
            "ell=0.3",
            "--rtol",
            "1e-6",
            "-o",
            tmp_path / "sw",
        ),
        2,
        "--rtol does not apply to --mode kinematic",
    )


def test_a_misspelt_setting_of_a_study_case_is_an_error(tmp_path):
    deck = slider_with(
        tmp_path,
        "\nstudies:\n",
        "\nstudies:\n  s: {cases: [{label: a, mode: kinematic, options: {t_edn: 0.1}}]}\n",
    )
    one_error(cli("check", deck), 2, "options.t_edn", "did you mean t_end?")


# -- one writer per output: locks ----------------------------------------------------------------
def _plant_lock(path: Path, pid: int) -> None:
    import json
    import socket

    path.write_text(
        json.dumps(
            {
                "pid": pid,
                "host": socket.gethostname(),
                "command": "mbsim run",
                "started": "2026-11-27T21:00:00+00:00",
            }
        )
    )


def _dead_pid() -> int:
    import subprocess
    import sys

    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_a_second_run_to_an_output_in_use_is_refused(tmp_path):
    out = tmp_path / "r.h5"
    _plant_lock(tmp_path / "r.h5.lock", os.getpid())  # a live holder
    res = cli("run", SLIDER, "--mode", "kinematic", "--t-end", "0.01", "-o", out)
    one_error(
        res,
        2,
        f"output {out} is in use",
        f"process {os.getpid()}",
        "mbsim run",
        f"delete {out}.lock",
    )
    assert not out.exists() and (tmp_path / "r.h5.lock").exists()


def test_a_stale_lock_of_a_dead_process_is_taken_over_with_a_warning(tmp_path):
    out = tmp_path / "r.h5"
    dead = _dead_pid()
    _plant_lock(tmp_path / "r.h5.lock", dead)
    res = cli("run", SLIDER, "--mode", "kinematic", "--t-end", "0.01", "-o", out)
    assert res.exit_code == 0, res.output
    warnings = [ln for ln in res.stderr.splitlines() if ln.startswith("warning:")]
    assert (
        len(warnings) == 1 and f"process {dead}" in warnings[0] and "no longer runs" in warnings[0]
    )
    assert out.is_file() and not (tmp_path / "r.h5.lock").exists()


def test_the_lock_is_released_after_an_error(tmp_path):
    out = tmp_path / "r.h5"
    res = cli(
        "run",
        SLIDER,
        "--mode",
        "kinematic",
        "--set",
        "parameters.ell=0.2362",
        "--t-end",
        "0.15",
        "-o",
        out,
    )  # locks up near t = 0.11 s: exit 1, data kept
    assert res.exit_code == 1, res.output
    assert out.is_file() and not (tmp_path / "r.h5.lock").exists()


def test_two_processes_writing_one_output(tmp_path):
    """A long run holds its -o; a second run to it is refused naming the first one's pid;
    SIGTERM ends the first (its outputs kept) and releases the lock."""
    import signal
    import subprocess
    import sys
    import threading
    import time

    out, lock = tmp_path / "r.h5", tmp_path / "r.h5.lock"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    first = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "mbsim",
            "-v",  # logs "assembly at t = ..." once the analysis runs
            "run",
            str(SLIDER),
            "-m",
            "kinematic",
            "--t-end",
            "500",
            "--step",
            "0.001",
            "-o",
            str(out),
            "--no-progress",
        ],
        env=env,
        stderr=subprocess.PIPE,
        text=True,
    )
    lines, assembled = [], threading.Event()

    def read_stderr():  # the SIGTERM below must reach the analysis, not its start-up
        for line in first.stderr:
            lines.append(line)
            if "assembly at t =" in line:
                assembled.set()

    reader = threading.Thread(target=read_stderr, daemon=True)
    reader.start()
    try:
        end = time.monotonic() + 60
        while not lock.exists() and first.poll() is None and time.monotonic() < end:
            time.sleep(0.05)
        assert lock.exists(), "the first run did not take the lock"
        assert assembled.wait(60), "".join(lines)
        second = subprocess.run(
            [
                sys.executable,
                "-m",
                "mbsim",
                "run",
                str(SLIDER),
                "-m",
                "kinematic",
                "--t-end",
                "0.01",
                "-o",
                str(out),
            ],
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert second.returncode == 2, second.stderr
        assert f"process {first.pid} on host" in second.stderr and "Traceback" not in second.stderr
    finally:
        first.send_signal(signal.SIGTERM)
        first.wait(timeout=120)
        reader.join(timeout=10)
    assert first.returncode == 1, "".join(lines)  # interrupted, outputs kept
    assert out.is_file() and not lock.exists(), "".join(lines)


def test_an_interrupt_before_the_first_output_still_writes_the_file(tmp_path, monkeypatch):
    """Ctrl-C or SIGTERM (raised as KeyboardInterrupt by the run's handler) while the
    analysis assembles, before its output loop catches it: one error line, exit 1, and
    a file marked incomplete with no output time, the lock released."""
    import h5py

    import mbsim.analyses.kinematic as kinematic

    def interrupted_while_assembling(model, options):
        raise KeyboardInterrupt

    monkeypatch.setattr(kinematic, "kinematic", interrupted_while_assembling)
    out = tmp_path / "r.h5"
    res = cli("run", SLIDER, "-m", "kinematic", "-o", out, "--no-progress")
    one_error(res, 1, "interrupted", "no output reached", str(out))
    with h5py.File(out, "r") as f:
        assert f.attrs["status"] == "incomplete" and f["time"].shape == (0,)
    assert not (tmp_path / "r.h5.lock").exists()


def test_a_signal_while_the_results_are_written_waits_for_the_file(tmp_path, monkeypatch):
    """SIGTERM after the analysis has returned does not cut the file short: it is written
    whole (complete), then the run ends with one error line, exit 1."""
    import signal

    import h5py

    import mbsim.output

    write = mbsim.output.write_result

    def terminated_while_writing(result, path):
        # the run's own handler must be in place, else the signal would end pytest
        assert callable(signal.getsignal(signal.SIGTERM))
        os.kill(os.getpid(), signal.SIGTERM)
        return write(result, path)

    monkeypatch.setattr(mbsim.output, "write_result", terminated_while_writing)
    out = tmp_path / "r.h5"
    res = cli("run", SLIDER, "-m", "kinematic", "--t-end", "0.05", "-o", out, "--no-progress")
    one_error(res, 1, "interrupted", "results are kept in", str(out))
    with h5py.File(out, "r") as f:
        assert f.attrs["status"] == "complete" and f["time"].shape[0] > 1


def test_a_second_sweep_into_a_folder_in_use_is_refused(tmp_path):
    out = tmp_path / "sw"
    out.mkdir()
    _plant_lock(out / "sweep.lock", os.getpid())
    res = small_sweep(out)
    one_error(res, 2, f"sweep folder {out} is in use", f"process {os.getpid()}")
    assert not list(out.glob("*.h5"))
    _plant_lock(out / "sweep.lock", _dead_pid())
    res = small_sweep(out)
    assert res.exit_code == 0, res.output
    assert "no longer runs" in res.stderr
    assert len(list(out.glob("ell=*.h5"))) == 2 and not (out / "sweep.lock").exists()


def test_sweep_whose_folder_fills_before_the_cases_run_ends_in_one_line(tmp_path, monkeypatch):
    """The spool folder of the workers' results cannot be made (ENOSPC): one error line,
    exit 1, nothing half-written left as a result."""
    import mbsim.batch

    def full(*a, **k):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), "spool")

    monkeypatch.setattr(mbsim.batch.tempfile, "TemporaryDirectory", full)
    out = tmp_path / "sw"
    res = small_sweep(out)
    one_error(res, 1, f"sweep into {out} stopped after 0 of 2 case(s)", os.strerror(errno.ENOSPC))
    assert not list(out.glob("ell=*.h5")) and not (out / "sweep.lock").exists()
    assert [r["status"] for r in read_index(out / "index.csv")] == ["cancelled"] * 2


def test_sweep_into_a_folder_that_cannot_be_made_runs_nothing(tmp_path, monkeypatch):
    real_mkdir = Path.mkdir

    def read_only(self, *a, **k):
        if self.name == "sw":
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(self))
        return real_mkdir(self, *a, **k)

    monkeypatch.setattr(Path, "mkdir", read_only)
    out = tmp_path / "sw"
    res = small_sweep(out)
    one_error(res, 2, f"output folder {out}", os.strerror(errno.EROFS))
