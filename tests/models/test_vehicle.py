"""Vehicle deck (Haug Sec. 12.5, Tables 12.5.1-12.5.9; tires: mbsim/forces/tire.py).

Fast: the book's counts, assembly, the reinterpreted joints at Table 12.5.9, the static
equilibrium against Table 12.5.9.  Slow: lane changes, circle, settling.
"""

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from mbsim import equations as eq
from mbsim.analyses.assembly import assemble
from mbsim.api import load_model, run_model
from mbsim.cli import main

DECK = Path(__file__).resolve().parents[2] / "models" / "vehicle.yaml"
G = 9.81

# Table 12.5.9 (model 1): x, y, z of the centroids
TABLE_12_5_9 = {
    "chassis": (0.0, 0.0, 0.5385),
    "wheel_fr": (0.6014, 1.1761, 0.3449),
    "wheel_fl": (-0.5992, 1.1772, 0.3449),
    "wheel_rr": (0.5788, -1.2918, 0.2617),
    "wheel_rl": (-0.5812, -1.2907, 0.2617),
}


@pytest.mark.parametrize(("scene", "nc", "nh", "dof"), [(None, 56, 44, 12), ("model1", 42, 32, 10)])
def test_book_counts(scene, nc, nh, dof):
    """Model 2 as the book lists it: nc = 56, nh = 44, DOF = 12 (no ground body)."""
    args = ["info", str(DECK)] + (["--scene", scene] if scene else [])
    out = CliRunner().invoke(main, args)
    assert out.exit_code == 0, out.output
    assert f"nc = {nc}" in out.output and f"nh = {nh}" in out.output
    assert f"DOF = {nc} - {nh} = {dof}" in out.output
    assert f"Rank of Phi_q at the assembled configuration: {nh} of {nh}" in out.output


@pytest.mark.parametrize("scene", [None, "model1", "lane2", "circle", "settle", "table12_5_9"])
def test_scenes_assemble(scene):
    _, model = load_model(DECK, scene=scene)
    asm = assemble(model)
    assert asm.residual < 1e-10 and not asm.redundant_items


def test_table_corrections():
    spec, _ = load_model(DECK, scene="settle")
    assert spec.bodies["wheel_rl"].r[0] == pytest.approx(-0.58)  # Table 12.5.8 body 5
    assert spec.joints["I"].points["wheel_rl"].R[0] == pytest.approx(0.3774)  # Table 12.5.5


def test_reinterpreted_joints_keep_table_12_5_9():
    """At Table 12.5.9 (4-digit rounding) every constraint holds to ~1e-3, among them the
    rev-sph (chassis P moved along the arm axis, length 0.3227) and the strut (wheel-side
    axis toward the top mount). With the book's rev-sph data (P as printed, 0.203) the
    residuals would be 0.048 (f.d) and 0.065 (|d|^2 - C^2)."""
    _, model = load_model(DECK, scene="table12_5_9")
    phi = eq.phi(model, model.q0)
    worst = {it.name: float(np.abs(phi[it.rows]).max()) for it in model.items}
    for name in ("A-B", "E-F", "B-C", "F-G", "tie_fr", "tie_fl", "H", "I", "D"):
        assert worst[name] < 1.5e-3, (name, worst[name])


@pytest.fixture(scope="module")
def equilibrium_model1():
    _, model = load_model(DECK, scene="model1", overrides={"parameters.v0": "0"})
    res = run_model(model, "equilibrium", {"method": "minimum"})
    assert res.complete, res.message
    return model, res


def test_equilibrium_against_table_12_5_9(equilibrium_model1):
    """Wheels within 1 mm in height and 4 mm in plan; the chassis stands 7.5 mm higher and
    pitches 0.6 deg less nose-down than Table 12.5.9, which is not a static equilibrium of the
    tabulated springs (docs/models.md): both are stated there, so here they are bounds."""
    model, res = equilibrium_model1
    for name, table in TABLE_12_5_9.items():
        r = res.channel(f"bodies/{name}/r").data[-1]
        if name.startswith("wheel"):
            assert abs(r[2] - table[2]) < 1e-3, name
            assert np.abs(r[:2] - table[:2]).max() < 4e-3, name
    z = res.channel("bodies/chassis/r").data[-1, 2]
    assert 0.005 < z - 0.5385 < 0.010
    e1 = res.channel("bodies/chassis/p").data[-1, 1]
    assert e1 == pytest.approx(-0.00155, abs=2e-4)  # table: -0.0065


def test_tire_loads_carry_the_weight(equilibrium_model1):
    model, res = equilibrium_model1
    loads = [res.channel(f"forces/tire_{w}/F_ver").data[-1] for w in ("fr", "fl", "rr", "rl")]
    assert sum(loads) == pytest.approx(model.mass.sum() * G, rel=1e-6)
    assert loads[0] == pytest.approx(loads[1], rel=1e-3) and loads[2] == pytest.approx(
        loads[3], rel=1e-3
    )
    assert loads[0] == pytest.approx(3564.0, abs=5.0) and loads[2] == pytest.approx(3346.0, abs=5.0)


def test_initial_state_is_the_model_2_equilibrium():
    """The deck starts at this model's own equilibrium (rounded), so a straight run at 55 mph
    starts without a transient; the minimum-energy search moves no body more than 0.1 mm."""
    _, model = load_model(DECK, overrides={"parameters.v0": "0"})
    res = run_model(model, "equilibrium", {"method": "minimum"})
    r = np.array([res.channel(f"bodies/{b}/r").data[-1] for b in model.body_names])
    moved = np.abs(r - assemble(model).q.reshape(model.nb, 7)[:, :3]).max()
    assert moved < 1e-4


def angles(res):
    """(roll, yaw) of the chassis (rad): roll about its forward axis y', yaw about z."""
    from mbsim.rotations import A

    Am = A(res.channel("bodies/chassis/p").data)
    return -np.arcsin(Am[:, 2, 0]), np.arctan2(-Am[:, 0, 1], Am[:, 1, 1])


@pytest.fixture(scope="module")
def lane_changes():
    out = {}
    for scene in ("model1_lane1", "lane1", "model1_lane2", "lane2"):
        _, model = load_model(DECK, scene=scene)
        res = run_model(model, "dynamic", {})
        assert res.complete, res.message
        out[scene] = res
    return out


@pytest.mark.slow
def test_lane_change_is_3_6_m(lane_changes):
    for scene in ("model1_lane1", "model1_lane2"):
        x = lane_changes[scene].channel("bodies/chassis/r").data[:, 0]
        assert -x[-1] == pytest.approx(3.6, abs=0.1), scene


@pytest.mark.slow
@pytest.mark.parametrize("n", ["1", "2"])
def test_stabilizer_bars_reduce_peak_roll(lane_changes, n):
    roll1 = np.abs(angles(lane_changes[f"model1_lane{n}"])[0]).max()
    roll2 = np.abs(angles(lane_changes[f"lane{n}"])[0]).max()
    assert roll2 < 0.75 * roll1, (np.degrees(roll1), np.degrees(roll2))


@pytest.fixture(scope="module")
def circles():
    out = {}
    for mph in (20, 55):
        _, model = load_model(DECK, scene="circle", overrides={"parameters.v0": f"{mph} mph"})
        res = run_model(model, "dynamic", {})
        assert res.complete, res.message
        out[mph] = res
    return out


@pytest.mark.slow
def test_circle_55_mph_saturates_slides_and_slows(circles):
    res = circles[55]
    fl, fv = res.channel("forces/tire_fl/F_lat").data, res.channel("forces/tire_fl/F_ver").data
    sat = res.channel("forces/tire_fl/saturated").data > 0
    assert sat.mean() > 0.2
    assert np.allclose(np.abs(fl[sat]), 0.8 * fv[sat], rtol=1e-9)  # F_lat = mu F_ver
    v = np.linalg.norm(res.channel("bodies/chassis/rd").data[:, :2], axis=1)
    assert v[-1] < 0.5 * v[0]  # the speed drops markedly (lateral slip only dissipates)
    _, yaw = angles(res)
    vel = res.channel("bodies/chassis/rd").data
    drift = np.angle(np.exp(1j * (yaw - np.arctan2(-vel[:, 0], vel[:, 1]))))
    assert np.degrees(np.abs(drift).max()) > 20.0  # heading not tangent to the path


@pytest.mark.slow
def test_circle_20_mph_follows_the_steer(circles):
    res = circles[20]
    for w in ("fr", "fl", "rr", "rl"):
        assert res.channel(f"forces/tire_{w}/saturated").data.max() == 0.0, w
    v = np.linalg.norm(res.channel("bodies/chassis/rd").data[:, :2], axis=1)
    assert v[-1] > 0.9 * v[0]
    _, yaw = angles(res)
    vel = res.channel("bodies/chassis/rd").data
    drift = np.angle(np.exp(1j * (yaw - np.arctan2(-vel[:, 0], vel[:, 1]))))
    assert np.degrees(np.abs(drift).max()) < 3.0  # nearly tangent to the path
    # a circle of about the Ackermann radius (wheelbase 2.47 m / 4.7 deg steer = 31 m)
    w = np.gradient(yaw, res.t)[-100:]
    assert np.mean(v[-100:] / np.abs(w)) == pytest.approx(31.0, rel=0.1)


@pytest.mark.slow
def test_settling_from_table_12_5_8_reaches_the_equilibrium(equilibrium_model1):
    _, eq_res = equilibrium_model1
    _, model = load_model(DECK, scene="settle")
    res = run_model(model, "dynamic", {})
    assert res.complete, res.message
    z = res.channel("bodies/chassis/r").data[:, 2]
    assert z[-1] == pytest.approx(eq_res.channel("bodies/chassis/r").data[-1, 2], abs=1e-3)
