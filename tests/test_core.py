"""mbsim.core, the one implementation of the equations in production, against the numpy
reference (tests/reference/equations.py, basic.py), and the rule that production never
imports that reference.

Cases: every deck in models/ with each of its scenes, every joint and driver type (the small
two-body decks of tests/test_constraints.py), q off the constraint manifold and |p| off 1.

Bounds (as in tests/test_kernels.py): constraint terms, M, Q and the energies are the same
formulas evaluated in another order of operations (C vs numpy einsum), < 100 operations per
entry at ~1.1e-16 each: they agree to 1e-13 of the largest entry.  Accelerations and
multipliers solve the same linear system by another factorisation (Schur complement of the
modified mass matrix, or the dense KKT LU, vs numpy's dense KKT LU): the difference is
round-off times the condition number, max(1e-10, 1e-15 cond) (_solve_tolerance).
"""

from __future__ import annotations

import ast
import pkgutil
from pathlib import Path

import numpy as np
import pytest

import mbsim
from mbsim import core
from mbsim.constraints import DRIVERS, JOINTS
from mbsim.deck import load_deck
from mbsim.model import compile_model
from mbsim.options import deck_context
from tests.helpers import spec
from tests.reference import equations as eq
from tests.test_constraints import _driver_specs, _joint_spec, _two_bodies
from tests.test_kernels import ROOT, SCENES, _close, _solve_tolerance

rng = np.random.default_rng(2424)
TERMS = 1e-13  # module doc


def _check_core(model, q, qd, t, rows=None):
    """Every free function of mbsim.core on ``rows`` against the reference."""
    data = core.make_data(model, rows)
    sel = slice(None) if rows is None else rows
    ref = eq.constraints(model, q, t, qd=qd, gamma=True, nu=True)
    got = core.constraints(model, data, q, t, qd=qd, gamma=True, nu=True)
    for name in ("phi", "jac", "gamma", "nu"):
        _close(getattr(got, name), getattr(ref, name)[sel], TERMS)
    _close(core.phi(model, data, q, t), ref.phi[sel], TERMS)
    _close(core.phi_q(model, data, q, t), ref.jac[sel], TERMS)
    _close(core.phi_q(model, data, q, t, sparse=True), ref.jac[sel], TERMS)
    _close(core.nu(model, data, q, t), ref.nu[sel], TERMS)
    _close(core.gamma(model, data, q, qd, t), ref.gamma[sel], TERMS)
    _close(core.mass_matrix(model, data, q), eq.mass_matrix(model, q), TERMS)
    _close(core.mass_matrix(model, data, q, sparse=True), eq.mass_matrix(model, q), TERMS)
    Q, F, n_local = core.applied_forces(model, data, q, qd, t)
    Qr, Fr, nr = eq.applied_forces(model, q, qd, t)
    for a, b in ((Q, Qr), (F, Fr), (n_local, nr)):
        _close(a, b, TERMS)
    _close(core.generalized_forces(model, data, q, qd, t), Qr, TERMS)
    T, V = core.energy(model, data, q, qd)
    _close(T, eq.kinetic_energy(model, q, qd), TERMS)
    _close(V, eq.potential_energy(model, q), TERMS)
    qdd, lam = core.accelerations(model, data, q, qd, t)
    qdd_r, lam_r = eq.accelerations(model, q, qd, t, rows=rows)
    tol = _solve_tolerance(model, q, t, rows, data.system)
    _close(qdd, qdd_r, tol)
    _close(lam, lam_r, tol)
    assert lam.shape == (model.m,)


@pytest.mark.parametrize("name, scene", SCENES)
def test_core_matches_the_reference_on_every_deck(name, scene):
    """At the assembled position, 1e-6 off it (the parallel four-bars are singular at some
    positions 1e-3 away, where both solves lose every digit), on the assembly's rows."""
    from mbsim.analyses.assembly import assemble

    spec = load_deck(ROOT / "models" / f"{name}.yaml", scene=scene)
    model = compile_model(spec)
    asm = assemble(model, hold=deck_context(spec, shapes=False).hold)  # the deck's assembly
    q = asm.q + 1e-6 * rng.normal(size=model.nq)
    qd = 0.1 * rng.normal(size=model.nq)
    rows = None if asm.active_rows.size == model.m else asm.active_rows
    _check_core(model, q, qd, 0.0, rows)


@pytest.mark.parametrize("type_", sorted(JOINTS))
def test_core_matches_the_reference_on_every_joint_type(type_):
    model = compile_model(spec(_two_bodies(), [_joint_spec(type_)], gravity=(0, 0, -9.81)))
    q = model.q0 + 0.1 * rng.normal(size=model.nq)
    qd = rng.normal(size=model.nq)
    _check_core(model, q, qd, 0.37)


@pytest.mark.parametrize("type_", sorted(DRIVERS))
def test_core_matches_the_reference_on_every_driver_type(type_):
    joints, drivers = _driver_specs(type_)
    model = compile_model(spec(_two_bodies(), joints, drivers, gravity=(0, -9.81, 0)))
    q = model.q0 + 0.1 * rng.normal(size=model.nq)
    qd = rng.normal(size=model.nq)
    for t in (0.37, 2.9):  # the angle driver's target wraps past pi at t = 2.9
        _check_core(model, q, qd, t)


def test_make_data_is_built_once_per_model_and_row_set():
    model = compile_model(load_deck(ROOT / "models" / "slider_crank.yaml"))
    all_rows = core.make_data(model)
    assert core.make_data(model) is all_rows
    assert core.make_data(model, np.arange(model.m)) is all_rows
    some = core.make_data(model, np.arange(model.m - 1))
    assert some is not all_rows and some.rows.size == model.m - 1
    assert core.make_data(model, np.arange(model.m - 1)) is some


def test_project_positions_lands_on_the_constraints():
    """The one Newton correction: from 1e-3 off the manifold to max |Phi| <= 1e-12."""
    model = compile_model(load_deck(ROOT / "models" / "slider_crank.yaml"))
    q0 = model.q0 + 1e-3 * rng.normal(size=model.nq)
    from mbsim.analyses.assembly import assemble

    rows = assemble(model).active_rows
    q, ok, its, res = core.project_positions(model, core.make_data(model, rows), q0, 0.0)
    assert ok and res <= 1e-12 and its >= 1
    assert np.abs(eq.phi(model, q)[rows]).max() <= 1e-12


def test_non_finite_terms_name_the_constraints():
    from mbsim.errors import AnalysisError

    model = compile_model(load_deck(ROOT / "models" / "slider_crank.yaml"))
    q = model.q0.copy()
    q[7] = np.inf
    with pytest.raises(AnalysisError, match="overflowed"):
        core.phi(model, None, q)


def _imports(path: Path) -> set[str]:
    """Every module name an import statement of the file names (absolute or relative)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            names.add(base)
            names.update(f"{base}.{a.name}" for a in node.names)
    return names


def test_no_module_of_mbsim_imports_the_numpy_reference():
    """The reference exists only under tests/: production has one implementation."""
    pkg = Path(mbsim.__file__).parent
    offenders = []
    for info in pkgutil.walk_packages([str(pkg)], "mbsim."):
        rel = info.name.split(".")[1:]
        path = pkg.joinpath(*rel)
        path = path / "__init__.py" if info.ispkg else path.with_suffix(".py")
        for name in _imports(path):
            if name.startswith("tests") or name in ("mbsim.equations", "mbsim.constraints.basic"):
                offenders.append(f"{info.name}: {name}")
    assert not offenders, offenders
    assert not (pkg / "equations.py").exists() and not (pkg / "constraints" / "basic.py").exists()


@pytest.mark.parametrize("t", [0.0, 0.11, 0.37])
def test_kinematic_state_matches_dense_solves_of_the_reference(t):
    """core.kinematic_state (one C call: Newton, then qd and qdd on one LU) against numpy:
    the reference's Phi at the returned q below tol, qd = J^-1 nu and qdd = J^-1 gamma of the
    reference by LAPACK (cond(J) ~ 20: 1e-12 of the largest entry), and cond_2 against the
    SVD to 1e-6 (Lanczos stops when its Ritz value changes by < 1e-10; extreme Ritz values
    converge superlinearly, so the error is of that order, well inside 1e-6)."""
    from mbsim.analyses.assembly import assemble

    model = compile_model(load_deck(ROOT / "models" / "slider_crank.yaml"))
    asm = assemble(model, t=t)
    data = core.make_data(model, asm.active_rows)
    q0 = asm.q + 1e-4 * rng.normal(size=model.nq)
    status, q, qd, qdd, info = core.kinematic_state(model, data, q0, t, 1e-10, 25, cond=True)
    assert status == 0 and info[0] >= 1 and info[1] <= 1e-10
    assert np.abs(eq.phi(model, q, t)).max() <= 1e-10
    ref = eq.constraints(model, q, t, nu=True)
    _close(qd, np.linalg.solve(ref.jac, ref.nu), 1e-12)
    _close(qdd, np.linalg.solve(ref.jac, eq.gamma(model, q, qd, t)), 1e-12)
    s = np.linalg.svd(ref.jac, compute_uv=False)
    assert info[2] == pytest.approx(s[0] / s[-1], rel=1e-6)


def test_kinematic_state_reports_no_convergence_and_a_singular_jacobian():
    """max_iter = 0 from 1e-3 off the manifold: status 3 (no convergence); the first body's
    Euler parameters set to zero make its normalisation row 2 p^T of Phi_q zero, and with a
    tolerance that accepts any residual the LU meets a zero pivot: status 2 (singular)."""
    from mbsim.analyses.assembly import assemble

    model = compile_model(load_deck(ROOT / "models" / "slider_crank.yaml"))
    asm = assemble(model)
    data = core.make_data(model, asm.active_rows)
    status, *_ = core.kinematic_state(model, data, asm.q + 1e-3, 0.0, 1e-10, 0)
    assert status == 3
    q = asm.q.copy()
    q[3:7] = 0.0  # ground body's Euler parameters zero: its normalisation row 2 p^T = 0
    status, *_ = core.kinematic_state(model, data, q, 0.0, 1e30, 0)
    assert status == 2


def test_apply_minv_inverts_the_modified_mass_matrix():
    """System.apply_minv (C, the exact block inverse) against numpy's solve with the
    reference's Mt = M + c p p^T (tests/test_kernels.py): cond(Mt) ~ 1e3 on the governor, so
    1e-12 of the largest entry."""
    from tests.test_kernels import _modified_mass

    model = compile_model(load_deck(ROOT / "models" / "governor.yaml"))
    q = model.q0 + 1e-2 * rng.normal(size=model.nq)
    X = rng.normal(size=(model.nq, 3))
    got = core.make_data(model).system.apply_minv(q, X)
    _close(got, np.linalg.solve(_modified_mass(model, q), X), 1e-12)
    _close(core.make_data(model).system.apply_minv(q, X[:, 0]), got[:, 0], 0.0)


def test_data_lives_and_dies_with_its_model():
    """make_data keeps the C tables on the model: a model no longer used is collected with
    them (a sweep compiling many models in one process does not keep them all)."""
    import gc
    import weakref

    model = compile_model(load_deck(ROOT / "models" / "slider_crank.yaml"))
    core.make_data(model)
    ref = weakref.ref(model)
    del model
    gc.collect()
    assert ref() is None
