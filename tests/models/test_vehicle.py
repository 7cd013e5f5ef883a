"""Vehicle deck (Haug Sec. 12.5, Tables 12.5.1-12.5.9; tires: mbsim/forces/tire.py).

Fast: the book's counts, assembly, the reinterpreted joints at Table 12.5.9, the static
equilibrium against Table 12.5.9, the study ``settling`` (Figs. 12.5.4, 12.5.5).
Slow: the studies ``equilibrium``, ``lane_change`` (Figs. 12.5.7-12.5.10) and ``circle``
(Figs. 12.5.11-12.5.13), each run as ``mbsim study models/vehicle.yaml NAME`` runs it
(:func:`mbsim.study.run_study`), with the seed's statements and regression numbers.

Regression numbers were measured with this code (docs/gallery.md prints the same tables); the
tolerances of the dynamic ones come from rerunning each case at rtol 1e-5 (the deck: 1e-3).
"""

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from mbsim.analyses.assembly import assemble
from mbsim.api import load_model, run_model
from mbsim.cli import main
from mbsim.study import run_study
from tests.reference import equations as eq

DECK = Path(__file__).resolve().parents[2] / "models" / "vehicle.yaml"
G = 9.81


def study(factory, name):
    """Run a study as ``mbsim study`` does: every case complete, every figure written."""
    out = run_study(DECK, name, factory.mktemp(name))
    assert not out.problems, out.problems
    for c in out.cases:
        assert c.status == "complete", f"{c.label}: {c.status}: {c.message}"
    for fig in out.figures:
        assert fig.stat().st_size > 5000, fig
    return out


def check_numbers(values, expected, tolerances):
    for (col, want), tol in zip(expected.items(), tolerances):
        assert values[col] == pytest.approx(want, abs=tol), col


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
    spec, model = load_model(DECK, scene="model1", overrides={"parameters.v0": "0"})
    res = run_model(model, "equilibrium", {"method": "minimum"}, deck=spec)
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
    spec, model = load_model(DECK, overrides={"parameters.v0": "0"})
    res = run_model(model, "equilibrium", {"method": "minimum"}, deck=spec)
    r = np.array([res.channel(f"bodies/{b}/r").data[-1] for b in model.body_names])
    moved = np.abs(r - assemble(model).q.reshape(model.nb, 7)[:, :3]).max()
    assert moved < 1e-4


def angles(res):
    """(roll, yaw) of the chassis (rad): roll about its forward axis y', yaw about z."""
    from mbsim.rotations import A

    Am = A(res.channel("bodies/chassis/p").data)
    return -np.arcsin(Am[:, 2, 0]), np.arctan2(-Am[:, 0, 1], Am[:, 1, 1])


LANE_CASES = {"model1_lane1": "model1_lc1", "model1_lane2": "model1_lc2", "lane1": "model2_lc1",
              "lane2": "model2_lc2"}  # fmt: skip


@pytest.fixture(scope="module")
def lane_change_study(tmp_path_factory):
    out = study(tmp_path_factory, "lane_change")
    names = ["fig12_5_6a.png", "fig12_5_7.png", "fig12_5_8.png", "fig12_5_9.png",
             "fig12_5_10.png"]
    assert [p.name for p in out.figures] == names
    return out


@pytest.fixture(scope="module")
def lane_changes(lane_change_study):
    """scene -> Result of the study's case that runs it."""
    res = {c.name: c.result for c in lane_change_study.cases}
    return {scene: res[case] for scene, case in LANE_CASES.items()}


@pytest.mark.slow
def test_lane_change_is_3_6_m(lane_changes):
    for scene in ("model1_lane1", "model1_lane2"):
        x = lane_changes[scene].channel("bodies/chassis/r").data[:, 0]
        assert -x[-1] == pytest.approx(3.6, abs=0.1), scene


@pytest.mark.slow
@pytest.mark.parametrize("n", ["1", "2"])
def test_stabilizer_bars_reduce_peak_roll(lane_changes, n):
    """Sec. 12.5.4: "Roll motions of the vehicle are compared in Fig. 12.5.10 for both models
    and with both lane-change drivers. The roll-stabilizer effect in model 2 is clearly
    observed." Peak roll (exact angle about the chassis' forward axis) 3.37 -> 1.95 deg and
    5.58 -> 2.65 deg; "clearly" is read as a cut of at least a quarter."""
    roll1 = np.abs(angles(lane_changes[f"model1_lane{n}"])[0]).max()
    roll2 = np.abs(angles(lane_changes[f"lane{n}"])[0]).max()
    assert roll2 < 0.75 * roll1, (np.degrees(roll1), np.degrees(roll2))


@pytest.fixture(scope="module")
def circle_study(tmp_path_factory):
    out = study(tmp_path_factory, "circle")
    assert [p.name for p in out.figures] == ["fig12_5_6b.png", "fig12_5_11.png", "fig12_5_12.png",
                                             "fig12_5_13.png"]  # fmt: skip
    return out


@pytest.fixture(scope="module")
def circles(circle_study):
    """speed [mph] -> Result of the study's case."""
    return {int(c.name[3:]): c.result for c in circle_study.cases}


def drift(res):
    """Heading of the chassis minus the direction of its centroid's velocity (rad)."""
    _, yaw = angles(res)
    vel = res.channel("bodies/chassis/rd").data
    return np.angle(np.exp(1j * (yaw - np.arctan2(-vel[:, 0], vel[:, 1]))))


def speed(res):
    return np.linalg.norm(res.channel("bodies/chassis/rd").data[:, :2], axis=1)


def saturated(res, wheel):
    return res.channel(f"forces/tire_{wheel}/saturated").data > 0


WHEELS = ("fr", "fl", "rr", "rl")
RAMP_END = 1.5  # s, end of curve 3's ramp (parameters t_c + T_c)


@pytest.mark.slow
def test_circle_55_mph_saturates_slides_and_slows(circles):
    """Sec. 12.5.4: "For 55 mph, the maximum tire slip force occurs; that is,
    F_lat = mu F_ver, until the speed of the vehicle substantially decreases due to large
    lateral slip", "considerable speed loss ... in the 55 mph case" and "the vehicle is not
    tangent to the path during the maximum slip period" (Figs. 12.5.11-12.5.13). Measured
    (curve 3 held at -6.5 mm, C_alpha = 30 kN/rad): all four tires at mu F_ver together 61 %
    of the time after the ramp (82 % of 1.7-8.0 s), the last saturation at 7.6 s at 10.8 m/s;
    24.6 -> 10.6 m/s; the heading up to 21.5 deg off the path, within 0.04 deg again in the
    last second."""
    res = circles[55]
    t, v = res.t, speed(res)
    after = t > RAMP_END
    for w in WHEELS:  # F_lat = mu F_ver wherever a tire is saturated
        fl = res.channel(f"forces/tire_{w}/F_lat").data
        fv = res.channel(f"forces/tire_{w}/F_ver").data
        sat = saturated(res, w)
        assert sat[after].mean() > 0.5, w
        assert np.allclose(np.abs(fl[sat]), 0.8 * fv[sat], rtol=1e-9), w
    every = np.all([saturated(res, w) for w in WHEELS], axis=0)
    assert every[after].mean() > 0.5  # the whole car at its friction limit, not one tire
    last = np.nonzero(np.any([saturated(res, w) for w in WHEELS], axis=0))[0][-1]
    assert v[last] < 0.65 * v[0] and t[last] < t[-1] - 0.5  # until the speed has dropped
    assert v[-1] < 0.6 * v[0]  # the speed drops markedly (lateral slip only dissipates)
    heading = np.degrees(np.abs(drift(res)))
    assert heading.max() > 10.0  # heading not tangent to the path while sliding
    assert heading[t > t[-1] - 1.0].max() < 2.0  # tangent again once the tires grip


@pytest.mark.slow
def test_circle_20_mph_follows_the_steer(circles):
    """The contrast at 20 mph: no tire saturates (at most 27 % of mu F_ver), the speed stays
    (chassis 8.94 -> 8.66 m/s), the car is tangent to its path within 0.6 deg and drives the
    Ackermann circle of its front wheels' steer (3.07 deg: 2.468 m / tan 3.07 deg = 46.1 m;
    measured 47.4 m, the tires' slip angles adding a little understeer)."""
    res = circles[20]
    for w in WHEELS:
        assert not saturated(res, w).any(), w
    v = speed(res)
    assert v[-1] > 0.95 * v[0]
    assert np.degrees(np.abs(drift(res)).max()) < 2.0  # nearly tangent to the path
    _, yaw = angles(res)
    heading = [res.channel(f"forces/tire_{w}/heading").data[-1] for w in ("fl", "fr")]
    steer = np.mean(np.angle(np.exp(1j * (np.array(heading) - yaw[-1]))))  # wheels vs chassis
    wheelbase = 1.17938 + 1.28851  # front and rear wheel centres at equilibrium (deck)
    w = np.gradient(yaw, res.t)[-100:]
    radius = np.mean(v[-100:] / np.abs(w))
    assert radius == pytest.approx(wheelbase / np.tan(steer), rel=0.05)


@pytest.mark.slow
def test_circle_40_mph_stays_below_the_car_limit(circles):
    """40 mph, the middle case (C_alpha = 30 kN/rad): the car understeers at up to 0.71 mu g,
    the outer tires at most at 64 % of mu F_ver, within 3.5 deg of tangent, and loses 17 % of
    its speed (17.9 -> 14.8 m/s), under a third of the 55 mph loss (57 %). Not the contrast
    of 20 mph: the unloaded inner tires run at mu F_ver for 85 % of the time after the ramp,
    until the car has slowed (last at 8.8 s): model 1 has no bars and C_alpha does not fall
    with the load, so an inner tire reaches its limit from about 0.5 mu g; no rack hold value
    avoids it at 40 mph and still lets 55 mph slide: docs/models.md, Steering."""
    res = circles[40]
    after = res.t > RAMP_END
    for w in ("fr", "rr"):  # the outer (right) tires stay clear of the limit
        fl = np.abs(res.channel(f"forces/tire_{w}/F_lat").data)
        fv = res.channel(f"forces/tire_{w}/F_ver").data
        assert not saturated(res, w).any() and (fl / (0.8 * fv)).max() < 0.8, w
    assert saturated(res, "fl")[after].mean() > 0.8 and saturated(res, "rl")[after].mean() > 0.8
    v, v55 = speed(res), speed(circles[55])
    assert v[-1] > 0.8 * v[0]
    assert 1 - v[-1] / v[0] < 0.35 * (1 - v55[-1] / v55[0])
    # within 3.5 deg of tangent (the chassis; 21.5 deg at 55 mph): the softer tires' slip
    # angles at 0.7 mu g, not a slide
    assert np.abs(drift(res)).max() < 0.25 * np.abs(drift(circles[55])).max()


def test_settling_from_table_12_5_8(tmp_path_factory, equilibrium_model1):
    """Sec. 12.5.2, Figs. 12.5.4, 12.5.5: model 1 at rest, released from Table 12.5.8's
    estimates, settles under the suspension damping toward the static equilibrium (study
    ``settling``, 5 s). Regression: the assembled start (kinematic, exact) and the state at
    5 s. The book's light damping leaves a +-0.4 mm, +-0.05 deg oscillation there, whose
    phase and amplitude depend on the integrator: at rtol 1e-5 instead of the deck's 1e-3 the
    state at 5 s moves by 0.07 mm and 0.019 deg; tolerances 0.2 mm and 0.04 deg."""
    out = study(tmp_path_factory, "settling")
    assert [p.name for p in out.figures] == ["fig12_5_4.png", "fig12_5_5.png"]
    res = out.cases[0].result
    _, eq_res = equilibrium_model1
    z_eq = eq_res.channel("bodies/chassis/r").data[-1, 2]
    z = res.channel("bodies/chassis/r").data[:, 2]
    assert z[0] == pytest.approx(0.54744, abs=1e-5)  # Table 12.5.8's estimates, assembled
    assert z[-1] == pytest.approx(z_eq, abs=1e-3)
    last = res.t > 4.0  # the last second oscillates about the equilibrium
    assert np.mean(z[last]) == pytest.approx(z_eq, abs=3e-4)
    e1 = res.channel("bodies/chassis/p").data[:, 1]
    swing = [np.ptp(e1[(res.t > a) & (res.t < a + 1)]) for a in (0.0, 4.0)]
    assert swing[1] < 0.5 * swing[0]  # the pitch oscillation decays
    check_numbers(out.values["settle"], {"chassis z [m]": 0.546344, "pitch [deg]": -0.183068},
                  (2e-4, 0.04))  # fmt: skip


# Regression (study equilibrium): chassis z, e1, FR and RR wheel z, rack z [m]; FR and RR tire
# loads [N]. The minimum-energy search converges to ~1e-7 m: 2e-5 m, 2e-6 and 0.5 N; the case
# settled dynamically (stopped at speeds below 2e-3, within t_end = 60 s: with C_alpha =
# 30 kN/rad the tires damp the plan motion less and 30 s no longer sufficed) lies within
# 2e-5 m and 1 N of it.
EQUILIBRIUM = {
    "model1": (0.546016, -0.00155119, 0.344979, 0.26167, 0.167286, 3564.15, 3346.01),
    "model2": (0.545865, -0.00154516, 0.344957, 0.261643, 0.16715, 3568.58, 3351.39),
    "settle": (0.546017, -0.00155104, 0.344979, 0.26167, 0.167287, 3564.11, 3345.98),
}
EQUILIBRIUM_COLUMNS = ("chassis z [m]", "chassis e1", "FR wheel z [m]", "RR wheel z [m]",
                       "rack z [m]", "FR tire load [N]", "RR tire load [N]")  # fmt: skip


@pytest.mark.slow
def test_equilibrium_study(tmp_path_factory):
    """Sec. 12.5.2: "Static equilibrium analysis of model 1 is performed using dynamic
    analysis": settled from Table 12.5.8 by the suspension damping, model 1 reaches the
    minimum of its potential energy (to 0.1 mm), with the wheels at Table 12.5.9's heights
    (1 mm; the tire radii are chosen for it) and the chassis 7.5 mm higher (Table 12.5.9 is
    not an equilibrium of the tabulated springs: docs/models.md). Model 2's bars change the
    heights by less than 0.2 mm."""
    out = study(tmp_path_factory, "equilibrium")
    v = out.values
    for col in EQUILIBRIUM_COLUMNS[:5]:
        assert v["settle"][col] == pytest.approx(v["model1"][col], abs=1e-4), col
        assert v["model2"][col] == pytest.approx(v["model1"][col], abs=2e-4), col
    for case in ("model1", "settle"):
        assert v[case]["FR wheel z [m]"] == pytest.approx(TABLE_12_5_9["wheel_fr"][2], abs=1e-3)
        assert v[case]["RR wheel z [m]"] == pytest.approx(TABLE_12_5_9["wheel_rr"][2], abs=1e-3)
        assert 0.005 < v[case]["chassis z [m]"] - TABLE_12_5_9["chassis"][2] < 0.010
    for case, expected in EQUILIBRIUM.items():
        tols = (2e-5, 2e-6, 2e-5, 2e-5, 2e-5, 0.5, 0.5)
        if case == "settle":
            tols = (4e-5, 4e-6, 4e-5, 4e-5, 4e-5, 1.0, 1.0)
        check_numbers(v[case], dict(zip(EQUILIBRIUM_COLUMNS, expected)), tols)


# Regression (study lane_change): final x [m], peak roll [deg], peak lateral acceleration
# [m/s^2], whether the front-left tire saturated. At rtol 1e-5 instead of the deck's 1e-3 these
# move by up to 26 mm, 0.008 deg and 0.02 m/s^2 (model 1, lane change 2: the saturated tires
# leave a heading error that the end position integrates): tolerances 0.05 m, 0.03 deg,
# 0.05 m/s^2.
LANE_CHANGE = {
    "model1_lc1": (-3.5939, 3.37305, 3.74513, 0),
    "model1_lc2": (-3.61864, 5.58082, 5.18876, 1),
    "model2_lc1": (-3.70632, 1.95468, 3.80441, 0),
    "model2_lc2": (-1.7737, 2.64532, 4.83437, 1),
}
LANE_CHANGE_COLUMNS = ("x final [m]", "peak roll [deg]", "peak lateral acc [m/s^2]",
                       "saturated FL")  # fmt: skip


@pytest.mark.slow
@pytest.mark.parametrize("case", list(LANE_CHANGE))
def test_lane_change_regression(lane_change_study, case):
    expected = dict(zip(LANE_CHANGE_COLUMNS, LANE_CHANGE[case]))
    check_numbers(lane_change_study.values[case], expected, (0.05, 0.03, 0.05, 0))


# Regression (study circle): final speed of the left rear tire [m/s], largest front-left and
# rear-left slip angles [deg], whether each tire saturated (FL, RL: inner; FR, RR: outer). At
# rtol 1e-5 instead of the deck's 1e-3 these move by 0.0001/0.0002/0.0004 (20 mph),
# 0.0009/0.0007/0.002 (40 mph) and 0.14/0.28/0.33 (55 mph: the slide): tolerances
# 0.001/0.001/0.001, 0.002/0.002/0.004 and 0.3/0.6/0.7.
CIRCLE = {
    "mph20": ((8.55216, 1.2659, 1.1241, 0, 0, 0, 0), (0.001, 0.001, 0.001, 0, 0, 0, 0)),
    "mph40": ((14.649, 5.42508, 4.3904, 1, 1, 0, 0), (0.002, 0.002, 0.004, 0, 0, 0, 0)),
    "mph55": ((10.4553, 23.4908, 23.0436, 1, 1, 1, 1), (0.3, 0.6, 0.7, 0, 0, 0, 0)),
}
CIRCLE_COLUMNS = ("speed final [m/s]", "max slip FL [deg]", "max slip RL [deg]", "saturated FL",
                  "saturated RL", "saturated FR", "saturated RR")  # fmt: skip


@pytest.mark.slow
@pytest.mark.parametrize("case", list(CIRCLE))
def test_circle_regression(circle_study, case):
    expected, tols = CIRCLE[case]
    check_numbers(circle_study.values[case], dict(zip(CIRCLE_COLUMNS, expected)), tols)
