"""Generalized coordinate partitioning (Wehage & Haug 1982; Haug Sec. 11.4).

The coordinates split into dependent u (one per independent constraint row) and
independent v.  An explicit RK pair integrates only y = (v, vd, w); at every stage

1. u solves Phi(u, v, t) = 0 by Newton, started from the RK combination of the stage
   velocities (exact to the local error: two Newton steps, correct and confirm),
2. ud solves Phi_u ud = nu - Phi_v vd,
3. qdd, lam solve the equations of motion; the stage derivative is (vd, vdd, power).

The constraints therefore hold to the Newton tolerance at every output.

Choice of v (``partition`` option).  ``lu``: Wehage & Haug's Gaussian elimination with
column pivoting of Phi_q (partial pivoting of Phi_q^T; the pivot columns are u).
``nullspace`` (default): QR with column pivoting of N^T, N an orthonormal basis of the null
space of Phi_q; the k coordinates whose rows of N span the largest volume are v, so that the
map from the degrees of freedom to v is as well conditioned as the model allows.  Measured
on the governor, LU pivoting of the unscaled Phi_q picks pairs of Euler parameters of one
ball that both follow the spin, and DOP853 then rejects half its steps; the null-space
choice picks the spindle's spin parameter and a ball's swing parameter.

Re-partitioning.  The sensitivity s = max |Phi_u^-1 Phi_v| (how far u moves per unit of v;
Haug eq. 11.4.x, du = -Phi_u^-1 Phi_v dv) is checked after every accepted step; past
``repartition_ratio`` times max(1, s at the last partition) the coordinates are chosen
again at the current state.  (The condition number of Phi_u alone misses the classic case:
for a free body Phi_u = 2 e0 is 1 x 1 with condition 1 while e0 -> 0.)  A failed stage also
triggers a new partition at the start of the step.
"""

from __future__ import annotations

import logging

import numpy as np
import scipy.linalg as la
import scipy.sparse.linalg as spla

from mbsim.integrators.base import rms_norm
from mbsim.integrators.rk import ClassicRK4, Dop853, RungeKuttaIntegrator, StageFailure


log = logging.getLogger(__name__)

BRANCH_JUMP = 1e3  # scaled deviation of the dependent coordinates that rejects a step


def quintic_hermite(a, b):
    """g(t, k) on [a[0], b[0]]: the quintic Hermite interpolant of q (k = 0) or its rate
    (k = 1) from the states a, b = (t, q, qd, qdd) at the ends of a step (fifth order)."""
    t0, q0, v0, a0 = a[:4]
    t1, q1, v1, a1 = b[:4]
    h = t1 - t0

    def g(t, k=0):
        x = (t - t0) / h
        x2, x3, x4, x5 = x * x, x ** 3, x ** 4, x ** 5
        if k == 0:
            return ((1 - 10 * x3 + 15 * x4 - 6 * x5) * q0 + (10 * x3 - 15 * x4 + 6 * x5) * q1
                    + h * ((x - 6 * x3 + 8 * x4 - 3 * x5) * v0 + (-4 * x3 + 7 * x4 - 3 * x5) * v1)
                    + h * h * (0.5 * (x2 - 3 * x3 + 3 * x4 - x5) * a0
                               + 0.5 * (x3 - 2 * x4 + x5) * a1))
        return ((-30 * x2 + 60 * x3 - 30 * x4) * (q0 - q1) / h
                + (1 - 18 * x2 + 32 * x3 - 15 * x4) * v0 + (-12 * x2 + 28 * x3 - 15 * x4) * v1
                + h * (0.5 * (2 * x - 9 * x2 + 12 * x3 - 5 * x4) * a0
                       + 0.5 * (3 * x2 - 8 * x3 + 5 * x4) * a1))

    return g


class Partition:
    """iv: (nv,) independent coordinates; iu: (m_a,) dependent ones; s0: sensitivity."""

    __slots__ = ("iv", "iu", "s0")

    def __init__(self, iv, iu, s0):
        self.iv, self.iu, self.s0 = iv, iu, s0


class GeneralizedCoordinatePartitioning(RungeKuttaIntegrator):
    formulation = "gcp"
    repartition_ratio = 1.2
    partition_method = "nullspace"
    max_newton = 8

    def __init__(self, system, t0, q0, qd0, t_bound, options=None):
        super().__init__(system, t0, q0, qd0, t_bound, options)
        self.n = system.nq
        self.ratio = float(self.options.get("repartition_ratio", self.repartition_ratio))
        self.method = self.options.get("partition", self.partition_method)
        if self.method not in ("nullspace", "lu"):
            raise ValueError(f"partition: expected nullspace | lu, got {self.method!r}")
        self.newton_tol = float(self.options.get(
            "newton_tol", 1e-12 if self.h_fixed else min(1e-9, max(1e-12, 1e-2 * self.atol))))
        self.counters["repartitions"] = 0
        self._pred = None  # the full q predicted for the next stage (see _trial)
        qdd, _, _ = system.accelerations(self.q, self.qd, self.t)
        self._ref = (self.t, self.q.copy(), self.qd.copy(), qdd)  # Newton predictor data
        self._ref_prev = None  # the same at the start of the last step (dense output)
        self._last = None  # (t, y, q, qd, qdd, factor) of the latest stage
        self._jac = None
        self.part = self._partition(self.t, self.q)
        self.n_err = 2 * self.part.iv.size  # (v, vd); the work integral is not controlled
        self._start()

    # -- partitioning ----------------------------------------------------------------------
    def _partition(self, t, q):
        s = self.system
        J = s.terms(q, t, phi=False).jac
        Jd = J.toarray() if s.sparse else J
        m = Jd.shape[0]
        k = self.n - m
        if self.method == "lu":
            perm, _, U = la.lu(Jd.T, p_indices=True, check_finite=False)
            d = np.abs(np.diag(U))
            iu = np.flatnonzero(perm < m)
        else:
            Qf, R = la.qr(Jd.T, check_finite=False)
            d = np.abs(np.diag(R))
            _, piv = la.qr(Qf[:, m:].T, mode="r", pivoting=True, check_finite=False)
            iu = np.setdiff1d(np.arange(self.n), piv[:k])
        if d.size and d.min() <= 1e-12 * d.max():
            raise StageFailure("the constraint Jacobian lost rank: no set of dependent "
                               "coordinates (a lock-up or a bifurcation)")
        iv = np.setdiff1d(np.arange(self.n), iu)
        return Partition(iv, iu, self._sensitivity(self._factor(J, iu), J, iv))

    def _factor(self, J, iu):
        self.system.counters["factorizations"] += 1
        if self.system.sparse:
            try:
                return spla.splu(J[:, iu].tocsc())
            except RuntimeError as exc:
                raise StageFailure(f"singular Phi_u ({exc})") from exc
        return la.lu_factor(J[:, iu], check_finite=False)

    def _sensitivity(self, fac, J, iv):
        """max |Phi_u^-1 Phi_v| (module doc)."""
        Jv = J[:, iv]
        Z = self._solve(fac, Jv.toarray() if self.system.sparse else Jv)
        return float(np.abs(Z).max(initial=0.0))

    def _solve(self, fac, b):
        if self.system.sparse:
            return fac.solve(b)
        return la.lu_solve(fac, b, check_finite=False)

    # -- the stage function ----------------------------------------------------------------
    def _complete(self, t, v, vd, part):
        """q from Newton on Phi(u, v, t) = 0, qd from the velocity equations.

        The start is the RK combination of the full stage velocities (``_trial``), exact to
        the local error, so that two Newton steps (correct, confirm) usually suffice."""
        s, (iv, iu) = self.system, (part.iv, part.iu)
        if self._pred is not None:
            q, self._pred = self._pred, None
        else:  # second-order Taylor predictor from the last accepted state
            t0, q0, qd0, qdd0 = self._ref
            tau = t - t0
            q = q0 + tau * qd0 + (0.5 * tau * tau) * qdd0
        q[iv] = v
        for _ in range(self.max_newton):
            T = s.terms(q, t, jac=True, nu=s.rheonomic)
            fac = self._factor(T.jac, iu)
            du = self._solve(fac, T.phi)
            q[iu] -= du
            s.counters["newton_iterations"] += 1
            if np.abs(du).max(initial=0.0) <= self.newton_tol:
                break  # Phi_q of this iterate is within newton_tol of Phi_q(q): keep it
        else:
            # the corrections may stagnate at round-off of an ill-conditioned Phi_u while the
            # constraints themselves hold: then keep it (a failure here lost whole runs)
            if np.abs(T.phi).max(initial=0.0) > self.newton_tol:
                self._raise_newton_failure(T, t)
        qd = np.empty(self.n)
        qd[iv] = vd
        rhs = -(T.jac[:, iv] @ vd)
        if s.rheonomic:
            rhs += T.nu
        qd[iu] = self._solve(fac, rhs)
        self._jac = T.jac
        return q, qd, fac

    def _raise_newton_failure(self, T, t):
        s = self.system
        worst = np.argsort(-np.abs(T.phi))[:3]
        names = s.model.items_of_rows(s.rows[worst])
        raise StageFailure(f"Newton iteration for the dependent coordinates did not "
                           f"converge at t = {t:.6g} s (max |Phi| = "
                           f"{np.abs(T.phi).max():.3g}); constraints: {', '.join(names)}")

    def _rhs(self, t, y, ctx=None):
        part = ctx or self.part
        k = part.iv.size
        q, qd, fac = self._complete(t, y[:k], y[k:2 * k], part)
        qdd, _, power = self.system.accelerations(q, qd, t, jac=self._jac)
        self._last = (t, y, q, qd, qdd, fac)
        out = np.empty_like(y)
        out[:k], out[k:2 * k], out[-1] = y[k:2 * k], qdd[part.iv], power
        return out

    # -- the RK family hooks -----------------------------------------------------------------
    def _trial(self, h):
        """The RK step of the base class, with the full q of each stage predicted by the same
        RK combination of the full stage velocities (q' = qd)."""
        tab, K, t, y = self.tableau, self.K, self.t, self.y
        q0 = self._ref[1]
        QD = np.empty((tab.n_stages, self.n))
        QD[0] = self._ref[2]
        K[0] = self.f
        for s in range(1, tab.n_stages):
            a = tab.A[s, :s]
            pred = q0 + h * (QD[:s].T @ a)
            self._pred = pred.copy()
            K[s] = self._rhs(t + tab.C[s] * h, y + h * (K[:s].T @ a))
            QD[s] = self._last[3]
        y_new = y + h * (K[:-1].T @ tab.B)
        pred = q0 + h * (QD.T @ tab.B)
        self._pred = pred.copy()
        f_new = self._rhs(t + h, y_new)
        K[-1] = f_new
        self._QD = (np.vstack([QD, self._last[3]]), q0, pred)  # for _extra_error, dense
        self._check_branch(t + h, self._last[2], pred)
        return y_new, f_new

    def _check_branch(self, t, q, pred):
        """Reject a Newton solution q of the dependent coordinates far from the RK solution
        pred of the full q (q' = qd with the method's weights, accurate to the local error):
        it has jumped to another branch of the constraints (at a change point, e.g. a
        parallelogram's flat position).  Fixed step: no tolerance to measure it with."""
        if self.h_fixed is not None:
            return
        dev = rms_norm(q - pred, self.atol + self.rtol * np.abs(pred))
        if dev > BRANCH_JUMP:
            raise StageFailure(f"t = {t:.6g} s: the dependent coordinates moved {dev:.3g} "
                               f"tolerances from the RK solution (another branch of the "
                               f"constraints)")

    def _extra_error(self, h):
        """The embedded error estimate of the full q (q' = qd, the stages' full velocities),
        beside that of (v, vd): near a change point of the mechanism the map from v to the
        dependent coordinates is nearly singular, and a step that the (v, vd) estimate
        accepts can still be far off in u (measured: 5.6 mm instead of 1e-9 m on the
        parallel four-bar's flat passage at rtol 1e-8)."""
        Kq, q0, q1 = self._QD
        scale = self.atol + self.rtol * np.maximum(np.abs(q0), np.abs(q1))
        return self.tableau.error_norm(Kq, h, scale)

    def _context(self):
        return self.part

    def _y_from_state(self):
        iv = self.part.iv
        return np.concatenate([self.q[iv], self.qd[iv], [self.w]])

    def _state_from_y(self, t, y, ctx=None):
        last = self._last
        if last is not None and last[0] == t and last[1] is y:
            return last[2], last[3], float(y[-1])
        part = ctx or self.part
        k = part.iv.size
        q, qd, _ = self._complete(t, y[:k], y[k:2 * k], part)
        return q, qd, float(y[-1])

    def _dense_output_impl(self):
        """The RK interpolant of (v, vd); the dependent coordinates by Newton as at the stages.

        Every Newton solve here starts from the same RK method applied to the full q
        (q' = qd with the stages' full velocities, ``_trial``): DOP853's three extra stages
        from their RK combination, an output time from the continuous extension of q.
        Either is accurate to the local error, so that Newton stays on the branch the step
        followed.  A worse start (the Taylor predictor from the step's end, measured on the
        parallel four-bar at rtol 1e-6) lands, near a flat passage, on a solution of the
        independent rows that the dropped redundant rows do not satisfy: the cranks no
        longer parallel, the extra stages' accelerations wrong, 6 mm of error at the outputs
        although both ends of the step were within 2e-7 m."""
        t0, h, y0, y1, K, ctx = self._dense_args
        QD, q0, q1 = self._dense_q
        tab = self.tableau
        stage_qd = list(QD)  # the full qd of every stage, extra stages appended below
        extra = iter(getattr(tab, "A_EXTRA", ()))

        def stage(t, y):  # an extra stage of the interpolant (DOP853)
            a = next(extra)[: len(stage_qd)]
            pred = q0 + h * (np.array(stage_qd).T @ a)
            self._pred = pred.copy()
            try:
                f = self._rhs(t, y, ctx)
            finally:
                self._pred = None
            self._check_branch(t, self._last[2], pred)
            stage_qd.append(self._last[3])
            return f

        try:  # the extra stages may fail near a singular position
            g = tab.dense(stage, t0, h, y0, y1, K)
        except StageFailure:
            g = None
        prev, cur = self._ref_prev, self._ref
        hermite5 = quintic_hermite(prev, cur) if prev is not None and prev[0] < cur[0] else None
        if g is None and hermite5 is None:
            raise StageFailure("no interpolant for this step")
        gq = None
        if g is not None:  # the continuous extension of the full q, from the same stages
            done = iter(stage_qd[len(QD):])
            gq = tab.dense(lambda t, y: next(done), t0, h, q0, q1, np.array(stage_qd[: len(QD)]))
        w0, w1 = float(y0[-1]), float(self.y[-1])

        def dense(t):
            try:
                if g is None:
                    raise StageFailure("no RK interpolant for this step")
                pred = gq(t)
                self._pred = pred.copy()
                q, qd, w = self._state_from_y(t, g(t), ctx)
                self._check_branch(t, q, pred)
                return q, qd, w
            except StageFailure:
                if hermite5 is None:
                    raise
                # near a singular position the step's partition may not solve at t: the
                # quintic Hermite interpolant of the full state (q, qd, qdd at both ends of
                # the step: fifth order), projected onto the constraints, at this output only
                s = self.system
                q, ok, _, res = s.project_positions(hermite5(t), t, tol=self.newton_tol)
                if not ok and res > 1e2 * self.newton_tol:
                    raise
                x = (t - prev[0]) / (cur[0] - prev[0])
                return q, s.project_velocities(q, hermite5(t, 1), t), (1 - x) * w0 + x * w1
            finally:
                self._pred = None

        return dense

    def _accept(self, t, y, f):
        lt, ly, q, qd, qdd, fac = self._last  # the FSAL stage: the accepted state
        self._dense_q = self._QD  # the accepted trial's full-q stages (dense output)
        self._ref_prev = self._ref
        self._ref = (t, q, qd, qdd)
        sens = self._sensitivity(fac, self._jac, self.part.iv)
        if sens > self.ratio * max(1.0, self.part.s0):
            part = self._partition(t, q)
            if np.array_equal(part.iu, self.part.iu):
                self.part.s0 = max(sens, part.s0)  # the same set is still the best
            else:
                self.part = part
                self.counters["repartitions"] += 1
                log.debug("t = %.6g s: coordinates partitioned again (sensitivity %.3g); "
                          "independent: %s", t, sens, part.iv.tolist())
                iv = part.iv
                y = np.concatenate([q[iv], qd[iv], y[-1:]])
                f = np.concatenate([qd[iv], qdd[iv], f[-1:]])
                self._last = (t, y, q, qd, qdd, fac)
        return y, f

    def _recover(self):
        """After a failed stage: partition again at the start of the step."""
        t0, q0, qd0, qdd0 = self._ref
        try:
            part = self._partition(t0, q0)
        except StageFailure:
            return False
        if np.array_equal(part.iu, self.part.iu):
            return False
        self.part = part
        self.counters["repartitions"] += 1
        iv = part.iv
        self.y = np.concatenate([q0[iv], qd0[iv], self.y[-1:]])
        self.f = np.concatenate([qd0[iv], qdd0[iv], self.f[-1:]])
        return True


class GcpRK45(GeneralizedCoordinatePartitioning):
    name = "gcp-rk45"
    description = "coordinate partitioning (Wehage-Haug), Dormand-Prince 5(4) on (v, vd)"
    order = 5


class GcpDop853(GeneralizedCoordinatePartitioning):
    name = "gcp-dop853"
    description = "coordinate partitioning (Wehage-Haug), DOP853 (order 8) on (v, vd)"
    order = 8
    tableau = Dop853


class GcpRK4(GeneralizedCoordinatePartitioning):
    name = "gcp-rk4"
    description = "coordinate partitioning (Wehage-Haug), classic fixed-step RK4 (needs --step)"
    order = 4
    adaptive = False
    tableau = ClassicRK4
