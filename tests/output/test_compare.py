"""Regression comparison: the isclose criterion with b as reference, problems reported."""

from __future__ import annotations

import numpy as np
import pytest

from mbsim.output.compare import compare_files, compare_results, scaled_error
from mbsim.output.hdf5 import read_result, write_result
from mbsim.result import Result


def make_result(nt: int = 201) -> Result:
    t = np.linspace(0.0, 2.0, nt)
    r = Result(mode="dynamic", t=t)
    r.add(
        "bodies/crank/r",
        np.column_stack([np.cos(t), np.sin(t), 0 * t + 1]),
        "m",
        components=("x", "y", "z"),
    )
    r.add("drivers/crank/torque", 3.0 + np.sin(2 * t), "N m")
    return r


def test_identical_files_pass(tmp_path):
    pa = write_result(make_result(), tmp_path / "a.h5")
    pb = write_result(make_result(), tmp_path / "b.h5")
    ok, diffs, problems = compare_files(pa, pb, rtol=0.0, atol=0.0)
    assert ok and problems == []
    assert [d.scaled for d in diffs] == [0.0, 0.0]


def test_small_change_caught_by_rtol(tmp_path):
    b = make_result()
    a = make_result()
    a.channels["bodies/crank/r"].data[50, 1] *= 1 + 1e-6
    pa, pb = write_result(a, tmp_path / "a.h5"), write_result(b, tmp_path / "b.h5")
    ok, diffs, problems = compare_files(pa, pb, rtol=1e-9)
    assert not ok and problems == []
    worst = diffs[0]
    assert worst.channel == "bodies/crank/r" and worst.failed
    assert worst.index == (50, 1) and worst.time == pytest.approx(b.t[50])
    assert worst.scaled == pytest.approx(1e-6 / 1e-9, rel=1e-6)
    assert not diffs[1].failed  # the torque channel is identical
    ok, diffs, problems = compare_files(pa, pb, rtol=1e-3)
    assert ok and diffs[0].scaled == pytest.approx(1e-3, rel=1e-6)


def test_missing_channel_reported():
    a, b = make_result(), make_result()
    del a.channels["drivers/crank/torque"]
    b.add("joints/REV1/force", np.zeros((201, 3)), "N")
    ok, _, problems = compare_results(a, b)
    assert not ok
    assert any("drivers/crank/torque" in p and "missing in a" in p for p in problems)
    assert any("joints/REV1/force" in p and "missing in a" in p for p in problems)
    ok, _, problems = compare_results(a, b, channels=["bodies.crank.r"])
    assert ok and problems == []


def test_shape_and_time_problems():
    a, b = make_result(), make_result(nt=101)
    ok, _, problems = compare_results(a, b)
    assert not ok and any("time axes differ" in p for p in problems)
    # issue 13: different time axes are one problem line, not one per channel as well
    assert problems == ["time axes differ: 201 samples in a, 101 in b"], problems
    a, b = make_result(), make_result()
    b.channels["bodies/crank/r"].data = b.channels["bodies/crank/r"].data[:, :2]
    ok, _, problems = compare_results(a, b)
    assert not ok and any("shape" in p for p in problems)  # a real shape difference stays
    a, b = make_result(), make_result()
    a.t = a.t + 1e-3
    ok, _, problems = compare_results(a, b, rtol=1e-9)
    assert not ok and any("time axes differ" in p for p in problems)
    ok, _, problems = compare_results(a, b, atol=1e-2)
    assert ok, problems


def test_status_difference_is_a_problem():
    a, b = make_result(), make_result()
    a.status = "incomplete"
    ok, _, problems = compare_results(a, b)
    assert not ok and problems == ["status differs: a is 'incomplete', b is 'complete'"]


def test_scaled_error_rules():
    nan, inf = np.nan, np.inf
    a = np.array([1.0, nan, nan, 1.0, inf, 1.0, 0.0, 2.0])
    b = np.array([1.0, nan, 1.0, nan, inf, inf, 0.0, 1.0])
    diff, scaled = scaled_error(a, b, rtol=0.0, atol=0.0)
    np.testing.assert_array_equal(scaled, [0, 0, inf, inf, 0, inf, 0, inf])
    diff, scaled = scaled_error(a, b, rtol=0.5, atol=0.25)
    assert scaled[-1] == pytest.approx(1.0 / 0.75)
    assert np.all(np.isfinite(diff[[0, 1, 4, 6, 7]]))
    # numpy.isclose agreement on finite values (b the reference)
    rng = np.random.default_rng(1)
    x, y = rng.normal(size=1000), rng.normal(size=1000)
    y[::3] = x[::3] * (1 + 1e-7)
    _, scaled = scaled_error(x, y, rtol=1e-6, atol=1e-3)
    np.testing.assert_array_equal(scaled <= 1, np.isclose(x, y, rtol=1e-6, atol=1e-3))


def test_round_trip_compares_exactly(tmp_path):
    r = make_result()
    ok, _, problems = compare_results(read_result(write_result(r, tmp_path / "r.h5")), r, 0, 0)
    assert ok and problems == []


# --------------------------------------------------------------------------- mbsim compare


def compare_cli(*args):
    from click.testing import CliRunner

    from mbsim.cli import main

    return CliRunner().invoke(main, ["compare", *map(str, args)])


@pytest.fixture
def golden(tmp_path):
    """A reference file and an identical copy written separately."""
    return (write_result(make_result(), tmp_path / "golden.h5"),
            write_result(make_result(), tmp_path / "new.h5"))


def table_rows(output):
    """The rows of the differences table: [channel, time, A, B, |A-B|, scaled]."""
    lines = output.splitlines()
    start = next(i for i, line in enumerate(lines) if line.split()[:2] == ["channel", "time"])
    return [line.split() for line in lines[start + 1:] if line.split()[0] not in
            ("agree:", "DIFFER:")]


def test_cli_identical_files_exit_0(golden):
    new, ref = golden[1], golden[0]
    for tol in (["--rtol", "0", "--atol", "0"], []):  # exact, and the defaults
        r = compare_cli(new, ref, *tol)
        assert r.exit_code == 0, r.output
        assert r.output.splitlines()[-1].startswith("agree: 0 of 2 channels outside")


@pytest.mark.parametrize("change, where", [
    ("relative", (120, 1)),  # y of the crank at t = 1.2 s: 0.932 * (1 + 1e-6)
    ("absolute", (0, 1)),  # sin(0) = 0 + 1e-6: a change at a zero value
])
def test_cli_catches_a_1e_6_change_in_one_channel(golden, tmp_path, change, where):
    """One element of one channel changed by 1e-6 (relative, or absolute at zero): exit 1
    at the default tolerances (rtol 1e-9, atol 0), the table names that channel first with
    the time and both values; the other channel agrees. --rtol 1e-5 / --atol 1e-5 accept
    it; --channels limited to the other channel passes."""
    ref = golden[0]
    a = make_result()
    d = a.channels["bodies/crank/r"].data
    old = d[where]
    d[where] = old * (1 + 1e-6) if change == "relative" else old + 1e-6
    new = write_result(a, tmp_path / "changed.h5")
    r = compare_cli(new, ref)
    assert r.exit_code == 1, r.output
    assert r.output.splitlines()[-1].startswith("DIFFER: 1 of 2 channels outside rtol=1e-09")
    rows = table_rows(r.output)
    assert len(rows) == 1  # only the failing channel is listed
    chan, t, va, vb, err = rows[0][0], *map(float, rows[0][1:5])
    assert chan == "bodies.crank.r" and t == pytest.approx(a.t[where[0]], abs=1e-12)
    assert va == pytest.approx(d[where], abs=1e-7) and vb == pytest.approx(old, abs=1e-7)
    assert err == pytest.approx(abs(d[where] - old), rel=1e-3)  # the table's |A-B|, 3 digits
    loose = ["--rtol", "1e-5"] if change == "relative" else ["--atol", "1e-5"]
    assert compare_cli(new, ref, *loose).exit_code == 0
    assert compare_cli(new, ref, "--channels", "drivers.crank.torque").exit_code == 0
    assert compare_cli(new, ref, "--channels", "bodies.crank.r").exit_code == 1


def test_cli_structural_problems_exit_1(golden, tmp_path):
    a = make_result()
    del a.channels["drivers/crank/torque"]
    new = write_result(a, tmp_path / "fewer.h5")
    r = compare_cli(new, golden[0], "--rtol", "0", "--atol", "0")
    assert r.exit_code == 1
    assert "problem: channel 'drivers/crank/torque' missing in a" in r.output
    r = compare_cli(new, golden[0], "-n", "1")
    assert r.exit_code == 1 and len(table_rows(r.output)) == 1


def test_cli_bad_input_exit_2(golden, tmp_path):
    text = tmp_path / "not.h5"
    text.write_text("not HDF5")
    assert compare_cli(text, golden[0]).exit_code == 2
    assert compare_cli(golden[1], golden[0], "--rtol", "-1").exit_code == 2


# -- issue 26: defaults that find real differences ----------------------------------------------


def _cli(*args):
    from click.testing import CliRunner

    from mbsim.cli import main

    return CliRunner().invoke(main, [str(a) for a in args])


def test_default_atol_ignores_round_off_about_zero_and_finds_a_centimetre(tmp_path):
    """b: z = 0 exactly; a: z = 2e-21 (round-off) and the torque 0.01 N m off at one output.
    With atol 0 the round-off is the worst row (scaled ~1e12 x); with the default (rtol x the
    channel's range: 2e-9 m for r, which spans 2 m) it passes and the torque is found."""
    a, b = make_result(), make_result()
    b.channels["bodies/crank/r"].data[:, 2] = 0.0
    a.channels["bodies/crank/r"].data[:, 2] = 2e-21
    a.channels["drivers/crank/torque"].data[50] += 0.01
    ok, diffs, _ = compare_results(a, b, rtol=1e-9, atol=0.0)
    assert not ok and diffs[0].channel == "bodies/crank/r" and diffs[0].abs_err == 2e-21
    ok, diffs, _ = compare_results(a, b, rtol=1e-9, atol=None)
    assert not ok
    assert [d.channel for d in diffs if d.failed] == ["drivers/crank/torque"]
    assert diffs[0].abs_err == pytest.approx(0.01)
    pa, pb = write_result(a, tmp_path / "a.h5"), write_result(b, tmp_path / "b.h5")
    res = _cli("compare", pa, pb)
    assert res.exit_code == 1
    assert "drivers.crank.torque" in res.output.splitlines()[1]
    assert "DIFFER: 1 of 2 channels outside rtol=1e-09, atol=rtol x range" in res.output


def test_monitors_are_compared_only_when_asked(tmp_path):
    a, b = make_result(), make_result()
    for r, h in ((a, 1e-3), (b, 2e-3)):  # two tolerances: different steps, same motion
        r.add("monitors/step_size", np.full(len(r.t), h), "s")
    pa, pb = write_result(a, tmp_path / "a.h5"), write_result(b, tmp_path / "b.h5")
    res = _cli("compare", pa, pb)
    assert res.exit_code == 0 and "agree: 0 of 2 channels" in res.output
    res = _cli("compare", pa, pb, "--monitors")
    assert res.exit_code == 1 and "monitors.step_size" in res.output


def test_different_time_axes_are_refused_with_the_reason(tmp_path):
    pa = write_result(make_result(201), tmp_path / "a.h5")
    pb = write_result(make_result(401), tmp_path / "b.h5")
    res = _cli("compare", pa, pb)
    assert res.exit_code == 1
    assert "0 of 0" not in res.output
    assert ("DIFFER: time axes differ: 201 samples in a, 401 in b; run both with the same "
            "t_start, t_end and step") in res.output
