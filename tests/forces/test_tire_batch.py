"""The tires of a model evaluated together (mbsim/forces/tire.py: TireGroup, one call of the
C law, mbsim/fast/kernels.c ``mb_tire_states``) against the tire law one tire at a time
(tests/forces/tire_reference.py), on the states of a vehicle run that slides (the deck's
scene ``circle``: 55 mph, every tire at mu F_ver for most of the run after the steer) and on
states where the law's branches switch.

Both compute the same floating-point operations up to their order (C loops against matmul,
a x b by components against skew(a) b), so they agree to a few ulps of the largest term:
1e-12 of the force scale (the largest |F| of the states compared) for the forces, 1e-12 of
the force scale times the lever (about the wheel radius, < 1 m) for the moments, 1e-12 for
the angles and dimensionless quantities at O(1)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mbsim import core
from mbsim.api import load_model, run_model
from mbsim.rotations import omega_local_to_pd
from tests.forces.tire_reference import REL, SCALARS, VECTORS, assert_matches, tire_state

DECK = Path(__file__).resolve().parents[2] / "models" / "vehicle.yaml"


@pytest.fixture(scope="module")
def circle_run():
    """(model, t (nt,), q, qd (nt, nq), result) of the circle scene to 3 s (the tires
    saturate from about 1.7 s)."""
    spec, model = load_model(DECK, scene="circle")
    res = run_model(model, "dynamic", {"t_end": 3.0}, deck=spec)
    assert res.status == "complete", res.message
    t = np.asarray(res.t)
    q, qd = [], []
    for name in model.body_names:
        r, p, rd, om = (
            res.channels[f"bodies/{name}/{key}"].data for key in ("r", "p", "rd", "omega_local")
        )
        pd = np.array([omega_local_to_pd(pk, wk) for pk, wk in zip(p, om)])
        q.append(np.concatenate([r, p], axis=1))
        qd.append(np.concatenate([rd, pd], axis=1))
    return model, t, np.concatenate(q, axis=1), np.concatenate(qd, axis=1), res


def tires_of(model):
    return [el for el in model.forces if el.type == "tire"]


def reference(model, q, qd):
    """{quantity: (nt, ne, ...)} from the one-tire-at-a-time law."""
    rows = []
    for qk, vk in zip(q, qd):
        st = core.State(model, qk, vk)
        rows.append([tire_state(el, st) for el in tires_of(model)])
    return {
        key: np.array([[np.asarray(s[key], float) for s in row] for row in rows])
        for key in VECTORS + SCALARS
    }


def test_circle_run_covers_the_linear_and_the_saturated_law(circle_run):
    """The states compared cover the saturated branch and the linear one."""
    model, t, q, qd, _ = circle_run
    sat = reference(model, q, qd)["saturated"]
    assert 0 < sat.mean() < 1


def test_group_at_each_state_matches_the_one_tire_law(circle_run):
    model, t, q, qd, _ = circle_run
    tires = tires_of(model)
    assert len({id(el.group) for el in tires}) == 1  # one group per model (Tire.bind)
    rows = []
    for qk, vk in zip(q, qd):
        st = core.State(model, qk, vk)
        rows.append([el.state(st, 0.0) for el in tires])
    batch = {
        key: np.array([[np.asarray(s[key], float) for s in row] for row in rows])
        for key in VECTORS[:1] + VECTORS[2:] + SCALARS
    }
    batch["n_local"] = np.array(
        [
            [tires[0].group.at(core.State(model, qk, vk))["n_local"][k] for k in range(len(tires))]
            for qk, vk in zip(q, qd)
        ]
    )
    assert_matches(batch, reference(model, q, qd))


def test_loads_match_the_one_tire_law(circle_run):
    """apply (the dynamic path) and loads_many (the outputs) add F and s_C x A^T F."""
    model, t, q, qd, _ = circle_run
    ref = reference(model, q, qd)
    nt, nb = len(t), model.nb
    F, n = np.zeros((nt, nb, 3)), np.zeros((nt, nb, 3))
    F_ref, n_ref = np.zeros((nt, nb, 3)), np.zeros((nt, nb, 3))
    Fm, nm = np.zeros((nt, nb, 3)), np.zeros((nt, nb, 3))
    states = core.States(model, q, qd)
    for k, el in enumerate(tires_of(model)):
        el.loads_many(states, t, Fm, nm)
        for i in range(nt):
            el.apply(core.State(model, q[i], qd[i]), t[i], F[i], n[i])
            F_ref[i, el.b] += ref["F"][i, k]
            n_ref[i, el.b] += ref["n_local"][i, k]
    scale = np.abs(ref["F"]).max()
    for got in (F, Fm):
        assert np.abs(got - F_ref).max() <= REL * scale
    for got in (n, nm):
        assert np.abs(got - n_ref).max() <= REL * scale * max(1.0, np.abs(ref["sc"]).max())


def test_channels_match_the_one_tire_law(circle_run):
    """channels_many (what a run records: every output at once) and channels (one state)."""
    model, t, q, qd, _ = circle_run
    ref = reference(model, q, qd)
    scale = np.abs(ref["F"]).max()
    bounds = {"F_ver": scale, "F_lat": scale, "force": scale}
    heading = np.arctan2(-ref["u"][..., 0], ref["u"][..., 1])
    states = core.States(model, q, qd)
    for k, el in enumerate(tires_of(model)):
        many = el.channels_many(states, t)
        one = el.channels(core.State(model, q[-1], qd[-1]), t[-1])
        expected = {
            key: ref[key][:, k]
            for key in ("F_ver", "F_lat", "alpha", "saturated", "deflection", "speed")
        }
        expected["heading"], expected["force"] = heading[:, k], ref["F"][:, k]
        assert set(many) == set(one) == set(expected)
        for key, want in expected.items():
            bound = REL * bounds.get(key, 1.0)
            assert np.abs(many[key][0] - want).max() <= bound, (el.name, key)
            assert np.abs(np.asarray(one[key][0]) - want[-1]).max() <= bound, (el.name, key)
            assert many[key][1] == one[key][1]  # units


@pytest.mark.parametrize("seed", range(5))
def test_branches_match_the_one_tire_law(circle_run, seed):
    """Random states about the run's: tires off the ground, in reverse, at standstill speed,
    beyond the limit, turned on their side (the forward axis vertical: u falls back to y)."""
    model, t, q, qd, _ = circle_run
    rng = np.random.default_rng(seed)
    nt = 40
    qs = q[rng.integers(0, len(t), nt)].copy()
    vs = qd[rng.integers(0, len(t), nt)].copy() * rng.choice([-1.0, 0.0, 0.01, 1.0], (nt, 1))
    qs[:, 2::7] += rng.uniform(-0.05, 0.05, (nt, model.nb))  # heights: some tires lift
    vs += rng.normal(scale=0.5, size=vs.shape)
    side = np.array([np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0])  # 90 deg about x
    qs[: nt // 4, 3:7] = side  # the chassis on its side (its p: forward y' along z)
    for el in tires_of(model):
        qs[: nt // 4, 7 * el.b + 3 : 7 * el.b + 7] = side
    for k in range(nt):  # renormalise p (the random steps keep |p| = 1 only roughly)
        for b in range(model.nb):
            p = qs[k, 7 * b + 3 : 7 * b + 7]
            qs[k, 7 * b + 3 : 7 * b + 7] = p / np.linalg.norm(p)
    tires = tires_of(model)
    states = core.States(model, qs, vs)
    batch = tires[0].group.at_many(states)
    assert_matches(batch, reference(model, qs, vs))
    ref = reference(model, qs, vs)
    assert ref["F_ver"].min() == 0.0 and ref["F_ver"].max() > 0.0


def test_a_system_evaluates_the_tires_in_c_with_the_loads_of_each_tire(circle_run):
    """The System compiles the tires (no Python force element is left on the vehicle's step
    path) and its loads equal the numpy equations' (tests/reference/equations.py), which
    add each element's own apply."""
    from mbsim.fast.dynamics import EL_TIRE, System
    from tests.reference import equations as eq

    model, t, q, qd, _ = circle_run
    system = System(model)
    assert not system.py_forces
    compiled = system.ei[system.ei[:, 0] == EL_TIRE, 1]
    assert sorted(compiled) == sorted(el.b for el in tires_of(model))
    for k in (0, len(t) // 2, len(t) - 1):
        Q, F, n = system.loads(q[k], qd[k], t[k])
        Q_ref, F_ref, n_ref = eq.applied_forces(model, q[k], qd[k], t[k])
        scale = np.abs(F_ref).max()
        assert np.abs(F - F_ref).max() <= REL * scale
        assert np.abs(n - n_ref).max() <= REL * scale  # levers < 1 m
        assert np.abs(Q - Q_ref).max() <= REL * max(scale, np.abs(Q_ref).max())


def test_outputs_evaluate_the_group_once_per_states(circle_run, monkeypatch):
    """Every tire's loads_many and channels_many at one States read one evaluation of the
    group (TireGroup.at_many), and each tire's column equals its own group of one (the
    same C function on the same numbers: to the bit, checked to REL of the force scale)."""
    from mbsim.fast import dynamics

    model, t, q, qd, _ = circle_run
    tires = tires_of(model)
    states = core.States(model, q, qd)
    alone = {el.name: el.own.at_many(states) for el in tires}  # before counting
    calls = []
    law = dynamics.tire_states
    monkeypatch.setattr(dynamics, "tire_states", lambda *a: calls.append(1) or law(*a))
    F, n = np.zeros((len(t), model.nb, 3)), np.zeros((len(t), model.nb, 3))
    channels = {}
    for el in tires:
        el.loads_many(states, t, F, n)
        channels[el.name] = el.channels_many(states, t)
    assert len(calls) == 1
    scale = np.abs(alone[tires[0].name]["F"]).max()
    F_alone, n_alone = np.zeros_like(F), np.zeros_like(n)
    for el in tires:
        own = alone[el.name]
        F_alone[:, el.b] += own["F"][:, 0]
        n_alone[:, el.b] += own["n_local"][:, 0]
        for key in ("F_ver", "F_lat", "alpha", "deflection", "speed"):
            bound = REL * (scale if key.startswith("F") else 1.0)
            assert np.abs(channels[el.name][key][0] - own[key][:, 0]).max() <= bound, key
        assert np.abs(channels[el.name]["force"][0] - own["F"][:, 0]).max() <= REL * scale
    assert np.abs(F - F_alone).max() <= REL * scale
    assert np.abs(n - n_alone).max() <= REL * scale  # levers < 1 m (module doc)
    tires[0].channels_many(core.States(model, q, qd), t)  # a new States: evaluated again
    assert len(calls) == 2
