"""The sparse set-up of large models (mbsim.analyses.common.DENSE_NQ and up): rank and
redundancy, assembly steps and initial velocities give the dense path's answers.

Each test runs one model through both paths (by moving the DENSE_NQ threshold, or, for the
initial velocities, by calling both).  Bounds: the
two paths solve the same equations by different factorizations (sparse LU of J J^T or the
Schur complement J Mt^-1 J^T vs dense QR/SVD), so they agree to round-off times the
condition number: cond(J J^T) of a 60-link spherical chain is ~1e5, so 1e-9 relative leaves a
margin of 10-100 over the differences seen (4e-12)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

import mbsim.analyses.assembly as assembly
import mbsim.analyses.initial as initial
from mbsim import core
from mbsim.analyses.common import rank_and_redundant, sparse_gram_factor
from mbsim.deck import load_deck
from mbsim.model import compile_model

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))
from common import chain_spec  # noqa: E402


def _chain_with_given_velocities(n=60):
    spec = chain_spec(n)
    links = list(spec.bodies.values())[1:]
    for k, b in enumerate(links[:4]):
        object.__setattr__(b, "omega", np.array([0.3 * k, np.nan, 1.0]))
    object.__setattr__(links[10], "rdot", np.array([0.1, 0.2, np.nan]))
    return compile_model(spec)


def _both_velocity_paths(model, q, active, t0=0.0, rtol=1e-10):
    """(qd, free) of the Schur path and of the SVD path of step 2 of mbsim.analyses.initial on
    the same conditions (the Schur path's answer None where it declines a near-singular S)."""
    data = core.make_data(model, active)
    C, c, w, _ = initial.given_conditions(model, q)
    schur = initial._schur_velocities(model, data, q, t0, C, c, w, rtol)
    qd, free, _ = initial._svd_velocities(model, data, q, t0, C, c, w, rtol)
    return schur, (qd, free)


def test_schur_initial_velocities_match_the_svd_path_on_a_large_chain():
    model = _chain_with_given_velocities()
    asm = assembly.assemble(model)
    (qd_s, free_s), (qd_d, free_d) = _both_velocity_paths(model, asm.q, asm.active_rows)
    assert np.abs(qd_s - qd_d).max() <= 1e-9 * np.abs(qd_d).max()
    assert free_s == free_d
    J = core.phi_q(model, None, asm.q)
    assert np.abs(J @ qd_s - core.nu(model, None, asm.q)).max() <= 1e-12


@pytest.mark.parametrize("deck", ["governor", "slider_crank", "vehicle", "andrews",
                                  "compressor"])
def test_schur_initial_velocities_match_the_svd_path_on_the_decks(deck):
    """The decks' given velocities (the vehicle gives all 48 components, the governor 3 and
    leaves one free) meet the constraints and the given components as the SVD path does, to
    round-off times the Schur factor's condition: the path declines a factor whose smallest
    pivot ratio r makes eps / r exceed rtol / 100, so the two agree to within rtol = 1e-10
    relative."""
    model = compile_model(load_deck(ROOT / "models" / f"{deck}.yaml"))
    asm = assembly.assemble(model)
    (qd_s, free_s), (qd_d, free_d) = _both_velocity_paths(model, asm.q, asm.active_rows)
    assert qd_s is not None
    assert np.abs(qd_s - qd_d).max() <= 1e-10 * max(1.0, np.abs(qd_d).max())
    assert free_s == free_d


def test_a_start_next_to_a_change_point_takes_the_svd_path():
    """The parallel four-bar's deck start: Schur factor pivot ratio 1.9e-4, under
    100 eps / rtol = 2.2e-4: the Schur path declines, initial_velocities gives the SVD
    path's answer."""
    model = compile_model(load_deck(ROOT / "models" / "parallel_fourbar.yaml"))
    asm = assembly.assemble(model)
    (qd_s, _), (qd_d, _) = _both_velocity_paths(model, asm.q, asm.active_rows)
    assert qd_s is None
    qd, _ = initial.initial_velocities(model, asm.q, 0.0, asm.active_rows)
    assert np.array_equal(qd, qd_d)


def test_sparse_velocities_without_given_components_have_least_kinetic_energy():
    """No given velocity and nu = 0: the chain starts at rest (qd = 0)."""
    model = compile_model(chain_spec(60))
    asm = assembly.assemble(model)
    qd, info = initial.initial_velocities(model, asm.q, 0.0, asm.active_rows)
    assert np.abs(qd).max() == 0.0 and info["free_velocity_dof"] == model.nq - model.m


def test_rank_of_a_full_rank_chain_is_certified_by_the_sparse_factor():
    model = compile_model(chain_spec(60))
    J = core.phi_q(model, None, model.q0, sparse=True)
    assert sparse_gram_factor(J) is not None
    rank, red = rank_and_redundant(model, J)
    assert rank == model.m and red.size == 0
    assert rank_and_redundant(model, J.toarray())[0] == model.m


@pytest.mark.parametrize("scene", [None, "loops2"])
def test_redundant_rows_found_from_a_sparse_jacobian_as_from_a_dense_one(scene):
    """The parallel four-bar's loops leave dependent rows: the sparse factor refuses to
    certify them, and the dense QR names the same rows as from the dense Jacobian."""
    model = compile_model(load_deck(ROOT / "models" / "parallel_fourbar.yaml", scene=scene))
    q = assembly.assemble(model).q
    J = core.phi_q(model, None, q, sparse=True)
    assert sparse_gram_factor(J) is None
    rank_s, red_s = rank_and_redundant(model, J)
    rank_d, red_d = rank_and_redundant(model, J.toarray())
    assert rank_s == rank_d < model.m and np.array_equal(red_s, red_d)


def test_sparse_assembly_steps_match_the_dense_ones(monkeypatch):
    """From estimates 1e-3 off the manifold: the same least-norm Newton steps, the same q."""
    model = compile_model(chain_spec(60))
    q0 = model.q0 + 1e-3 * np.random.default_rng(7).normal(size=model.nq)
    monkeypatch.setattr(assembly, "DENSE_NQ", 10**9)
    qd_, its_d, _ = assembly.newton(model, q0)
    monkeypatch.setattr(assembly, "DENSE_NQ", 10)
    qs_, its_s, res = assembly.newton(model, q0)
    assert res <= 1e-10 and its_s == its_d
    assert np.abs(qs_ - qd_).max() <= 1e-9


def test_weakest_direction_of_a_sparse_jacobian_matches_the_svd():
    """Diagnosis of a large model: Lanczos on J J^T names the rows of the weakest singular
    direction as the dense SVD does, and gives its extreme singular values to 1e-9."""
    from mbsim.analyses.common import singular_rows

    model = compile_model(chain_spec(60))
    J = core.phi_q(model, None, model.q0, sparse=True)
    rows, s = singular_rows(model, J)
    U, s_ref, _ = np.linalg.svd(J.toarray())
    ref_rows = np.argsort(-np.abs(U[:, -1]))[:6]
    assert set(rows) == set(ref_rows)
    assert s[0] == pytest.approx(s_ref[0], rel=1e-9) and s[-1] == pytest.approx(s_ref[-1], rel=1e-9)
