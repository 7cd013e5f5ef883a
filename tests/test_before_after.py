"""benchmarks/before_after.py's table on canned script output (no script is run, nothing is
timed): the figure-line convention of benchmarks/common.py read back, rounds merged, and
the markdown table with both sides, failures and figures printed on one side only."""

import importlib.util
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.fixture(scope="module")
def harness():
    sys.path.insert(0, str(BENCH))
    try:
        spec = importlib.util.spec_from_file_location("before_after", BENCH / "before_after.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        yield mod
    finally:
        sys.path.remove(str(BENCH))


BEFORE = """\
peers: cases startup; medians of 5
    mbsim --help                          wall 0.412 s [0.401-0.430]
figure: mbsim --help wall = 0.412 s (median of 5, spread 0.401..0.43)
figure: chain N = 4096, 2-step run and file: wall = failed (exit 1: error: cannot write \
the results: object header message is too large)
figure: compiled share of a default governor run (cProfile) = 16 % (median of 3, spread 15..17)
figure: only before = 1 x (median of 1, spread 1..1)
not a figure: = 3 s
"""

AFTER = """\
figure: mbsim --help wall = 0.206 s (median of 5, spread 0.2..0.25)
figure: chain N = 4096, 2-step run and file: wall = 41.5 s (median of 1, spread 41.5..41.5)
figure: compiled share of a default governor run (cProfile) = 64 % (median of 3, spread 60..70)
figure: only after = 2 x (median of 1, spread 2..2)
"""


def test_figure_line_reads_back_what_it_prints(harness):
    from common import figure_line, parse_figure

    fig = parse_figure(figure_line("chain N = 64: CPU per step", [3.0, 1.0, 2.0],
                                   "ms CPU per simulated s"))
    assert fig == {"name": "chain N = 64: CPU per step", "value": 2.0,
                   "unit": "ms CPU per simulated s", "n": 3, "lo": 1.0, "hi": 3.0}
    derived = parse_figure(figure_line("ratio", [0, 0, 0], "x", spread=(12.5, 10.0, 15.0)))
    assert (derived["value"], derived["lo"], derived["hi"], derived["n"]) == (12.5, 10, 15, 3)
    assert parse_figure("figure: x = failed (timed out after 900 s)") == {
        "name": "x", "error": "timed out after 900 s"}
    assert parse_figure("    mbsim --help wall 0.412 s") is None


def test_collect_keeps_figures_and_skips_commentary(harness):
    got = harness.collect(BEFORE)
    assert list(got) == ["mbsim --help wall", "chain N = 4096, 2-step run and file: wall",
                         "compiled share of a default governor run (cProfile)", "only before"]
    assert got["mbsim --help wall"]["value"] == pytest.approx(0.412)
    assert "object header message is too large" in got[
        "chain N = 4096, 2-step run and file: wall"]["error"]


def test_table_has_both_sides_ratio_failures_and_one_sided_figures(harness):
    table = harness.format_table(harness.collect(BEFORE), harness.collect(AFTER),
                                 ("before aeac177", "after 1234abc"))
    lines = table.splitlines()
    assert lines[0] == "| figure | unit | before aeac177 | after 1234abc | after / before |"
    assert lines[1] == "|---|---|---|---|---|"
    cells = [[c.strip() for c in ln.split("|")[1:-1]] for ln in lines[2:]]
    rows = {c[0]: c for c in cells}
    assert rows["mbsim --help wall"] == ["mbsim --help wall", "s", "0.412 [0.401..0.43]",
                                         "0.206 [0.2..0.25]", "0.5"]
    failed = rows["chain N = 4096, 2-step run and file: wall"]
    assert failed[2].startswith("failed (exit 1: error: cannot write")
    assert failed[3] == "41.5 [41.5..41.5]" and failed[4] == ""
    assert rows["compiled share of a default governor run (cProfile)"][4] == "4"
    assert rows["only before"][3] == "not printed"
    assert rows["only after"][2] == "not printed"
    assert len(rows) == 5


def test_rounds_merge_to_median_of_medians_and_whole_spread(harness):
    rounds = [{"name": "f", "value": v, "unit": "s", "n": 3, "lo": v - 1, "hi": v + 1}
              for v in (5.0, 3.0, 4.0)]
    merged = harness.merge_rounds(rounds)
    assert (merged["value"], merged["lo"], merged["hi"], merged["n"]) == (4.0, 2.0, 6.0, 9)
    failed = {"name": "f", "error": "timed out"}
    assert harness.merge_rounds([failed, rounds[0]]) == rounds[0]
    assert harness.merge_rounds([failed]) == failed


def test_a_pipe_in_an_error_does_not_break_the_table(harness):
    table = harness.format_table({"f": {"name": "f", "error": "exit 1: a | b"}}, {})
    assert table.splitlines()[2].count(" | ") == 4
