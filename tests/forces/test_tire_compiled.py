"""The tire law in C (mbsim/fast/kernels.c ``tire_law``: the ``EL_TIRE`` element of the
equations of motion and ``mb_tire_states``, the quantities at given states) against the
scalar law of tests/forces/tire_reference.py, the Python implementation mbsim ran before.

Bounds.  Both sides compute each quantity by the same formula with the same roundings up to
the order of the sums (a 3-term dot product or cross product, A s' by rows or by matmul): a
few roundings deep, each quantity agrees to a few ulps of its largest term.  The tests ask
REL = 1e-12 of the scale (the largest |F| of the states compared for forces, that times the
lever for moments, 1 for angles, speeds and lengths at O(1)): some 4500 eps, the bound of
tests/forces/test_tire_batch.py.  The largest differences seen here: 3e-16 of the scale for
forces and moments, 7e-15 m/s for velocities and speeds (up to about 40 m/s), 3e-15 rad for
alpha.  (The slip angle's atan2 is exact to about an ulp and continuous away from v_fwd =
v_lat = 0, where both sides compute exact zeros.)

Runs: the vehicle integrated with its tires in C and with the reference law as Python force
elements (:func:`tires_in_python`) follow right-hand sides that differ by round-off, so
both are solutions of the same problem within their error control: each output within
RUN_FACTOR (rtol |x| + atol) of the other, the integrator's tolerance on that component with
a margin for the accumulation over the steps (the largest share of it measured: 2.5e-11 at
the deck's rtol 1e-3, 1.2e-6 at rtol 1e-6, 0.08 at rtol 1e-9 with DOP853, where the step
sequences part; all three on a wheel's rd)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from mbsim import core
from mbsim.api import load_model, run_model
from mbsim.fast import dynamics
from mbsim.forces.base import ForceElement
from mbsim.forces.tire import Tire
from mbsim.model import compile_model
from mbsim.rotations import G as rot_G
from tests.forces.builders import force
from tests.forces.tire_reference import REL, SCALARS, VECTORS, assert_matches, tire_state
from tests.helpers import body, spec
from tests.reference import equations as eq

DECK = Path(__file__).resolve().parents[2] / "models" / "vehicle.yaml"
RUN_FACTOR = 10.0
R0 = 0.30


def tires_model():
    """Three free bodies, four tires: two on w1 (damping and rolling resistance, a slanted
    forward axis), one on w2 whose forward axis is z' (vertical at the identity: u falls
    back to y), one on w3 with the defaults; gravity off."""
    tires = [
        force("t1", "tire", ["w1"], {"w1": [0.1, 0.2, -0.05]}, kt=2.0e5, radius=R0,
              c_alpha=4.0e4, c=1.5e3, rolling=0.015),
        force("t2", "tire", ["w1"], {"w1": [-0.1, -0.3, 0.02]}, kt=1.5e5, radius=0.28,
              c_alpha=6.0e4, mu=1.1, v_min=1.0, forward=[1.0, 1.0, 0.2]),
        force("t3", "tire", ["w2"], {"w2": [0.0, 0.0, 0.0]}, kt=2.5e5, radius=R0,
              c_alpha=2.0e5, forward=[0.0, 0.0, 1.0]),
        force("t4", "tire", ["w3"], {"w3": [0.0, 0.05, 0.0]}, kt=2.0e5, radius=R0,
              c_alpha=3.0e4),
    ]  # fmt: skip
    bodies = [body(n, 40.0, (1.0, 0.5, 1.0)) for n in ("w1", "w2", "w3")]
    return compile_model(spec(bodies, forces=tires))


def tires_of(model):
    return [el for el in model.forces if isinstance(el, Tire)]


def reference(model, q, qd):
    """{quantity: (nt, ne, ...)} from the one-tire-at-a-time law."""
    rows = []
    for qk, vk in zip(q, qd):
        st = core.State(model, qk, vk)
        rows.append([tire_state(el, st) for el in tires_of(model)])
    return {key: np.array([[np.asarray(s[key], float) for s in row] for row in rows])
            for key in VECTORS + SCALARS}  # fmt: skip


def random_states(model, rng, nt):
    """(q, qd) (nt, nq): heights about the radius (some tires off the ground), orientations
    about z alone and arbitrary ones, speeds of 0, below v_min and above it in every
    direction (reverse included)."""
    q = np.zeros((nt, model.nb, 7))
    qd = np.zeros((nt, model.nb, 7))
    q[..., :2] = rng.normal(size=(nt, model.nb, 2))
    q[..., 2] = rng.uniform(0.15, 0.45, (nt, model.nb))
    yaw = rng.uniform(-np.pi, np.pi, (nt, model.nb))
    tilt = rng.normal(scale=0.1, size=(nt, model.nb, 3))  # about z, then tipped a little
    p = np.concatenate([np.cos(yaw / 2)[..., None], tilt], axis=-1)
    p[..., 3] += np.sin(yaw / 2)
    wild = rng.random((nt, model.nb)) < 0.3
    p[wild] = rng.normal(size=(int(wild.sum()), 4))
    q[..., 3:] = p / np.linalg.norm(p, axis=-1, keepdims=True)
    speed = rng.choice([0.0, 0.2, 12.0], (nt, model.nb, 1))
    rd = rng.normal(size=(nt, model.nb, 3)) * speed
    omega = rng.normal(scale=2.0, size=(nt, model.nb, 3)) * (speed > 0)
    qd[..., :3] = rd
    for k in range(nt):
        for b in range(model.nb):
            qd[k, b, 3:] = 0.5 * rot_G(q[k, b, 3:]).T @ omega[k, b]  # pd = G^T w' / 2
    return q.reshape(nt, -1), qd.reshape(nt, -1)


def corner_states(model):
    """(q, qd) (n, nq), one branch of the law per state (tire t1 on w1; w2 at the identity
    keeps t3's forward axis vertical throughout)."""
    q0 = np.zeros((model.nb, 7))
    q0[:, 2], q0[:, 3] = 0.25, 1.0  # every spindle near 0.25 below its radius
    cases = []

    def case(z=None, v=(0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0), p=None):
        q, qd = q0.copy(), np.zeros((model.nb, 7))
        if z is not None:
            q[:, 2] = z
        if p is not None:
            q[0, 3:] = p
        qd[:, :3] = v
        qd[0, 3:] = 0.5 * rot_G(q[0, 3:]).T @ np.asarray(w, float)
        cases.append((q.reshape(-1), qd.reshape(-1)))

    case()  # standstill: alpha = atan2(0, 0) = 0, no lateral force, not saturated
    case(v=(0.0, 20.0, 0.0))  # straight ahead: alpha = 0, f_lin = 0 (not saturated)
    case(v=(0.0, -20.0, 0.0))  # straight back: rolling resistance pushes forward
    case(v=(3.0, -20.0, 0.0))  # reverse with slip: alpha from |v_fwd|
    case(v=(8.0, 5.0, 0.0))  # beyond mu F_ver: saturated
    case(v=(0.1, 0.2, 0.0))  # below v_min: faded
    case(z=0.5, v=(8.0, 5.0, 0.0))  # off the ground: no force, not saturated
    case(v=(0.0, 20.0, 20.0))  # t1 on the ground, k_t d - c d_dot < 0: no tension
    case(v=(0.5, 20.0, 20.0))  # the same with slip: f_lin != 0 >= mu F_ver = 0
    side = [math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0]  # w1 on its side
    case(v=(4.0, 1.0, -0.2), w=(0.0, 1.0, 2.0), p=side)  # y' vertical: heading y
    return np.array([c[0] for c in cases]), np.array([c[1] for c in cases])


def test_corner_states_cover_every_branch():
    model = tires_model()
    ref = reference(model, *corner_states(model))
    t1 = ref["F_ver"][:, 0], ref["saturated"][:, 0], ref["alpha"][:, 0], ref["speed"][:, 0]
    f_ver, sat, alpha, speed = t1
    assert (f_ver == 0).any() and (f_ver > 0).any()
    assert (ref["deflection"][:, 0] > 0)[f_ver == 0].any()  # clamped on the ground
    assert sat.any() and not sat[alpha == 0].any()
    assert ((speed > 0) & (speed < 0.5)).any() and (speed == 0).any()
    assert np.all(ref["u"][:, 2] == [0.0, 1.0, 0.0])  # t3's forward axis stands vertical
    assert np.array_equal(ref["u"][-1, 0], [0.0, 1.0, 0.0])  # t1's on its side
    assert (ref["F_roll"][:, 0] < 0).any() and (ref["F_roll"][:, 0] > 0).any()


def test_c_law_matches_the_reference_at_corner_states():
    model = tires_model()
    q, qd = corner_states(model)
    group = tires_of(model)[0].group
    assert_matches(group.at_many(core.States(model, q, qd)), reference(model, q, qd))


@pytest.mark.parametrize("seed", range(4))
def test_c_law_matches_the_reference_at_random_states(seed):
    model = tires_model()
    q, qd = random_states(model, np.random.default_rng(seed), 200)
    ref = reference(model, q, qd)
    assert 0 < ref["saturated"].mean() < 1 and (ref["F_ver"] == 0).any()
    assert_matches(tires_of(model)[0].group.at_many(core.States(model, q, qd)), ref)
    for k in (0, 57, 199):  # a tire alone at one state: its own group of one
        st = core.State(model, q[k], qd[k])
        for j, el in enumerate(tires_of(model)):
            one = el.state(st, 0.0)
            for key in VECTORS[:1] + VECTORS[2:] + SCALARS:
                scale = np.abs(ref["F"]).max() if key.startswith("F") else 1.0
                assert np.abs(one[key] - ref[key][k, j]).max() <= REL * scale, key


def test_system_applies_the_tires_in_c_as_the_reference_adds_them(monkeypatch):
    """Q, F, n' of a System (tires compiled: no Python element) equal the numpy equations
    with the reference law as each tire's apply (tests/reference/equations.py), with two
    tires on one body and tires on different bodies."""
    model = tires_model()
    system = dynamics.System(model)
    assert not system.py_forces and list(system.ei[:, 0]) == [dynamics.EL_TIRE] * 4
    q, qd = random_states(model, np.random.default_rng(7), 60)
    group = tires_of(model)[0].group
    for qk, vk in zip(q, qd):  # the equations' F is the group's to the bit (one C function)
        F_group = np.zeros((model.nb, 3))
        group.apply(core.State(model, qk, vk), 0.0, F_group, np.zeros((model.nb, 3)))
        assert np.array_equal(system.loads(qk, vk, 0.0)[1], F_group)
    monkeypatch.setattr(Tire, "apply", reference_apply)
    for qk, vk in zip(q, qd):
        Q, F, n = system.loads(qk, vk, 0.0)
        Q_ref, F_ref, n_ref = eq.applied_forces(model, qk, vk, 0.0)
        scale = max(1.0, np.abs(F_ref).max())
        assert np.abs(F - F_ref).max() <= REL * scale
        assert np.abs(n - n_ref).max() <= REL * scale  # levers < 1 m
        assert np.abs(Q - Q_ref).max() <= REL * scale  # Q_p = 2 G^T n', |p| = 1


def reference_apply(self, st, t, F, n_local):
    """Tire.apply by the reference law (the Python path)."""
    s = tire_state(self, st)
    F[self.b] += s["F"]
    n_local[self.b] += s["n_local"]


def tires_in_python(monkeypatch):
    """Models compiled from now on apply their tires in Python by the reference law, as
    mbsim did before the law was compiled: the System leaves them out of its tables
    (element_tables), calls their ``apply`` per evaluation, and the outputs their
    ``loads_many`` (the contract's default: ``apply`` per output)."""
    compiled = dynamics.element_tables

    def tables(forces):
        ei, ef, py = compiled([el for el in forces if not isinstance(el, Tire)])
        return ei, ef, py + tuple(el for el in forces if isinstance(el, Tire))

    monkeypatch.setattr(dynamics, "element_tables", tables)
    monkeypatch.setattr(Tire, "apply", reference_apply)
    monkeypatch.setattr(Tire, "loads_many", ForceElement.loads_many)


@pytest.fixture(scope="module")
def circle_states():
    """(t, q, qd) at the outputs of the vehicle's circle scene to 3 s (every tire
    saturates after the steer)."""
    spec_, model = load_model(DECK, scene="circle")
    res = run_model(model, "dynamic", {"t_end": 3.0}, deck=spec_)
    assert res.status == "complete", res.message
    return np.asarray(res.t), *state_arrays(model, res)


def state_arrays(model, res):
    """(q, qd) (nt, nq) of a result's body channels."""
    q, qd = [], []
    for name in model.body_names:
        r, p, rd, om = (res.channels[f"bodies/{name}/{key}"].data
                        for key in ("r", "p", "rd", "omega_local"))  # fmt: skip
        pd = 0.5 * np.einsum("tji,tj->ti", rot_G(p), om)  # pd = G^T w' / 2
        q.append(np.concatenate([r, p], axis=1))
        qd.append(np.concatenate([rd, pd], axis=1))
    return np.concatenate(q, axis=1), np.concatenate(qd, axis=1)


def test_vehicle_forces_and_accelerations_equal_the_python_path(circle_states, monkeypatch):
    """The vehicle's System with compiled tires against one with the reference law in
    Python, at the circle run's outputs: Q to REL of its scale; the accelerations solve the
    same equations with those Q (the same factorisation), so they agree to the round-off of
    Q times the solve's condition (bound 1e-10 of their scale, tests/test_kernels.py)."""
    t, q, qd = circle_states
    a = dynamics.System(load_model(DECK, scene="circle")[1])  # its tables built here
    tires_in_python(monkeypatch)
    b = dynamics.System(load_model(DECK, scene="circle")[1])
    assert not a.py_forces and [el.type for el in b.py_forces] == ["tire"] * 4
    for k in range(0, len(t), 7):
        Qa, Qb = a.generalized_forces(q[k], qd[k], t[k]), b.generalized_forces(q[k], qd[k], t[k])
        assert np.abs(Qa - Qb).max() <= REL * np.abs(Qb).max()
        qdd_a, qdd_b = a.accelerations(q[k], qd[k], t[k])[0], b.accelerations(q[k], qd[k], t[k])[0]
        assert np.abs(qdd_a - qdd_b).max() <= 1e-10 * np.abs(qdd_b).max()


def compare_runs(scene, opt, monkeypatch):
    """The vehicle run ``opt`` with compiled tires and with the reference law in Python:
    {channel: largest |difference| / its bound} for every body's r, rd and every tire's F_ver,
    the bound RUN_FACTOR (rtol |x| + atol) (module doc); F_ver = k_t (radius - z) with the
    spindle at the wheel's origin, so its bound is k_t times its wheel's height bound."""
    runs = []
    for python in (False, True):
        if python:
            tires_in_python(monkeypatch)
        spec_, model = load_model(DECK, scene=scene)
        res = run_model(model, "dynamic", opt, deck=spec_)
        assert res.status == "complete", res.message
        py = dynamics.System(model).py_forces  # the tables the run used (model_table)
        assert [el.type for el in py] == (["tire"] * 4 if python else [])
        runs.append((model, res))
    (model, a), (_, b) = runs
    rtol, atol = float(a.summary["rtol"]), float(a.summary["atol"])
    assert np.array_equal(a.t, b.t)

    def bound(x):
        return RUN_FACTOR * (rtol * np.abs(x).max() + atol)

    def data(res, key):
        return np.asarray(res.channels[key].data)

    ratios = {}
    for name in model.body_names:
        for key in (f"bodies/{name}/r", f"bodies/{name}/rd"):
            ratios[key] = np.abs(data(a, key) - data(b, key)).max() / bound(data(b, key))
    for el in tires_of(model):
        assert el.s.tolist() == [0.0, 0.0, 0.0]  # the spindle at the wheel's origin
        z = data(b, f"bodies/{model.body_names[el.b]}/r")[:, 2]
        key = f"forces/{el.name}/F_ver"
        ratios[key] = np.abs(data(a, key) - data(b, key)).max() / (el.kt * bound(z))
    return ratios


def assert_within(ratios):
    worst = max(ratios, key=ratios.get)
    assert ratios[worst] <= 1.0, f"{worst}: {ratios[worst]:.3g} of its bound"


def test_vehicle_run_equals_the_python_path(monkeypatch):
    """The deck as written (genalpha, rtol 1e-3, 6 s)."""
    assert_within(compare_runs(None, {}, monkeypatch))


def test_vehicle_tight_run_equals_the_python_path(monkeypatch):
    """The circle scene (all four tires saturated for most of it) at rtol 1e-6."""
    assert_within(compare_runs("circle", {"t_end": 3.0, "rtol": 1e-6, "atol": 1e-8},
                               monkeypatch))


@pytest.mark.slow
def test_vehicle_dop853_run_at_1e_9_equals_the_python_path(monkeypatch):
    """DOP853 at rtol 1e-9 on the circle scene: the two runs' step sequences part, and the
    outputs stay within the tolerance (measured: 0.08 of RUN_FACTOR's bound)."""
    assert_within(compare_runs("circle", {"t_end": 3.0, "rtol": 1e-9, "atol": 1e-11,
                                          "integrator": "dop853"}, monkeypatch))
