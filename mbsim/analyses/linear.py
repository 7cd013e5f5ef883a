"""Linear analysis: eigenvalues and modes of the equations of motion about a reference state.

Reference states (option ``about``):

``equilibrium`` (default)
    The deck's equilibrium method (``analysis: equilibrium: method``): ``minimum`` (a static
    equilibrium, Haug Sec. 11.5) or ``steady`` (a steady spin, e.g. the governor at Table
    12.6.6 with its engine torque feedback).  ``minimum`` and ``steady`` name one directly.
``state``
    The state (q, qd) at time ``time`` of a dynamic run from the deck's initial conditions
    (a frozen-time linearisation: it describes the motion near that instant only).

Coordinates.  With N (nq, n) an orthonormal basis of null(Phi_q) at the reference q0 (the
active rows, normalisation rows included, so N has no component along any p: the Euler
parameters enter only through rotations) the independent coordinates are the linear chart

    v = N^T (q - q0),   vd = N^T qd,   vdd = N^T qdd,

exact at any distance from q0: q(v) is the point on Phi = 0 with N^T (q - q0) = v (Newton
along the complement Nc of N), qd(v, vd) solves [Phi_q; N^T] qd = [nu; vd].  The state
z = (v, vd) obeys zd = F(z) = (vd, N^T qdd(q, qd)) with qdd from the reference KKT solve
:func:`mbsim.core.accelerations` (Haug Ch. 11); the state matrix

    A = dF/dz = [[0, I], [dvdd/dv, dvdd/dvd]]

is formed by central differences of F with the stated steps ``fd_step`` (positions, m or
unit Euler parameter) and ``fd_step * max(1, |vd0|)`` (velocities); the result is checked
by repeating with steps 4 times larger (summary ``fd_check``: the largest change of an
eigenvalue relative to the largest |lambda|).  An eigenvalue that changes by more than
:data:`FD_RESOLVED` of the largest is not a derivative at all (a force law that switches or
has a kink at the reference: the compressor's valve law at rest gave -1.8e10 1/s, 0.75
changed): the result is kept, marked incomplete, with the eigenvalues named.  A small
eigenvalue that changes by half its size is noise about a double zero (below).  No analytic
Jacobian of the force laws exists yet (expression laws, tires), hence finite differences
everywhere.

Steady spin (``steady``).  The state is expressed in the frame turning with the spin
Omega = omega * axis about the point c: r = c + R(Omega t) (r~ - c), p = s(t) * p~ (Hamilton
product, s the spin quaternion), so that

    r~dd = rdd - 2 Omega x r~d - Omega x (Omega x (r~ - c))
    p~dd = pdd + |Omega|^2 / 4 p~ - (0, Omega) * p~d

and the steady state is an equilibrium of the rotating-frame equations (F(z0) = 0, summary
``residual``); the spin angle is a cyclic coordinate (a zero eigenvalue, named neutral) and
the spin speed a state, so feedback through the speed (the governor's T_s = C dl) is in A.

Verdict.  Eigenvalues with |lambda| <= ``zero_tol`` * max(1, max |lambda|) are *neutral*
modes (rigid-body motions, free spins, cyclic coordinates); each is named by the bodies and
directions it moves.  A coordinate with neither stiffness nor damping (a crank that gravity
does not load) is a double zero with one eigenvector, the block [[0, 1], [0, 0]]: a
perturbation delta of A moves it to +-sqrt(delta), so its noise is the square root of a
simple zero's; an eigenvalue below sqrt(``zero_tol``) * max(1, max |lambda|) that changes by
at least half its size with the 4 x steps is that noise, neutral too (the three-body
slider-crank: +-8e-5 at h = 1e-6, +-8e-4 real at 1e-5, otherwise `stable` or `unstable`
depending on the step).  Free spins are also recognised from the model's structure
(:func:`free_spins`: a body's turn about a principal axis that the constraints allow and no
load depends on) and their eigenvalues set to exactly 0, whatever the finite differences'
noise divided by a slender body's axial inertia would make of them.  ``unstable``: some
other eigenvalue has Re lambda > ``re_tol`` *
max(1, max |lambda|); else ``neutral`` if there are neutral modes, else ``stable``
(undamped oscillations, Re = 0, count as stable: bounded).  ``stable`` = not unstable.
Frequencies: omega_n = |lambda| (rad/s), f = omega_n / 2 pi (Hz), omega_d = |Im lambda|;
damping ratio zeta = -Re lambda / |lambda| (1: critically damped, < 0: growing).
"""

from __future__ import annotations

import logging
import time as _time

import numpy as np
import scipy.linalg as la

from mbsim import core
from mbsim.analyses.assembly import assemble
from mbsim.analyses.common import Recorder
from mbsim.errors import ConvergenceError, DeckError
from mbsim.options import analysis_options
from mbsim.result import STATUS_INCOMPLETE, Result
from mbsim.rotations import G as rot_G

log = logging.getLogger(__name__)

DEFAULTS = {
    "about": "equilibrium",  # equilibrium | minimum | steady | state
    "time": None,  # 'state': time of the dynamic run to linearise at, s
    "t": None,  # minimum/steady: time at which loads are evaluated (default: equilibrium's t)
    "fd_step": 1e-6,  # central-difference step (positions; velocities * max(1, |vd0|))
    "zero_tol": 1e-5,  # |lambda| below this (relative) is a neutral mode
    "re_tol": 1e-6,  # Re lambda above this (relative) is growth
    "phi_tol": 1e-13,
}

FD_RESOLVED = 1e-3
"""An eigenvalue is resolved by the central differences when it changes by less than this x
max(1, max |lambda|) with the steps made 4 times larger (summary ``fd_check``).  On smooth
equations the change is the truncation error O(h^2) plus the round-off O(eps / h): 4e-13
(pendulum, sleeping top) to 3e-6 (the vehicle's 188 rad/s mode) at h = 1e-6, docs/deck.md;
a force that switches or has a kink within 4 h of the reference makes a derivative of size
1/h, which changes by O(1) (the compressor's valve law at rest: 0.75).  1e-3 lies between
with 2.5 decades of margin on each side."""

COORD = ("x", "y", "z", "e0", "e1", "e2", "e3")
BODY_COORD = ("x", "y", "z", "theta_x'", "theta_y'", "theta_z'")


def _qmul(a, b):
    """Hamilton product of quaternions a, b (..., 4): A(a * b) = A(a) A(b)."""
    a0, av = a[..., :1], a[..., 1:]
    b0, bv = b[..., :1], b[..., 1:]
    return np.concatenate([a0 * b0 - np.sum(av * bv, -1, keepdims=True),
                           a0 * bv + b0 * av + np.cross(av, bv)], -1)


class Chart:
    """The linear chart v = N^T (q - q0) on Phi = 0 and the state derivative F(z).

    model: compiled Model; q0 (nq,) the reference configuration; rows: active constraint
    rows; t: time at which forces and drivers are evaluated; spin: None or (Omega (3,),
    c (3,), bodies) for the rotating frame of a steady spin.
    """

    def __init__(self, model, q0, rows, t, spin=None, tol=1e-13):
        self.model, self.q0, self.rows, self.t, self.spin, self.tol = model, q0, rows, t, spin, tol
        J = core.phi_q(model, None, q0, t)[rows]
        _, s, Vt = la.svd(J, full_matrices=True)
        rank = int(np.sum(s > 1e-10 * max(s[0], 1e-300))) if s.size else 0
        self.N = Vt[rank:].T  # (nq, n) tangent basis
        self.Nc = Vt[:rank].T  # (nq, rank) normal basis
        self.n = self.N.shape[1]

    def q(self, v):
        """The configuration on Phi = 0 with N^T (q - q0) = v (Newton along Nc)."""
        model, rows, t = self.model, self.rows, self.t
        q = self.q0 + self.N @ v
        for _ in range(30):
            T = core.constraints(model, None, q, t)
            ph = T.phi[rows]
            if np.abs(ph).max(initial=0.0) < self.tol:
                return q
            q = q - self.Nc @ la.lstsq(T.jac[rows] @ self.Nc, ph)[0]
        if np.abs(core.phi(model, None, q, t)[rows]).max(initial=0.0) < 1e3 * self.tol:
            return q
        raise ConvergenceError("linear: the perturbed configuration could not be assembled "
                               "(fd_step too large for this mechanism?)")

    def qd(self, q, vd):
        """Velocity (nq,) with N^T qd = vd and Phi_q qd = nu (relative to the spin frame)."""
        T = core.constraints(self.model, None, q, self.t, phi=False, nu=True)
        K = np.vstack([T.jac[self.rows], self.N.T])
        return la.lstsq(K, np.concatenate([T.nu[self.rows], vd]))[0]

    def spin_terms(self, q, qd_rel):
        """(qd_inertial, qdd_frame): the spin field added to the relative velocity and the
        frame acceleration (Coriolis, centripetal) to subtract from qdd (module doc)."""
        if self.spin is None:
            return qd_rel, 0.0
        Omega, c, bodies = self.spin
        nb = self.model.nb
        Q = q.reshape(nb, 7)
        V = qd_rel.reshape(nb, 7)
        qd = V.copy()
        acc = np.zeros((nb, 7))
        om4 = np.concatenate([[0.0], Omega])
        for b in bodies:
            rho = Q[b, :3] - c
            qd[b, :3] += np.cross(Omega, rho)
            qd[b, 3:] += 0.5 * _qmul(om4, Q[b, 3:])
            acc[b, :3] = 2 * np.cross(Omega, V[b, :3]) + np.cross(Omega, np.cross(Omega, rho))
            acc[b, 3:] = -(Omega @ Omega) / 4 * Q[b, 3:] + _qmul(om4, V[b, 3:])
        return qd.reshape(-1), acc.reshape(-1)

    def vdd(self, v, vd):
        q = self.q(v)
        qd_rel = self.qd(q, vd)
        qd, frame = self.spin_terms(q, qd_rel)
        qdd = core.accelerations(self.model, core.make_data(self.model, self.rows), q, qd,
                                 self.t)[0]
        return self.N.T @ (qdd - frame)

    def F(self, z):
        n = self.n
        return np.concatenate([z[n:], self.vdd(z[:n], z[n:])])

    def state_matrix(self, vd0, h):
        """A = dF/dz at z0 = (0, vd0) by central differences (positions h, velocities
        h max(1, |vd0|))."""
        n = self.n
        z0 = np.concatenate([np.zeros(n), vd0])
        hv = h * max(1.0, float(np.abs(vd0).max(initial=0.0)))
        A = np.zeros((2 * n, 2 * n))
        A[:n, n:] = np.eye(n)
        for k in range(2 * n):
            dz = h if k < n else hv
            e = np.zeros(2 * n)
            e[k] = dz
            A[n:, k] = (self.vdd((z0 + e)[:n], (z0 + e)[n:])
                        - self.vdd((z0 - e)[:n], (z0 - e)[n:])) / (2 * dz)
        return A, self.F(z0)


FREE_SPIN_ANGLE = 0.5
"""rad: the finite turn of a body about one of its principal axes by which a free spin is
recognised (below): a law that depends on the turn changes by O(1) of its size over half a
radian, a symmetry by round-off; a small test angle would blur the two with the finite
differences' own error."""
FREE_SPIN_RATE = 1.0
"""rad/s: the spin rate at which velocity-dependent loads (dampers, tires) are compared."""
FREE_SPIN_REL = 1e-9
"""The loads (forces and torques on every body, global) of a free spin differ from those of
the reference by at most this fraction of their size plus the weight scale m g: round-off
is 1e-15 of it; any law coupled to the spin changes by far more than 1e-9 over 0.5 rad."""


def _loads(model, q, qd, t):
    """(nb, 6): applied force (global) and torque (global) on each body, gravity included."""
    _, F, n_local = core.applied_forces(model, None, q, qd, t)
    A = core.State(model, q).A
    return np.concatenate([F, np.einsum("bij,bj->bi", A, n_local)], axis=1)


def free_spins(model, chart, qd0):
    """Directions of the chart (v space) that are free spins by structure, and their names.

    A body's turn about one of its principal axes through its centroid (a rod about its own
    axis between ball joints, a wheel on its axle) is a neutral mode exactly when the
    constraints allow it (a finite turn keeps Phi = 0) and no load depends on it (the
    forces and torques on every body are the same after a turn of FREE_SPIN_ANGLE and at a
    spin of FREE_SPIN_RATE): then no stiffness or damping acts along it, and the mode has
    lambda = 0 twice.  The finite differences alone cannot say so: the noise of dF/dv along
    the spin, divided by a slender rod's axial inertia (1e-9 kg m^2), gives a spurious real
    pair of 1e-3 1/s.  Only about a state at rest (qd0 = 0) and without a spin frame.

    Returns (D (n, k) orthonormal, names (k,)).
    """
    n = chart.n
    if chart.spin is not None or np.any(qd0) or n == 0:
        return np.zeros((n, 0)), []
    q0, t, rows = chart.q0, chart.t, chart.rows
    base = _loads(model, q0, np.zeros(model.nq), t)
    scale = float(np.abs(base).max(initial=0.0)) + float(
        np.max(model.mass, initial=0.0) * max(np.linalg.norm(model.gravity), 1.0))
    phi_tol = max(1e3 * chart.tol, 1e-10)
    st = core.State(model, q0)
    dirs, names = [], []
    for b in range(model.nb):
        if model.is_ground[b]:
            continue
        _, axes = np.linalg.eigh(model.J_local[b])
        p = q0[7 * b + 3: 7 * b + 7]
        for k in range(3):
            u = axes[:, k]
            turn = np.concatenate([[np.cos(FREE_SPIN_ANGLE / 2)],
                                   np.sin(FREE_SPIN_ANGLE / 2) * u])
            q1 = q0.copy()
            q1[7 * b + 3: 7 * b + 7] = _qmul(p, turn)  # body-frame turn: A(p) A(turn)
            if np.abs(core.phi(model, None, q1, t)[rows]).max(initial=0.0) > phi_tol:
                continue
            dq = np.zeros(model.nq)
            dq[7 * b + 3: 7 * b + 7] = 0.5 * rot_G(p).T @ u  # omega' = 2 G pd = u
            spin = FREE_SPIN_RATE * dq
            if (np.abs(_loads(model, q1, np.zeros(model.nq), t) - base).max() > FREE_SPIN_REL
                    * scale or np.abs(_loads(model, q0, spin, t) - base).max()
                    > FREE_SPIN_REL * scale):
                continue
            d = chart.N.T @ dq
            if np.linalg.norm(chart.N @ d - dq) > 1e-8 * np.linalg.norm(dq):
                continue  # not a motion of the chart (should not happen once Phi holds)
            dirs.append(d / np.linalg.norm(d))
            g = st.A[b] @ u
            names.append(f"{model.body_names[b]}: free spin about its principal axis "
                         f"{_fmt(u)} (global {_fmt(g)})")
    if not dirs:
        return np.zeros((n, 0)), []
    Q, R = np.linalg.qr(np.column_stack(dirs))
    keep = np.abs(np.diag(R)) > 1e-8
    return Q[:, keep], [nm for nm, kk in zip(names, keep) if kk]


def without_free_spins(A, D):
    """The state matrix with the free spins' columns set to their exact values: no load
    depends on the turn or the rate along D (free_spins), so dvdd/dv D = dvdd/dvd D = 0.
    Block-triangular then: the spins' eigenvalues are exactly 0, the others those of the
    complement, free of the finite differences' noise along D."""
    if D.shape[1] == 0:
        return A
    n = D.shape[0]
    P = np.eye(n) - D @ D.T
    A = A.copy()
    A[n:, :n] = A[n:, :n] @ P
    A[n:, n:] = A[n:, n:] @ P
    return A


def sort_eigen(lam, X):
    """Order by natural frequency |lambda|, then Im lambda descending (pairs adjacent,
    the positive-frequency member first)."""
    order = np.lexsort((-lam.imag, np.round(np.abs(lam), 10)))
    return lam[order], X[:, order]


def body_modes(model, q0, dq):
    """Mode shapes in body coordinates: (nmodes, nb, 6) complex, [dx dy dz] global (m) and
    [theta_x' theta_y' theta_z'] small rotation in body axes (rad) = 2 G(p) dp (Haug eq.
    6.3.18 applied to a displacement)."""
    nb = model.nb
    P = q0.reshape(nb, 7)[:, 3:]
    Gm = rot_G(P)  # (nb, 3, 4)
    D = dq.T.reshape(-1, nb, 7)
    rot = 2 * np.einsum("bij,kbj->kbi", Gm, D[:, :, 3:])
    return np.concatenate([D[:, :, :3], rot], axis=2)


def describe_mode(model, q0, shape_body, tol=0.1) -> str:
    """Name a (neutral) mode by the bodies it moves: 'spin of spindle, ball1 about global
    (0, 1, 0)' when they turn together, 'link2: rotation about body axis (0, 0, 1)' for one
    body, 'translation of ... along (...)'.  shape_body: (nb, 6) complex body-coordinate shape."""
    S = np.real(shape_body * np.exp(-1j * np.angle(shape_body.flat[np.argmax(np.abs(
        shape_body))])))
    A = core.State(model, q0).A
    rot_g = np.einsum("bij,bj->bi", A, S[:, 3:])  # global rotation vectors
    mags = np.maximum(np.linalg.norm(S[:, :3], axis=1), np.linalg.norm(S[:, 3:], axis=1))
    top = mags.max(initial=0.0)
    groups: list[list] = []  # [kind, unit vector, [body names], body axis]

    def fmt(a):
        a = a * np.sign(a[np.argmax(np.abs(a))])
        return "(" + ", ".join(f"{x:.3g}" for x in np.where(np.abs(a) < 1e-6, 0.0, a)) + ")"

    for b in np.argsort(-mags):
        if mags[b] < tol * top or model.is_ground[b]:
            continue
        rotates = np.linalg.norm(S[b, 3:]) >= np.linalg.norm(S[b, :3])
        vec = rot_g[b] if rotates else S[b, :3]
        u = vec / np.linalg.norm(vec)
        for g in groups:
            if g[0] == rotates and abs(abs(g[1] @ u) - 1) < 1e-6:
                g[2].append(model.body_names[b])
                break
        else:
            groups.append([rotates, u, [model.body_names[b]], S[b, 3:] / np.linalg.norm(
                S[b, 3:]) if rotates else None])
    parts = []
    for rotates, u, names, ax in groups[:4]:
        if rotates and len(names) == 1:
            parts.append(f"{names[0]}: rotation about body axis {fmt(ax)} (global {fmt(u)})")
        elif rotates:
            parts.append(f"rotation of {', '.join(names)} together about global {fmt(u)}")
        else:
            parts.append(f"translation of {', '.join(names)} along global {fmt(u)}")
    return "; ".join(parts) or "no motion"


def name_neutral(model, q0, dq, rtol=1e-3) -> list[str]:
    """Names of the neutral subspace spanned by the columns of dq (nq, k), complex or real.

    The span (rank by SVD) is described in the simplest terms that fit it: first motions of
    one body alone (its rotation about one of its body axes, its translation along a global
    axis: a free spin), then rigid motions of all moving bodies together (translation along
    a global axis, rotation about a global axis through their mass centre: a cyclic spin, a
    vehicle's plan position and heading), each tested for membership of the span (relative
    residual < rtol) in body coordinates; what is left is described by :func:`describe_mode`.
    """
    if dq.size == 0:
        return []
    V = np.hstack([np.real(dq), np.imag(dq)])
    U, s, _ = la.svd(body_modes(model, q0, V).reshape(V.shape[1], -1).T, full_matrices=False)
    rank = int(np.sum(s > 1e-6 * max(s[0], 1e-300)))
    span = U[:, :rank]  # (6 nb, r) orthonormal, body coordinates
    nb = model.nb
    moving = [b for b in range(nb) if not model.is_ground[b]]
    st = core.State(model, q0)
    A = st.A
    candidates = []  # (name, (6 nb,) body-coordinate vector)
    for b in moving:
        for k, ax in enumerate(("x'", "y'", "z'")):
            T = np.zeros((nb, 6))
            T[b, 3 + k] = 1.0
            g = A[b][:, k]
            candidates.append((f"{model.body_names[b]}: rotation about body axis {ax} "
                               f"(global {_fmt(g)})", T.reshape(-1)))
        for k, ax in enumerate("xyz"):
            T = np.zeros((nb, 6))
            T[b, k] = 1.0
            candidates.append((f"{model.body_names[b]}: translation along global {ax}",
                               T.reshape(-1)))
    if len(moving) > 1:
        m = model.mass[moving]
        c = (m[:, None] * st.r[moving]).sum(0) / m.sum()
        who = "all moving bodies" if len(moving) == nb - int(model.is_ground.sum()) else ""
        for k, ax in enumerate("xyz"):
            T = np.zeros((nb, 6))
            T[moving, k] = 1.0
            candidates.append((f"translation of {who} along global {ax}", T.reshape(-1)))
        for k, ax in enumerate("xyz"):
            w = np.eye(3)[k]
            T = np.zeros((nb, 6))
            for b in moving:
                T[b, :3] = np.cross(w, st.r[b] - c)
                T[b, 3:] = A[b].T @ w
            candidates.append((f"rotation of {who} together about global {ax} through "
                               f"{_fmt(c, keep_sign=True)}", T.reshape(-1)))
    names, taken = [], np.zeros((span.shape[0], 0))
    for name, T in candidates:
        if taken.shape[1] >= rank:
            break
        T = T / np.linalg.norm(T)
        if np.linalg.norm(T - span @ (span.T @ T)) > rtol:
            continue  # not a neutral motion
        rest = T - taken @ (taken.T @ T)
        if np.linalg.norm(rest) < 0.1:
            continue  # already named
        taken = np.column_stack([taken, rest / np.linalg.norm(rest)])
        names.append(name)
    if taken.shape[1] < rank:  # the others, one orthogonal direction each
        left = span - taken @ (taken.T @ span)
        Ul, sl, _ = la.svd(left, full_matrices=False)
        for k in range(rank - taken.shape[1]):
            names.append(describe_mode(model, q0, Ul[:, k].reshape(nb, 6)))
    return names


def _fmt(a, keep_sign=False) -> str:
    a = np.asarray(a, float)
    if not keep_sign:
        a = a * np.sign(a[np.argmax(np.abs(a))])
    return "(" + ", ".join(f"{x:.3g}" for x in np.where(np.abs(a) < 1e-6, 0.0, a) + 0.0) + ")"


def classify(lam, zero_tol=1e-5, re_tol=1e-6, structural=None, change=None):
    """(verdict, neutral mask, growing mask): see the module doc.  ``structural``: a mask
    of eigenvalues known neutral from the model's structure (free spins); ``change``: each
    eigenvalue's change with the difference steps made 4 times larger (:func:`fd_change`):
    an eigenvalue below sqrt(zero_tol) max(1, max |lambda|) that changes by half its own
    size is the differences' noise about a double zero (module doc), neutral."""
    scale = max(1.0, float(np.abs(lam).max(initial=0.0)))
    mag = np.abs(lam)
    neutral = mag <= zero_tol * scale
    if change is not None:
        neutral |= (mag <= np.sqrt(zero_tol) * scale) & (change >= 0.5 * mag)
    if structural is not None:
        neutral |= structural
    growing = (lam.real > re_tol * scale) & ~neutral
    if growing.any():
        return "unstable", neutral, growing
    return ("neutral" if neutral.any() else "stable"), neutral, growing


def fd_change(lam, lam4):
    """(n,) |lambda_k - its twin| between the eigenvalues ``lam`` of the state matrix at the
    difference step h and ``lam4`` at 4 h, each paired with its nearest twin (an assignment,
    so that a pair of close eigenvalues is not matched twice)."""
    from scipy.optimize import linear_sum_assignment

    dist = np.abs(lam[:, None] - lam4[None, :])
    rows_, cols_ = linear_sum_assignment(dist)
    change = np.zeros(lam.size)
    change[rows_] = dist[rows_, cols_]
    return change


def unresolved_message(model, lam, change, unresolved, scale):
    """The message of a linear analysis whose differences do not converge: the eigenvalues
    that change with the step and what makes a state matrix step-dependent."""
    shown = ", ".join(f"{lam[k].real:.4g}{lam[k].imag:+.4g}j (changes by {change[k]:.2g})"
                      for k in np.flatnonzero(unresolved)[:4])
    hybrid = [el.name for el in model.forces if getattr(el, "hybrid", False)]
    cause = (f"a force law that switches or has a kink at the reference state ("
             f"{', '.join(hybrid)}: a switching, contact or friction element)" if hybrid else
             "a force law that switches or has a kink at the reference state")
    return (f"the eigenvalues depend on the finite-difference step: with steps 4 times larger "
            f"{shown} (more than {FD_RESOLVED:g} x max |lambda| = {FD_RESOLVED * scale:.3g}); "
            f"the equations of motion are not differentiable there, {cause}: the modes and "
            f"the verdict are not those of a linearisation")


def modal_quantities(lam):
    """omega_n = |lambda| (rad/s), f (Hz), omega_d = |Im lambda| (rad/s), zeta."""
    wn = np.abs(lam)
    with np.errstate(invalid="ignore", divide="ignore"):
        zeta = np.where(wn > 0, -lam.real / np.where(wn > 0, wn, 1.0), 0.0)
    return wn, wn / (2 * np.pi), np.abs(lam.imag), zeta


def _options(model, options):
    """(run, opt): the RunOptions and the settings as a dict, ``method`` read as ``about``."""
    run = analysis_options("linear", model, options, DEFAULTS)
    opt = dict(run)
    if opt.get("method"):  # `mbsim run --mode linear --method steady`
        opt["about"] = opt.pop("method")
    return run, opt


def reference_state(model, opt, run):
    """(q0, qd0, t, rows, spin, description, equilibrium result or None); ``run``: the
    linear analysis' RunOptions (its deck context: the deck's equilibrium and dynamic
    settings, the assembly's hold)."""
    from mbsim.analyses import equilibrium as eqm

    about = opt["about"]
    hold = run.context.hold
    eopt = run.within("equilibrium", {k: opt[k] for k in ("t",) if opt.get(k) is not None})
    if about == "equilibrium":
        about = "steady" if eopt["method"] == "steady" else "minimum"
    if about in ("minimum", "steady"):
        eopt = eopt.replace(method=about)
        if about == "steady" and eopt.get("body") is None and eopt.get("axis") is None:
            raise DeckError("linear about 'steady' needs analysis.equilibrium.body (or axis and "
                            "point) of the spinning body")
        res = eqm.equilibrium(model, eopt)
        if not res.complete:
            raise ConvergenceError(f"linear: the reference {about} state: {res.message}")
        from mbsim.analyses.inverse import states_from_result

        q = states_from_result(model, res)[0][-1]
        t = float(eopt["t"])
        rows = assemble(model, q, t, tol=1e-11, hold=hold).active_rows
        spin = None
        if about == "steady":
            axis, c, _ = eqm._spin_axis(model, eopt)
            w = float(res.summary["omega"])
            bodies = [k for k in range(model.nb) if not model.is_ground[k]]
            if eopt.get("bodies") is not None:
                bodies = [model.body_index(n) for n in eopt["bodies"]]
            spin = (w * np.asarray(axis, float), np.asarray(c, float), bodies)
            desc = f"steady spin at {w:.6g} rad/s about {np.round(axis, 6).tolist()}"
        else:
            desc = "static equilibrium (minimum of the potential energy)"
        return q, np.zeros(model.nq), t, rows, spin, desc, res
    if about == "state":
        if opt.get("time") is None:
            raise DeckError("linear about 'state' needs 'time' (s): the instant of the dynamic "
                            "run to linearise at")
        from mbsim.analyses.dynamic import dynamic
        from mbsim.analyses.inverse import states_from_result

        time = float(opt["time"])
        dopt = {"t_end": time, "step": time / max(1, int(np.ceil(time / 0.01)))} if time > 0 \
            else {"t_end": 0.0}
        res = dynamic(model, run.within("dynamic", dopt))
        if not res.complete:
            raise ConvergenceError(f"linear: the dynamic run to t = {time:g} s: {res.message}")
        qs, qds = states_from_result(model, res)[:2]
        rows = assemble(model, qs[-1], time, tol=1e-11, hold=hold).active_rows
        return qs[-1], qds[-1], time, rows, None, f"state at t = {time:g} s of a dynamic run", \
            None
    raise DeckError(f"unknown linear 'about' {opt['about']!r}; choose equilibrium, minimum, "
                    "steady or state")


def linear(model, options=None) -> Result:
    """Eigenvalues, frequencies, damping ratios and modes about the reference (module doc)."""
    wall0 = _time.perf_counter()
    run, opt = _options(model, options)
    opt.pop("progress", None)
    q0, qd0, t, rows, spin, desc, _ = reference_state(model, opt, run)
    chart = Chart(model, q0, rows, t, spin, tol=float(opt["phi_tol"]))
    n = chart.n
    if n == 0:
        names = ", ".join(it.name for it in model.items if it.kind == "driver") or "none"
        raise DeckError(f"linear analysis needs free coordinates, but the constraints and "
                        f"drivers ({names}) leave DOF = 0: remove the drivers (active: false "
                        "or a scene) to study the free motion")
    h = float(opt["fd_step"])
    qd_rel0 = qd0
    vd0 = chart.N.T @ qd_rel0
    A, F0 = chart.state_matrix(vd0, h)
    A4, _ = chart.state_matrix(vd0, 4 * h)
    D, spin_names = free_spins(model, chart, qd_rel0)
    A, A4 = without_free_spins(A, D), without_free_spins(A4, D)
    lam, X = la.eig(A) if n else (np.zeros(0, complex), np.zeros((0, 0), complex))
    lam, X = sort_eigen(lam, X)
    lam4 = la.eigvals(A4)
    # the free spins' 2k eigenvalues are exactly 0 (a Jordan block each: computed as
    # +-sqrt(eps)-sized values at most), the smallest in modulus
    structural = np.zeros(lam.size, bool)
    structural[np.argsort(np.abs(lam))[: 2 * D.shape[1]]] = True
    scale = max(1.0, float(np.abs(lam).max(initial=0.0)))
    change = fd_change(lam, lam4)
    fd_check = float(change.max(initial=0.0)) / scale
    verdict, neutral, growing = classify(lam, float(opt["zero_tol"]), float(opt["re_tol"]),
                                         structural, change)
    unresolved = (change > FD_RESOLVED * scale) & ~neutral
    wn, fhz, wd, zeta = modal_quantities(lam)
    wn[neutral], fhz[neutral], wd[neutral], zeta[neutral] = 0.0, 0.0, 0.0, 0.0
    # mode shapes: position part of each eigenvector, in q and in body coordinates, scaled
    # so that the largest body-coordinate component is 1 (real, positive)
    dq = chart.N @ X[:n] if n else np.zeros((model.nq, 0))
    bm = body_modes(model, q0, dq)
    for k in range(bm.shape[0]):
        flat = bm[k].reshape(-1)
        big = flat[np.argmax(np.abs(flat))] if flat.size else 1.0
        if abs(big) > 0:
            bm[k] /= big
            dq[:, k] /= big
    neutral_names = name_neutral(model, q0, dq[:, neutral])
    residual = float(np.abs(F0[n:]).max(initial=0.0)) if spin is not None or not \
        np.any(qd0) else None

    rec = Recorder(model)
    qd_in, _ = chart.spin_terms(q0, qd_rel0) if spin is not None else (qd0, 0.0)
    qdd0 = core.accelerations(model, core.make_data(model, rows), q0, qd_in, t)[0]
    rec.add(t, q0, qd_in, qdd0)
    res = rec.result("linear", run.context.only)
    labels_q = [f"{b}.{c}" for b in model.body_names for c in COORD]
    labels_b = [f"{b}.{c}" for b in model.body_names for c in BODY_COORD]
    res.arrays = {
        "linear/eigenvalues": (lam.astype(np.complex128), {
            "unit": "1/s", "description": "eigenvalues of the state matrix, sorted by |lambda|"}),
        "linear/omega_n": (wn, {"unit": "rad/s", "description": "natural frequency |lambda|"}),
        "linear/frequency_hz": (fhz, {"unit": "Hz", "description": "|lambda| / (2 pi)"}),
        "linear/omega_d": (wd, {"unit": "rad/s", "description": "damped frequency |Im lambda|"}),
        "linear/damping_ratio": (zeta, {"unit": "", "description": "-Re lambda / |lambda|"}),
        "linear/neutral": (neutral.astype(np.int8), {
            "unit": "", "description": "1: neutral mode (rigid-body, free spin, cyclic)"}),
        "linear/growing": (growing.astype(np.int8), {
            "unit": "", "description": "1: growing mode (Re lambda > re_tol max(1, |lambda|))"}),
        "linear/modes/q": (dq.T.astype(np.complex128), {
            "unit": "", "description": "mode shapes (nmodes, nq) in q = [r, p] per body",
            "components": np.array(labels_q, dtype=object)}),
        "linear/modes/body": (bm.reshape(bm.shape[0], -1).astype(np.complex128), {
            "unit": "m, rad", "description": "mode shapes (nmodes, 6 nb): dx dy dz (global, m), "
            "small rotation about body axes (rad); largest component 1",
            "components": np.array(labels_b, dtype=object)}),
        "linear/state_matrix": (A, {"unit": "", "description": "A = dF/dz, z = (v, vd)"}),
        "linear/basis": (chart.N, {"unit": "", "description": "N (nq, n): v = N^T (q - q0)"}),
        "linear/q0": (q0, {"unit": "", "description": "reference configuration"}),
        "linear/qd0": (qd_in, {"unit": "", "description": "reference velocity (inertial)"}),
    }
    res.attrs = {"stable": verdict != "unstable", "stability": verdict}
    pairs = [k for k in range(lam.size) if lam[k].imag >= 0 or neutral[k]]
    res.summary = {
        "about": desc,
        "dof": n,
        "stability": verdict,
        "stable": verdict != "unstable",
        "neutral_modes": neutral_names,
        "free_spins": spin_names,
        "eigenvalues": [complex(x) for x in lam],
        "frequencies_hz": [float(fhz[k]) for k in pairs],
        "damping_ratios": [float(zeta[k]) for k in pairs],
        "jacobian": f"central differences, step {h:g} (positions), "
                    f"{h * max(1.0, float(np.abs(vd0).max(initial=0.0))):g} (velocities)",
        "fd_check": fd_check,
    }
    if residual is not None:
        res.summary["residual"] = residual
    res.settings = {k: v for k, v in opt.items() if v is not None}
    if unresolved.any():  # results kept, marked incomplete: the CLI exits 1
        res.status = STATUS_INCOMPLETE
        res.message = unresolved_message(model, lam, change, unresolved, scale)
    res.wall_time = _time.perf_counter() - wall0
    return res
