"""mbsim sweep: cases, parallel runs, index, resuming, failures, interrupts, Dask, summaries."""

import csv
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from mbsim.cli import main
from mbsim.output import compare_results, read_result
from mbsim.sweep import (
    SUMMARIES,
    SweepError,
    make_cases,
    parse_param,
    parse_summary,
    plan_sweep,
    read_index,
    run_sweep,
    settle_time,
    split_values,
)

MODELS = Path(__file__).resolve().parents[1] / "models"
SLIDER = MODELS / "slider_crank.yaml"
T_END = "0.1"  # 21 outputs at the deck's 0.005 s step: fast, and the slider moves
ELLS = ("0.3", "0.27", "0.24")
SUMS = ("bodies.slider.r.x:final", "bodies.slider.r.x:min", "bodies.slider.r.x:max",
        "bodies.slider.r.x:mean", "bodies.slider.r.x:peak", "bodies.slider.r.x:settle_time")


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def sweep_args(out, ells=ELLS, *extra):
    args = ["sweep", SLIDER, "--mode", "kinematic", "--param", "ell=" + ",".join(ells),
            "--t-end", T_END, "-j", "2", "-o", out]
    for s in SUMS:
        args += ["--summary", s]
    return args + list(extra)


@pytest.fixture(scope="module")
def base_sweep(tmp_path_factory):
    """The 3-case slider-crank sweep, run once on 2 processes; tests copy the folder."""
    out = tmp_path_factory.mktemp("sweep") / "sc"
    r = invoke(*sweep_args(out))
    assert r.exit_code == 0, r.output
    return out, r.output


def copy_of(base_sweep, tmp_path):
    out = tmp_path / "sc"
    shutil.copytree(base_sweep[0], out)
    return out


# --------------------------------------------------------------------------- the sweep


def test_sweep_writes_case_files_and_index(base_sweep):
    out, output = base_sweep
    names = [f"ell={e}" for e in ELLS]
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [f"{n}.h5" for n in names] + ["index.csv", "index.h5"])
    assert output.count(": complete, wall") == 3 and "3 complete" in output
    rows = read_index(out / "index.csv")
    assert [r["case"] for r in rows] == names and [r["ell"] for r in rows] == list(ELLS)
    assert all(r["status"] == "complete" and r["skipped"] == "no" for r in rows)
    assert list(rows[0]) == ["case", "ell", "status", "skipped", "message", "wall_s", "file",
                             *SUMS]
    h5rows = read_index(out / "index.h5")
    assert [r["ell"] for r in h5rows] == [0.3, 0.27, 0.24]  # numbers in HDF5
    for r, h in zip(rows, h5rows):
        assert h["file"] == r["file"] == f"{r['case']}.h5" and h["skipped"] is False
        for s in SUMS:  # CSV holds repr(float): the same float64 as the HDF5 index
            assert float(r[s]) == h[s]
    with h5py.File(out / "index.h5") as f:
        assert f.attrs["mode"] == "kinematic" and "ell" in f.attrs["params"]


def test_summaries_match_single_runs(base_sweep, tmp_path):
    """Each case equals `mbsim run --set parameters.ell=...` exactly, and its summaries are
    the SUMMARIES functions of that run's channel."""
    out = base_sweep[0]
    rows = {r["ell"]: r for r in read_index(out / "index.h5")}
    for ell in ("0.27", "0.24"):
        single = tmp_path / f"single_{ell}.h5"
        r = invoke("run", SLIDER, "--mode", "kinematic", "--t-end", T_END, "--set",
                   f"parameters.ell={ell}", "-o", single, "-q")
        assert r.exit_code == 0, r.output
        a, b = read_result(out / f"ell={ell}.h5"), read_result(single)
        ok, diffs, problems = compare_results(a, b, rtol=0, atol=0)
        assert ok and not problems and len(diffs) == len(b.channels)
        x = b.channel("bodies/slider/r").data[:, 0]
        row = rows[float(ell)]
        for s in SUMS:
            name = s.rpartition(":")[2]
            assert row[s] == SUMMARIES[name](b.t, x), s
        assert row["bodies.slider.r.x:final"] == x[-1]
        assert row["bodies.slider.r.x:peak"] == np.abs(x).max()
        assert a.settings["overrides"] == {"parameters.ell": ell}


def test_resume_runs_only_missing_or_incomplete_cases(base_sweep, tmp_path):
    """A sweep killed part-way: one file missing, one marked incomplete. Running the same
    command again runs those two only; the third file is not touched."""
    out = copy_of(base_sweep, tmp_path)
    (out / "ell=0.27.h5").unlink()
    with h5py.File(out / "ell=0.24.h5", "r+") as f:
        f.attrs["status"] = "incomplete"
    kept = out / "ell=0.3.h5"
    mtime = kept.stat().st_mtime_ns
    r = invoke(*sweep_args(out))
    assert r.exit_code == 0, r.output
    assert "ell=0.3: complete (kept: up to date)" in r.output
    assert r.output.count("(kept: up to date)") == 1
    rows = {r["case"]: r for r in read_index(out / "index.csv")}
    assert [rows[f"ell={e}"]["skipped"] for e in ELLS] == ["yes", "no", "no"]
    assert kept.stat().st_mtime_ns == mtime
    assert all(row["status"] == "complete" for row in rows.values())
    assert rows["ell=0.3"]["bodies.slider.r.x:final"] != ""  # summaries of a kept case too


def test_changed_options_rerun_the_cases(base_sweep, tmp_path):
    """A file made with another t_end (or deck, --set, scene) is not up to date."""
    out = copy_of(base_sweep, tmp_path)
    r = invoke("sweep", SLIDER, "--mode", "kinematic", "--param", "ell=0.3", "--t-end", "0.05",
               "-o", out, "-q")
    assert r.exit_code == 0, r.output
    assert read_index(out / "index.h5")[0]["skipped"] is False
    assert read_result(out / "ell=0.3.h5").t[-1] == 0.05


def test_failed_and_incomplete_cases_do_not_stop_the_others(tmp_path):
    """ell = 0.2362 m locks the slider-crank up near t = 0.11 s (incomplete, data kept);
    ell = abc is not a number (failed, no file); the others complete. Exit code 1."""
    out = tmp_path / "bad"
    r = invoke("sweep", SLIDER, "--mode", "kinematic", "--param", "ell=0.3,0.2362,abc",
               "--t-end", "0.15", "-o", out, "--summary", "bodies.slider.r.x:final")
    assert r.exit_code == 1, r.output
    rows = {r["ell"]: r for r in read_index(out / "index.csv")}
    assert rows["0.3"]["status"] == "complete" and rows["0.3"]["message"] == ""
    assert rows["0.2362"]["status"] == "incomplete" and "t = " in rows["0.2362"]["message"]
    assert rows["0.2362"]["file"] == "ell=0.2362.h5" and rows["0.2362"][
        "bodies.slider.r.x:final"] == ""  # no summaries of a partial run
    assert read_result(out / "ell=0.2362.h5").status == "incomplete"
    assert rows["abc"]["status"] == "failed" and rows["abc"]["file"] == ""
    assert "parameters.ell" in rows["abc"]["message"] and not (out / "ell=abc.h5").exists()
    assert "2 of 3 case(s) not complete" in r.output


def test_interrupt_keeps_finished_cases_and_writes_index(tmp_path):
    """Ctrl-C (a KeyboardInterrupt in this process) after the first finished case: pending
    cases are cancelled, the finished ones kept, the index lists both; a re-run completes."""
    params = [parse_param("ell=0.3,0.29,0.28,0.27")]
    plan = plan_sweep(SLIDER, "kinematic", params, tmp_path / "int", options={"t_end": 0.05})
    seen = []

    def ctrl_c(record):
        seen.append(record)
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_sweep(plan, on_case=ctrl_c, jobs=1)
    rows = read_index(tmp_path / "int" / "index.h5")
    done = [r for r in rows if r["status"] == "complete"]
    assert [r["case"] for r in done] == [seen[0].case.name]
    assert all(r["status"] == "cancelled" and r["file"] == "" for r in rows if r not in done)
    assert sorted(p.name for p in (tmp_path / "int").iterdir()) == sorted(
        [done[0]["file"], "index.csv", "index.h5"])  # no temporary files left
    outcome = run_sweep(plan, jobs=2)
    assert outcome.ok and sum(r.skipped for r in outcome.records) == 1


# --------------------------------------------------------------------------- usage errors


@pytest.mark.parametrize("args, says", [
    (["--param", "elll=0.3,0.27"], "did you mean parameters.ell"),
    (["--param", "ell=0.3", "--param", "omega=1,2", "--zip"], "--zip needs lists of equal"),
    (["--param", "ell"], "expected NAME=V1,V2"),
    (["--param", "ell=0.3", "--summary", "bodies.slider.r.x:median"], "unknown summary"),
    (["--param", "ell=0.3", "--set", "parameters.ell=0.27"], "both --set and --param"),
    (["--param", "ell=0.3", "--scene", "nope"], "unknown scene"),
])
def test_usage_errors_exit_2_before_running(tmp_path, args, says):
    out = tmp_path / "u"
    r = invoke("sweep", SLIDER, "--mode", "kinematic", "--t-end", "0.02", "-o", out, *args)
    assert r.exit_code == 2, r.output
    assert says in r.output and "Traceback" not in r.output
    assert not any(out.glob("*.h5"))


def test_unreachable_scheduler_is_a_usage_error(tmp_path, monkeypatch):
    pytest.importorskip("distributed")
    monkeypatch.setattr("mbsim.sweep.CONNECT_TIMEOUT", 1.0)
    r = invoke("sweep", SLIDER, "--mode", "kinematic", "--param", "ell=0.3", "-o",
               tmp_path / "u", "--scheduler", "tcp://127.0.0.1:9")  # discard port: nobody
    assert r.exit_code == 2 and "--scheduler tcp://127.0.0.1:9: cannot connect" in r.output


def test_scheduler_without_dask_says_what_to_install(tmp_path, monkeypatch):
    monkeypatch.setitem(__import__("sys").modules, "distributed", None)  # import fails
    r = invoke("sweep", SLIDER, "--mode", "kinematic", "--param", "ell=0.3", "-o",
               tmp_path / "u", "--scheduler", "tcp://127.0.0.1:8786")
    assert r.exit_code == 2 and "pip install 'mbsim[cluster]'" in r.output


def test_unknown_summary_channel_is_a_usage_error_after_the_runs(tmp_path):
    r = invoke("sweep", SLIDER, "--mode", "kinematic", "--t-end", "0.02", "-o", tmp_path / "s",
               "--param", "ell=0.3", "--summary", "bodies.slider.rr.x:final",
               "--summary", "bodies.slider.r:final")
    assert r.exit_code == 2, r.output
    assert "warning: --summary bodies.slider.rr.x:final" in r.output
    assert "name one: bodies.slider.r.x, bodies.slider.r.y, bodies.slider.r.z" in r.output
    row = read_index(tmp_path / "s" / "index.csv")[0]
    assert row["status"] == "complete" and "--summary" in row["message"]


# --------------------------------------------------------------------------- cases, summaries


def test_cases_product_zip_and_names():
    k, c = parse_param("k=1000,2000"), parse_param("forces.spring.c=10, 20")
    assert (k.path, c.path, c.values) == ("parameters.k", "forces.spring.c", ("10", "20"))
    prod = make_cases([k, c])
    assert [x.name for x in prod] == ["k=1000_forces.spring.c=10", "k=1000_forces.spring.c=20",
                                      "k=2000_forces.spring.c=10", "k=2000_forces.spring.c=20"]
    assert prod[1].overrides == {"parameters.k": "1000", "forces.spring.c": "20"}
    assert [x.name for x in make_cases([k, c], zip_=True)] == [
        "k=1000_forces.spring.c=10", "k=2000_forces.spring.c=20"]
    odd = make_cases([parse_param("bodies.crank.r=[0, 0.1, 0.12],'30 deg'")])
    assert [x.name for x in odd] == ["bodies.crank.r=0-0.1-0.12", "bodies.crank.r=30-deg"]
    assert split_values("1,[2, 3],'a,b', {x: 1, y: 2}") == ["1", "[2, 3]", "'a,b'",
                                                           "{x: 1, y: 2}"]
    with pytest.raises(SweepError, match="same file name"):
        make_cases([parse_param("p='a b',a/b")])
    with pytest.raises(SweepError, match="given twice"):
        make_cases([k, parse_param("parameters.k=1")])
    assert parse_summary("bodies/collar/r/y:settle_time").column == "bodies.collar.r.y:settle_time"


def test_settle_time_of_a_first_order_response():
    """x = 1 - exp(-t/tau) enters the 2 % band around its final value x_f = 1 - exp(-T/tau)
    when exp(-t/tau) - exp(-T/tau) = 0.02 x_f: t = -tau ln(0.02 + 0.98 exp(-T/tau)),
    about 3.9 tau (the textbook '4 time constants' of the 2 % criterion)."""
    tau, T = 0.5, 10.0
    t = np.linspace(0.0, T, 20001)
    x = 1 - np.exp(-t / tau)
    exact = -tau * np.log(0.02 + 0.98 * np.exp(-T / tau))
    assert abs(settle_time(t, x) - exact) < 1e-6  # linear interpolation, step 5e-4
    assert settle_time(t, 3 + 0 * t) == 0.0  # never outside: settled from the start
    y = np.where(t < 2, 1.0, 0.0)  # final value 0: band 2 % of max |x|, leaves at t = 2
    assert 1.9995 <= settle_time(t, y) <= 2.0
    # a damped oscillation about 2: the last exit from the band is a peak near the end
    z = 2 + np.exp(-t) * np.cos(10 * t)
    ts = settle_time(t, z)
    assert np.all(np.abs(z[t > ts + 1e-3] - z[-1]) <= 0.02 * abs(z[-1]))
    assert np.abs(z[(t < ts) & (t > ts - 0.1)] - z[-1]).max() > 0.02 * abs(z[-1]) * 0.99


# --------------------------------------------------------------------------- Dask


def test_dask_cluster_gives_identical_results(base_sweep, tmp_path):
    """The same sweep on a local Dask cluster (loopback only) writes the same numbers."""
    distributed = pytest.importorskip("distributed")
    out = tmp_path / "dask"
    with distributed.LocalCluster(n_workers=2, processes=True, threads_per_worker=1,
                                  host="127.0.0.1", dashboard_address=None) as cluster:
        r = invoke(*sweep_args(out, ELLS, "--scheduler", cluster.scheduler_address))
    assert r.exit_code == 0, r.output
    local = {r["case"]: r for r in read_index(base_sweep[0] / "index.h5")}
    for row in read_index(out / "index.h5"):
        ref = local[row["case"]]
        assert row["status"] == ref["status"] == "complete"
        assert all(row[s] == ref[s] for s in SUMS)
        a, b = read_result(out / row["file"]), read_result(base_sweep[0] / ref["file"])
        ok, diffs, problems = compare_results(a, b, rtol=0, atol=0)
        assert ok and not problems and diffs


# --------------------------------------------------------------------------- governor


@pytest.mark.slow
def test_governor_spring_rate_sweep(tmp_path):
    """The governor study (Haug Sec. 12.6, models 1-3: k = 1000, 2000, 3000 N/m) on two
    processes, with the collar's transition time and the final spindle speed per case."""
    out = tmp_path / "gov"
    r = invoke("sweep", MODELS / "governor.yaml", "--mode", "dynamic", "--param",
               "k=1000,2000,3000", "-j", "2", "-o", out,
               "--summary", "bodies.spindle.omega.y:final",
               "--summary", "bodies.collar.r.y:settle_time")
    if r.exit_code == 2 and "not available" in r.output:
        pytest.skip("dynamic mode not available")
    assert r.exit_code == 0, r.output
    rows = read_index(out / "index.h5")
    assert [row["k"] for row in rows] == [1000.0, 2000.0, 3000.0]
    for row in rows:
        assert row["status"] == "complete"
        assert np.isfinite(row["bodies.spindle.omega.y:final"])
        t_end = read_result(out / row["file"]).t[-1]
        assert 0.0 <= row["bodies.collar.r.y:settle_time"] <= t_end
    with open(out / "index.csv", newline="") as fh:
        assert "bodies.collar.r.y:settle_time" in next(csv.reader(fh))
