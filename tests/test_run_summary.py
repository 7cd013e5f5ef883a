"""`mbsim run`'s summary: findings rounded to SUMMARY_DIGITS significant digits; internals
(solver switches, None, empty lists, counters that stayed 0) only with -v (issue 26)."""

import re
from pathlib import Path

from click.testing import CliRunner

from mbsim.cli import main

GOVERNOR = Path(__file__).resolve().parents[1] / "models" / "governor.yaml"


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def test_summary_is_rounded_and_hides_internals(tmp_path):
    res = run("run", GOVERNOR, "--mode", "dynamic", "--t-end", "0.1", "-o", tmp_path / "g.h5")
    assert res.exit_code == 0, res.output
    lines = res.output.splitlines()
    for hidden in ("h: None", "sparse:", "row_changes", "equations:", "formulation:",
                   "t_reached:", "redundant: []"):
        assert not any(hidden in line for line in lines), hidden
    cpu = next(line for line in lines if line.strip().startswith("cpu:"))
    assert re.fullmatch(r"\s*cpu: [0-9.e+-]+", cpu)
    assert len(re.sub(r"[^0-9]", "", cpu.split(":")[1].split("e")[0]).lstrip("0")) <= 4
    counters = lines[-1]
    assert "steps" in counters and not re.search(r"\b\w+ 0(,|$)", counters)


def test_verbose_summary_shows_everything(tmp_path):
    res = run("-v", "run", GOVERNOR, "--mode", "dynamic", "--t-end", "0.1", "-o",
              tmp_path / "g.h5")
    assert res.exit_code == 0, res.output
    assert "sparse: False" in res.output and "rejected_steps 0" in res.output


def test_value_text_rounds_numbers_in_lists_and_complex():
    from mbsim.cli import _value_text

    assert _value_text(0.018695745999999902) == "0.0187"
    assert _value_text([-0.47684712345, 6.537881234]) == "[-0.4768, 6.538]"
    assert _value_text(complex(-0.476847123, 6.53788123)) == "-0.4768+6.538j"
    assert _value_text(list(range(20))) == "[20 values]"
    assert _value_text(True) == "True" and _value_text(3) == "3"
