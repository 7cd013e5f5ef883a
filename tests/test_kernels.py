"""The compiled fast path (mbsim.fast) against the numpy path it replaces.

References: :func:`mbsim.equations.constraints`, ``applied_forces``, ``mass_matrix``,
``accelerations`` and :class:`mbsim.integrators.system.System`, on the random joint and
driver specs of tests/test_constraints.py (q off the constraint manifold, |p| off 1), the
decks in models/ and the spatial chains of benchmarks/eval_constraints.py.

Bounds: constraint terms are the same formulas in another order of operations, so they
agree to round-off, 1e-13 of the largest entry (O(1) data: ~1e-16 per operation, < 100
operations).  Accelerations solve the same linear system by another factorisation (Schur
complement of the modified mass matrix vs dense LU of the KKT matrix): the difference is
round-off times the condition number, bounded here by 1e-10 of the largest entry.
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg as la

from mbsim import equations as eq
from mbsim import fast
from mbsim.constraints import DRIVERS, JOINTS
from mbsim.deck import load_deck, load_deck_text
from mbsim.model import compile_model
from tests.forces.builders import force, two_body_model
from tests.helpers import body, joint, pts, spec
from tests.test_constraints import _driver_specs, _joint_spec, _two_bodies

pytestmark = pytest.mark.skipif(not fast.AVAILABLE, reason="numba is not installed")

ROOT = Path(__file__).resolve().parents[1]
DECKS = sorted(p.stem for p in (ROOT / "models").glob("*.yaml"))
rng = np.random.default_rng(31337)


def _chain(n):
    path = ROOT / "benchmarks" / "eval_constraints.py"
    mod_spec = importlib.util.spec_from_file_location("_eval_constraints", path)
    mod = importlib.util.module_from_spec(mod_spec)
    mod_spec.loader.exec_module(mod)
    return compile_model(load_deck_text(mod.chain_yaml(n), f"chain{n}"))


def _close(a, b, tol):
    """max |a - b| <= tol * max(1, max |b|), with the numbers in the message."""
    a = a.toarray() if hasattr(a, "toarray") else np.asarray(a)
    b = b.toarray() if hasattr(b, "toarray") else np.asarray(b)
    assert a.shape == b.shape
    err = float(np.abs(a - b).max(initial=0.0))
    scale = max(1.0, float(np.abs(b).max(initial=0.0)))
    assert err <= tol * scale, f"max error {err:.3g} > {tol:g} x {scale:.3g}"


def _check_constraints(model, q, qd, t, sparse=False):
    ref = eq.constraints(model, q, t, qd=qd, gamma=True, nu=True)
    fc = fast.FastConstraints(model, sparse=sparse)
    got = fc.constraints(q, t, qd=qd, gamma=True, nu=True)
    for name in ("phi", "jac", "gamma", "nu"):
        _close(getattr(got, name), getattr(ref, name), 1e-13)
    # the buffers of evaluate hold the same numbers; phi alone leaves jac and gamma out
    T = fc.evaluate(q, t, qd=qd, gamma=True)
    _close(T.jac, ref.jac, 1e-13)
    only = fc.constraints(q, t, jac=False)
    assert only.jac is None and only.gamma is None and only.nu is None
    _close(only.phi, ref.phi, 1e-13)


def _independent_rows(model, q, t=0.0):
    """Rows of Phi_q(q) that are linearly independent (QR with column pivoting of J^T)."""
    J = eq.constraints(model, q, t).jac
    _, R, piv = la.qr(J.T, mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    return np.sort(piv[: int(np.sum(d > 1e-9 * d.max()))])


def _check_accelerations(model, q, qd, t, rows=None):
    qdd, lam = eq.accelerations(model, q, qd, t, rows=rows)
    fd = fast.FastDynamics(model, rows)
    for _ in range(2):  # a second call on the same object: nothing stale is reused
        a, b, _power = fd.accelerations(q, qd, t)
        _close(a, qdd, 1e-10)
        _close(fd.full_lam(b), lam, 1e-10)


# -- every joint and driver type: the specs of tests/test_constraints.py ----------------------
@pytest.mark.parametrize("type_", sorted(JOINTS))
def test_joint_terms_and_accelerations_match_numpy(type_):
    model = compile_model(spec(_two_bodies(), [_joint_spec(type_)], gravity=(0, 0, -9.81)))
    q = model.q0 + 0.1 * rng.normal(size=model.nq)
    qd = rng.normal(size=model.nq)
    _check_constraints(model, q, qd, 0.37)
    _check_constraints(model, q, qd, 0.37, sparse=True)
    _check_accelerations(model, q, qd, 0.37)


@pytest.mark.parametrize("type_", sorted(DRIVERS))
def test_driver_terms_and_accelerations_match_numpy(type_):
    joints, drivers = _driver_specs(type_)
    model = compile_model(spec(_two_bodies(), joints, drivers, gravity=(0, -9.81, 0)))
    q = model.q0 + 0.1 * rng.normal(size=model.nq)
    qd = rng.normal(size=model.nq)
    for t in (0.37, 2.9):  # the angle driver's target wraps past pi at t = 2.9
        _check_constraints(model, q, qd, t)
        _check_accelerations(model, q, qd, t)


def test_ground_and_normalization_rows():
    model = compile_model(
        spec(
            [body("g", ground=True), body("a", r=(1, 2, 3))],
            [joint("S", "spherical", "g", "a", {"g": pts([1, 0, 0]), "a": pts([0, 1, 0])})],
        )
    )
    q = model.q0 + 0.1 * rng.normal(size=model.nq)
    _check_constraints(model, q, rng.normal(size=model.nq), 0.0)


# -- the decks and the chains ------------------------------------------------------------------
@pytest.mark.parametrize("name", DECKS)
def test_decks_match_numpy(name):
    model = compile_model(load_deck(ROOT / "models" / f"{name}.yaml"))
    q = model.q0 + 1e-3 * rng.normal(size=model.nq)
    qd = 0.1 * rng.normal(size=model.nq)
    _check_constraints(model, q, qd, 0.21)
    _check_accelerations(model, q, qd, 0.21, _independent_rows(model, q, 0.21))


def test_four_bar_singular_inertia_takes_the_kkt_path():
    """Table 12.3.1 gives Izz = 0: no exact Mt^-1, the dense KKT solve instead."""
    model = compile_model(load_deck(ROOT / "models" / "four_bar.yaml"))
    fd = fast.FastDynamics(model)
    assert fd.kkt and set(fd.singular) == {"link1", "link2", "link3"}


@pytest.mark.parametrize("n", [4, 128])
def test_chains_match_numpy(n):
    """N = 128: nq = 903 >= SPARSE_NQ, the CSR Jacobian in its fixed pattern."""
    model = _chain(n)
    q = model.q0.copy()
    qd = 0.1 * rng.normal(size=model.nq)
    fc = fast.FastConstraints(model)
    assert fc.sparse == (model.nq >= fast.SPARSE_NQ)
    T = fc.constraints(q, 0.0)
    ref = eq.constraints(model, q, 0.0, sparse=True)
    assert (T.jac.nnz == ref.jac.nnz) if fc.sparse else isinstance(T.jac, np.ndarray)
    _check_constraints(model, q, qd, 0.0, sparse=fc.sparse)
    _check_accelerations(model, q, qd, 0.0)


# -- the System interface ----------------------------------------------------------------------
def _governor():
    return compile_model(load_deck(ROOT / "models" / "governor.yaml"))


def _slider_crank():
    return compile_model(load_deck(ROOT / "models" / "slider_crank.yaml"))


@pytest.mark.parametrize("build", [_governor, _slider_crank])
def test_system_interface_matches_numpy_system(build):
    from mbsim.integrators.system import System

    model = build()
    rows = _independent_rows(model, model.q0)
    q = model.q0 + 1e-3 * rng.normal(size=model.nq)
    qd = 0.1 * rng.normal(size=model.nq)
    t = 0.3
    for sparse in (False, True):
        ref, fd = System(model, rows, sparse), fast.FastDynamics(model, rows, sparse)
        assert (fd.m, fd.rheonomic, fd.sparse) == (ref.m, ref.rheonomic, ref.sparse)
        assert np.array_equal(fd.norm_pos, ref.norm_pos)
        a, b = (
            fd.terms(q, t, qd=qd, gamma=True, nu=True),
            ref.terms(q, t, qd=qd, gamma=True, nu=True),
        )
        for name in ("phi", "jac", "gamma", "nu"):
            _close(getattr(a, name), getattr(b, name), 1e-13)
        _close(fd.nu(q, t), ref.nu(q, t), 1e-13)
        for kw in ({}, {"baumgarte": (5.0, 7.0)}, {"jac": b.jac}):
            x, y = fd.accelerations(q, qd, t, **kw), ref.accelerations(q, qd, t, **kw)
            _close(x[0], y[0], 1e-10)
            _close(x[1], y[1], 1e-10)
            assert abs(x[2] - y[2]) <= 1e-10 * max(1.0, abs(y[2]))
        _close(fd.full_lam(x[1]), ref.full_lam(y[1]), 1e-10)
        assert np.allclose(fd.violations(q, qd, t), ref.violations(q, qd, t), rtol=1e-12)
        assert np.allclose(fd.energy(q, qd), ref.energy(q, qd), rtol=1e-14)
        qp, ok, _, res = fd.project_positions(q, t)
        qr, ok_r, _, _ = ref.project_positions(q, t)
        assert ok and ok_r and res <= 1e-12
        _close(qp, qr, 1e-9)
        _close(fd.project_velocities(qp, qd, t), ref.project_velocities(qr, qd, t), 1e-9)
    assert set(fd.counters) == set(ref.counters)


def test_mass_matrix_and_applied_forces_match_numpy():
    model = _governor()
    q = model.q0 + 1e-2 * rng.normal(size=model.nq)
    qd = rng.normal(size=model.nq)
    fd = fast.FastDynamics(model)
    assert not fd.py_forces  # the governor's spring is a compiled TSDA
    _close(fd.mass_matrix(q), eq.mass_matrix(model, q), 1e-13)
    ref = eq.applied_forces(model, q, qd, 0.4)[0]
    _close(fd.generalized_forces(q, qd, 0.4), ref, 1e-13)
    _close(fd.applied_forces(eq.State(model, q, qd), 0.4), ref, 1e-13)  # System's signature


def test_compiled_and_python_force_elements_match_numpy():
    """TSDA (with damping), constant forces and torques (global, follower, pair) compiled; a
    law-driven force falls back to its Python apply."""
    forces = [
        force(
            "S",
            "tsda",
            ("a", "b"),
            {"a": rng.normal(size=3), "b": rng.normal(size=3)},
            k=120.0,
            c=7.0,
            L0=0.8,
        ),
        force("F", "force", ("a",), {"a": rng.normal(size=3)}, vector=rng.normal(size=3)),
        force(
            "FL",
            "force",
            ("b",),
            {"b": rng.normal(size=3)},
            vector=rng.normal(size=3),
            frame="local",
        ),
        force("T", "torque", ("a", "b"), vector=rng.normal(size=3)),
        force("TL", "torque", ("a", "b"), vector=rng.normal(size=3), frame="local"),
        force("T1", "torque", ("b",), vector=rng.normal(size=3), frame="local"),
        force(
            "L",
            "force",
            ("a",),
            {"a": rng.normal(size=3)},
            law="3*t + 1",
            direction=[0.0, 1.0, 1.0],
        ),
    ]
    model = two_body_model(forces, rng)
    fd = fast.FastDynamics(model)
    assert [el.name for el in fd.py_forces] == ["L"] and fd.ei.shape[0] == 6
    q = model.q0 + 0.1 * rng.normal(size=model.nq)
    qd = rng.normal(size=model.nq)
    _close(fd.generalized_forces(q, qd, 0.7), eq.applied_forces(model, q, qd, 0.7)[0], 1e-13)
    _check_accelerations(model, q, qd, 0.7)


def test_rows_subset_and_bad_shapes():
    model = _governor()
    rows = np.arange(0, model.m, 2)
    fc = fast.FastConstraints(model, rows)
    q = model.q0 + 1e-3 * rng.normal(size=model.nq)
    ref = eq.constraints(model, q, 0.0)
    T = fc.constraints(q, 0.0)
    _close(T.phi, ref.phi[rows], 1e-13)
    _close(T.jac, ref.jac[rows], 1e-13)
    with pytest.raises(ValueError, match=r"q: expected shape \(35,\)"):
        fast.FastDynamics(model).accelerations(q[:-1], q, 0.0)
    with pytest.raises(ValueError, match="gamma needs the velocities"):
        fc.evaluate(q, gamma=True)


def test_without_numba_the_fast_classes_raise_import_error():
    code = (
        "import mbsim.fast as f, pytest\n"
        "assert not f.AVAILABLE\n"
        "from mbsim.deck import load_deck\nfrom mbsim.model import compile_model\n"
        "m = compile_model(load_deck('models/governor.yaml'))\n"
        "with pytest.raises(ImportError, match='needs numba'):\n    f.FastConstraints(m)\n"
        "with pytest.raises(ImportError, match='needs numba'):\n    f.FastDynamics(m)\n"
        "assert type(f.make_system(m)).__name__ == 'System'\n"
    )
    env = dict(os.environ, MBSIM_NO_NUMBA="1")
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr
