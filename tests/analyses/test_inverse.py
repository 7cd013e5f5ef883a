"""Inverse dynamics: driver torques against hand formulas and the power balance, joint
reactions against Newton's third law, forward -> inverse round trip, singular extremes."""

import numpy as np
import pytest

from mbsim.analyses.dynamic import dynamic
from mbsim.analyses.inverse import inverse, multipliers, states_from_result
from mbsim.analyses.reactions import reactions
from mbsim.deck.spec import ForceSpec, FunctionSpec
from mbsim.errors import DeckError
from mbsim.expr import parse_expression
from mbsim.model import compile_model
from tests.analyses.test_kinematic_slider_crank import slider_crank_model
from tests.helpers import body, driver, func, joint, pts, slider_crank_spec, spec

# pendulum: arm of mass m, centroid a distance l below the pivot at theta = 0, revolute axis x
M_ARM, L_ARM, JXX, G = 2.0, 0.5, 0.3, 9.81
THETA = "0.5*sin(3*t) + 2*t"


def pendulum_spec(theta=THETA, drivers=True, forces=()):
    bodies = [body("arm", M_ARM, (JXX, 0.1, 0.3), (0, 0, -L_ARM)), body("ground", ground=True)]
    joints = [joint("pivot", "revolute", "ground", "arm",
                    {"ground": pts((0, 0, 0), (1, 0, 0), (0, 1, 0)),
                     "arm": pts((0, 0, L_ARM), (1, 0, L_ARM), (0, 1, L_ARM))})]
    drv = []
    if drivers:
        fn = theta if isinstance(theta, FunctionSpec) else func(
            "expression", expr=parse_expression(theta))
        drv = [driver("motor", "rotation", fn, joint="pivot")]
    return spec(bodies, joints, drv, forces=forces, gravity=(0, 0, -G))


def power_terms(model, res):
    """dT/dt and the power of gravity from the body channels alone (no multipliers):
    dT/dt = sum m rd.rdd + omega'.J' omegad'  (d/dt of T = 1/2 m rd^2 + 1/2 w'.J'w'),
    P_g = sum m g.rd."""
    dT = np.zeros(len(res.t))
    Pg = np.zeros(len(res.t))
    for b, name in enumerate(model.body_names):
        def ch(k, name=name):
            return res.channel(f"bodies/{name}/{k}").data

        m, J = model.mass[b], model.J_local[b]
        dT += m * np.sum(ch("rd") * ch("rdd"), 1)
        dT += np.einsum("ti,ij,tj->t", ch("omega_local"), J, ch("omegad_local"))
        Pg += m * ch("rd") @ model.gravity
    return dT, Pg


def test_pendulum_torque_matches_hand_formula_and_power():
    model = compile_model(pendulum_spec())
    res = inverse(model, {"t_end": 2.0, "step": 0.01})
    assert res.complete, res.message
    t = res.t
    th = 0.5 * np.sin(3 * t) + 2 * t
    thdd = -4.5 * np.sin(3 * t)
    # torque on the arm about +x: (Jxx + m l^2) thdd + m g l sin(theta) (moment about the pivot)
    tau = (JXX + M_ARM * L_ARM**2) * thdd + M_ARM * G * L_ARM * np.sin(th)
    got = res.channel("drivers/motor/torque").data
    # kinematics to Newton tol 1e-10 and an exact square solve: round-off level, 1e-9 relative
    assert np.abs(got - tau).max() < 1e-9 * np.abs(tau).max()
    dT, Pg = power_terms(model, res)
    P = got * (1.5 * np.cos(3 * t) + 2)  # torque x driver rate f'(t)
    assert np.abs(P - (dT - Pg)).max() < 1e-8 * np.abs(P).max()
    np.testing.assert_allclose(res.channel("drivers/motor/power").data, P, rtol=0, atol=1e-12)


@pytest.mark.parametrize("source", ["spec", "deck"])
@pytest.mark.parametrize("ell", [0.3, 0.27])
def test_slider_crank_power_balance(ell, source):
    """Driver torque x crank rate = dT/dt - P_gravity at every output time (the joints are
    ideal, so the driver is the only other source of work); dT/dt and P_gravity come from
    the kinematic channels, independently of lam.  1e-8 of the peak power: the identity
    holds exactly for the computed (q, qd, qdd); only round-off times cond(Phi_q) < 1e3
    remains.  Both the model built here and the shipped deck."""
    model = slider_crank_model(ell, source)
    res = inverse(model, {"t_end": 1.0, "step": 0.01})
    assert res.complete, res.message
    tau = res.channel("drivers/crank/torque").data
    P = tau * (-2 * np.pi)
    dT, Pg = power_terms(model, res)
    assert np.abs(P - (dT - Pg)).max() < 1e-8 * np.abs(P).max()
    assert np.abs(P).max() > 1.0  # the check is not vacuous (peak ~1.9 W for ell = 0.3)


def test_slider_crank_reactions_obey_third_law():
    """Loads of a joint on its two bodies are equal and opposite (global), torques about the
    common joint point too (spherical, revolute, universal: P_i = P_j)."""
    model = compile_model(slider_crank_spec(0.3))
    res = inverse(model, {"t_end": 0.5, "step": 0.05})
    for name in ("A", "B", "C"):
        Fi = res.channel(f"joints/{name}/force_i").data
        Fj = res.channel(f"joints/{name}/force_j").data
        Ti = res.channel(f"joints/{name}/torque_i").data
        Tj = res.channel(f"joints/{name}/torque_j").data
        scale = np.abs(Fi).max()
        assert scale > 1.0
        assert np.abs(Fi + Fj).max() < 1e-10 * scale, name
        assert np.abs(Ti + Tj).max() < 1e-10 * max(1.0, np.abs(Ti).max()), name
    # a spherical joint transmits no torque; a revolute none about its axis f
    assert np.abs(res.channel("joints/B/torque_i").data).max() < 1e-10
    assert np.abs(res.channel("joints/A/torque_j_local").data[:, 0]).max() < 1e-10
    # the slider's translational joint carries the slider's weight (2 kg x 9.81) and the
    # vertical load of the rod at C; no force along the slide direction f
    ft = res.channel("joints/T/force_i_local").data
    assert np.abs(ft[:, 0]).max() < 1e-10


def test_forward_then_inverse_recovers_the_applied_torque():
    """Forward dynamics (mbsim's dynamic analysis, rtol 1e-10) of the free pendulum under a
    known torque, then inverse dynamics with the computed angle as a cubic-spline driver: the
    driver torque equals the applied torque.  Error budget: the spline's second derivative
    (h = 2e-3: ~ h^2 theta^(4)/12 ~ 1e-5 rad/s^2, times J_pivot 0.8) and the integration
    (~1e-9): 1e-5 of the peak torque (3 N m), away from the spline's end intervals."""
    law = ["1 + 2*sin(3*t)", 0, 0]
    fwd = compile_model(pendulum_spec(drivers=False, forces=[
        ForceSpec("push", "torque", ("arm",), {}, {"law": law, "frame": "global"})]))
    dyn = dynamic(fwd, {"t_end": 1.0, "step": 2e-3, "rtol": 1e-10, "atol": 1e-12})
    assert dyn.complete, dyn.message
    p = dyn.channel("bodies/arm/p").data
    theta = np.unwrap(2 * np.arctan2(p[:, 1], p[:, 0]))  # rotation about +x from rest
    table = FunctionSpec("table", {"t": dyn.t, "value": theta, "interpolation": "cubic"})
    inv = compile_model(pendulum_spec(theta=table))
    res = inverse(inv, {"t_start": 0.05, "t_end": 0.95, "step": 0.01})
    assert res.complete, res.message
    applied = 1 + 2 * np.sin(3 * res.t)
    got = res.channel("drivers/motor/torque").data
    assert np.abs(got - applied).max() < 1e-5 * np.abs(applied).max()


def test_slider_crank_dynamic_states_give_back_the_torque_and_reactions():
    """Exact round trip without a spline: the slider-crank runs free (crank at -2 pi rad/s,
    torque 0.3 sin(2 pi t) N m on the crank); at each output the dynamic analysis's own
    (q, qd, qdd) in the equations of the driven model (Phi_q of the angle driver does not
    depend on its target) give a driver torque equal to the applied one, and the joint
    reactions from the dynamic run's constraints/lam equal those from the inverse
    multipliers.  Both solve the same linear equations: round-off times cond < 1e3."""
    free = slider_crank_spec(0.3)
    free.drivers = {}
    free.bodies["crank"].omega = np.array([-2 * np.pi, 0.0, 0.0])
    free.forces = {"push": ForceSpec("push", "torque", ("crank",), {},
                                     {"law": ["0.3*sin(2*pi*t)", 0, 0], "frame": "global"})}
    fwd = compile_model(free)
    dyn = dynamic(fwd, {"t_end": 0.3, "step": 0.01, "rtol": 1e-10, "atol": 1e-12})
    assert dyn.complete, dyn.message
    driven = compile_model(slider_crank_spec(0.3))
    q, qd, qdd = states_from_result(fwd, dyn)
    rows = np.arange(driven.m)
    lam = np.array([multipliers(driven, q[k], qd[k], qdd[k], t, rows)
                    for k, t in enumerate(dyn.t)])
    (drv,) = [it for it in driven.items if it.kind == "driver"]
    applied = 0.3 * np.sin(2 * np.pi * dyn.t)
    assert np.abs(-lam[:, drv.rows[0]] - applied).max() < 1e-9
    # reactions usable after a dynamic run: the same loads from either set of multipliers
    by_dyn = {(r.item, r.side): r for r in reactions(fwd, q, dyn.channel("constraints/lam").data)}
    by_inv = {(r.item, r.side): r for r in reactions(driven, q, lam)}
    assert by_dyn.keys() == by_inv.keys()
    for key, r in by_dyn.items():
        scale = max(1.0, np.abs(r.force).max())
        assert np.abs(r.force - by_inv[key].force).max() < 1e-9 * scale, key
        assert np.abs(r.torque - by_inv[key].torque).max() < 1e-9 * scale, key


def test_near_singular_slider_crank_resolves_the_torque_spike():
    """ell = 0.24 passes within 0.0425 m of the crank plane at t = 0.110 s (reference §1.1):
    cond(Phi_q) peaks there and the torque swings from +0.99 N m (t = 0.078 s) to -0.74 N m
    (t = 0.143 s), against |torque| < 0.3 N m for the 0.3 m rod.
    The run completes, the power balance holds through the spike, and the extreme torques
    agree between output steps 1e-3 and 5e-4 (sampling error of a smooth peak ~ h^2)."""
    model = compile_model(slider_crank_spec(0.24))
    out = {}
    for h in (1e-3, 5e-4):
        res = inverse(model, {"t_start": 0.06, "t_end": 0.16, "step": h})
        assert res.complete, res.message
        tau = res.channel("drivers/crank/torque").data
        dT, Pg = power_terms(model, res)
        assert np.abs(-2 * np.pi * tau - (dT - Pg)).max() < 1e-8 * np.abs(2 * np.pi * tau).max()
        cond = res.channel("constraints/condition").data
        out[h] = (tau.max(), tau.min(), res.t[np.argmax(cond)], cond.max())
    (mx1, mn1, _, _), (mx2, mn2, tc2, c2) = out[1e-3], out[5e-4]
    assert abs(mx1 - mx2) < 1e-4 * abs(mx2) and abs(mn1 - mn2) < 1e-4 * abs(mn2)
    assert 0.105 <= tc2 <= 0.115  # the near-singular point
    assert 50 < c2 < 1e3  # ill-conditioned but far from singular (101 at t = 0.11)
    assert mx2 > 0.9 and mn2 < -0.6  # the spike (0.3 m rod: |torque| < 0.3 N m)


def test_locked_slider_crank_stops_with_a_named_error_and_keeps_the_data():
    """ell = 0.2362 < sqrt(0.1^2 + 0.12^2) + 0.08 = 0.236205: the rod cannot reach the
    slider axis when the crank pin is farthest from it (crank angle 50.2 deg, t = 0.1106 s).
    The run stops at the first output time past that point, naming time and joints."""
    model = compile_model(slider_crank_spec(0.2362))
    res = inverse(model, {"t_end": 1.0, "step": 0.01})
    assert res.status == "incomplete"
    # the lock-up is named as such, with the joints of the closed loop (the rod's two ends)
    assert res.message.startswith("t = 0.11 s: no configuration satisfies the constraints")
    assert "lock-up" in res.message
    involved = set(res.message.split("constraints involved: ")[1].split(", "))
    assert {"B", "C"} <= involved, res.message
    assert "\n" not in res.message
    assert len(res.t) == 11 and res.t[-1] == pytest.approx(0.10)
    assert res.channel("drivers/crank/torque").data.shape == (11,)
    assert res.channel("joints/A/force_i").data.shape == (11, 3)


def test_inverse_needs_dof_zero():
    model = compile_model(pendulum_spec(drivers=False))
    with pytest.raises(DeckError) as err:
        inverse(model, {"t_end": 0.1})
    msg = str(err.value)
    assert "DOF = 1" in msg and "none" in msg and "\n" not in msg
    assert err.value.where.path == "drivers"
    crank = slider_crank_spec(0.3)
    free = compile_model(spec(list(crank.bodies.values()), list(crank.joints.values()),
                              gravity=(0, 0, -9.81)))
    with pytest.raises(DeckError, match="DOF = 1"):
        inverse(free, {"t_end": 0.1})


def test_ctrl_c_while_the_reactions_are_computed_keeps_the_outputs_before(monkeypatch):
    """A KeyboardInterrupt at the 6th output's multipliers ends the run as incomplete with
    the 5 outputs before it, every channel of the same length, and the message saying so."""
    import mbsim.analyses.inverse as inv

    calls = {"n": 0}

    def interrupted(*args):
        calls["n"] += 1
        if calls["n"] == 6:
            raise KeyboardInterrupt
        return multipliers(*args)

    monkeypatch.setattr(inv, "multipliers", interrupted)
    res = inverse(compile_model(pendulum_spec()), {"t_end": 0.1, "step": 0.01})
    assert res.status == "incomplete" and "interrupted (Ctrl-C)" in res.message
    assert len(res.t) == 5
    assert all(c.data.shape[0] == 5 for c in res.channels.values())


SLIDER_DECK = __import__("pathlib").Path(__file__).resolve().parents[2] / "models" / \
    "slider_crank.yaml"


def test_joint_friction_in_inverse_dynamics_matches_the_driven_dynamic_run():
    """The driven slider-crank (models/slider_crank.yaml) with Coulomb friction in the slider's
    guide (mu_k 0.01, normal load the guide's reaction force and moment): the inverse dynamics
    takes the friction's slip direction from the prescribed motion and its normal load from
    lam, as the dynamic run of the same driven deck (DOF 0: the motion is the drivers', the
    friction comes from that run's own modes, events and reaction loop).  Once the friction
    was left out (0 N, the driver's torque that of the frictionless guide) and its NaN mode
    failed the run as an "overflow".  Agreement: the dynamic run at rtol 1e-9 (error
    estimate ~1e-14 m), so the two differ by the kinematic Newton tolerance (1e-10) and the
    reaction loops' 1e-14: measured 1.3e-9 of max |lam| 36; bound 1e-7 of it.  Energy: the
    driver's and the friction's work add up to the change of T + V (Simpson on the 5 ms
    outputs, measured 1e-9 J of the driver's 0.16 J)."""
    from scipy.integrate import simpson

    from mbsim.api import load_model, run_model
    from tests.reference.equations import kinetic_energy, potential_energy

    sets = {"forces.slider_friction.active": "true"}
    spec_, model = load_model(SLIDER_DECK, overrides=sets)
    inv = run_model(model, "inverse", {}, deck=spec_)
    dyn = run_model(model, "dynamic", {"t_end": 1.0, "step": 0.005, "rtol": 1e-9,
                                       "atol": 1e-11}, deck=spec_)
    assert inv.complete and dyn.complete, (inv.message, dyn.message)
    fr = inv.channel("forces/slider_friction/friction").data
    N = inv.channel("forces/slider_friction/normal_load").data
    v = inv.channel("forces/slider_friction/slip_velocity").data
    assert np.all(np.abs(v) > 1e-4)  # slips at every output: |F| = mu_k N against v
    np.testing.assert_allclose(np.abs(fr), 0.01 * N, rtol=1e-12)
    assert np.all(fr * v < 0)
    lam_i, lam_d = inv.channel("constraints/lam").data, dyn.channel("constraints/lam").data
    scale = np.abs(lam_i).max()
    assert np.abs(lam_i - lam_d[:, :lam_i.shape[1]]).max() < 1e-7 * scale
    np.testing.assert_allclose(fr, dyn.channel("forces/slider_friction/friction").data,
                               atol=1e-7 * np.abs(fr).max())
    q, qd, _ = states_from_result(model, inv)
    E = [kinetic_energy(model, q[k], qd[k]) + potential_energy(model, q[k])
         for k in range(len(inv.t))]
    P = inv.channel("drivers/crank/power").data + inv.channel("forces/slider_friction/power").data
    half = len(inv.t) // 2 + 1
    assert abs(simpson(P[:half], x=inv.t[:half]) - (E[half - 1] - E[0])) < 1e-6


@pytest.mark.parametrize("mode", ["kinematic", "equilibrium"])
def test_analyses_without_modes_complete_on_a_deck_with_joint_friction(mode):
    """Kinematic and equilibrium analyses have neither the modes nor the reactions a joint
    friction's force needs: they write no channels of it (once 0 N and a NaN mode that
    ended the run, exit 1, as an "overflow") and complete."""
    from mbsim.api import load_model, run_model

    spec_, model = load_model(SLIDER_DECK, overrides={"forces.slider_friction.active": "true"})
    res = run_model(model, mode, {}, deck=spec_)
    assert res.complete, res.message
    assert not [k for k in res.channels if "slider_friction" in k]
