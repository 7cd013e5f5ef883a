"""Change points of a mechanism: one measure, one policy, one completion, one step across.

A change point is a configuration where the active rows of Phi_q approach a rank loss, as
at the flat position of a parallelogram linkage: the independent rows admit a second
solution branch there, and every solve through a factor of Phi_q (or of Phi_u, or of the
Schur complement S = Phi_q M^-1 Phi_q^T) amplifies round-off.  The gcp and index-1
families (:mod:`mbsim.integrators.gcp`, :mod:`mbsim.integrators.index1`) pass such points
with the same four pieces, all of them here:

1. **The measure** s: an estimate of sigma_min / sigma_max of the active constraint
   Jacobian, dimensionless and linear in the distance to the point (0.35 theta on the four
   parallel cranks of models/parallel_fourbar.yaml, theta in rad from the flat position).
   Each family reads it from the factor it computes anyway: index-1 from the Schur factor
   of its accelerations, whose pivots go as sigma^2 (:func:`measure_from_schur`: the square
   root of the smallest pivot / diagonal that mbsim/fast/kernels.c reports); gcp from the LU
   factor of Phi_u (:func:`measure_from_lu`: smallest / largest |pivot|).
2. **The policy** (:class:`Policy`): every threshold, once, in terms of s, the tolerances and
   the machine epsilon; its docstring gives each derivation.
3. **Tangent coordinates** v = C q, C = (N^T M N)^-1 N^T M, N an orthonormal basis of the
   null space of Phi_q at a reference point (the M-orthogonal projection onto its tangent
   space: Mani, Haug & Atkinson 1985; Potra & Yen 1991).  They complete Phi_q to the square
   matrix A = [Phi_q; C]; the state follows from v, vd by one Newton completion
   (:func:`newton`, shared with gcp's coordinate partition), the accelerations from the
   reduced equations (T^T M T) v'' = T^T (Q - M p), T = A^-1 [0; I], p = A^-1 [gamma; 0]
   (Haug Sec. 11.4 with T in place of [I; -Phi_u^-1 Phi_v]), which solve only A: no Schur
   complement, whose condition is the square of Phi_q's.
4. **The step across** (:class:`Approach`): a motion that approaches the point slowly meets
   the round-off of the constraint equations themselves there; the step across the point is
   chosen to keep its stages clear of it.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from mbsim.integrators.rk import StageFailure

EPS = float(np.finfo(float).eps)

# -- the policy ------------------------------------------------------------------------------
# Every constant of the policy, once; Policy's docstring derives each.  s is the measure above
# (dimensionless); "tolerances" are the scaled RMS norms of the error test (1 = the tolerance).
SCHUR_PIVOT_FLOOR = 1e-8  # kernels.c PIVOT_FLOOR: Schur pivot / diagonal below which it is raised
S_FIXED = 1e-3  # s of the tangent switch for fixed steps (no tolerance)
S_INDEX1_CAP = 10 ** -2.5  # the index-1 switch's largest s (Schur pivot ratio 1e-5)
S_NOISE = 1e-5  # the round-off probe is not used below this s (Schur pivot ratio 1e-10)
NEAR_INDEX1 = 10 ** 1.5  # an approach is followed below this x the switch (index-1)
NEAR_GCP = 3.0  # ... (gcp)
NOISE_ERR = 0.1  # tangent steps whose error norm exceeds this are probed for round-off
NOISE_STEP = 1e-2  # steps cut below this x a passage's first tangent step: the q part is noise
BRANCH_JUMP = 1e3  # tolerances: a completion that moves q farther started off the branch
APPROACH_CUT = 0.1  # a step cut below this x the last step before the approach: step across


@dataclasses.dataclass(frozen=True)
class Policy:
    """The thresholds of one run near change points (all dimensionless; s is the measure of
    the module doc, linear in the distance to the point).

    tangent: s below which a step's stages are in tangent coordinates (0: never).
        A solve through a factor whose pivot ratio is s amplifies relative round-off by
        1/s, and the accelerations come out of three such solves in a row: q from the
        constraints, qd from the velocity equations with Phi_q(q), qdd from the
        acceleration equations with Phi_q(q) and gamma(q, qd).  Their relative noise is
        then eps s^-3, which must stay below what the error test asks, rtol:
        s < (eps / rtol)^(1/3) = 6.1e-4, 2.8e-3, 1.3e-2, 6.1e-2 at rtol 1e-6, 1e-8, 1e-10,
        1e-12: gcp's switch, at least S_FIXED.  The index-1 family switches later, at
        the square of that law, (eps / rtol)^(2/3) = 3.7e-7, 7.9e-6, 1.7e-4, 3.7e-3 at the
        same tolerances: this exponent is measured, not derived.  Its tangent steps cost
        more per stage than its Schur path, and the Schur path is accurate there on every
        motion measured; the derived law itself moved the slow crossing of
        benchmarks/dead_centre.py (w0 10.51, projection-dop853, rtol 1e-10) from 7.9e-11 m
        in 0.75 s to 2.9e-10 m in 9 s (eps / rtol, the Schur solve's condition bound: 2.3e-10
        m, 9.8 s).  Its limits: at least sqrt(SCHUR_PIVOT_FLOOR) = 1e-4, where the
        kernels' pivot floor changes the Schur solve itself (below it the Schur
        accelerations are not those of the equations), and at most S_INDEX1_CAP: a run
        whose s at the start is already below the switch keeps the Schur path (a model's
        scaling is not a change point), and the seed decks' smallest s at regular states is
        2.4e-2 (Schur ratio 5.9e-4), eight times the cap.  Fixed steps have no tolerance:
        S_FIXED, the law at rtol 2e-7, for both families.
    near: s below which the approach to the point is followed (:class:`Approach`);
        NEAR_INDEX1 or NEAR_GCP x tangent.
    noise_s: below this s a tangent step's round-off is not taken off its error test
        (index-1 ``_stage_noise``): there the noise is that of a crossing, unbounded.
    noise_err: error norms above this are probed for round-off (a norm below it passes
        anyway; the probe costs two completions).
    noise_step: once a passage's steps are cut below this x its first tangent step, the
        error test of the full q (index-1) is left out: an embedded estimate of
        truncation error falls like h^(p+1), so what still cuts the step is round-off.
    branch_jump: a completion that moves q by more than this many tolerances started off
        the step's branch (gcp rejects the step; index-1 dense output completes another
        interpolant).  The RK prediction it starts from is accurate to the local error,
        about one tolerance; the other branch lies s x (the mechanism's size) away.
    cut: an adaptive step cut below this x the last step before the approach makes the
        approach try a step across the point.
    newton_tol: the completion's Newton tolerance on max |dq| (m or rad): a hundredth of
        atol, within [1e-12, 1e-9] (1e-12 for fixed steps): its own error stays two orders
        below the error test's, and above the round-off of q ~ 1 (Newton stagnates there).
    """

    tangent: float
    near: float
    noise_s: float
    noise_err: float
    noise_step: float
    branch_jump: float
    cut: float
    newton_tol: float

    @staticmethod
    def law(rtol):
        """(eps / rtol)^(1/3): the s below which three solves' round-off exceeds rtol."""
        return (EPS / rtol) ** (1.0 / 3.0)

    @classmethod
    def for_run(cls, family, rtol, atol, fixed, tangent=True):
        """The policy of a run: family 'gcp' | 'index-1'; fixed: a fixed-step run;
        tangent: False takes no tangent coordinates (index-1 option ``tangent_steps``)."""
        if fixed:
            s = S_FIXED
        elif family == "gcp":
            s = max(S_FIXED, cls.law(rtol))
        else:
            s = min(S_INDEX1_CAP, max(np.sqrt(SCHUR_PIVOT_FLOOR), cls.law(rtol) ** 2))
        s = s if tangent else 0.0
        near = (NEAR_GCP if family == "gcp" else NEAR_INDEX1) * s
        newton_tol = 1e-12 if fixed else min(1e-9, max(1e-12, 1e-2 * atol))
        return cls(tangent=s, near=near, noise_s=S_NOISE, noise_err=NOISE_ERR,
                   noise_step=NOISE_STEP, branch_jump=BRANCH_JUMP, cut=APPROACH_CUT,
                   newton_tol=newton_tol)

    def off(self):
        """The same policy without tangent coordinates."""
        return dataclasses.replace(self, tangent=0.0, near=0.0)


def measure_from_schur(pivot_ratio):
    """s from the Schur factor's smallest pivot / diagonal (~ sigma^2; <= 0 at the point)."""
    return float(np.sqrt(max(pivot_ratio, 0.0)))


def measure_from_lu(fac, sparse):
    """s from an LU factor (scipy's lu_factor, or splu when sparse): smallest / largest
    |pivot| (at the four-bar's flat position 0.2 x the angle from it)."""
    d = np.abs(fac.U.diagonal() if sparse else np.diag(fac[0]))
    return float(d.min() / d.max()) if d.size and d.max() > 0 else 1.0


# -- tangent coordinates --------------------------------------------------------------------
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


def newton(system, t, q, correction, tol, max_iter):
    """The one Newton completion of both families: q on Phi(q, t) = 0 and the family's own
    equations for its independent coordinates.  correction(T, q) -> (dq (nq,), fac) gives
    the Newton step from the terms T at q (gcp coordinates: dq on u from Phi_u; tangent
    coordinates: dq from A = [Phi_q; C] on [Phi; C q - v]).  Returns (q, T, fac, ok): T, fac
    of the last iterate; ok unless Newton neither stopped moving (max |dq| <= tol) nor left
    max |Phi| <= tol within max_iter iterations (corrections may stagnate at round-off
    while the constraints hold: that is kept)."""
    s = system
    x = np.array(q, dtype=float)
    for _ in range(max_iter):
        T = s.terms(x, t, jac=True, nu=s.rheonomic)
        dx, fac = correction(T, x)
        x -= dx
        s.counters["newton_iterations"] += 1
        if np.abs(dx).max(initial=0.0) <= tol:
            return x, T, fac, True  # Phi_q of this iterate is within tol of Phi_q(x)
    return x, T, fac, bool(np.abs(T.phi).max(initial=0.0) <= tol)


def complete(system, t, q, v, vd, C, tol, max_iter):
    """(q, qd, fac, T) in tangent coordinates: q on Phi(q, t) = 0 with C q = v by
    :func:`newton` from q, qd from A qd = [nu; vd], fac the LU of A at the last iterate, T
    its constraint terms.  qd is None where Newton failed (the caller says why)."""
    s = system

    def correction(T, x):
        fac = factor(s, T.jac, C)
        return solve(s, fac, np.concatenate([T.phi, C @ x - v])), fac

    x, T, fac, ok = newton(s, t, q, correction, tol, max_iter)
    if not ok:
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


# -- the step across -------------------------------------------------------------------------
class Approach:
    """A motion's approach to a change point, and the step across it.

    Near the point the tangent coordinates' accelerations carry round-off that grows like
    s^-3 (the policy's three solves; about 3e-21 s^-3 in C qdd on the four cranks): the
    completed state lies on a computed constraint set u w = eps whose curvature near the
    crossing u = w = 0 is ~ eps / theta^3.  A motion that approaches the point slowly has
    its steps cut by that noise as it nears the point, ~ distance^3, and never arrives.  A
    step across instead whose stages stay clear of the point meets only the noise of its
    nearest stage, which falls with the step (a DOP853 step of 1e-2 s with the point midway
    between its stages at c = 1/3 and 0.6 keeps them 1.3e-3 s from it).  Fixed steps meet
    the same noise wherever a stage lands next to the point.

    So after each accepted step the integrator reports s (the measure, linear in the
    distance to the point).  While s is below the policy's ``near``, the time d to the point
    is extrapolated linearly from the last two states (:func:`crossing_time`), and
    :meth:`step` gives the step to try instead of the one proposed: the step whose stages,
    dense output's included, lie farthest from the point (:func:`clear_step`) among
    - adaptive steps that cross it, of at most the larger of the proposed step and the
      last step before the approach (their truncation error), once the proposed step has
      been cut below the policy's ``cut`` x that last one (uncut, the controller's steps
      pass the point as they are: a motion that turns short of the point, where the
      prediction is wrong, keeps them), tried again only once d has halved; the error test
      decides;
    - fixed steps h: a step in [h/2, 3h/2] once d < 3h/2.
    """

    def __init__(self, stages, h_fixed, policy):
        self.stages, self.h_fixed = stages, h_fixed  # stages: stage_times
        self.near, self.cut = policy.near, policy.cut
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
            if self.h_far is None or h_abs >= self.cut * self.h_far:
                return None
            h_cap = max(h_abs, self.h_far)
            if not (d < h_cap and d <= 0.5 * self.d_tried):
                return None
            self.d_tried = d
            moved = clear_step(self.stages, d, d * (1 + 1e-9), h_cap)[0]
        self.tried = moved
        return moved


def crossing_time(approach):
    """The time from the last of two states (t, s) to the change point ahead, s the measure
    (linear in the distance to it), extrapolated linearly; None unless s falls."""
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
    gap, where an error in d matters least.  c: the stage times (:func:`stage_times`)."""
    h = np.concatenate([d / (0.5 * (c[1:] + c[:-1])), [lo, hi]])
    h = np.sort(h[(h >= lo) & (h <= hi)])
    clear = np.abs(np.outer(h, c) - d).min(axis=1)
    i = int(np.argmax(clear))  # (the first of equals: the smallest step)
    return float(h[i]), float(clear[i])
