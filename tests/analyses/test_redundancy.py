"""Redundant constraints: dropped only when consistent (a warning), named when they conflict.

The decks: the slider-crank of models/ with a second driver `push` on its slider
(translation driver on joint T), and a planar four-bar built from four spatial revolute
joints (tests/analyses/data/planar_fourbar.yaml: three consistently redundant rows).
The CLI runs in a subprocess so that standard error is read as a user sees it.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml

from mbsim.analyses import redundancy
from mbsim.api import load_model
from mbsim.errors import ModelError
from mbsim.output import read_result

ROOT = Path(__file__).resolve().parents[2]
DATA = Path(__file__).resolve().parent / "data"
FOURBAR = DATA / "planar_fourbar.yaml"

# the slider's position where the crank (driver angle pi/2 + omega t) puts it: the rod of
# length ell joins the crank pin B = A + 0.08 (0, cos phi, sin phi), A = (0, 0.1, 0.12), to
# the slider point C = (x, 0, 0) (models/slider_crank.yaml's header).  The translation
# driver on T = [slider, ground] measures f_slider . (P_ground - P_slider) = -x.
SLIDER_X = ("sqrt(ell**2 - (0.1 + 0.08*cos(pi/2 + omega*t))**2"
            " - (0.12 + 0.08*sin(pi/2 + omega*t))**2)")
PUSH = f"-{SLIDER_X}"


def mbsim(*args):
    return subprocess.run([sys.executable, "-m", "mbsim", *map(str, args)],
                          capture_output=True, text=True, cwd=ROOT, timeout=300)


def slider_crank_with_push(tmp_path, function, name="deck.yaml"):
    deck = yaml.safe_load((ROOT / "models" / "slider_crank.yaml").read_text())
    for key in ("scenes", "studies"):
        deck.pop(key, None)
    deck["drivers"]["push"] = {"type": "translation", "joint": "T", "function": function}
    deck["analysis"] = {"kinematic": {"t_end": 0.3, "step": 0.005},
                        "inverse": {"t_end": 0.3, "step": 0.005},
                        "dynamic": {"t_end": 0.3, "step": 0.005}}
    path = tmp_path / name
    path.write_text(yaml.safe_dump(deck, sort_keys=False))
    return path


def errors(stderr):
    return [line for line in stderr.splitlines() if line.startswith("error:")]


@pytest.mark.parametrize("mode", ["kinematic", "inverse", "dynamic"])
def test_over_driven_crank_slider_is_refused_naming_both_drivers(tmp_path, mode):
    """Rotation driver on the crank and translation driver on the slider (DOF -1); both hold
    at t = 0 (the slider starts where the crank puts it), the slider's driven speed 0.01 m/s
    conflicts with the crank's: the deck's structure, exit 2, no results file."""
    deck = slider_crank_with_push(tmp_path, "-(xC + 0.01*t)")
    out = tmp_path / "out.h5"
    r = mbsim("run", deck, "--mode", mode, "-o", out)
    assert r.returncode == 2, r.stderr
    (line,) = errors(r.stderr)
    assert "drivers crank and push over-determine the mechanism (DOF -1)" in line
    assert "velocity level" in line
    assert "Traceback" not in r.stderr
    assert not out.exists()
    assert "complete" not in r.stdout


def test_conflict_appearing_part_way_keeps_the_consistent_outputs(tmp_path):
    """The push driver follows the crank exactly until t = 0.1 s, then moves the slider
    away from where the rod can hold it (0.5 (t - 0.1)^2 beyond): the run ends at the first
    output past 0.1 s, exit 1, the outputs before kept and marked incomplete."""
    deck = slider_crank_with_push(tmp_path, f"{PUSH} - 0.5*max(t - 0.1, 0)**2")
    out = tmp_path / "part.h5"
    r = mbsim("run", deck, "--mode", "kinematic", "-o", out)
    assert r.returncode == 1, r.stderr
    (line,) = errors(r.stderr)
    assert "t = 0.1 s" in line and "crank" in line and "push" in line
    with h5py.File(out) as f:
        assert f.attrs["status"] == "incomplete"
        t = f["time"][()]
        assert t[-1] == pytest.approx(0.095)
    x = read_result(out).channels["points/slider/position"].data[:, 0]
    # the kept outputs are right: the slider where the crank puts it (Newton tol 1e-10 on
    # Phi, Jacobian condition below 1e2 here: 1e-8 m)
    ell, omega = 0.3, -2 * np.pi
    phi = np.pi / 2 + omega * t
    exact = np.sqrt(ell**2 - (0.1 + 0.08 * np.cos(phi))**2 - (0.12 + 0.08 * np.sin(phi))**2)
    assert np.max(np.abs(x - exact)) < 1e-8


def test_consistent_over_driven_crank_slider_runs_with_one_warning(tmp_path):
    """The same two drivers, the slider's following the crank exactly: consistent, exit 0
    and exactly one warning line."""
    deck = slider_crank_with_push(tmp_path, PUSH)
    r = mbsim("run", deck, "--mode", "inverse", "-o", tmp_path / "c.h5")
    assert r.returncode == 0, r.stderr
    warnings = [line for line in r.stderr.splitlines() if line.startswith("warning:")]
    assert len(warnings) == 1 and "redundant constraints removed" in warnings[0]


@pytest.mark.parametrize("mode", ["kinematic", "inverse"])
def test_planar_fourbar_of_revolute_joints_one_warning_and_exact_motion(tmp_path, mode):
    """Four revolute joints with parallel axes: three dependent rows, consistent.  Exit 0,
    exactly one `warning:` line on stderr, every row (dropped ones included) held, and the
    rocker pin C where the closed-form four-bar puts it."""
    out = tmp_path / "pf.h5"
    r = mbsim("run", FOURBAR, "--mode", mode, "-o", out)
    assert r.returncode == 0, r.stderr
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("warning: redundant constraints removed")
    res = read_result(out)
    t, C = res.t, res.channels["points/C/position"].data
    # closed form: B on the crank circle, C on the circles of radius 3 about B and 2.5 about
    # D = (3.5, 0), the branch of the deck's estimates (above the line B-D)
    th = np.pi / 2 + 2 * t
    B = np.stack([np.cos(th), np.sin(th)], 1)
    D = np.array([3.5, 0.0])
    dist = np.linalg.norm(D - B, axis=1)
    u = (D - B) / dist[:, None]
    x = (3.0**2 - 2.5**2 + dist**2) / (2 * dist)
    h = np.sqrt(3.0**2 - x**2)
    exact = B + x[:, None] * u + h[:, None] * np.stack([-u[:, 1], u[:, 0]], 1)
    # Newton tol 1e-10 on Phi; the driven Jacobian's condition is below 1e2 on this path
    assert np.max(np.abs(C[:, :2] - exact)) < 1e-8
    assert np.max(np.abs(C[:, 2])) < 1e-10


def test_check_names_the_dependent_items_and_passes_consistent_rows():
    """redundancy.check on the four-bar at its assembled state: the dropped rows hold at
    every level; a velocity that breaks one of them is named with the joints involved."""
    from mbsim.analyses.assembly import assemble
    from tests.reference import equations as eq

    _, model = load_model(FOURBAR)
    asm = assemble(model)
    T = eq.constraints(model, asm.q, 0.0, nu=True)
    red, act = asm.redundant_rows, asm.active_rows
    assert red.size == 3
    qd = np.linalg.lstsq(T.jac[act], T.nu[act], rcond=None)[0]
    redundancy.check(model, T.jac, red, act, 0.0, phi=T.phi, qd=qd, nu=T.nu)
    # a velocity satisfying only the active rows but not the dropped one: a body spinning
    # out of the plane is no solution of the active rows, so take the active rows' nu
    # and move the dropped rows' right-hand side instead
    nu = T.nu.copy()
    nu[red[0]] += 1.0
    with pytest.raises(ModelError, match="velocity level") as info:
        redundancy.check(model, T.jac, red, act, 0.0, qd=qd, nu=nu)
    assert set(info.value.items) >= {model.items[model.row_item[red[0]]].name}


def test_a_row_dropped_with_no_row_left_names_its_own_item():
    """Phi_q of rank 0 (a deck whose estimates overflow, found by the fuzzer): every row is
    dropped and the dependency of each on the active rows is empty; the conflict names the
    row's own item instead of failing on the empty reduction."""
    _, model = load_model(str(Path(__file__).resolve().parents[2] / "models" / "four_bar.yaml"))
    red, act = np.arange(model.m), np.zeros(0, int)
    C = np.zeros((model.m, 0))
    assert redundancy.conflict_items(model, C, red, act, 0) == model.items_of_rows([0])


@pytest.mark.parametrize("cranks", [4, 41])
def test_redundant_loops_hanging_at_rest_start_without_a_conflict(cranks):
    """Parallel cranks on one coupler hanging at rest (the flat-free equilibrium theta =
    -pi/2, qd = 0): the dropped rows are consistent, so the initial state is found, with
    qdd = 0 up to the round-off of terms of the size of g (eps g cond(Phi_q): 2.2e-16 x
    9.81 x ~1e3 ~ 2e-12 m/s^2; bound 1e-9).  At rest qdd itself is that round-off, so the
    acceleration check's scale must be the size of the terms (gravity against the
    constraint forces), not |qdd| (which once refused this mechanism as conflicting)."""
    from mbsim.analyses.initial import initial_state
    from tests.integrators import models as M

    model = M.parallel_fourbar(cranks)
    q, qd, qdd, lam, info = initial_state(model)
    assert np.abs(qd).max() == 0.0
    assert np.abs(qdd).max() <= 1e-9
    assert np.abs(lam).max() > 1.0  # the constraint forces carry the weight

