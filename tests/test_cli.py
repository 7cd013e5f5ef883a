"""The command line end to end: exit codes, one-line errors, files written."""

from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from mbsim.cli import main
from mbsim.output import list_channels

MODELS = Path(__file__).resolve().parents[1] / "models"


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def test_run_kinematic_writes_complete_results(tmp_path):
    out = tmp_path / "sc.h5"
    r = run("run", MODELS / "slider_crank.yaml", "--mode", "kinematic", "--t-end", "0.2",
            "-o", out, "--plot")
    assert r.exit_code == 0, r.output
    with h5py.File(out) as f:
        assert f.attrs["status"] == "complete"
        assert f.attrs["mode"] == "kinematic"
        assert f["time"].shape[0] == 41
        assert "slider-crank" in f["deck"][()].decode()
    assert dict((n, u) for n, _, u, _ in list_channels(out))["bodies/slider/r"] == "m"
    assert out.with_suffix(".png").stat().st_size > 1000


def test_output_template_and_set(tmp_path):
    r = run("run", MODELS / "slider_crank.yaml", "--mode", "kinematic", "--t-end", "0.05",
            "--set", "parameters.ell=0.27", "-o", str(tmp_path / "sc_{ell}.h5"), "-q")
    assert r.exit_code == 0, r.output
    assert (tmp_path / "sc_0.27.h5").exists()


def test_set_unknown_path_is_an_error(tmp_path):
    r = run("run", MODELS / "slider_crank.yaml", "--mode", "kinematic", "--set",
            "parameters.elll=0.27", "-o", tmp_path / "x.h5")
    assert r.exit_code == 2
    assert "parameters.ell" in r.output  # did-you-mean
    assert not (tmp_path / "x.h5").exists()


def test_kinematic_needs_dof_zero(tmp_path):
    r = run("run", MODELS / "governor.yaml", "--mode", "kinematic", "-o", tmp_path / "g.h5")
    assert r.exit_code == 2
    line = r.output.strip()
    assert "\n" not in line and "governor.yaml" in line and "DOF = 2" in line
    assert ": drivers: kinematic analysis needs DOF = 0" in line  # the key path of the cause


def test_bad_deck_one_line_error(tmp_path):
    deck = tmp_path / "bad.yaml"
    deck.write_text((MODELS / "slider_crank.yaml").read_text().replace(
        "crank: {P: [0.0, 0.08, 0.0]}", "crank: {P: [0.0, 0.08]}"))
    r = run("check", deck)
    assert r.exit_code == 2
    assert r.output.count("\n") == 1
    assert "bad.yaml" in r.output and "joints.B.points.crank.P" in r.output
    assert "Traceback" not in r.output


def test_singular_run_keeps_partial_results(tmp_path):
    """ell = 0.2362 m is the singular length 0.236205 rounded down: the run stops at the
    lock-up, names the joints and keeps the results up to there, marked incomplete."""
    out = tmp_path / "s.h5"
    r = run("run", MODELS / "slider_crank.yaml", "--mode", "kinematic", "--set",
            "parameters.ell=0.2362", "-o", out)
    assert r.exit_code == 1, r.output
    with h5py.File(out) as f:
        assert f.attrs["status"] == "incomplete"
        t = f["time"][()]
        assert 0.0 < t[-1] < 0.2
        msg = f.attrs["message"]
    assert "t = 0.11 s" in msg and "lock-up" in msg
    assert "lock-up" in r.output  # the one-line error says it too


def test_check_info_list(tmp_path):
    r = run("check", MODELS / "slider_crank.yaml")
    assert r.exit_code == 0 and "max |Phi|" in r.output
    r = run("info", MODELS / "slider_crank.yaml")
    assert r.exit_code == 0 and "DOF = 28 - 28 = 0" in r.output
    for what in ("joints", "drivers", "forces", "modes", "functions", "units", "integrators"):
        r = run("list", what)
        assert r.exit_code == 0, (what, r.output)
    assert "revolute" in run("list", "joints").output


def test_plot_compare_export(tmp_path):
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    for f in (a, b):
        assert run("run", MODELS / "slider_crank.yaml", "--mode", "kinematic", "--t-end", "0.1",
                   "-o", f, "-q").exit_code == 0
    r = run("plot", a, "-y", "bodies.slider.r.x", "-o", tmp_path / "p.svg")
    assert r.exit_code == 0 and (tmp_path / "p.svg").exists()
    r = run("plot", a, "-y", "bodies.slider.nope", "-o", tmp_path / "p.png")
    assert r.exit_code == 2 and "did you mean" in r.output
    assert run("compare", a, b, "--rtol", "0", "--atol", "0").exit_code == 0
    with h5py.File(b, "r+") as f:  # one element of bodies/slider/r (layout: docs/hdf5.md)
        ch = f["channels"][()]
        k = list(ch["name"]).index(b"bodies/slider/r")
        col = ch["column"][k]
        f["values"][5, col] = f["values"][5, col] * (1 + 1e-6)
    r = run("compare", a, b, "--rtol", "1e-9")
    assert r.exit_code == 1 and "bodies.slider.r" in r.output
    r = run("export", a, "--csv", tmp_path / "a.csv", "--channels", "bodies.slider.r")
    assert r.exit_code == 0
    data = np.loadtxt(tmp_path / "a.csv", delimiter=",", skiprows=1)
    assert data.shape == (21, 4)
    (tmp_path / "a.csv").unlink()
    r = run("export", a, "--csv")  # the form: --csv alone writes a.csv beside a.h5
    assert r.exit_code == 0 and (tmp_path / "a.csv").exists()


@pytest.mark.parametrize("cmd", ["run", "info", "check"])
def test_missing_file(cmd, tmp_path):
    args = [cmd, tmp_path / "nope.yaml"] + (["--mode", "kinematic"] if cmd == "run" else [])
    r = run(*args)
    assert r.exit_code == 2 and "nope.yaml" in r.output
