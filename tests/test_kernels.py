"""The C kernels (mbsim.fast: FastConstraints, System) against the numpy reference.

References: :func:`tests.reference.equations.constraints`, ``applied_forces``, ``mass_matrix`` and
``accelerations`` (dense KKT solve), on the random joint and driver specs of
tests/test_constraints.py (q off the constraint manifold, |p| off 1), every deck in models/
with each of its scenes, and the spatial chains of benchmarks/eval_constraints.py.  Also the
loader of the C library (mbsim.fast._lib): compile cache, stale builds, no compiler.

Bounds: constraint terms are the same formulas in another order of operations, so they
agree to round-off, 1e-13 of the largest entry (O(1) data: ~1e-16 per operation, < 100
operations).  Accelerations solve the same linear system by another factorisation (Schur
complement of the modified mass matrix vs dense LU of the KKT matrix): the difference is
round-off times the condition number, bounded here by 1e-10 of the largest entry (the
largest error seen over the decks is below 1e-12).
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg as la

from mbsim import fast
from mbsim.constraints import DRIVERS, JOINTS
from mbsim.deck import load_deck, load_deck_text
from mbsim.deck.loader import parse_deck, scene_names
from mbsim.fast.dynamics import column_masks
from mbsim.model import compile_model
from tests.forces.builders import force, two_body_model
from tests.helpers import body, joint, pts, spec
from tests.reference import equations as eq
from tests.test_constraints import _driver_specs, _joint_spec, _two_bodies

ROOT = Path(__file__).resolve().parents[1]
DECKS = sorted(p.stem for p in (ROOT / "models").glob("*.yaml"))


@lru_cache(maxsize=None)
def _scenes(name):
    return scene_names(parse_deck(ROOT / "models" / f"{name}.yaml").root)


SCENES = [(d, s) for d in DECKS for s in [None, *_scenes(d)]]
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


def _solve_tolerance(model, q, t, rows, fd):
    """Bound on the relative difference of two backward-stable solves of the same equations:
    10 u cond (u = 1.1e-16) of the matrix factored (the Schur matrix J Mt^-1 J^T, the KKT
    matrix when J' is singular), and at least 1e-10 (module doc).  It matters only for the
    parallel four-bar (cond(S) ~ 1e9: all 42 coordinates constrained)."""
    J = eq.constraints(model, q, t).jac
    J = J if rows is None else J[rows]
    if fd.kkt:
        K = np.block([[eq.mass_matrix(model, q), J.T], [J, np.zeros((J.shape[0],) * 2)]])
        cond = np.linalg.cond(K)
    else:
        cond = np.linalg.cond(J @ np.linalg.inv(_modified_mass(model, q)) @ J.T)
    return max(1e-10, 1e-15 * cond)


def _check_accelerations(model, q, qd, t, rows=None):
    qdd, lam = eq.accelerations(model, q, qd, t, rows=rows)
    fd = fast.System(model, rows)
    tol = _solve_tolerance(model, q, t, rows, fd)
    for _ in range(2):  # a second call on the same object: nothing stale is reused
        a, b, _power = fd.accelerations(q, qd, t)
        _close(a, qdd, tol)
        _close(fd.full_lam(b), lam, tol)


def _modified_mass(model, q):
    """Mt = M + c p p^T per Euler-parameter block, c = 4 tr(J') / 3 (module doc of
    mbsim/fast/dynamics.py), from the reference mass matrix."""
    Mt = eq.mass_matrix(model, q)
    for b in range(model.nb):
        p = q[7 * b + 3 : 7 * b + 7]
        c = 4.0 * np.trace(model.J_local[b]) / 3.0
        Mt[7 * b + 3 : 7 * b + 7, 7 * b + 3 : 7 * b + 7] += c * np.outer(p, p)
    return Mt


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
@pytest.mark.parametrize("name, scene", SCENES)
def test_decks_match_numpy(name, scene):
    """Every deck and scene: Phi, Phi_q, gamma, nu, Q, M to 1e-13, qdd and lam on the active
    rows to 1e-10 or 10 u cond (module doc, _solve_tolerance); among them the rotational
    driver (angle kernel: slider-crank, four-bar inverse*, compressor inverse/nontwist),
    singular J' (four-bar: the KKT path) and Python force elements (the vehicle's tires, the
    compressor's pressure laws)."""
    model = compile_model(load_deck(ROOT / "models" / f"{name}.yaml", scene=scene))
    q = model.q0 + 1e-3 * rng.normal(size=model.nq)
    qd = 0.1 * rng.normal(size=model.nq)
    _check_constraints(model, q, qd, 0.21)
    system = fast.System(model)
    _close(system.mass_matrix(q), eq.mass_matrix(model, q), 1e-13)
    _close(system.generalized_forces(q, qd, 0.21), eq.applied_forces(model, q, qd, 0.21)[0], 1e-13)
    _check_accelerations(model, q, qd, 0.21, _independent_rows(model, q, 0.21))


def test_four_bar_singular_inertia_takes_the_kkt_path():
    """Table 12.3.1 gives Izz = 0: no exact Mt^-1, the dense KKT solve instead."""
    model = compile_model(load_deck(ROOT / "models" / "four_bar.yaml"))
    fd = fast.System(model)
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



def _envelope_factor(system):
    """(L unit lower, D) in the Schur order from the System's envelope (kernels.c
    schur_factor: row k holds L[k, fc[k]:k] and 1 / D_kk)."""
    _, order, fc, off = system.sidx
    n = order.size
    L, D = np.eye(n), np.empty(n)
    for k in range(n):
        row = system._env[off[k] : off[k] + k - fc[k] + 1]
        L[k, fc[k] : k] = row[:-1]
        D[k] = 1.0 / row[-1]
    return L, D


@pytest.mark.parametrize("build", ["chain16", "governor"])
def test_schur_factor_is_ldlt_of_the_schur_matrix(build):
    """The envelope factor is S = L D L^T of the Schur matrix S = J Mt^-1 J^T (reference J
    and Mt) in the RCM order, D > 0, and pivot_ratio = min D_kk / S_kk.  Bound: J agrees to
    1e-13 (above), so S to ~2e-13 of its largest diagonal; the factorization's backward
    error is (w + 1) u sqrt(S_ii S_jj) (w: row width, below 20; Higham 2002, Thm 10.3,
    the L D L^T form), so 1e-12 of the largest diagonal."""
    model = _chain(16) if build == "chain16" else _governor()
    q = model.q0 + 1e-3 * rng.normal(size=model.nq)  # |p| off 1: Mt's 1 / s^2 exercised
    qd = rng.normal(size=model.nq)
    system = fast.System(model)
    system.accelerations(q, qd, 0.2)
    J = eq.constraints(model, q, 0.2).jac
    S = J @ np.linalg.inv(_modified_mass(model, q)) @ J.T
    order = system.sidx[1]
    S = S[np.ix_(order, order)]
    L, D = _envelope_factor(system)
    assert np.all(D > 0.0)
    _close(L @ np.diag(D) @ L.T, S, 1e-12 * float(np.diag(S).max()))
    assert abs(system.pivot_ratio - min(1.0, float((D / np.diag(S)).min()))) <= 1e-10


# -- the System interface ----------------------------------------------------------------------
def _governor():
    return compile_model(load_deck(ROOT / "models" / "governor.yaml"))


def _slider_crank():
    return compile_model(load_deck(ROOT / "models" / "slider_crank.yaml"))


@pytest.mark.parametrize("build", [_governor, _slider_crank])
def test_system_interface_matches_the_reference(build):
    """System's methods against numpy statements of the same equations: the KKT solve of
    equations.accelerations (with Baumgarte's gamma for ``baumgarte``), and the Mt-weighted
    least-norm corrections dq = Mt^-1 J^T (J Mt^-1 J^T)^-1 r of the projections."""
    model = build()
    rows = _independent_rows(model, model.q0)
    q = model.q0 + 1e-3 * rng.normal(size=model.nq)
    qd = 0.1 * rng.normal(size=model.nq)
    t = 0.3
    ref = eq.constraints(model, q, t, qd=qd, gamma=True, nu=True)
    J, g, nu, phi = ref.jac[rows], ref.gamma[rows], ref.nu[rows], ref.phi[rows]
    M = eq.mass_matrix(model, q)
    Q = eq.applied_forces(model, q, qd, t)[0]

    def kkt(gam):
        n = model.nq
        K = np.block([[M, J.T], [J, np.zeros((rows.size, rows.size))]])
        sol = la.solve(K, np.concatenate([Q, gam]))
        return sol[:n], sol[n:]

    for sparse in (False, True):
        fd = fast.System(model, rows, sparse)
        rheonomic = any(it.kind == "driver" or it.func is not None for it in model.items)
        assert (fd.m, fd.sparse, fd.rheonomic) == (rows.size, sparse, rheonomic)
        T = fd.terms(q, t, qd=qd, gamma=True, nu=True)
        for got, want in ((T.phi, phi), (T.jac, J), (T.gamma, g), (T.nu, nu)):
            _close(got, want, 1e-13)
        _close(fd.nu(q, t), nu, 1e-13)
        a, b_ = 5.0, 7.0
        cases = (({}, g), ({"baumgarte": (a, b_)}, g - 2 * a * (J @ qd - nu) - b_ * b_ * phi),
                 ({"jac": T.jac}, g))
        for kw, gam in cases:
            qdd, lam, power = fd.accelerations(q, qd, t, **kw)
            qdd_ref, lam_ref = kkt(gam)
            _close(qdd, qdd_ref, 1e-10)
            _close(lam, lam_ref, 1e-10)
            assert abs(power - (Q @ qd - lam_ref @ nu)) <= 1e-10 * max(1.0, abs(Q @ qd))
        full = fd.full_lam(lam)
        assert full.shape == (model.m,) and np.array_equal(full[rows], lam)
        R = eq.constraints(model, q, t, qd=qd, nu=True)
        v_ref = (np.abs(R.phi).max(), np.abs(R.jac @ qd - R.nu).max())
        assert np.allclose(fd.violations(q, qd, t), v_ref, rtol=1e-12, atol=1e-15)
        assert fd.energy(q, qd) == (eq.kinetic_energy(model, q, qd), eq.potential_energy(model, q))
        # one Newton step of the projection from q, by the formula
        Mti = np.linalg.inv(_modified_mass(model, q))
        dq = Mti @ J.T @ np.linalg.solve(J @ Mti @ J.T, phi)
        fd.counters["newton_iterations"] = 0
        q1 = fd.project_positions(q, t, max_iter=1)[0]
        _close(q1, q - dq, 1e-10)
        qp, ok, its, res = fd.project_positions(q, t)
        assert ok and res <= 1e-12 and its == fd.counters["newton_iterations"] - 1
        Rp = eq.constraints(model, qp, t, nu=True)
        Jp = Rp.jac[rows]
        Mti = np.linalg.inv(_modified_mass(model, qp))
        vp_ref = qd - Mti @ Jp.T @ np.linalg.solve(Jp @ Mti @ Jp.T, Jp @ qd - Rp.nu[rows])
        vp = fd.project_velocities(qp, qd, t)
        _close(vp, vp_ref, 1e-10)
        assert np.abs(Rp.jac @ vp - Rp.nu).max() < 1e-12
    assert set(fd.counters) == {"function_evaluations", "constraint_evaluations",
                                "factorizations", "newton_iterations"}


def test_mass_matrix_and_applied_forces_match_numpy():
    model = _governor()
    q = model.q0 + 1e-2 * rng.normal(size=model.nq)
    qd = rng.normal(size=model.nq)
    fd = fast.System(model)
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
    fd = fast.System(model)
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
        fast.System(model).accelerations(q[:-1], q, 0.0)
    with pytest.raises(ValueError, match="gamma needs the velocities"):
        fc.evaluate(q, gamma=True)


# -- the Schur products' column masks (mbsim.fast.dynamics.column_masks, kernels.c pair_dot) --
def _every_kernel_models():
    """Every joint and driver type on two free bodies (the random specs above: every basic
    kernel), every deck (ground bodies, the angle kernel, singular J') and a chain."""
    models = [compile_model(spec(_two_bodies(), [_joint_spec(t)], gravity=(0, 0, -9.81)))
              for t in sorted(JOINTS)]
    for t in sorted(DRIVERS):
        joints, drivers = _driver_specs(t)
        models.append(compile_model(spec(_two_bodies(), joints, drivers, gravity=(0, -9.81, 0))))
    models += [compile_model(load_deck(ROOT / "models" / f"{d}.yaml")) for d in DECKS]
    return models + [_chain(4)]


def test_column_masks_cover_every_entry_the_kernels_write():
    """column_masks says where each kernel's rows of the compact Phi_q (Jc) can be nonzero;
    the Schur products leave the other columns out as exact zeros, so every entry outside
    the masks must be exactly 0 at any state (q off the manifold, |p| off 1, t past the
    angle driver's wrap)."""
    for model in _every_kernel_models():
        fc = fast.FastConstraints(model)
        masks = column_masks(fc.ci, model.m)
        inside = ((masks[:, :, None] >> np.arange(7)) & 1).astype(bool).reshape(model.m, 14)
        for t in (0.37, 2.9):
            q = model.q0 + 0.3 * rng.normal(size=model.nq)
            fc.compact(q, t, rng.normal(size=model.nq), gamma=True)
            assert np.count_nonzero(fc.Jc[~inside]) == 0, model.title
            assert np.count_nonzero(fc.Jc[inside]) > 0


def test_schur_products_without_the_zero_columns_change_no_bit():
    """The accelerations on the kernels' own Phi_q (Schur products over the masked columns)
    equal, to the bit, those on the same Phi_q passed in by the caller (mb_accelerations'
    JAC_CALLER: every column): skipping exact zeros changes no sum."""
    for model in _every_kernel_models():
        system = fast.System(model)
        if system.kkt:  # (no Schur complement)
            continue
        for t in (0.37, 2.9):
            q = model.q0 + 1e-2 * rng.normal(size=model.nq)
            qd = rng.normal(size=model.nq)
            jac = system.terms(q, t).jac
            qdd_a, lam_a, power_a = system.accelerations(q, qd, t)
            ratio_a = system.pivot_ratio
            qdd_b, lam_b, power_b = system.accelerations(q, qd, t, jac=jac)
            assert np.array_equal(qdd_a, qdd_b) and np.array_equal(lam_a, lam_b), model.title
            assert power_a == power_b and ratio_a == system.pivot_ratio


def test_tables_are_built_once_per_model_and_row_set():
    """The constant tables (flatten, body table, force elements) and the Schur matrix's
    symbolic analysis (order, envelope, products) are built by the first System of a model
    and row set and shared, read-only, by later ones; a System on other rows gets its own.
    Reusing them changes no number: the accelerations of a second System equal, bit for
    bit, those of a System of a freshly compiled copy of the model."""
    model = _chain(8)
    q = model.q0 + 1e-3 * rng.normal(size=model.nq)
    qd = 1e-1 * rng.normal(size=model.nq)
    a, b = fast.System(model), fast.System(model)
    assert b.sidx is a.sidx and b.pairs is a.pairs and b.bt is a.bt and b.fc.ci is a.fc.ci
    assert not (a.sidx.flags.writeable or a.bt.flags.writeable or a.fc.cf.flags.writeable)
    rows = _independent_rows(model, q)[:-3]  # another row set: its own structure
    c = fast.System(model, rows)
    assert c.sidx is not a.sidx and c.sidx.shape[1] == rows.size
    assert fast.System(model, rows).sidx is c.sidx
    fresh = _chain(8)
    for sys_b, sys_f in ((b, fast.System(fresh)), (c, fast.System(fresh, rows))):
        qdd_b, lam_b, _ = sys_b.accelerations(q, qd, 0.3)
        qdd_f, lam_f, _ = sys_f.accelerations(q, qd, 0.3)
        assert np.array_equal(qdd_b, qdd_f) and np.array_equal(lam_b, lam_f)
    _check_accelerations(model, q, qd, 0.3)  # (a System from the shared tables)


def test_buffers_from_one_allocation_are_separate_arrays():
    """_lib.Model.zeros carves the buffers from one block: each the size asked for, zero,
    and the C pointer of each is its own first element (a write through C to one buffer
    lands in it and in no other)."""
    from mbsim.fast import _lib

    c = _lib.Model()
    a, b, m = c.zeros(Q=5, qdd=(2, 3), F=(1, 3))
    assert (a.shape, b.shape, m.shape) == ((5,), (2, 3), (1, 3))
    assert not (a.any() or b.any() or m.any())
    for name, arr in (("Q", a), ("qdd", b), ("F", m)):
        assert getattr(c.s, name) == arr.ctypes.data
    b[:] = 1.0
    assert not (a.any() or m.any())


# -- the loader of the C library (mbsim.fast._lib) ---------------------------------------------
_FIRST_USE = """
import sys
import mbsim.fast as f
from mbsim.fast import _lib
_lib._installed = lambda digest: None  # as in a source checkout without a built library
lines = []
f.on_compile = lines.append
_lib.library()
print(repr(lines))
"""


def test_first_use_compiles_once_into_the_cache(tmp_path):
    """An empty cache: one compile, announced once through on_compile; the next process loads
    the cached library without compiling (the file name carries the source hash)."""
    env = dict(os.environ, MBSIM_CACHE_DIR=str(tmp_path))
    run = [sys.executable, "-c", _FIRST_USE]
    first = subprocess.run(run, cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert first.returncode == 0, first.stderr
    assert first.stdout.strip() == repr(["compiling kernels (first run only) ..."])
    built = list(tmp_path.glob("kernels-*"))
    assert len(built) == 1 and not list(tmp_path.glob("*.tmp*"))
    again = subprocess.run(run, cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert again.returncode == 0 and again.stdout.strip() == "[]", again.stderr


def test_a_library_built_from_another_source_is_not_used(tmp_path, monkeypatch):
    from mbsim.fast import _lib

    lib = _lib.library()
    path = Path(lib._name)
    fake = tmp_path / "_kernels.cpython-test.so"
    fake.write_bytes(path.read_bytes())
    monkeypatch.setattr(_lib, "HERE", tmp_path)
    digest = _lib._hash_of(lib)
    assert digest == _lib.source_hash()  # every build carries the hash of its kernels.c
    assert _lib._installed(digest) is not None
    assert _lib._installed("0" * 16) is None  # stale: kernels.c was edited since


def test_without_a_compiler_the_error_says_what_to_install(monkeypatch, tmp_path):
    from mbsim.fast import _lib

    monkeypatch.setenv("PATH", str(tmp_path))  # no cc, gcc, clang
    monkeypatch.delenv("CC", raising=False)
    with pytest.raises(_lib.KernelBuildError, match="no C compiler found.*apt install gcc"):
        _lib.compiler()
    code = (
        "import sys\nfrom mbsim.fast import _lib\n_lib._installed = lambda digest: None\n"
        "from mbsim.cli import main\n"
        "main(['run', 'models/governor.yaml', '--mode', 'dynamic', '-o', sys.argv[1]])\n"
    )
    env = dict(os.environ, PATH=str(tmp_path), MBSIM_CACHE_DIR=str(tmp_path / "cache"))
    env.pop("CC", None)
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path / "g.h5")], cwd=ROOT,
                         env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 1
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "no C compiler" in lines[0]
