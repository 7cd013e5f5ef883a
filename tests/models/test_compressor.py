"""Air-compressor deck (Haug Sec. 12.4; geometry reconstructed, shared/reference/geometry.md §3).

Fast: counts, assembly, the force-law parameters, inverse dynamics at 600 rpm (30 deg).
Slow: the dynamics under the constant torque, the 40 deg and fifteen-body inverse runs.
"""

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from mbsim import equations as eq
from mbsim.analyses.assembly import assemble
from mbsim.api import load_model, run_model
from mbsim.cli import main

DECK = Path(__file__).resolve().parents[2] / "models" / "compressor.yaml"
PSI = 6894.757293168  # Pa


def inverse(scene="inverse", overrides=None, step=0.001):
    _, model = load_model(DECK, scene=scene, overrides=overrides)
    res = run_model(model, "inverse", {"step": step})
    assert res.complete, res.message
    return res


def mean_over_revolution(res, name):
    """Mean of a channel over [0, 0.1 s): one revolution at 20 pi rad/s, the end left out."""
    return float(np.mean(res.channel(name).data[:-1]))


@pytest.mark.parametrize(("scene", "nc", "nh"), [(None, 63, 62), ("model15", 105, 104)])
def test_counts_dof_and_rank(scene, nc, nh):
    """9 bodies: 6 + 5 + 5 + 1 + 6 x (5 + 1) + 9 = 62 equations; 15 bodies: rods with a
    spherical (3) and a universal (4) joint instead of a distance constraint (1)."""
    _, model = load_model(DECK, scene=scene)
    assert model.nq == nc and model.m == nh
    asm = assemble(model)
    assert asm.rank == nh and asm.dof == 1 and not asm.redundant_items
    assert asm.residual < 1e-10
    args = ["info", str(DECK)] + (["--scene", scene] if scene else [])
    out = CliRunner().invoke(main, args)
    assert out.exit_code == 0, out.output
    assert f"DOF = {nc} - {nh} = 1" in out.output


@pytest.mark.parametrize("scene", ["tilt40", "inverse", "model15", "dynamic30", "psi0"])
def test_scenes_assemble(scene):
    _, model = load_model(DECK, scene=scene)
    asm = assemble(model)
    assert asm.residual < 1e-10, scene
    if scene == "model15":  # the 30 deg rod estimates are within rounding of the assembly
        assert np.abs(asm.q - model.q0).max() < 1e-4


def test_initial_configuration_is_exact():
    """Piston heights are computed in the deck from |disk point - piston| = 1: the estimates
    already satisfy every constraint; piston 1 at y_A = -1.1 (reference §3.2)."""
    _, model = load_model(DECK)
    assert np.abs(eq.phi(model, model.q0)).max() < 1e-12
    b = model.body_index("piston1")
    assert model.q0[7 * b + 1] == pytest.approx(-1.1, abs=1e-12)


def test_force_law_parameters():
    """Reference §3.4: F_C = area x p_max, K = F_C/20, F_min = F_C/4; W = 1637.3 J per stroke,
    constant torque 6 W/(2 pi) = 1563.5 N m at 500 psi."""
    spec, _ = load_model(DECK)
    p = spec.parameters
    FC = np.pi * 0.1**2 / 4 * 500 * PSI
    assert p["FC"] == pytest.approx(FC, rel=1e-9)
    assert p["yC"] == pytest.approx(-1.06)
    assert p["K"] == pytest.approx(FC / 20, rel=1e-9)
    assert p["Fmin"] == pytest.approx(FC / 4, rel=1e-9)
    assert p["W"] == pytest.approx(1637.3, abs=0.1)
    assert p["torque0"] == pytest.approx(1563.5, abs=0.1)
    # W is the integral of the curve of Fig. 12.4.1 (both pieces) over the stroke
    y = np.linspace(-1.1, -0.9, 200001)
    with np.errstate(divide="ignore"):  # the hyperbola at y_A, on the branch not taken
        F = np.where(y < p["yC"], FC / 2 * (1 - np.cos(np.pi * (y + 1.1) / 0.04)),
                     p["K"] / (y + 1.1) - p["Fmin"])  # fmt: skip
    assert np.trapezoid(F, y) == pytest.approx(p["W"], rel=1e-8)


def test_inverse_500_psi_torque_averages_the_constant_torque():
    """Energy balance at constant speed: the mean driving torque over a revolution equals
    6 W/(2 pi) (the air's work per revolution over 2 pi)."""
    res = inverse()
    spec, _ = load_model(DECK)
    mean = mean_over_revolution(res, "drivers/drive/torque")
    assert mean == pytest.approx(spec.parameters["torque0"], rel=2e-3)
    y = res.channel("bodies/piston1/r").data[:, 1]
    assert y.min() == pytest.approx(-1.1, abs=1e-9) and y.max() == pytest.approx(-0.9, abs=1e-4)
    fx = res.channel("joints/ball/force_i").data[:, 0]
    assert np.all(np.isfinite(fx)) and np.ptp(fx) > 1000.0  # the x position constraint force


def test_inverse_0_psi_torque_is_inertial_and_averages_zero():
    """Without air the driving torque only accelerates the disk and pistons: it averages zero
    over a revolution (the kinetic energy is periodic)."""
    res = inverse()  # 500 psi, for the scale
    res0 = inverse(overrides=_psi0())
    T0 = res0.channel("drivers/drive/torque").data
    assert np.abs(T0).max() > 10.0  # inertial torque, tens of N m
    assert abs(mean_over_revolution(res0, "drivers/drive/torque")) < 1e-6 * np.abs(T0).max()
    assert np.abs(T0).max() < 0.1 * np.abs(res.channel("drivers/drive/torque").data).max()


def _psi0():
    out = {"parameters.pmax": "0 psi"}
    out.update({f"forces.air{k}.active": "false" for k in range(1, 7)})
    return out


def _model15():
    out = {
        f"{group}.{name}{k}.active": "true"
        for k in range(1, 7)
        for group, name in (("bodies", "rod"), ("joints", "ball"), ("joints", "pin"))
    }
    out.update({f"joints.rod{k}.active": "false" for k in range(1, 7)})
    return out


TILT40 = {"parameters.alpha": "40 deg", "parameters.yA": "-1.12836", "parameters.yB": "-0.87109"}


@pytest.mark.slow
@pytest.mark.parametrize("overrides", [TILT40, _model15()], ids=["tilt40", "model15"])
def test_other_inverse_runs(overrides):
    """40 deg (Figs. 12.4.4, 12.4.5): the torque still averages 6 W/(2 pi), the force law
    spanning the longer stroke; fifteen-body model (Project 12.2): the same mean (the rods'
    kinetic energy is periodic too), other peaks."""
    spec, _ = load_model(DECK, scene="inverse", overrides=overrides)
    res = inverse(overrides=overrides)
    mean = mean_over_revolution(res, "drivers/drive/torque")
    assert mean == pytest.approx(spec.parameters["torque0"], rel=2e-3)


def rotor_angle(res):
    w = res.channel("bodies/rotor/omega").data[:, 1]
    return w, np.concatenate([[0.0], np.cumsum((w[1:] + w[:-1]) / 2 * np.diff(res.t))])


@pytest.mark.slow
@pytest.mark.parametrize("omega0", [60.0, 70.0, 80.0])
def test_dynamics_periodic_from_60_to_80(omega0):
    """Constant torque = mean air torque (100 psi, see the deck): the motion is periodic, the
    rotor speed returns to omega0 after every revolution."""
    _, model = load_model(DECK, scene="dynamic60", overrides={"parameters.omega0": str(omega0)})
    res = run_model(model, "dynamic", {"t_end": 0.25})
    assert res.complete, res.message
    w, theta = rotor_angle(res)
    assert w.min() > 0.3 * omega0  # never near a stall
    assert theta[-1] > 2 * 2 * np.pi * 0.9  # about two revolutions or more
    for k in (1, 2):
        i = int(np.argmin(np.abs(theta - 2 * np.pi * k)))
        if abs(theta[i] - 2 * np.pi * k) < 0.05:
            assert w[i] == pytest.approx(omega0, rel=0.01)


@pytest.mark.slow
@pytest.mark.parametrize("scene", ["dynamic30", "dynamic60_psi500"])
def test_dynamics_stop_before_one_cycle(scene):
    """From 30 rad/s (and from 60 rad/s at 500 psi) the kinetic energy does not carry the
    rotor through the first compression: it stops before one revolution; the run ends at the
    stall (the valve law switches on the piston velocity's sign)."""
    _, model = load_model(DECK, scene=scene)
    res = run_model(model, "dynamic", {"t_end": 0.3})
    assert not res.complete and "h_min" in res.message
    w, theta = rotor_angle(res)
    assert theta[-1] < 2 * np.pi
    assert w[-1] < 0.05 * w[0]
