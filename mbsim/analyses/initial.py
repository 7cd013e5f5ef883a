"""Consistent initial conditions for a dynamic analysis (positions, velocities, accelerations).

1. Positions: :func:`mbsim.analyses.assembly.assemble` (redundant rows dropped: ``active``).
2. Velocities: the constraints Phi_q qd = nu (hard) plus the velocities the deck gives
   (each given component is one condition):

   - ``rdot`` (global):          e_k^T rd_b = rdot_k
   - ``omega`` (global):         2 E(p_b)_k pd_b = omega_k       (Haug eq. 6.3.17)
   - ``omega_local`` (body):     2 G(p_b)_k pd_b = omega'_k      (Haug eq. 6.3.18)

   Writing qd = qd_p + N z with N a basis of null(Phi_q) (so the constraints hold exactly),
   the given conditions become C N z = c - C qd_p.  They are solved in the least-squares
   sense with kinetic-energy weights (sqrt(m) for rdot rows, sqrt(J_kk) for omega rows, so
   that rows of different units are comparable): consistent data are met exactly; data that
   conflict with the constraints or with each other are met as closely as the constraints
   allow, with a warning naming the bodies whose given velocity changed and by how much.
   Whatever freedom is left is fixed by minimum kinetic energy, 1/2 qd^T M qd.
   Hook: further conditions (e.g. a joint's relative rate) are rows appended in
   :func:`given_conditions`; nothing else changes.
3. Accelerations and multipliers: the one solve of the equations of motion
   (:func:`mbsim.core.accelerations`) on the active rows; the multipliers of dropped rows
   are 0.
"""

from __future__ import annotations

import logging

import numpy as np
import scipy.linalg as la

from mbsim import core
from mbsim.analyses import redundancy
from mbsim.analyses.assembly import assemble
from mbsim.analyses.common import DENSE_NQ
from mbsim.errors import AnalysisError
from mbsim.fast import SolveError
from mbsim.rotations import A as rot_A
from mbsim.rotations import E as rot_E
from mbsim.rotations import G as rot_G

log = logging.getLogger(__name__)
XYZ = "xyz"
EPS = float(np.finfo(float).eps)


def given_conditions(model, q):
    """Rows C (n, nq), targets c (n,), weights w (n,) and labels [(body, key, k)] of the
    velocities the deck gives (NaN: not given)."""
    nb = model.nb
    p = q.reshape(nb, 7)[:, 3:]
    Ep, Gp, Am = rot_E(p), rot_G(p), rot_A(p)
    rows, c, w, labels = [], [], [], []
    for b, name in enumerate(model.body_names):
        J, A = model.J_local[b], Am[b]
        for key, given in (
            ("rdot", model.rdot0[b]),
            ("omega", model.omega0[b]),
            ("omega_local", model.omega0_local[b]),
        ):
            for k in np.flatnonzero(np.isfinite(given)):
                row = np.zeros(model.nq)
                if key == "rdot":
                    row[7 * b + k] = 1.0
                    weight = model.mass[b]
                elif key == "omega":
                    row[7 * b + 3 : 7 * b + 7] = 2.0 * Ep[b, k]
                    weight = (A @ J @ A.T)[k, k]
                else:
                    row[7 * b + 3 : 7 * b + 7] = 2.0 * Gp[b, k]
                    weight = J[k, k]
                rows.append(row)
                c.append(given[k])
                w.append(np.sqrt(weight) if weight > 0 else 1.0)
                labels.append((name, key, int(k)))
    # hook: joint relative rates given in the deck would append their rows here
    C = np.array(rows).reshape(-1, model.nq)
    return C, np.array(c, float), np.array(w, float), labels


def initial_velocities(model, q, t0=0.0, active=None, rtol=1e-10):
    """(qd, info) from the constraints and the given velocities (module doc, step 2).

    On the integrators' Schur factor (:func:`_schur_velocities`: one factorisation, O(nq)
    per given condition); by SVDs of Phi_q and of the given conditions on its null space
    where the model has no such factor (the KKT path) or, below DENSE_NQ coordinates, where
    that solve fails, is near singular or is not finite (the SVD path then names what is
    not: a 1e308 point, a singular inertia)."""
    active = np.arange(model.m) if active is None else active
    data = core.make_data(model, active)
    C, c, w, labels = given_conditions(model, q)
    if not data.system.kkt:
        # phi checked as well: the input guard of 1e308 points
        h = core.constraints(model, data, q, t0, jac=False, nu=True).nu
        large = model.nq >= DENSE_NQ  # (no dense SVD of a large model: its error stands)
        try:
            qd, free = _schur_velocities(model, data, q, t0, C, c, w, rtol)
        except (SolveError, la.LinAlgError):
            if large:
                raise
            qd = None
        if qd is not None and (large or np.isfinite(qd).all()):
            return qd, _report(labels, C, c, h, qd, free, rtol)
    qd, free, h = _svd_velocities(model, data, q, t0, C, c, w, rtol)
    return qd, _report(labels, C, c, h, qd, free, rtol)


def _svd_velocities(model, data, q, t0, C, c, w, rtol):
    """(qd, free velocity DOF, nu) of step 2 (module doc) by SVDs: of Phi_q, for a particular
    solution and a basis N of its null space, then of the given conditions on N; the rest
    by least kinetic energy with the full mass matrix."""
    T = core.constraints(model, data, q, t0, nu=True)  # input guard: 1e308 points
    H, h = T.jac, T.nu
    M = core.mass_matrix(model, data, q)
    core.require_finite(model, t0, M=M)  # input guard: 1e308 inertia
    # constraints: qd = qd_p + N z
    U, s, Vt = la.svd(H, full_matrices=True)
    rank = int(np.sum(s > rtol * max(1.0, s[0] if s.size else 1.0)))
    qd_p = Vt[:rank].T @ ((U[:, :rank].T @ h) / s[:rank])
    N = Vt[rank:].T
    # given velocities, weighted least squares in z
    Cw = w[:, None] * (C @ N)
    cw = w * (c - C @ qd_p)
    if Cw.shape[0]:
        U2, s2, Vt2 = la.svd(Cw, full_matrices=True)
        r2 = int(np.sum(s2 > rtol * max(1.0, s2[0] if s2.size else 1.0)))
        z1 = Vt2[:r2].T @ ((U2[:, :r2].T @ cw) / s2[:r2])
        Nc = Vt2[r2:].T
    else:
        z1, Nc = np.zeros(N.shape[1]), np.eye(N.shape[1])
    # remaining freedom: minimum kinetic energy
    base = qd_p + N @ z1
    free = N @ Nc
    if free.shape[1]:
        K = free.T @ M @ free
        z2 = la.solve(K, -free.T @ (M @ base), assume_a="pos")
        qd = base + free @ z2
    else:
        qd = base
    return qd, int(free.shape[1]), h


def _schur_velocities(model, data, q, t0, C, c, w, rtol):
    """(qd, free velocity DOF) of step 2 (module doc) without a basis of null(Phi_q), or
    (None, None) where the Schur factor is too close to singular (below): with
    Mt the modified mass matrix of :mod:`mbsim.fast.dynamics` (equal to M on the constraint
    set, where p^T pd = 0) and S = Phi_q Mt^-1 Phi_q^T (the Schur factor the integrators
    use, sparse: linear in the size of chains and trees),

        qd0 = Mt^-1 Phi_q^T S^-1 nu             the least-kinetic-energy solution of the
                                                constraints alone
        B   = (I - Mt^-1 Phi_q^T S^-1 Phi_q) Mt^-1 C^T   (nq, nc) the least-energy directions
                                                in null(Phi_q) that change the given components

    and qd = qd0 + B z with z the weighted least-squares solution of C B z = c - C qd0 (a
    small nc x nc system): the given components are met as closely as the constraints allow
    and the rest has least kinetic energy, as the SVD path's answer.  One factorisation of S
    serves qd0 and every column of B.  S squares the condition of Phi_q: a solve through it
    is off by up to eps / r relative, r its smallest pivot ratio, so the answer is None
    (the SVD path's, off by eps / sqrt(r), is taken instead) where that could reach a
    hundredth of rtol, the rank tolerance of this step: r < 100 eps / rtol = 2.2e-4 at
    rtol 1e-10, i.e. within sigma_min / sigma_max ~ 0.015 of a change point (the parallel
    four-bar's deck start has r = 1.9e-4; the governor 6.2e-3, the slider-crank 1.3e-3).
    From DENSE_NQ coordinates on no dense SVD is made: the Schur answer stands there, as in
    the integrators' own projections (spherical chains: r = 0.18 at 4 to 1024 links)."""
    sys = data.system
    nc = C.shape[0]
    Y = sys.apply_minv(q, C.T) if nc else np.zeros((model.nq, 0))  # (nq, nc)
    qd0, B, r = sys.least_energy_velocities(q, t0, Y)
    if not r >= 100.0 * EPS / rtol and model.nq < DENSE_NQ:
        return None, None
    if nc == 0:
        return qd0, model.nq - data.rows.size
    G = C @ B
    z, _, rank, _ = la.lstsq(w[:, None] * G, w * (c - C @ qd0),
                             cond=rtol * max(1.0, np.abs(G).max(initial=0.0)))
    return qd0 + B @ z, model.nq - data.rows.size - int(rank)


def _report(labels, C, c, h, qd, free, rtol):
    """info of :func:`initial_velocities`: the freedom left, and the given components the
    constraints made change (with a warning naming them)."""
    info = {
        "free_velocity_dof": int(free),
        "given": len(labels),
        "changed": {},
        "warnings": [],
    }
    if labels:
        dev = C @ qd - c
        scale = max(1.0, float(np.abs(c).max()), float(np.abs(h).max(initial=0.0)))
        thr = 1e3 * rtol * scale
        bad = np.abs(dev) > thr
        if bad.any():
            changed: dict[str, dict[str, np.ndarray]] = {}
            for (name, key, k), d in zip(labels, dev):
                changed.setdefault(name, {}).setdefault(key, np.zeros(3))[k] = d
            named = {(n, key) for (n, key, _), b in zip(labels, bad) if b}
            info["changed"] = {
                n: {k: v for k, v in ks.items() if (n, k) in named}
                for n, ks in changed.items()
                if any(n == m for m, _ in named)
            }
            parts = []
            for name, keys in info["changed"].items():
                for key, d in keys.items():
                    unit = "m/s" if key == "rdot" else "rad/s"
                    comps = ", ".join(f"{x:.4g}" if abs(x) > thr else "0" for x in d)
                    parts.append(f"{name} {key} by ({comps}) {unit}")
            msg = (
                "the given initial velocities conflict with the constraints (or each other); "
                "least-squares compromise changed: " + "; ".join(parts)
            )
            info["warnings"].append(msg)
            log.warning(msg)
    return info


POLISH_STEPS = 3  # from a residual below tol Newton squares it: 1e-10 -> round-off in one


def initial_state(model, t0: float = 0.0, q=None, tol: float = 1e-10, hold=None):
    """Consistent (q, qd, qdd, lam, info) at t0 (module doc).

    Parameters
    ----------
    model : compiled Model.
    t0 : initial time (s).
    q : (nq,) initial estimate; default the deck's ``model.q0``.
    tol : Newton tolerance on max |Phi| for the assembly, which then continues to the
        round-off of Phi (:func:`mbsim.analyses.assembly.newton`'s ``polish``).
    hold : coordinates the assembly keeps at their estimates ('BODY.COORD', the deck's
        ``analysis.assembly.hold``: ``options.context.hold``); None: none.

    Returns
    -------
    q, qd, qdd : (nq,) positions, velocities, accelerations satisfying Phi = 0,
        Phi_q qd = nu, Phi_q qdd = gamma on the active rows.
    lam : (m,) multipliers (0 on redundant rows).
    info : dict with 'assembly' (Assembly), 'active_rows', 'warnings' (list of str),
        'changed' ({body: {'rdot'|'omega'|'omega_local': (3,) change}}), 'given' (number of
        given components), 'free_velocity_dof' (freedom fixed by minimum kinetic energy).
    """
    # Newton past tol to the round-off of Phi (POLISH_STEPS): an index-3 method's first step
    # solves Phi = 0 to round-off and would take the assembly's residual (up to tol) as a
    # jump of the first step, which its error estimate sees at every step size
    # (generalized-alpha at atol 1e-10 on the vehicle's circle scene: a jump of 8.6e-11 m
    # against the step's tolerance of 1e-11 m, h_min at t = 0)
    asm = assemble(model, q, t0, tol, hold=hold, polish=POLISH_STEPS)
    q = asm.q
    active = asm.active_rows
    qd, info = initial_velocities(model, q, t0, active)
    info["warnings"] = list(asm.warnings) + info["warnings"]
    info["assembly"] = asm
    info["active_rows"] = active
    qdd, lam = core.accelerations(model, core.make_data(model, active), q, qd, t0)
    if active.size < model.m:
        # the dropped rows must hold at velocity and acceleration level too (a driver that
        # over-determines the mechanism holds at the assembled position only)
        T = core.constraints(model, None, q, t0, qd=qd, phi=False, gamma=True, nu=True)
        redundancy.check(model, T.jac, asm.redundant_rows, active, t0, qd=qd, nu=T.nu,
                         qdd=qdd, gamma=T.gamma, qdd_terms=_acceleration_terms(
                             model, q, qd, t0, qdd), start=True)
    return q, qd, qdd, lam, info


def _acceleration_terms(model, q, qd, t, qdd):
    """(nq,) the size of the two terms whose sum is qdd: the accelerations the applied
    forces give the bodies held by nothing but their Euler-parameter normalisation, and the
    constraint forces' share, qdd less those.  A mechanism at rest under load (hanging at
    equilibrium) has qdd = 0 from terms of the size of g, and the dropped rows carry their
    round-off; None where that solve is not possible (the check then uses qdd alone)."""
    free = [r for it in model.items if it.kind == "normalization" for r in it.rows]
    try:
        a_free, _ = core.accelerations(model, core.make_data(model, np.sort(free)), q, qd, t)
    except (AnalysisError, SolveError):  # a scale only: the check stands without it
        return None
    return np.abs(a_free) + np.abs(qdd - a_free)

