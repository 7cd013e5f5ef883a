"""Tangent coordinates near a change point of a mechanism (shared by gcp and index-1).

Where Phi_q (the active rows) approaches a rank loss, as at the flat position of a
parallelogram linkage, the Schur complement Phi_q M^-1 Phi_q^T has an eigenvalue ~ sigma^2
and its pivot floor (mbsim/fast/kernels.c) changes the result.  Tangent coordinates
v = C q, C = (N^T M N)^-1 N^T M, N an orthonormal basis of the null space of Phi_q at a
reference point (the M-orthogonal projection onto its tangent space: Mani, Haug & Atkinson
1985; Potra & Yen 1991), complete Phi_q to the square matrix A = [Phi_q; C], and the
accelerations come from the reduced equations (T^T M T) v'' = T^T (Q - M p), T = A^-1 [0; I],
p = A^-1 [gamma; 0] (Haug Sec. 11.4 with T in place of [I; -Phi_u^-1 Phi_v]), which solve
only A.  The module doc of :mod:`mbsim.integrators.gcp` has the measurements.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from mbsim.integrators.rk import StageFailure

# A completion that moves the coordinates by more than this many tolerances (scaled RMS norm)
# started from a state off the step's branch: gcp rejects such a step, the index-1
# projection methods complete another interpolant of such an output.  On the four cranks at
# rtol 2e-11 the completions of index-1 outputs in tangent steps moved q by 0.1-136
# tolerances, and by 1.4e6 where the interpolant was 5.9e-5 m off (index1, dense output).
BRANCH_JUMP = 1e3


def mass_times(system, q, X):
    """M(q) X, M block diagonal (System.mass_blocks)."""
    Mb = system.mass_blocks(q)
    nb = Mb.shape[0]
    return np.einsum("bij,bjk->bik", Mb, X.reshape(nb, 7, -1)).reshape(X.shape)


def tangent_map(system, q, Jd):
    """C (k, nq) of the tangent coordinates at q (Jd: dense Phi_q there, (m, nq), full row
    rank); None where the mass matrix is singular on the tangent space (a massless motion:
    no M-orthogonal projection)."""
    m, n = Jd.shape
    Qf, _ = la.qr(Jd.T, check_finite=False)
    N = Qf[:, m:n]
    MN = mass_times(system, q, N)
    try:
        cf = la.cho_factor(N.T @ MN, check_finite=False)
    except la.LinAlgError:
        return None
    return la.cho_solve(cf, MN.T, check_finite=False)  # C N = I


def factor(system, J, C):
    """LU of A = [Phi_q; C] (nq x nq)."""
    system.counters["factorizations"] += 1
    if system.sparse:
        try:
            return spla.splu(sp.vstack([J, sp.csr_matrix(C)]).tocsc())
        except RuntimeError as exc:
            raise StageFailure(f"singular [Phi_q; C] ({exc})") from exc
    return la.lu_factor(np.vstack([J, C]), check_finite=False)


def solve(system, fac, b, trans=False):
    """A^-1 b (A^-T b) with a factor of :func:`factor` (or any LU of the same kind)."""
    if system.sparse:
        return fac.solve(b, trans="T" if trans else "N")
    return la.lu_solve(fac, b, trans=1 if trans else 0, check_finite=False)


def basis(system, fac, k):
    """T = A^-1 [0; I] (nq x k): the tangent space with C T = I."""
    n = system.nq
    E = np.zeros((n, k))
    E[n - k:] = np.eye(k)
    return solve(system, fac, E)


def complete(system, t, q, v, vd, C, tol, max_iter):
    """(q, qd, fac, T): q on Phi(q, t) = 0 with C q = v by Newton on [Phi(q, t); C q - v] = 0
    from q, qd from A qd = [nu; vd], fac the LU of A = [Phi_q; C] at the last iterate, T its
    constraint terms.  qd is None when Newton neither stopped moving (max |dx| <= tol) nor
    left |Phi| <= tol within max_iter iterations (the caller says why)."""
    s = system
    x = np.array(q, dtype=float)
    for _ in range(max_iter):
        T = s.terms(x, t, jac=True, nu=s.rheonomic)
        fac = factor(s, T.jac, C)
        dx = solve(s, fac, np.concatenate([T.phi, C @ x - v]))
        x -= dx
        s.counters["newton_iterations"] += 1
        if np.abs(dx).max(initial=0.0) <= tol:
            break  # Phi_q of this iterate is within tol of Phi_q(x): keep it
    else:
        # the corrections may stagnate at round-off while the constraints themselves hold
        if np.abs(T.phi).max(initial=0.0) > tol:
            return x, None, fac, T
    nu = T.nu if s.rheonomic else np.zeros(s.m)
    return x, solve(s, fac, np.concatenate([nu, vd])), fac, T


def accelerations(system, t, q, qd, fac, k):
    """(qdd, power) from the reduced equations (module doc): (T^T M T) v'' = T^T (Q - M p), the
    constraint forces dropping out (T^T Phi_q^T = 0); power = Q.qd - lam.nu with lam from
    A^T [lam; mu] = Q - M qdd (mu = 0)."""
    s = system
    G = s.terms(q, t, qd=qd, phi=False, jac=False, gamma=True, nu=s.rheonomic)
    Tb = basis(s, fac, k)
    p = solve(s, fac, np.concatenate([G.gamma, np.zeros(k)]))
    Q = s.generalized_forces(q, qd, t)
    MTp = mass_times(s, q, np.column_stack([Tb, p]))
    try:
        a = la.solve(Tb.T @ MTp[:, :k], Tb.T @ (Q - MTp[:, k]), assume_a="sym",
                     check_finite=False)
    except la.LinAlgError as exc:
        raise StageFailure(f"t = {t:.6g} s: singular reduced mass matrix ({exc})") from exc
    s.counters["factorizations"] += 1
    qdd = Tb @ a + p
    power = float(Q @ qd)
    if s.rheonomic:
        r = Q - mass_times(s, q, qdd[:, None])[:, 0]
        lam = solve(s, fac, r, trans=True)[: s.m]
        power -= float(lam @ G.nu)
    return qdd, power


class Approach:
    """A motion's approach to a change point, and the step across it.

    Near the change point the tangent coordinates' accelerations carry round-off that grows
    like ratio^-1.5 (ratio: the Schur pivot ratio, ~ 0.12 theta^2 on the four cranks;
    about 3e-21 ratio^-1.5 in C qdd there): the completed state lies on a computed
    constraint set u w = eps whose curvature near the crossing u = w = 0 is ~ eps / theta^3.
    A motion that approaches the point slowly (the four cranks crossing their flat position
    at 0.32 rad/s) has its steps cut by that noise as it nears the point, ~ distance^3, and
    never arrives: at rtol 1e-10 projection-dop853 took 2400 steps of down to 3e-10 s to
    come within 4e-6 s of it.  A step across instead whose stages stay clear of the point
    meets only the noise of its nearest stage, which falls with the step (a DOP853 step of
    1e-2 s with the point midway between its stages at c = 1/3 and 0.6 keeps them 1.3e-3 s,
    ratio 2e-8, from it).  Fixed steps meet the same noise wherever a stage lands next to
    the point: rk4 at h = 0.25 ms ended 1.2e-3 m off where 0.5 ms was 4e-11 m off.

    So after each accepted step the integrator reports s, a measure linear in the distance
    to the point (the square root of the Schur pivot ratio; the LU pivot ratio of Phi_u).
    While s falls below ``near``, the time d to the point is extrapolated linearly from the
    last two states (:func:`crossing_time`), and :meth:`step` gives the step to try instead
    of the one proposed: the step whose stages, dense output's included, lie farthest from
    the point (:func:`clear_step`) among
    - adaptive steps that cross it, of at most the larger of the proposed step and the
      last step before the approach (their truncation error), once the proposed step has
      been cut below CUT x that last one (uncut, the controller's steps pass the point
      as they are: a motion that turns short of the point, where the prediction is
      wrong, keeps them), tried again only once d has halved; the error test decides;
    - fixed steps h: a step in [h/2, 3h/2] once d < 3h/2.
    """

    CUT = 0.1

    def __init__(self, stages, h_fixed, near):
        self.stages, self.h_fixed, self.near = stages, h_fixed, near  # stages: stage_times
        self.h_far = None  # the last accepted step before the approach
        self.points = ()  # (t, s) of the last two accepted states of the approach
        self.d_tried = np.inf  # the predicted distance at the last step tried across
        self.tried = None  # the step size tried by the current step, if any

    def accepted(self, t, h, s):
        """After an accepted step of size h to t, s there (None: not comparable with the
        earlier ones, e.g. a new coordinate partition); True when it was a step across."""
        across = self.tried is not None and h >= 0.99 * self.tried
        self.tried = None
        if s is None:
            self.points = ()
        elif s >= self.near:
            self.h_far, self.points, self.d_tried = h, (), np.inf
        else:
            self.points = (self.points + ((t, s),))[-2:]
        return across

    def step(self, h_abs):
        """The step to try instead of h_abs, or None (class doc)."""
        self.tried = None
        if len(self.points) < 2:
            return None
        d = crossing_time(self.points)
        if d is None:
            return None
        if self.h_fixed is not None:
            h = self.h_fixed
            if d >= 1.5 * h:
                return None
            moved = clear_step(self.stages, d, 0.5 * h, 1.5 * h)[0]
            if moved == h:
                return None
        else:
            if self.h_far is None or h_abs >= self.CUT * self.h_far:
                return None
            h_cap = max(h_abs, self.h_far)
            if not (d < h_cap and d <= 0.5 * self.d_tried):
                return None
            self.d_tried = d
            moved = clear_step(self.stages, d, d * (1 + 1e-9), h_cap)[0]
        self.tried = moved
        return moved


def crossing_time(approach):
    """The time from the last of two states (t, s) to the change point ahead, s a measure
    linear in the distance to it (the LU pivot ratio of Phi_u, the square root of the Schur
    pivot ratio), extrapolated linearly; None unless s falls."""
    (t1, s1), (t2, s2) = approach
    if not 0.0 < s2 < s1:
        return None
    d = s2 * (t2 - t1) / (s1 - s2)
    return d if np.isfinite(d) else None


def stage_times(tableau):
    """A tableau's stage times in [0, 1], sorted, those of its dense output's extra stages
    included (DOP853's widest gap: 1/3 to 0.6; DP5's: 0.3 to 0.8; RK4's: 0 to 1/2)."""
    return np.unique(np.concatenate([tableau.C, getattr(tableau, "C_EXTRA", ()), [1.0]]))


def clear_step(c, d, lo, hi):
    """The step h in [lo, hi] whose stages lie farthest from a point d ahead, and that
    distance (the step's start and end, states of the run, count as stages): d / c for c
    the middle of a gap between stage times, lo or hi (the farthest lies at one of them),
    the smallest of equals.  With room to choose, the point lies in the middle of the widest
    gap, where an error in d matters least.  (Weighing the stages by their noise instead,
    h sum |c h - d|^-3, chose steps that a 70 % error in d, as the four cranks' ratio gives
    one step before the point, put next to it: rk4 at 0.25 ms ended 7e-3 m off, where this
    choice leaves 4e-10 m; at 0.3 ... 0.1 ms 2e-10 ... 8e-9 m, without moving the steps
    up to 1.2e-3 m.)  c: the stage times (:func:`stage_times`)."""
    h = np.concatenate([d / (0.5 * (c[1:] + c[:-1])), [lo, hi]])
    h = np.sort(h[(h >= lo) & (h <= hi)])
    clear = np.abs(np.outer(h, c) - d).min(axis=1)
    i = int(np.argmax(clear))  # (the first of equals: the smallest step)
    return float(h[i]), float(clear[i])
