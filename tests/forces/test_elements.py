"""Every force type: generalized forces against the potential (virtual work), damping power,
point-force moments and follower forces by hand.

Virtual work: for a tangent dq (dp perpendicular to p) Q . dq = -dV, dV by a central
difference of equations.potential_energy (step 1e-6: truncation ~ h^2 |V'''| ~ 1e-12,
round-off ~ 1e-16 |V| / h ~ 1e-10 for V ~ 1, so 1e-7 relative is a safe bound).
"""

import numpy as np
import pytest

from mbsim.errors import DeckError
from mbsim.forces import FORCES
from mbsim.model import compile_model
from mbsim.rotations import from_axis_angle
from tests.forces.builders import (
    Q_of,
    force,
    revolute_ab,
    rotations,
    tangent,
    two_body_deck,
    two_body_model,
)
from tests.helpers import body, joint, pts, spec
from tests.reference import equations as eq

rng = np.random.default_rng(2024)


def _case(type_):
    """A model with one element of type_ (conservative data where the type has any)."""
    if type_ == "tsda":
        f = force(
            "S",
            "tsda",
            ("a", "b"),
            {"a": rng.normal(size=3), "b": rng.normal(size=3)},
            k=120.0,
            c=0.0,
            L0=0.8,
        )
        return two_body_model([f], rng)
    if type_ == "rsda":
        J = revolute_ab(rng)
        f = force("R", "rsda", ("a", "b"), dict(J.points), joint="REV", k=35.0, theta0=0.0)
        d = two_body_deck([f], rng, [J])
        m = compile_model(d)
        # theta0 0.6 rad away from the current angle: far from the wrap at theta0 +- pi
        th, _ = m.forces[0].angle.terms(eq.State(m, m.q0))
        f.data["theta0"] = th + 0.6
        return compile_model(d)
    if type_ == "force":
        f = force("F", "force", ("a",), {"a": rng.normal(size=3)}, vector=rng.normal(size=3))
        return two_body_model([f], rng)
    if type_ == "torque":
        f = force("T", "torque", ("a", "b"), vector=rng.normal(size=3))
        return two_body_model([f], rng)
    if type_ == "tire":  # at rest only the vertical spring acts (tests/forces/test_tire.py)
        f = force("W", "tire", ("a",), {"a": rng.normal(size=3)}, kt=2e5, radius=10.0,
                  c_alpha=5e4)  # fmt: skip
        return two_body_model([f], rng)
    if type_ == "bushing":  # random poses: a large relative rotation (also test_bushing.py)
        P = rng.normal(size=3)
        frames = {b: pts(P, P + [1, 0, 0], P + [0, 1, 0]) for b in ("a", "b")}
        f = force("B", "bushing", ("a", "b"), frames, k=[800.0, 1200.0, 2000.0],
                  kr=[30.0, 45.0, 90.0], preload_force=[5.0, -3.0, 2.0])  # fmt: skip
        return two_body_model([f], rng)
    if type_ == "contact":  # two spheres overlapping by 10 % of their centre distance
        data = dict(geometry="sphere-sphere", radius=1.0, radius_i=1.0, k=1e4, exponent=1.5,
                    nu=0.3, c_max=0.0, restitution_law="lankarani-nikravesh", mu=0.0,
                    v_slip=1e-3)  # fmt: skip
        f = force("C", "contact", ("a", "b"), {"a": [0, 0, 0], "b": [0, 0, 0]}, **data)
        d = two_body_deck([f], rng)
        m = compile_model(d)
        g, _, _ = m.forces[0].geometry_of(eq.State(m, m.q0))
        L = 2.0 - g
        f.data.update(radius=0.55 * L, radius_i=0.55 * L)
        return compile_model(d)
    if type_ == "stop":  # a translational joint's travel beyond the upper stop
        P = rng.normal(size=3)
        Pb = rng.normal(size=(3, 3))
        J = joint("T", "translational", "a", "b",
                  {"a": pts(P, P + rng.normal(size=3), P + rng.normal(size=3)),
                   "b": pts(*Pb)})  # fmt: skip
        data = dict(joint="T", joint_type="translational", k=1e3, exponent=1.5, c_max=0.0,
                    restitution_law="lankarani-nikravesh")  # fmt: skip
        f = force("S", "stop", ("a", "b"), dict(J.points), upper=1e9, **data)
        d = two_body_deck([f], rng, [J])
        m = compile_model(d)
        s, *_ = m.forces[0].travel(eq.State(m, m.q0))
        f.data["upper"] = s - 0.3
        return compile_model(d)
    if type_ == "friction":  # a slipping translational joint, normal load the preload
        P = rng.normal(size=3)
        J = joint("T", "translational", "a", "b",
                  {"a": pts(P, P + rng.normal(size=3), P + rng.normal(size=3)),
                   "b": pts(*rng.normal(size=(3, 3)))})  # fmt: skip
        data = dict(joint="T", joint_type="translational", mu_s=0.5, mu_k=0.3, viscous=2.0,
                    preload=5.0, stribeck_velocity=0.1, reaction=False)  # fmt: skip
        return two_body_model([force("FR", "friction", ("a", "b"), dict(J.points), **data)],
                              rng, [J])
    raise KeyError(f"no test case for force type {type_!r}: add one")


def _slip_virtual_work(model, q):
    """A hybrid element (joint friction) in slip: its loads (apply_in) do the work Fs ds
    along the joint's coordinate s (ds by central differences along dq, step 1e-6)."""
    el = model.forces[0]
    qd = _velocity(model, q)
    st = eq.State(model, q, qd)
    G = eq.State(model, q).G
    for mode in ("+", "-"):
        F, n = np.zeros((model.nb, 3)), np.zeros((model.nb, 3))
        el.apply_in(mode, st, 0.0, None, F, n)
        Q = np.concatenate([F, 2 * np.einsum("bij,bi->bj", G, n)], axis=1).reshape(-1)
        Fs = el.slip_load(mode, st, None)[0]
        assert Fs != 0.0
        for _ in range(3):
            dq = tangent(model, q, rng)
            h = 1e-6
            ds = (el.travel(eq.State(model, q + h * dq))[0]
                  - el.travel(eq.State(model, q - h * dq))[0]) / (2 * h)
            assert abs(Q @ dq - Fs * ds) < 1e-7 * max(1.0, abs(Fs * ds)), (Q @ dq, Fs * ds)


@pytest.mark.parametrize("type_", sorted(FORCES))
def test_virtual_work(type_):
    """Q . dq = -dV for conservative elements; torques do T . dphi."""
    model = _case(type_)
    q = model.q0
    if type_ == "friction":  # hybrid with modes of its own (contact's modes keep the law)
        return _slip_virtual_work(model, q)
    Q = Q_of(model, q)
    for _ in range(3):
        dq = tangent(model, q, rng)
        if type_ == "torque":
            T = np.asarray(model.forces[0].vec, float)  # the deck's vector (frame global)
            dphi = rotations(model, q, dq)
            expected = T @ (dphi[1] - dphi[0])  # +T on b (j), -T on a (i)
            assert abs(Q @ dq - expected) < 1e-12 * max(1, abs(expected))
            continue
        h = 1e-6
        dV = (eq.potential_energy(model, q + h * dq) - eq.potential_energy(model, q - h * dq)) / (
            2 * h
        )
        assert eq.potential_energy(model, q) != 0.0
        assert abs(Q @ dq + dV) < 1e-7 * max(1.0, abs(dV)), (Q @ dq, -dV)


def _velocity(model, q):
    """A random qd with p . pd = 0 (a possible motion)."""
    return tangent(model, q, rng)


@pytest.mark.parametrize("type_", ["tsda", "rsda"])
def test_damping_power(type_):
    """k = 0, c > 0: Q . qd = -c rate^2 <= 0 (the gyroscopic term does no work); the rate
    against a central difference of the length/angle along q + s qd."""
    c = 7.5
    if type_ == "tsda":
        f = force(
            "S",
            "tsda",
            ("a", "b"),
            {"a": rng.normal(size=3), "b": rng.normal(size=3)},
            k=0.0,
            c=c,
            L0=0.3,
        )
        model = two_body_model([f], rng)
    else:
        J = revolute_ab(rng)
        f = force("R", "rsda", ("a", "b"), dict(J.points), joint="REV", c=c)
        model = two_body_model([f], rng, [J])
    el = model.forces[0]
    q = model.q0
    qd = _velocity(model, q)
    power = Q_of(model, q, qd) @ qd
    key = "velocity" if type_ == "tsda" else "rate"
    rate = el.channels(eq.State(model, q, qd), 0.0)[key][0]
    assert power <= 0 and abs(power + c * rate**2) < 1e-10 * max(1, c * rate**2)
    pos = "length" if type_ == "tsda" else "angle"
    h = 1e-6
    x = [el.channels(eq.State(model, q + s * qd, qd), 0.0)[pos][0] for s in (-h, h)]
    assert abs((x[1] - x[0]) / (2 * h) - rate) < 1e-6 * max(1, abs(rate))


def _one_body(forces, p=(1, 0, 0, 0), r=(0, 0, 0)):
    return compile_model(spec([body("a", 1.0, (1, 1, 1), r, p)], forces=forces))


def test_point_force_moment_by_hand():
    """Body turned 90 deg about z; F = (0, 0, 10) N at s' = (1, 0, 0): global arm A s' =
    (0, 1, 0), moment (0, 1, 0) x (0, 0, 10) = (10, 0, 0); in the body frame
    A^T (10, 0, 0) = (0, -10, 0) = s' x A^T F = (1, 0, 0) x (0, 0, 10)."""
    p = from_axis_angle([0, 0, 1], np.pi / 2)
    model = _one_body([force("F", "force", ("a",), {"a": [1, 0, 0]}, vector=[0, 0, 10])], p)
    _, F, n_local = eq.applied_forces(model, model.q0, np.zeros(7))
    np.testing.assert_allclose(F[0], [0, 0, 10], atol=1e-14)
    np.testing.assert_allclose(n_local[0], [0, -10, 0], atol=1e-12)
    A = eq.State(model, model.q0).A[0]
    np.testing.assert_allclose(A @ n_local[0], [10, 0, 0], atol=1e-12)


def test_follower_force_turns_with_the_body():
    """frame: local, F' = (1, 0, 0): global x at rest, global y after 90 deg about z."""
    f = force("F", "force", ("a",), {"a": [0, 0, 0]}, vector=[1, 0, 0], frame="local")
    for angle, expected in ((0.0, [1, 0, 0]), (np.pi / 2, [0, 1, 0]), (np.pi, [-1, 0, 0])):
        model = _one_body([f], from_axis_angle([0, 0, 1], angle))
        _, F, _n_local = eq.applied_forces(model, model.q0, np.zeros(7))
        np.testing.assert_allclose(F[0], expected, atol=1e-12)
        assert model.forces[0].potential(eq.State(model, model.q0)) == 0.0


def test_torque_local_frame_and_single_body():
    """A local torque (0, 0, 2) on a body turned 90 deg about x is global (0, -2, 0)."""
    p = from_axis_angle([1, 0, 0], np.pi / 2)
    model = _one_body([force("T", "torque", ("a",), vector=[0, 0, 2], frame="local")], p)
    _, _, n_local = eq.applied_forces(model, model.q0, np.zeros(7))
    np.testing.assert_allclose(n_local[0], [0, 0, 2], atol=1e-12)
    np.testing.assert_allclose(
        model.forces[0].channels(eq.State(model, model.q0), 0)["torque"][0], [0, -2, 0], atol=1e-12
    )


def test_tsda_sign_and_actuator():
    """Points 2 m apart on x, L0 = 1.5, k = 100: tension 50 N pulls them together; an actuator
    of 80 N pushes them apart (tension -30 N)."""
    bodies = [body("a", r=(0, 0, 0)), body("b", r=(2, 0, 0))]
    f = force("S", "tsda", ("a", "b"), {"a": [0, 0, 0], "b": [0, 0, 0]}, k=100.0, L0=1.5)
    model = compile_model(spec(bodies, forces=[f]))
    _, F, _ = eq.applied_forces(model, model.q0, np.zeros(14))
    np.testing.assert_allclose(F, [[50, 0, 0], [-50, 0, 0]])
    f.data["actuator"] = 80.0
    model = compile_model(spec(bodies, forces=[f]))
    _, F, _ = eq.applied_forces(model, model.q0, np.zeros(14))
    np.testing.assert_allclose(F, [[-30, 0, 0], [30, 0, 0]])
    assert model.forces[0].potential(eq.State(model, model.q0)) == pytest.approx(12.5)


def test_rsda_restoring_torque_by_hand():
    """Ground frame f = z, g = x; body b turned 0.3 rad about z, theta0 = 0, k = 10: the
    spring turns b back: torque -3 N m about z on b, +3 on the ground."""
    from tests.helpers import joint, pts

    J = joint(
        "REV",
        "revolute",
        "g",
        "b",
        {"g": pts([0, 0, 0], [0, 0, 1], [1, 0, 0]), "b": pts([0, 0, 0], [0, 0, 1], [1, 0, 0])},
    )
    f = force("R", "rsda", ("g", "b"), dict(J.points), joint="REV", k=10.0)
    bodies = [body("g", ground=True), body("b", p=from_axis_angle([0, 0, 1], 0.3))]
    model = compile_model(spec(bodies, [J], forces=[f]))
    st = eq.State(model, model.q0, np.zeros(14))
    _, _, n_local = eq.applied_forces(model, model.q0, np.zeros(14))
    np.testing.assert_allclose(st.A[1] @ n_local[1], [0, 0, -3], atol=1e-12)
    np.testing.assert_allclose(n_local[0], [0, 0, 3], atol=1e-12)
    ch = model.forces[0].channels(st, 0.0)
    assert ch["angle"][0] == pytest.approx(0.3) and ch["torque"][0] == pytest.approx(3.0)


def test_errors_name_the_field():
    with pytest.raises(DeckError, match="exactly one of vector, law"):
        _one_body([force("F", "force", ("a",), vector=[1, 0, 0], law=[0, 0, 1])])
    with pytest.raises(DeckError, match="needs a direction"):
        _one_body([force("F", "force", ("a",), law="3*t")])
    with pytest.raises(DeckError, match="unknown body"):
        _one_body([force("F", "force", ("nobody",), vector=[1, 0, 0])])
    with pytest.raises(DeckError, match="either a law"):
        two_body_model([force("S", "tsda", ("a", "b"), k=1.0, L0=1.0, law="2*l")], rng)


@pytest.mark.parametrize("type_", sorted(FORCES))
def test_many_equals_the_scalar_code_at_each_output(type_):
    """channels_many, potential_many, loads_many over a series of states (core.States) equal
    channels, potential, apply at each state to a few ulps (the array code of a type sums in
    another order; 1e-13 relative to the largest value)."""
    from mbsim import core

    model = _case(type_)
    states = [model.q0]
    for _ in range(4):  # nearby states (the contact still touching), random velocities
        q = model.q0 + 1e-3 * tangent(model, model.q0, rng)
        Qb = q.reshape(model.nb, 7)
        Qb[:, 3:] /= np.linalg.norm(Qb[:, 3:], axis=1, keepdims=True)
        states.append(q)
    q = np.array(states)
    qd = np.array([_velocity(model, qk) for qk in q])
    t = np.linspace(0.0, 0.4, len(q))
    series = core.States(model, q, qd)
    el = model.forces[0]
    many = el.channels_many(series, t)
    each = [el.channels(core.State(model, q[k], qd[k]), t[k]) for k in range(len(t))]
    assert set(many) == set(each[0])
    for key, (vals, unit) in many.items():
        ref = np.array([np.asarray(e[key][0], float) for e in each])
        assert unit == each[0][key][1]
        assert vals.shape == ref.shape, key
        assert np.allclose(vals, ref, rtol=0, atol=1e-13 * max(1.0, np.abs(ref).max())), key
    V = el.potential_many(core.States(model, q))
    V_ref = np.array([el.potential(core.State(model, qk)) for qk in q])
    assert np.allclose(V, V_ref, rtol=0, atol=1e-13 * max(1.0, np.abs(V_ref).max()))
    F, n = np.zeros((len(t), model.nb, 3)), np.zeros((len(t), model.nb, 3))
    el.loads_many(series, t, F, n)
    for k in range(len(t)):
        Fk, nk = np.zeros((model.nb, 3)), np.zeros((model.nb, 3))
        el.apply(core.State(model, q[k], qd[k]), t[k], Fk, nk)
        scale = max(1.0, np.abs(Fk).max(), np.abs(nk).max())
        assert np.allclose(F[k], Fk, rtol=0, atol=1e-13 * scale)
        assert np.allclose(n[k], nk, rtol=0, atol=1e-13 * scale)
