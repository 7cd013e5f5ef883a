"""The equations of motion as the integrators see them (System), and the registry contract."""

import numpy as np
import pytest

from mbsim.analyses.assembly import assemble
from mbsim.analyses.dynamic import dynamic
from mbsim.integrators import ALIASES, INTEGRATORS, System
from tests.integrators import models as M
from tests.reference import equations as eq


def _cases():
    gov = M.governor()
    sc = M.slider_crank()
    ch = M.chain(4)
    qc = assemble(ch).q
    rng = np.random.default_rng(1)
    qdc = rng.normal(size=ch.nq) * 0.1
    return [
        ("governor", gov, *M.governor_state(gov)),
        ("slider-crank", sc, *M.slider_crank_state(sc, 6.0)),
        ("chain", ch, qc, qdc),
    ]


@pytest.mark.parametrize("sparse", [False, True])
def test_accelerations_match_the_kkt_solve(sparse):
    """The Schur solve with the modified mass matrix equals the dense KKT solve of
    equations.accelerations (same equations; differences are round-off times cond ~ 1e4)."""
    for name, model, q, qd in _cases():
        s = System(model, sparse=sparse)
        qdd, lam, power = s.accelerations(q, qd, 0.0)
        qdd_ref, lam_ref = eq.accelerations(model, q, qd, 0.0)
        scale = max(1.0, np.abs(qdd_ref).max())
        assert np.abs(qdd - qdd_ref).max() < 1e-9 * scale, name
        assert np.abs(lam - lam_ref).max() < 1e-8 * max(1.0, np.abs(lam_ref).max()), name
        Q = eq.applied_forces(model, q, qd, 0.0)[0]
        assert power == pytest.approx(Q @ qd, rel=1e-12, abs=1e-12)


def test_modified_mass_inverse_is_exact_off_the_unit_sphere():
    """Mt_p^-1 is the exact inverse for |p| != 1 (module doc of mbsim/fast/dynamics.py): the
    Schur solve then still equals the dense KKT solve of equations.accelerations (round-off
    times cond, 1e-10), for a spinning free body with |p| = 1.05."""
    from mbsim.rotations import omega_local_to_pd

    model = M.free_body()
    q = model.q0.copy()
    q[3:] = [0.9, 0.2, -0.3, 0.4]
    qd = np.zeros(7)
    qd[:3] = (0.1, 0.0, 0.2)
    qd[3:] = omega_local_to_pd(q[3:] / np.linalg.norm(q[3:]), np.array([0.5, 0.2, 1.0]))
    qdd, lam, _ = System(model).accelerations(q, qd, 0.0)
    qdd_ref, lam_ref = eq.accelerations(model, q, qd, 0.0)
    assert np.abs(qdd - qdd_ref).max() < 1e-10 * max(1.0, np.abs(qdd_ref).max())
    assert np.abs(lam - lam_ref).max() < 1e-10 * max(1.0, np.abs(lam_ref).max())


def test_projections_reach_the_manifold():
    model = M.slider_crank()
    q, qd = M.slider_crank_state(model, 6.0)
    s = System(model)
    rng = np.random.default_rng(0)
    qp, ok, its, res = s.project_positions(q + 1e-3 * rng.normal(size=q.size), 0.0)
    assert ok and res < 1e-12 and its <= 6
    vp = s.project_velocities(qp, qd + 1e-2 * rng.normal(size=q.size), 0.0)
    assert s.violations(qp, vp, 0.0)[1] < 1e-12


def test_registry_contract():
    """scipy-style registry: every class names itself, describes itself in one line, states
    its order and formulation; aliases point at registered names."""
    for name, cls in INTEGRATORS.items():
        assert cls.name == name
        assert cls.description and "\n" not in cls.description
        assert cls.order >= 2
        assert cls.formulation in ("gcp", "index-1", "index-3")
    assert all(v in INTEGRATORS for v in ALIASES.values())


@pytest.mark.parametrize("name", list(INTEGRATORS))
def test_every_integrator_runs_a_free_body(name):
    """A short run of a spinning free body completes; energy is kept to the tolerance asked
    (rtol 1e-6 on a 0.2 s run: a relative energy error below 1e-4 leaves a wide margin)."""
    model = M.free_body()
    q = model.q0.copy()
    from mbsim.rotations import omega_local_to_pd

    qd = np.zeros(7)
    qd[:3] = (0.1, 0.0, 0.2)
    qd[3:] = omega_local_to_pd(q[3:], np.array([0.5, 0.2, 1.0]))
    opts = {
        "t_end": 0.2,
        "step": 0.05,
        "integrator": name,
        "rtol": 1e-6,
        "atol": 1e-8,
        "q0": q,
        "qd0": qd,
    }
    if not INTEGRATORS[name].adaptive:
        opts["h"] = 0.01
    res = dynamic(model, opts)
    assert res.complete, res.message
    E = res.channel("monitors/energy").data
    assert np.abs(E - E[0]).max() < 1e-4 * E[0]
    assert res.counters["steps"] > 0 and res.counters["function_evaluations"] > 0
