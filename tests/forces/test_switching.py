"""Switching force laws (mbsim.forces.switching): a law with ``where`` conditions on the sign
of a velocity is a hybrid element; at v = 0 it crosses, returns, or holds v at 0 (Filippov's
sliding mode) and leaves the hold when the force that needs lies outside the law's two
one-sided values.

Closed form (the block): mass M on a translational joint along x, from x = 0 at v = 1 m/s,
pushed by P(t) = 1 + 2 t and braked by the law where(v < 0, 5, -5) (N).  Sliding mode at
v = 0 while -5 <= -P <= 5.
- v > 0: M v' = P - 5 = 2 t - 4, v = 1 - 2 t + t^2 / 2, x = t - t^2 + t^3 / 6; v = 0 at
  t1 = 2 - sqrt(2) (the smaller root of t^2 - 4 t + 2).
- hold from t1 while P(t) <= 5, i.e. until t2 = 2 (alpha = (P + 5) / 10 reaches 1).
- after t2: M v' = 2 t - 4 again, v = (t - 2)^2 / 2, x = x(t1) + (t - 2)^3 / 6.
Without a sliding mode (P = -10): v = 1 - 7.5 t to t = 2/15, then v' = -2.5 (crossing).

Tolerances: the runs use rtol 1e-10, atol 1e-12; an event time is off by the solution's
error over the event function's rate (|e_v| / |v'| with |v'(t1)| = 1.41 m/s^2, and alpha' =
0.2 1/s at t2): 1e-8 s covers both with a margin of 100; positions 1e-8 m (the errors of
the state, ~1e-12, times the growth of cubic motion over 3 s).  While held, the velocity is
the projection's round-off (<= 1e-15 m/s; the families that do not project: their own
tolerance) and the position moves by less than 1e-12 m.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from mbsim import core
from mbsim.api import load_model, run_model
from mbsim.cli import main
from mbsim.forces.switching import Hold, Side, SwitchingLaw

M = 2.0
T1, T2 = 2.0 - math.sqrt(2.0), 2.0

DECK = """\
title: block braked by a switching law
gravity: [0, 0, 0]
bodies:
  ground: {{ground: true}}
  block: {{mass: {m}, inertia: [1, 1, 1], r: [0, 0, 0], rdot: [1, 0, 0]}}
joints:
  slide:
    type: translational
    bodies: [ground, block]
    points:
      ground: {{P: [0, 0, 0], Q: [1, 0, 0], R: [0, 1, 0]}}
      block: {{P: [0, 0, 0], Q: [1, 0, 0], R: [0, 1, 0]}}
forces:
  push:
    type: force
    body: block
    direction: [1, 0, 0]
    law: '{push}'
  brake:
    type: force
    body: block
    direction: [1, 0, 0]
    law: '{law}'
    measures:
      v: {{type: velocity, body: block, axis: x}}
{extra}
analysis:
  dynamic: {{t_end: 3.0, step: 0.01, rtol: 1.0e-10, atol: 1.0e-12, integrator: {integrator}}}
"""


def block(tmp_path, push="1 + 2*t", law="where(v < 0, 5, -5)", extra="",
          integrator="projection-dop853", name="block.yaml"):
    path = tmp_path / name
    path.write_text(DECK.format(m=M, push=push, law=law, extra=extra, integrator=integrator))
    return path


def run(path, **options):
    spec, model = load_model(path)
    return model, run_model(model, "dynamic", {"error_estimate": False, **options}, deck=spec)


def x_exact(t):
    x1 = T1 - T1**2 + T1**3 / 6
    return np.where(t < T1, t - t**2 + t**3 / 6, np.where(t < T2, x1, x1 + (t - T2) ** 3 / 6))


def events_of(res):
    return [(e["t"], e["event"], e["mode"]) for e in res.summary["events"]]


# every integrator family; the fixed-step ones at h = 1e-3 s: rk4 and gcp-rk4 (4th order,
# error ~ h^4 = 1e-12) within the adaptive runs' bounds; genalpha and hht (2nd order, error
# ~ h^2 x the jerk (1 m/s^3) = 1e-6 m; measured 2e-7 m and 3e-8 s) within 1e-6
FAMILIES = {"gcp-rk45": None, "gcp-dop853": None, "gcp-rk4": 1e-3, "projection": None,
            "projection-dop853": None, "baumgarte": None, "rk4": 1e-3, "genalpha": 1e-3,
            "hht": 1e-3}
SECOND_ORDER = ("genalpha", "hht")
# while held, the velocity is the velocity projection's round-off (<= 1e-15) in the families
# that project; baumgarte, genalpha and hht hold the velocity constraint to their own
# tolerance (drift stabilisation, Newton on rtol 1e-10: measured 8e-14 and 1.2e-12)
NOT_PROJECTED = ("baumgarte", "genalpha", "hht")


@pytest.mark.parametrize("integrator", list(FAMILIES))
def test_sliding_mode_enters_holds_and_leaves_at_the_analytic_times(tmp_path, integrator):
    h = FAMILIES[integrator]
    _, res = run(block(tmp_path, integrator=integrator), **({"h": h} if h else {}))
    tol = 1e-6 if integrator in SECOND_ORDER else 1e-8
    assert res.complete, res.message
    (te, ev1, m1), (tl, ev2, m2) = events_of(res)
    assert te == pytest.approx(T1, abs=tol) and ev1 == "v = 0"
    assert m1.startswith("v > 0 -> hold")
    assert tl == pytest.approx(T2, abs=1e-8) and ev2 == "alpha > 1"
    assert m2.endswith("-> v > 0")
    t = res.t
    x = res.channel("bodies/block/r").data[:, 0]
    v = res.channel("bodies/block/rd").data[:, 0]
    held = (t > te) & (t < tl)
    assert held.sum() > 100
    assert np.abs(v[held]).max() <= (1e-10 if integrator in NOT_PROJECTED else 1e-15)
    assert np.ptp(x[held]) <= 1e-12
    np.testing.assert_allclose(x, x_exact(t), rtol=0, atol=tol)
    side = res.channel("forces/brake/side").data
    assert np.all(side[held] == 0) and np.all(side[t < te] == 1)
    assert np.all(side[t > tl + 1e-8] == 1)
    # while held the brake carries Filippov's force, the push's opposite: -P(t) (its
    # multiplier with the held row: alpha = (P + 5) / 10 follows the push)
    F = res.channel("forces/brake/force").data[held, 0]
    np.testing.assert_allclose(F, -(1 + 2 * t[held]), rtol=0, atol=10 * tol)


def test_crossing_without_sliding_mode_keeps_the_plain_law(tmp_path):
    """P = -10: both sides push toward v < 0, so v crosses 0 at t = 2/15 and the law takes
    its other value there (the old behaviour, now at a located event)."""
    _, res = run(block(tmp_path, push="-10"))
    assert res.complete, res.message
    ((tc, _, mode),) = events_of(res)
    assert tc == pytest.approx(2 / 15, abs=1e-8) and mode == "v > 0 -> v < 0"
    t = res.t
    x = res.channel("bodies/block/r").data[:, 0]
    xc = 1 / 15  # x at 2/15: t - 3.75 t^2
    want = np.where(t < tc, t - 3.75 * t**2, xc - 1.25 * (t - tc) ** 2)
    np.testing.assert_allclose(x, want, rtol=0, atol=1e-8)
    F = res.channel("forces/brake/force").data[:, 0]
    np.testing.assert_array_equal(F, np.where(t < tc, -5.0, 5.0))


def test_a_law_without_velocity_conditions_stays_plain(tmp_path):
    _, model = load_model(block(tmp_path, law="where(t < 1, 5, -5)"))
    assert not any(isinstance(el, SwitchingLaw) for el in model.forces)
    _, model = load_model(block(tmp_path, name="b2.yaml"))
    (brake,) = [el for el in model.forces if isinstance(el, SwitchingLaw)]
    assert brake.type == "force" and brake.mname == "v"


def test_two_velocity_measures_in_one_law_are_a_deck_error(tmp_path):
    law = "where(v < 0, 5, where(w > 0, 1, -5))"
    path = block(tmp_path, law=law)
    text = path.read_text().replace(
        "      v: {type: velocity, body: block, axis: x}",
        "      v: {type: velocity, body: block, axis: x}\n"
        "      w: {type: velocity, body: block, axis: y}")
    path.write_text(text)
    out = CliRunner().invoke(main, ["run", str(path), "--mode", "dynamic"])
    assert out.exit_code == 2, out.output
    assert "forces.brake.law" in out.output and "one velocity measure" in out.output
    assert "Traceback" not in out.output


@pytest.mark.parametrize("kind", ["velocity", "velocity_local", "angular_velocity"])
def test_measure_gradient_and_rate_against_finite_differences(tmp_path, kind):
    """m = J(q) qd (gradient) and dm/dt from (q, qd, qdd) (rate) on a tumbling free body, a
    point off its centroid, against central differences along q(t) = q + qd t + qdd t^2/2
    (step 1e-6: truncation ~1e-12, round-off ~1e-10)."""
    measure = {"velocity": "{type: velocity, body: b, point: [0.3, -0.2, 0.1], axis: y}",
               "velocity_local": "{type: velocity, body: b, point: [0.3, -0.2, 0.1], "
                                 "axis: [0.6, 0, 0.8], frame: local}",
               "angular_velocity": "{type: angular_velocity, body: b, axis: [0, 0.6, 0.8]}"}
    deck = tmp_path / "free.yaml"
    deck.write_text(f"""\
title: a free body
gravity: [0, 0, 0]
bodies:
  b: {{mass: 1.0, inertia: [1, 2, 3], r: [0, 0, 0]}}
forces:
  f:
    type: force
    body: b
    direction: [0, 1, 0]
    law: 'where(m < 0, 1, 0)'
    measures:
      m: {measure[kind]}
""")
    _, model = load_model(deck)
    (el,) = model.forces
    rng = np.random.default_rng(3)
    p = rng.normal(size=4)
    p /= np.linalg.norm(p)
    q = np.concatenate([rng.normal(size=3), p])
    pd = rng.normal(size=4)
    pd -= p * (p @ pd)
    qd = np.concatenate([rng.normal(size=3), pd])
    qdd = rng.normal(size=7)
    qdd[3:] -= p * (p @ qdd[3:] + pd @ pd)  # p.pdd = -pd.pd (second derivative of p.p = 1)

    def m_at(h):
        qh = q + qd * h + qdd * h * h / 2
        qh[3:] /= np.linalg.norm(qh[3:])
        return el.measure.value(core.State(model, qh, qd + qdd * h), 0.0)

    st = core.State(model, q, qd)
    assert el.gradient(st, 7) @ qd == pytest.approx(el.measure.value(st, 0.0), rel=1e-12)

    class Ctx:
        pass

    ctx = Ctx()
    ctx.model, ctx.q, ctx.state = model, q, st
    h = 1e-6
    fd = (m_at(h) - m_at(-h)) / (2 * h)
    assert el.rate(ctx, qdd) == pytest.approx(fd, rel=1e-7, abs=1e-8)


def test_modes_print_for_the_summary():
    assert str(Side(-1, "v")) == "v < 0" and str(Side(1, "w")) == "w > 0"
    hold = Hold("air1", (("air1", 1), ("air3", -1)), 0.25)
    assert str(hold) == "hold (lead air1, alpha 0.25)" and hold.sigma("air3") == -1


DECKS = Path(__file__).resolve().parents[2] / "models"
# `mbsim run models/compressor.yaml --mode dynamic --scene dynamic30 --rtol 1e-10 --atol
# 1e-10`: the stop (air1's hold) at 0.0772532284 s (gcp-rk45; projection-dop853 agrees to
# 3e-9 s); a reference for the runs at the deck's rtol 1e-6 below, 1e5 times less accurate
STOP_AT_RTOL_1E_10 = 0.07725323


@pytest.mark.parametrize("integrator", ["gcp-rk45", "projection-dop853", "baumgarte",
                                        "genalpha"])
def test_compressor_from_30_rad_s_stops_and_stays_at_rest(integrator):
    """Sec. 12.4.3, Fig. 12.4.6: from 30 rad/s the motion stops before one cycle.  The six
    valve laws reach v = 0 together (v_k = c_k(theta) omega); they hold as one group (one
    row) and the run goes on to the scene's end at rest: the rotor's angular velocity 0 (the
    hold rows' projection gives qd = 0 exactly in the families that project; the others
    hold it to their tolerance) and the pistons still.  All six change mode at one event
    (those whose own switch the dense output placed a round-off later join it).  The stop
    time at rtol 1e-6 within 1e-4 s of the same run at rtol 1e-10 (0.0772532 s with
    gcp-rk45 and projection-dop853): e_omega / |omega'| ~ 0.05 rad/s / 1700 rad/s^2."""
    spec, model = load_model(DECKS / "compressor.yaml", scene="dynamic30")
    res = run_model(model, "dynamic", {"error_estimate": False, "integrator": integrator},
                    deck=spec)
    assert res.complete, res.message
    assert res.t[-1] == pytest.approx(0.3, abs=1e-12)
    stop = [e for e in res.summary["events"] if "hold" in e["mode"].split("->")[-1]]
    assert {e["element"] for e in stop} == {f"air{k}" for k in range(1, 7)}
    t_stop = stop[0]["t"]
    assert all(e["t"] == t_stop for e in stop)
    assert t_stop == pytest.approx(STOP_AT_RTOL_1E_10, abs=1e-4)
    projected = integrator not in ("baumgarte", "genalpha")
    after = res.t > t_stop
    w = res.channel("bodies/rotor/omega").data
    assert np.abs(w[after]).max() <= (1e-15 if projected else 1e-8)  # measured 4.5e-10
    y = res.channel("bodies/piston1/r").data[:, 1]
    assert np.ptp(y[after]) <= 1e-12
    assert np.all(w[res.t < t_stop - 0.002, 1] > 0)


def test_the_lead_of_a_hold_reports_the_holding_force_with_its_row(tmp_path):
    """While held, the brake applies F(v < 0) + alpha0 (F(v > 0) - F(v < 0)) and the hold
    row carries the rest: at rest M x'' = 0 = P + F_applied - lam (Phi = x - x1), so the
    whole holding force F_applied - lam is -P.  With the compiled model bound and every
    element's mode given, the channel adds the row's part."""
    model, _ = run(block(tmp_path))
    brake = next(el for el in model.forces if isinstance(el, SwitchingLaw))
    hold = Hold("brake", (("brake", 1),), 0.25)
    q = model.q0.copy()
    st = core.State(model, q, np.zeros(model.nq))
    t = 1.0  # P = 3
    applied = 5.0 + 0.25 * (-5.0 - 5.0)  # F(v < 0) + alpha0 (F(v > 0) - F(v < 0))
    lam = np.concatenate([np.zeros(model.m), [3.0 + applied]])
    modes = {"brake": hold}
    brake.bind(model)  # (compile_model binds every element that has bind)
    try:
        F = brake.channels_in(hold, st, t, lam, modes)["force"][0]
        np.testing.assert_allclose(F, [-3.0, 0.0, 0.0], atol=1e-15)
        assert brake.held_multiplier(lam, {"brake": Side(1)}) is None
    finally:
        brake.model = None


ROTOR = """\
title: rotor braked by a switching torque on its angular velocity
gravity: [0, 0, 0]
bodies:
  ground: {ground: true}
  rotor: {mass: 1.0, inertia: [1, 1, 2], r: [0, 0, 0], omega: [0, 0, 1]}
joints:
  shaft:
    type: revolute
    bodies: [ground, rotor]
    points:
      ground: [0, 0, 0,   0, 0, 1,   1, 0, 0]
      rotor: [0, 0, 0,   0, 0, 1,   1, 0, 0]
forces:
  push: {type: torque, body: rotor, direction: [0, 0, 1], law: '1 + 2*t'}
  brake:
    type: torque
    body: rotor
    direction: [0, 0, 1]
    law: 'where(w < 0, 5, -5)'
    measures:
      w: {type: angular_velocity, body: rotor, axis: z}
analysis:
  dynamic: {t_end: 3.0, step: 0.01, rtol: 1.0e-10, atol: 1.0e-12}
"""


def test_an_angular_velocity_holds_by_an_angle_row(tmp_path):
    """The block's law as torques on a rotor (I_zz = 2 = M, w = theta'): the same closed
    form, theta(t) = x(t), held by an angle row to ground about z from 2 - sqrt(2) s to 2 s."""
    deck = tmp_path / "rotor.yaml"
    deck.write_text(ROTOR)
    _, res = run(deck)
    assert res.complete, res.message
    (te, _, m1), (tl, _, m2) = events_of(res)
    assert te == pytest.approx(T1, abs=1e-8) and m1.startswith("w > 0 -> hold")
    assert tl == pytest.approx(T2, abs=1e-8) and m2.endswith("-> w > 0")
    p = res.channel("bodies/rotor/p").data
    theta = 2 * np.arctan2(p[:, 3], p[:, 0])
    np.testing.assert_allclose(theta, x_exact(res.t), rtol=0, atol=1e-8)
    w = res.channel("bodies/rotor/omega").data[:, 2]
    held = (res.t > te) & (res.t < tl)
    assert np.abs(w[held]).max() <= 1e-15 and np.ptp(theta[held]) <= 1e-12


def test_a_sliding_mode_the_element_cannot_hold_ends_the_run_naming_it(tmp_path):
    """The rotor's brake on its angular velocity in the body frame (frame: local): it
    switches at located events, but a hold needs a velocity along a global axis or an
    angular velocity about one, so the sliding mode at t = 2 - sqrt(2) ends the run there,
    incomplete (exit 1), the element named, the outputs before it kept."""
    deck = tmp_path / "rotor.yaml"
    deck.write_text(ROTOR.replace("axis: z}", "axis: z, frame: local}"))
    out = tmp_path / "rotor.h5"
    r = CliRunner().invoke(main, ["run", str(deck), "--mode", "dynamic", "-o", str(out)])
    assert r.exit_code == 1, r.output
    assert "brake" in r.output and "sliding mode" in r.output and "Traceback" not in r.output
    from mbsim.output.hdf5 import read_result

    res = read_result(out)
    assert res.status == "incomplete" and res.t[-1] == pytest.approx(T1, abs=0.011)
