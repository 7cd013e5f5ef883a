"""Bushing (mbsim/forces/bushing.py): natural frequencies and damping ratios of a block on a
bushing against the closed form, a free decay against the damped oscillation, the force as the
gradient of the potential, and the deck errors."""

from pathlib import Path

import numpy as np
import pytest

from mbsim import core
from mbsim.api import load_model, run_model
from mbsim.deck import load_deck_text
from mbsim.forces.bushing import jr_inverse, rotation_vector
from mbsim.model import compile_model
from mbsim.rotations import A as rot_A
from mbsim.rotations import from_axis_angle
from tests.forces.builders import assert_bad_edit, elastic_work_pairs

DECK = Path(__file__).parent / "data" / "bushing_block.yaml"
M = 2.0
J = np.array([0.3, 0.5, 0.7])
K, C = np.array([8000.0, 12000.0, 20000.0]), np.array([4.0, 6.0, 10.0])
KR, CR = np.array([300.0, 450.0, 900.0]), np.array([0.2, 0.3, 0.5])


def closed_form(mass, k, c) -> complex:
    """lambda of m x'' + c x' + k x = 0 with Im >= 0: (-c + sqrt(c^2 - 4 k m)) / (2 m)."""
    return (-c + np.sqrt(complex(c * c - 4 * k * mass))) / (2 * mass)


def eigenvalues(result) -> np.ndarray:
    lam = np.asarray(result.summary["eigenvalues"], dtype=complex)
    return np.sort_complex(lam[lam.imag > 0])


def test_six_modes_at_the_centroid_match_the_closed_form():
    """Bushing at the centroid, axes along the principal axes: six decoupled oscillators,
    omega = sqrt(k/m), sqrt(kr/J), zeta = c / (2 sqrt(k m)).  Central differences on a force
    that is linear near the reference: fd error ~ eps |F| / h, far below 1e-6."""
    spec, model = load_model(DECK)
    res = run_model(model, "linear", {}, deck=spec)
    expected = np.sort_complex(
        np.array(
            [closed_form(M, k, c) for k, c in zip(K, C)]
            + [closed_form(j, k, c) for j, k, c in zip(J, KR, CR)]
        )
    )
    lam = eigenvalues(res)
    assert lam.size == 6
    np.testing.assert_allclose(lam, expected, rtol=1e-6)
    zeta = sorted(res.summary["damping_ratios"])
    ref = sorted(
        [c / (2 * np.sqrt(k * M)) for k, c in zip(K, C)]
        + [c / (2 * np.sqrt(k * j)) for j, k, c in zip(J, KR, CR)]
    )
    np.testing.assert_allclose(zeta, ref, rtol=1e-6)


def test_offset_bushing_couples_translation_and_tilt():
    """Bushing at body point (0, 0, a), undamped.  A small tilt theta_y moves the point by
    a theta_y along x, so x and theta_y share V = kx (x + a theta_y)^2/2 + kry theta_y^2/2
    (likewise y with -a theta_x): det(K - w^2 M) = 0 gives
    m Jy w^4 - (m (kx a^2 + kry) + Jy kx) w^2 + kx kry = 0; z and theta_z stay decoupled."""
    a = 0.15
    text = DECK.read_text().replace(
        "P: [0, 0, 0], Q: [1, 0, 0], R: [0, 1, 0]",
        f"P: [0, 0, {a}], Q: [1, 0, {a}], R: [0, 1, {a}]",
    )
    text = text.replace("c: [4, 6, 10]", "c: [0, 0, 0]").replace(
        "cr: [0.2, 0.3, 0.5]", "cr: [0, 0, 0]"
    )
    res = run_model(compile_model(load_deck_text(text)), "linear", {})

    def pair(k, kr, j):
        b = M * (k * a * a + kr) + j * k
        disc = np.sqrt(b * b - 4 * M * j * k * kr)
        return [np.sqrt((b - disc) / (2 * M * j)), np.sqrt((b + disc) / (2 * M * j))]

    omega = sorted(
        pair(K[0], KR[1], J[1])
        + pair(K[1], KR[0], J[0])
        + [np.sqrt(K[2] / M), np.sqrt(KR[2] / J[2])]
    )
    lam = eigenvalues(res)
    np.testing.assert_allclose(np.sort(lam.imag), omega, rtol=1e-6)
    np.testing.assert_allclose(lam.real, 0, atol=1e-6 * max(omega))


def test_free_decay_of_the_vertical_mode():
    """z(t) = v0/wd exp(-zeta w t) sin(wd t) (m z'' + cz z' + kz z = 0, z(0) = 0, z'(0) = v0).
    rtol 1e-9, atol 1e-12 over 7 periods: the global error of an adaptive method is a few
    local tolerances per step accumulated over the run; bound 1e-6 of the amplitude."""
    v0 = 0.01
    _, model = load_model(DECK, overrides={"bodies.block.rdot": f"[0, 0, {v0}]"})
    res = run_model(
        model,
        "dynamic",
        {"t_end": 0.3, "step": 0.002, "rtol": 1e-9, "atol": 1e-12, "error_estimate": False},
    )
    assert res.complete
    w, zeta = np.sqrt(K[2] / M), C[2] / (2 * np.sqrt(K[2] * M))
    wd = w * np.sqrt(1 - zeta**2)
    z = v0 / wd * np.exp(-zeta * w * res.t) * np.sin(wd * res.t)
    got = res.channel("bodies/block/r").data[:, 2]
    assert np.abs(got - z).max() < 1e-6 * v0 / wd
    # the deflection channel is that motion in the bushing frame, the force -kz z - cz z'
    d = res.channel("forces/mount/deflection").data
    np.testing.assert_allclose(d[:, 2], got, atol=1e-15)
    f = res.channel("forces/mount/force").data[:, 2]
    zd = res.channel("bodies/block/rd").data[:, 2]
    np.testing.assert_allclose(f, -K[2] * got - C[2] * zd, atol=1e-9 * K[2] * v0 / wd)


@pytest.fixture
def general_bushing():
    """Two free bodies at random poses, a bushing with random frames, stiffness, preloads."""
    rng = np.random.default_rng(7)

    def frame():
        P = rng.normal(size=3)
        Q = P + rng.normal(size=3)
        u = Q - P
        w = rng.normal(size=3)
        w -= u * (u @ w) / (u @ u)
        return f"{{P: {P.tolist()}, Q: {Q.tolist()}, R: {(P + w).tolist()}}}"

    text = f"""
title: two bodies on a bushing
gravity: [0, 0, 0]
bodies:
  a: {{mass: 2, inertia: [1, 2, 3]}}
  b: {{mass: 3, inertia: [2, 2, 1], r: [0.1, -0.05, 0.08]}}
forces:
  mount:
    type: bushing
    bodies: [a, b]
    points: {{a: {frame()}, b: {frame()}}}
    k: [800, 1200, 2000]
    kr: [30, 45, 90]
    c: [3, 2, 1]
    cr: [0.1, 0.2, 0.3]
    preload_force: [5, -3, 2]
    preload_torque: [0.5, 0.2, -0.1]
"""
    model = compile_model(load_deck_text(text))
    q = model.q0.copy().reshape(2, 7)
    q[1, 3:] = from_axis_angle(rng.normal(size=3), 0.9)  # a large relative rotation (0.9 rad)
    return model, q.reshape(-1), rng


def test_elastic_loads_are_minus_the_gradient_of_the_potential(general_bushing):
    """Q (zero velocity) against central differences of V along random tangent directions
    (dp perpendicular to p), steps 1e-6: truncation ~ h^2 V''' ~ 1e-10 relative."""
    model, q, rng = general_bushing
    Q, _, _ = core.applied_forces(model, None, q, np.zeros(model.nq))
    for work, dV in elastic_work_pairs(model, q, rng, h=1e-6):
        assert work == pytest.approx(dV, rel=1e-7, abs=1e-9 * np.abs(Q).max())


def test_damping_only_dissipates(general_bushing):
    """The damping part's power -d'.C d' - theta'.Cr theta' <= 0: the loads' power at a random
    velocity minus that at zero velocity (the elastic part) is that non-positive number."""
    model, q, rng = general_bushing
    el = model.forces[0]
    from mbsim.core import State

    for _ in range(5):
        qd = rng.normal(size=model.nq)
        p = q.reshape(2, 7)[:, 3:]
        qd = qd.reshape(2, 7)
        qd[:, 3:] -= p * np.sum(qd[:, 3:] * p, 1, keepdims=True)
        qd = qd.reshape(-1)
        Qv, _, _ = core.applied_forces(model, None, q, qd)
        Q0, _, _ = core.applied_forces(model, None, q, np.zeros(model.nq))
        s = el.state(State(model, q, qd))
        # gyroscopic terms do no work (qd . Q_gyro = 0), so the difference is the damping power
        expected = -(s["dd"] @ (el.c * s["dd"]) + s["thd"] @ (el.cr * s["thd"]))
        assert (Qv - Q0) @ qd == pytest.approx(expected, rel=1e-9)


def test_rotation_vector_and_its_jacobian():
    """log(exp(theta)) = theta, and J_r^{-1} against differences of log(R exp(dphi))."""
    rng = np.random.default_rng(3)
    for angle in (1e-6, 0.3, 2.5):
        theta = rng.normal(size=3)
        theta *= angle / np.linalg.norm(theta)
        R = rot_A(from_axis_angle(theta, np.linalg.norm(theta)))
        np.testing.assert_allclose(rotation_vector(R), theta, rtol=1e-12, atol=1e-15)
        h = 1e-6
        Jn = np.column_stack(
            [
                (
                    rotation_vector(R @ rot_A(from_axis_angle(e, h)))
                    - rotation_vector(R @ rot_A(from_axis_angle(e, -h)))
                )
                / (2 * h)
                for e in np.eye(3)
            ]
        )
        np.testing.assert_allclose(Jn, jr_inverse(theta), atol=1e-8)


BAD = [
    ("k: [8000, 12000, 20000]", "k: [8000, -1, 20000]", "k must not be negative", "mount.k"),
    ("cr: [0.2, 0.3, 0.5]", "cr: [0.2, 0.3, -0.5]", "cr must not be negative", "mount.cr"),
    ("bodies: [ground, block]", "bodies: [ground, blok]", "blok", "mount.bodies"),
    (
        "block: {P: [0, 0, 0], Q: [1, 0, 0], R: [0, 1, 0]}",
        "block: {P: [0, 0, 0], Q: [1, 0, 0], R: [0.1, 1, 0]}",
        "orthogonal",
        "points.block.R",
    ),
    (
        "kr: [300, 450, 900]",
        "kr: [300, 450, 900]\n    torque_curves: [{polynomial: [0, 1]},"
        " {polynomial: [0, 1]}, {polynomial: [0, 1]}]",
        "either kr or torque_curves",
        "mount.torque_curves",
    ),
]


@pytest.mark.parametrize("old, new, message, path", BAD, ids=[b[2] for b in BAD])
def test_bad_parameters_name_the_key(old, new, message, path):
    assert_bad_edit(DECK, old, new, message, path)


def test_curves_replace_the_linear_stiffness():
    """force_curves with the linear polynomial k d give the linear bushing's loads; a cubic
    curve's potential is its integral (k d^2/2 + k3 d^4/4)."""
    base = DECK.read_text()
    curved = base.replace(
        "k: [8000, 12000, 20000]",
        "force_curves: [{polynomial: [0, 8000]}, {polynomial: [0, 12000]}, "
        "{polynomial: [0, 20000, 0, 1e6]}]",
    )
    m1, m2 = (compile_model(load_deck_text(t)) for t in (base, curved))
    q = m1.q0.copy()
    b = m1.body_index("block")
    q[7 * b : 7 * b + 3] = [0.01, -0.02, 0.03]
    Q1, _, _ = core.applied_forces(m1, None, q, np.zeros(m1.nq))
    Q2, _, _ = core.applied_forces(m2, None, q, np.zeros(m2.nq))
    assert Q2[7 * b + 2] - Q1[7 * b + 2] == pytest.approx(-1e6 * 0.03**3, rel=1e-12)
    np.testing.assert_allclose(Q2[7 * b : 7 * b + 2], Q1[7 * b : 7 * b + 2], rtol=1e-12)
    assert core.potential_energy(m2, None, q) - core.potential_energy(m1, None, q) == pytest.approx(
        1e6 * 0.03**4 / 4, rel=1e-9
    )


def test_preload_holds_the_weight_at_zero_deflection():
    """Gravity -z on the block and preload_force = m g up: the minimum of the potential is at
    zero deflection (equilibrium to the solver's tolerance); without the preload the block
    sags by m g / kz."""
    g = 9.81
    text = DECK.read_text().replace("gravity: [0, 0, 0]", f"gravity: [0, 0, {-g}]")
    sag = compile_model(load_deck_text(text))
    held = compile_model(
        load_deck_text(
            text.replace(
                "cr: [0.2, 0.3, 0.5]", f"cr: [0.2, 0.3, 0.5]\n    preload_force: [0, 0, {M * g!r}]"
            )
        )
    )
    for model, z in ((sag, -M * g / K[2]), (held, 0.0)):
        res = run_model(model, "equilibrium", {"method": "minimum"})
        assert res.complete, res.message
        zc = res.channel("bodies/block/r").data[-1, 2]
        assert zc == pytest.approx(z, abs=1e-9)
