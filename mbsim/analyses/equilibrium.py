"""Static equilibrium and steady spin (Haug Sec. 11.5 and 12.6.2).

Methods (``METHODS``, option ``method``):

``minimum`` (default)
    Minimum of the total potential energy V (gravity + springs + constant forces) on the
    constraint manifold, from the deck's estimates (or ``options['q0']``).  The stationarity
    (KKT) conditions are Q(q) - Phi_q^T lam = 0, Phi(q) = 0 (Haug Ch. 11), with Q the
    generalized applied force at rest (Q = -dV/dq up to components along p, which the
    normalisation multipliers absorb).  They are solved by a null-space Newton method:
    with N an orthonormal basis of null(Phi_q) (tangent to the manifold; it includes the
    normalisation rows, so its Euler-parameter parts are tangent to |p| = 1), the reduced
    force is r = N^T Q and the reduced Hessian

        H = -N^T d/dq (Q - Phi_q^T lam) N        (lam: least-squares multipliers at q)

    (the Hessian of the Lagrangian V + lam^T Phi projected on the tangent space), by central
    differences of the generalized force along the columns of N.  Steps N dz with
    H' dz = r (H' = H with eigenvalues replaced by max(|e|, delta), so every step goes
    downhill), a backtracking line search on V, and Newton's projection back onto Phi = 0.
    Stability (:func:`verdict`): the eigenvalues of H at the solution (summary
    ``eigenvalues``, mixed units: N/m along translations, N m per unit Euler parameter along
    rotations); all positive = a strict minimum = ``stable``; some negative = ``unstable``;
    the others ~ 0 (|e| <= 1e-7 max |e|) = ``neutral``: directions without stiffness (the
    free spin of a link about its own axis, a mechanism that moves at no cost), each named
    in ``neutral_modes`` by the bodies it turns or moves.  ``stable`` (bool) is true unless
    some direction is unstable (a neutral direction is not an instability) or the method
    did not converge.  Where N^T M N is positive definite the small-oscillation frequencies
    (H z = w^2 M z) are reported: ``frequencies`` (rad/s) and ``frequencies_hz`` of the
    non-neutral stable directions, ascending, and ``growth_rates`` (1/s, sqrt(-w^2)) of the
    unstable ones.  Other estimates reach other minima.

``settle``
    A damped dynamic run (:func:`mbsim.analyses.dynamic.dynamic`), released at rest from the
    estimates (``from_rest: false``: the deck's initial velocities), until the largest body
    velocity and acceleration stay below ``settle_tol``; optional artificial damping
    ``damping`` (1/s): F = -c m rd and n' = -c J' omega' on every body.  Reports the settled
    state, the settling time, and the reduced force and Hessian there.

``steady``
    A machine spinning at constant speed omega about a fixed axis (``axis``, ``point``; by
    default the axis of the revolute/cylindrical joint between ``body`` and ground): every
    non-ground body turns rigidly with Omega = omega * axis, so qd and qdd are the rigid
    rotation field (rd = Omega x (r - c), omega = Omega, rdd = Omega x (Omega x (r - c)),
    omegad = 0).  In the rotating frame this is an equilibrium of

        Q_eff(q) = Q(q, qd_rot) - M qdd_rot        (centrifugal + inertial torques + applied)

    whose potential is V_eff = V - 1/2 sum(m |Omega x (r - c)|^2 + Omega^T A J' A^T Omega).
    Given ``omega``: the configuration (the minimum method on Q_eff; the spin angle, a
    neutral direction, is held).  Without ``omega``: the speed at which the given
    configuration is steady, from the projection N^T (Q_0 + omega^2 Q_1) = 0 (least squares
    in omega^2, with Q_0 the static and omega^2 Q_1 the spin part of Q_eff; forces that depend
    on relative velocity vanish in rigid rotation).  Stability is judged on V_eff alone
    (gyroscopic coupling ignored).
"""

from __future__ import annotations

import dataclasses
import time as _time
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as la

from mbsim import core
from mbsim.analyses.assembly import assemble, newton
from mbsim.analyses.common import Recorder
from mbsim.analyses.dynamic import DEFAULTS as DYNAMIC_DEFAULTS
from mbsim.analyses.dynamic import dynamic
from mbsim.analyses.reactions import add_reaction_channels
from mbsim.errors import ConvergenceError, DeckError, ModelError
from mbsim.forces.base import ForceElement
from mbsim.options import analysis_options
from mbsim.result import STATUS_INCOMPLETE, Result

DEFAULTS = {
    "method": "minimum",
    "t": 0.0,  # time at which time-dependent loads and driver targets are evaluated
    "tol": 1e-9,  # reduced force, relative to the force scale
    "max_iter": 200,
    "max_step": 0.2,  # largest step in q (norm) per iteration
    "fd_step": 1e-6,  # central-difference step for the Hessian
    "phi_tol": 1e-11,
    # settle
    "t_end": 20.0,
    "step": 0.01,
    "damping": 0.0,
    "settle_tol": 1e-6,
    "from_rest": True,  # False: start from the deck's initial velocities
    # steady
    "body": None,
    "omega": None,
    "axis": None,
    "point": None,
}


# -- helpers -------------------------------------------------------------------------------

def null_basis(C, rtol=1e-10):
    """Orthonormal basis (nq, nq - rank) of null(C) by SVD."""
    if C.shape[0] == 0:
        return np.eye(C.shape[1])
    _, s, Vt = la.svd(C, full_matrices=True)
    rank = int(np.sum(s > rtol * max(s[0], 1e-300)))
    return Vt[rank:].T


def worst_coordinates(model, g, n=2) -> str:
    """Name the bodies and coordinates where the residual generalized force g is largest."""
    labels = ("x", "y", "z", "e0", "e1", "e2", "e3")
    order = [k for k in np.argsort(-np.abs(g))[:n] if abs(g[k]) > 1e-3 * np.abs(g).max()]
    return ", ".join(f"{model.body_names[k // 7]}.{labels[k % 7]} ({g[k]:.3g})" for k in order)


@dataclass
class Stationary:
    """Outcome of :func:`stationary_point`."""

    q: np.ndarray  # (nq,)
    lam: np.ndarray  # (m,) multipliers, 0 on redundant rows
    converged: bool
    iterations: int
    reduced_force: float  # max |N^T Q| at q
    eigenvalues: np.ndarray  # of the reduced Hessian H, ascending
    frequencies: np.ndarray | None  # rad/s, where N^T M N is positive definite
    energy: float
    message: str = ""
    energy_consistent: bool = True
    warnings: list[str] = field(default_factory=list)
    basis: np.ndarray | None = None  # (nq, n) N at q
    vectors: np.ndarray | None = None  # (n, n) eigenvectors of H (columns), as eigenvalues
    w2: np.ndarray | None = None  # (n,) generalized eigenvalues H z = w^2 N^T M N z


class Problem:
    """A generalized force g(q) (nq,) with its potential V(q) for one stationary problem."""

    def __init__(self, model, t, rows, force, energy, tangent=None):
        self.model, self.t, self.rows = model, t, rows
        self.force, self.energy, self.tangent = force, energy, tangent

    def basis(self, q):
        J = core.phi_q(self.model, None, q, self.t)[self.rows]
        C = J if self.tangent is None else np.vstack([J, self.tangent(q)[None, :]])
        return J, null_basis(C)

    def multipliers(self, J, g):
        return la.lstsq(J.T, g)[0]

    def hessian(self, q, lam, N, h):
        """H = -N^T d(g - Phi_q^T lam)/dq N by central differences along the columns of N."""
        def resid(x):
            return self.force(x) - core.phi_q(self.model, None, x, self.t)[self.rows].T @ lam
        if N.shape[1] == 0:
            return np.zeros((0, 0))
        KN = np.column_stack([(resid(q + h * n) - resid(q - h * n)) / (2 * h) for n in N.T])
        H = -N.T @ KN
        return 0.5 * (H + H.T)


def verdict(model, q, eigenvalues, vectors=None, basis=None, w2=None, rtol=1e-7,
            converged=True) -> dict:
    """stability, stable, neutral_modes (named) and the frequencies of a stationary point
    (module doc).  eigenvalues (n,) of H with their vectors (n, n) and N (nq, n) at q."""
    from mbsim.analyses.linear import name_neutral

    e = np.asarray(eigenvalues, float)
    tol = rtol * max(1.0, float(np.abs(e).max(initial=0.0)))
    neutral = np.abs(e) <= tol
    out = {"stability": classify(e, rtol), "neutral_modes": []}
    if vectors is not None and basis is not None and neutral.any():
        out["neutral_modes"] = name_neutral(model, q, basis @ vectors[:, neutral])
    out["stable"] = bool(converged and out["stability"] != "unstable")
    if w2 is not None:
        w2 = np.sort(np.asarray(w2, float))
        wtol = rtol * max(1.0, float(np.abs(w2).max(initial=0.0)))
        pos = np.sqrt(w2[w2 > wtol])
        out["frequencies"] = pos.tolist()
        out["frequencies_hz"] = (pos / (2 * np.pi)).tolist()
        if (w2 < -wtol).any():
            out["growth_rates"] = np.sqrt(-w2[w2 < -wtol]).tolist()
    return out


def classify(eigenvalues, rtol=1e-7):
    """'stable' (all > 0), 'neutral' (smallest ~ 0) or 'unstable' (some < 0)."""
    e = np.asarray(eigenvalues, float)
    if e.size == 0:
        return "stable"
    tol = rtol * max(1.0, float(np.abs(e).max()))
    if e.min() > tol:
        return "stable"
    return "unstable" if e.min() < -tol else "neutral"


def stationary_point(prob: Problem, q0, opt) -> Stationary:
    """Null-space Newton for g(q) - Phi_q^T lam = 0, Phi = 0, downhill in V (module doc)."""
    model, t, rows = prob.model, prob.t, prob.rows
    tol_phi, h = float(opt["phi_tol"]), float(opt["fd_step"])
    q = newton(model, q0, t, tol_phi, 50, rows=rows)[0]
    g = prob.force(q)
    scale = max(1.0, float(np.abs(g).max()), float(np.abs(model.mass * np.linalg.norm(
        model.gravity)).max()))
    J, N = prob.basis(q)
    # Does V belong to g?  dV along a tangent direction must equal -g . v (forces without
    # a potential, e.g. follower loads, make the line search use |r| instead).
    v = N @ np.ones(N.shape[1]) / np.sqrt(max(N.shape[1], 1)) if N.shape[1] else None
    consistent = True
    if v is not None:
        hv = 1e-5
        dV = (prob.energy(q + hv * v) - prob.energy(q - hv * v)) / (2 * hv)
        consistent = abs(dV + g @ v) <= 1e-5 * scale
    warnings = [] if consistent else [
        "the potential energy does not match the applied forces (non-conservative loads?): "
        "the line search uses the reduced force instead"]
    V = prob.energy(q)
    V_start = V
    it, message, converged = 0, "", False
    r = N.T @ g
    while True:
        lam_a = prob.multipliers(J, g)
        if np.abs(r).max(initial=0.0) <= opt["tol"] * scale:
            converged = True
            break
        if it >= opt["max_iter"]:
            break
        it += 1
        H = prob.hessian(q, lam_a, N, h)
        w, U = la.eigh(H)
        delta = 1e-8 * max(1.0, float(np.abs(w).max()))
        dz = U @ ((U.T @ r) / np.maximum(np.abs(w), delta))
        step = N @ dz
        nrm = np.linalg.norm(step)
        if nrm > opt["max_step"]:
            step *= opt["max_step"] / nrm
        alpha, accepted = 1.0, False
        slope = -(g @ step)  # dV along the step (< 0)
        r_norm = np.linalg.norm(r)
        best = None
        while alpha >= 1e-6:
            try:
                qt = newton(model, q + alpha * step, t, tol_phi, 50, rows=rows)[0]
            except ConvergenceError:
                alpha *= 0.5
                continue
            gt = prob.force(qt)
            Jt, Nt = prob.basis(qt)
            rt = Nt.T @ gt
            Vt = prob.energy(qt)
            ok_V = consistent and Vt <= V + 1e-4 * alpha * slope
            ok_r = np.linalg.norm(rt) < (1 - 1e-4 * alpha) * r_norm and (
                not consistent or Vt <= V + 1e-12 * max(1.0, abs(V)))
            if ok_V or ok_r:
                accepted = True
                break
            if best is None or np.linalg.norm(rt) < best[0]:
                best = (np.linalg.norm(rt), qt, gt, Jt, Nt, rt, Vt)
            alpha *= 0.5
        if not accepted:
            if best is None:
                message = "no step could be projected back onto the constraints"
                break
            _, qt, gt, Jt, Nt, rt, Vt = best
        q, g, J, N, r, V = qt, gt, Jt, Nt, rt, Vt
    lam_a = prob.multipliers(J, g)
    H = prob.hessian(q, lam_a, N, h)
    w, U = la.eigh(H) if H.size else (np.zeros(0), np.zeros((0, 0)))
    freq = w2 = None
    if H.size and prob.tangent is None:
        Mr = N.T @ core.mass_matrix(model, None, q) @ N
        try:
            w2 = la.eigh(H, 0.5 * (Mr + Mr.T), eigvals_only=True)
            freq = np.sign(w2) * np.sqrt(np.abs(w2))
        except la.LinAlgError:  # N^T M N not positive definite (zero inertias)
            freq = w2 = None
    lam = np.zeros(model.m)
    lam[rows] = lam_a
    if not converged and not message:
        resid = g - J.T @ lam_a
        cause = ""
        curv = float(r @ H @ r) / max(float(r @ r), 1e-300) if H.size else 0.0
        if consistent and V < V_start and curv <= 1e-6 * max(1.0, float(np.abs(w).max())):
            cause = (f"; the potential energy keeps falling (from {V_start:.6g} to {V:.6g} J) "
                     "with no restoring stiffness along the force: there is no minimum "
                     "(an unsupported body or an unbounded load?)")
        message = (f"equilibrium did not converge in {it} iterations: reduced force "
                   f"{np.abs(r).max():.3g} (tolerance {opt['tol'] * scale:.3g}), largest "
                   f"residual forces at {worst_coordinates(model, resid)}{cause}")
    return Stationary(q, lam, converged, it, float(np.abs(r).max(initial=0.0)), w, freq, V,
                      message, consistent, warnings, N, U, w2)




def _configuration(model, q):
    """{body: {'r': [3], 'p': [4]}}, round-off below 1e-13 shown as 0 (for the summary)."""
    qq = np.asarray(q, float).reshape(model.nb, 7)
    qq = np.where(np.abs(qq) < 1e-13, 0.0, qq) + 0.0
    return {n: {"r": qq[b, :3].tolist(), "p": qq[b, 3:].tolist()}
            for b, n in enumerate(model.body_names)}


def _result(model, opt, mode_method, t, q, qd, qdd, lam, sol: Stationary | None, extra=None):
    rec = Recorder(model)
    rec.add(t, q, qd, qdd)
    res = rec.result("equilibrium", opt.context.only)
    res.add("constraints/lam", lam[None, :], "", "Lagrange multipliers (rows as in the model)",
            model.row_label)
    add_reaction_channels(res, model, q[None, :], lam[None, :])
    s = {"method": mode_method, "configuration": _configuration(model, q)}
    if sol is not None:
        s.update(converged=sol.converged, iterations=sol.iterations,
                 reduced_force=sol.reduced_force, eigenvalues=sol.eigenvalues.tolist(),
                 **verdict(model, sol.q, sol.eigenvalues, sol.vectors, sol.basis, sol.w2,
                           converged=sol.converged),
                 **{"effective_potential" if mode_method == "steady" else
                    "potential_energy": sol.energy})
        if sol.warnings:
            s["warnings"] = list(sol.warnings)
        if not sol.converged:
            res.status, res.message = STATUS_INCOMPLETE, sol.message
    s.update(extra or {})
    res.summary = s
    return res


def _static_problem(model, t, rows):
    zero = np.zeros(model.nq)
    return Problem(model, t, rows, lambda q: core.generalized_forces(model, None, q, zero, t),
                   lambda q: core.potential_energy(model, None, q))


# -- methods -------------------------------------------------------------------------------

def minimum(model, opt) -> Result:
    """Minimum total potential energy from the estimates (module doc)."""
    t = float(opt["t"])
    q0 = model.q0 if opt.get("q0") is None else np.asarray(opt["q0"], float)
    asm = assemble(model, q0, t, tol=opt["phi_tol"], hold=opt.context.hold)
    sol = stationary_point(_static_problem(model, t, asm.active_rows), asm.q, opt)
    z = np.zeros(model.nq)
    return _result(model, opt, "minimum", t, sol.q, z, z, sol.lam, sol, {"dof": asm.dof})


class ArtificialDamping(ForceElement):
    """F = -c m rd, n' = -c J' omega' on every body (c in 1/s): mass-proportional damping
    that settles a model without changing its equilibria."""

    type = "artificial-damping"
    name = "artificial_damping"

    def __init__(self, model, c):
        self.c, self.m, self.J = float(c), model.mass, model.J_local

    def apply(self, st, t, F, n_local):
        F -= self.c * self.m[:, None] * st.rd
        n_local -= self.c * np.einsum("bij,bj->bi", self.J, st.omega_local)


def settle(model, opt) -> Result:
    """Damped dynamic run until velocities and accelerations stay below settle_tol."""
    run_model = model
    if opt["damping"]:
        run_model = dataclasses.replace(
            model, forces=tuple(model.forces) + (ArtificialDamping(model, opt["damping"]),))
    dyn_opt = {k: opt[k] for k in ("t_end", "step") if opt.get(k) is not None}
    for k in ("integrator", "rtol", "atol", "max_steps", "t_start", "progress"):
        if opt.get(k) is not None:
            dyn_opt[k] = opt[k]
    if opt["from_rest"]:  # released at rest from the (assembled) estimates
        q0 = model.q0 if opt.get("q0") is None else np.asarray(opt["q0"], float)
        dyn_opt["q0"] = assemble(model, q0, float(opt.get("t_start") or 0.0),
                                 tol=opt["phi_tol"], hold=opt.context.hold).q
        dyn_opt["qd0"] = np.zeros(model.nq)
    res = dynamic(run_model, opt.within("dynamic", dyn_opt, DYNAMIC_DEFAULTS))
    res.mode = "equilibrium"
    nt = len(res.t)
    speed = np.zeros(nt)
    for name in model.body_names:
        for key in ("rd", "omega", "rdd", "omegad"):
            ch = res.channels.get(f"bodies/{name}/{key}")
            if ch is not None:
                speed = np.maximum(speed, np.abs(ch.data).max(axis=1))
    tol = float(opt["settle_tol"])
    above = np.flatnonzero(speed > tol)
    summary = dict(res.summary)
    summary["method"] = "settle"
    summary["damping"] = float(opt["damping"])
    if nt == 0 or (above.size and above[-1] == nt - 1):
        summary["settled"] = False
        if res.status != STATUS_INCOMPLETE:
            res.status = STATUS_INCOMPLETE
            res.message = (f"did not settle by t = {res.t[-1] if nt else 0:.6g} s: largest "
                           f"velocity/acceleration {speed[-1] if nt else np.nan:.3g} > "
                           f"settle_tol {tol:.3g}; run longer (t_end) or add damping")
        res.summary = summary
        return res
    k = 0 if above.size == 0 else above[-1] + 1
    from mbsim.analyses.inverse import states_from_result

    q = states_from_result(model, res)[0][-1]
    t = float(res.t[-1])
    rows = assemble(model, q, t, tol=opt["phi_tol"], hold=opt.context.hold).active_rows
    prob = _static_problem(model, t, rows)
    J, N = prob.basis(q)
    g = prob.force(q)
    lam = prob.multipliers(J, g)
    H = prob.hessian(q, lam, N, float(opt["fd_step"]))
    w, U = la.eigh(H) if H.size else (np.zeros(0), np.zeros((0, 0)))
    summary.update(settled=True, settling_time=float(res.t[k]), configuration=_configuration(
        model, q), reduced_force=float(np.abs(N.T @ g).max(initial=0.0)),
        eigenvalues=w.tolist(), **verdict(model, q, w, U, N))
    res.summary = summary
    return res


def spin_field(model, q, Omega, c, bodies):
    """Rigid rotation with angular velocity Omega (3,) about the point c: (qd, qdd) (nq,)."""
    Qr = q.reshape(model.nb, 7)
    qd = np.zeros((model.nb, 7))
    qdd = np.zeros((model.nb, 7))
    st = core.State(model, q)
    for b in bodies:
        rho = Qr[b, :3] - c
        qd[b, :3] = np.cross(Omega, rho)
        qdd[b, :3] = np.cross(Omega, qd[b, :3])
        wl = st.A[b].T @ Omega
        pd = 0.5 * st.G[b].T @ wl  # Haug Ch. 6: pd = 1/2 G^T omega'
        qd[b, 3:] = pd
        qdd[b, 3:] = -(pd @ pd) * Qr[b, 3:]  # omega'd = 0, p^T pdd = -pd^T pd
    return qd.reshape(-1), qdd.reshape(-1)


def _spin_axis(model, opt):
    """(unit axis, point, body index or None) from the options or the body's joint to ground."""
    b = None
    if opt.get("body") is not None:
        try:
            b = model.body_index(opt["body"])
        except ValueError:
            raise DeckError(f"equilibrium.body: unknown body {opt['body']!r}; bodies: "
                            f"{', '.join(model.body_names)}") from None
    axis, point = opt.get("axis"), opt.get("point")
    if axis is None:
        if b is None:
            raise DeckError("equilibrium method 'steady' needs 'body' (spinning on a revolute or "
                            "cylindrical joint to ground) or 'axis' and 'point'")
        q = model.q0
        st = core.State(model, q)
        for it in model.items:
            if it.kind == "joint" and it.type in ("revolute", "cylindrical") and \
                    {it.bi, it.bj} >= {b} and model.is_ground[it.bi if it.bj == b else it.bj]:
                gb = it.bi if it.bj == b else it.bj
                Pg, Cg = (it.P_i, it.C_i) if gb == it.bi else (it.P_j, it.C_j)
                axis = st.A[gb] @ Cg[:, 0]
                point = st.r[gb] + st.A[gb] @ Pg if point is None else point
                break
        else:
            raise DeckError(f"equilibrium: body {model.body_names[b]!r} has no revolute or "
                            "cylindrical joint to ground; give 'axis' and 'point'")
    axis = np.asarray(axis, float)
    axis = axis / np.linalg.norm(axis)
    point = np.zeros(3) if point is None else np.asarray(point, float)
    return axis, point, b


def steady(model, opt) -> Result:
    """Steady spin: configuration for a given speed, or the speed for a given configuration."""
    t = float(opt["t"])
    axis, c, b = _spin_axis(model, opt)
    bodies = [k for k in range(model.nb) if not model.is_ground[k]]
    if opt.get("bodies") is not None:
        bodies = [model.body_index(n) for n in opt["bodies"]]
    q0 = model.q0 if opt.get("q0") is None else np.asarray(opt["q0"], float)
    asm = assemble(model, q0, t, tol=opt["phi_tol"], hold=opt.context.hold)
    rows = asm.active_rows

    def q_eff(q, Omega):
        qd, qdd = spin_field(model, q, Omega, c, bodies)
        Q = core.generalized_forces(model, None, q, qd, t)
        return Q - core.mass_matrix(model, None, q) @ qdd, qd, qdd

    def tangent(q):
        return spin_field(model, q, axis, c, bodies)[0]

    J0 = core.phi_q(model, None, asm.q, t)[rows]
    t0 = tangent(asm.q)
    if np.linalg.norm(J0 @ t0) > 1e-8 * max(1.0, np.linalg.norm(J0)) * np.linalg.norm(t0):
        raise ModelError("equilibrium 'steady': the constraints do not allow the rigid rotation "
                         f"about axis {np.round(axis, 6).tolist()} through "
                         f"{np.round(c, 6).tolist()} (a driver or a joint to ground holds it)")
    extra = {"axis": axis.tolist(), "point": c.tolist(), "dof": asm.dof}
    if opt.get("omega") is not None:
        w = float(opt["omega"])
        Omega = w * axis

        def energy(q):
            qd, _ = spin_field(model, q, Omega, c, bodies)
            st = core.State(model, q, qd)
            rot = np.einsum("bi,bij,bj->b", st.omega_local, model.J_local, st.omega_local)
            kin = model.mass * np.sum(st.rd ** 2, 1) + rot
            return core.potential_energy(model, None, q) - 0.5 * float(kin[bodies].sum())

        prob = Problem(model, t, rows, lambda q: q_eff(q, Omega)[0], energy, tangent)
        sol = stationary_point(prob, asm.q, opt)
        g, qd, qdd = q_eff(sol.q, Omega)
        extra.update(omega=w, holding_torque=_holding_torque(model, sol.q, g, sol.lam, tangent, t))
        return _result(model, opt, "steady", t, sol.q, qd, qdd, sol.lam, sol, extra)
    # the speed for the given configuration
    q = asm.q
    g0 = q_eff(q, 0.0 * axis)[0]
    g1 = q_eff(q, axis)[0] - g0
    J = core.phi_q(model, None, q, t)[rows]
    N = null_basis(np.vstack([J, tangent(q)[None, :]]))
    a, r0 = N.T @ g1, N.T @ g0
    if np.abs(a).max(initial=0.0) == 0:
        raise ModelError("equilibrium 'steady': spinning exerts no force along the free "
                         "coordinates, so no speed balances this configuration")
    w2 = -float(a @ r0) / float(a @ a)
    scale = max(1.0, float(np.abs(g0).max()))
    resid = float(np.abs(r0 + w2 * a).max())
    if w2 < 0:
        raise ModelError(f"equilibrium 'steady': this configuration would need omega^2 = "
                         f"{w2:.6g} < 0 (no real speed balances it)")
    w = float(np.sqrt(w2))
    g, qd, qdd = q_eff(q, w * axis)
    lam = np.zeros(model.m)
    lam[rows] = la.lstsq(J.T, g)[0]
    extra.update(omega=w, speed_residual=resid, holding_torque=_holding_torque(
        model, q, g, lam, tangent, t))
    res = _result(model, opt, "steady-speed", t, q, qd, qdd, lam, None, extra)
    if resid > opt["tol"] * 1e3 * scale:
        res.status = STATUS_INCOMPLETE
        res.message = (f"no speed makes this configuration steady: best omega = {w:.6g} rad/s "
                       f"leaves a reduced force {resid:.3g}; residual forces at "
                       f"{worst_coordinates(model, g - J.T @ lam[rows])}")
    return res


def _holding_torque(model, q, g, lam, tangent, t):
    """Torque about the spin axis needed to keep the speed constant (0 when none is)."""
    J = core.phi_q(model, None, q, t)
    return float(-(tangent(q) @ (g - J.T @ lam)))


# method name -> fn(model, opt: RunOptions) -> Result; opt.context: the run's deck context
# (the assembly's hold, outputs: only:, the deck's dynamic settings for 'settle')
METHODS = {"minimum": minimum, "settle": settle, "steady": steady}


def equilibrium(model, options=None) -> Result:
    """Run the equilibrium method named by ``options['method']`` (see the module doc)."""
    run = analysis_options("equilibrium", model, options, DEFAULTS)
    opt = dict(run)
    opt.pop("progress", None)  # passed on to the dynamic run of 'settle' (in ``run``)
    wall0 = _time.perf_counter()
    fn = METHODS.get(opt["method"])
    if fn is None:
        raise DeckError(f"unknown equilibrium method {opt['method']!r}; choose one of "
                        f"{', '.join(METHODS)}")
    res = fn(model, run)
    res.settings = {k: (float(v) if isinstance(v, (int, float)) and not isinstance(v, bool)
                        else v) for k, v in opt.items()
                    if v is not None and not isinstance(v, np.ndarray)}
    res.wall_time = _time.perf_counter() - wall0
    return res
