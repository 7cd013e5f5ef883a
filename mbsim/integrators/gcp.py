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
Haug Sec. 11.4, du = -Phi_u^-1 Phi_v dv) is checked after every accepted step; past
``repartition_ratio`` times max(1, s at the last partition) the coordinates are chosen
again at the current state.  (The condition number of Phi_u alone misses the classic case:
for a free body Phi_u = 2 e0 is 1 x 1 with condition 1 while e0 -> 0.)  A failed stage also
triggers a new partition at the start of the step.

Near a change point: tangent coordinates.  Where the mechanism approaches a singular position
(the parallel four-bar's flat position: Phi_q loses rank there, the independent rows admit a
second solution branch), Phi_u is close to singular for every choice of v, and round-off in
the dependent coordinates (~eps / sigma_min) becomes noise in ud (~1/sigma^2) and in the
accelerations (~1/sigma^3) along the soft directions of Phi_q: the three solves of the
change-point policy (:mod:`mbsim.integrators.changepoints`, ``Policy.tangent``).  The LU
pivot ratio of Phi_u is gcp's estimate of the measure s; below the policy's switch the
independent coordinates become the tangent coordinates v = C q of that module, taken at the
partition point.  C annihilates the M-orthogonal soft directions, where the noise lies, so
v'' does not carry it; q then solves [Phi(q, t); C q - v] = 0 by the shared Newton
completion on A = [Phi_q; C], qd = A^-1 [nu; vd], and the accelerations come from the
reduced equations, which solve only A.  A stage computed in coordinates with Phi_u below the
switch fails its step, which is tried again from its start in tangent coordinates (a step
may cross the singular position with no accepted point near it).  The tangent partition is
replaced when its sensitivity max |T| grows (as a coordinate one), or as soon as the
coordinate choice's Phi_u is above the switch again: RK4's error constant is larger in the
position-like tangent coordinates than in the Euler parameters the null-space choice picks.
A motion that approaches the change point slowly is given a step across it that keeps its
stages clear of it (:class:`changepoints.Approach`; counter ``straddle_steps``).

Where it runs.  On a dense Jacobian, in coordinates and in tangent coordinates alike, each
trial step (its stages, the change-point alarm, the branch test and both error norms, and
at an accepted end its sensitivity and measure) and each step's outputs are one C call
(mbsim/fast/partition.c, :mod:`mbsim.fast.partition`), as are the stages of the dense
output's Python fallback; Python is visited per trial for the step-size control,
``_accept``'s re-partitioning and the fallbacks.  Sparse Jacobians (splu) and loads that
depend on the multipliers take the stages here in Python; so does every stage with option
``compiled_step: false``.
"""

from __future__ import annotations

import logging

import numpy as np
import scipy.linalg as la
import scipy.sparse.linalg as spla

from mbsim.fast.dynamics import solve_error
from mbsim.fast.partition import (
    GP_ALARM,
    GP_CALLBACK,
    GP_NEWTON,
    GP_OK,
    GP_REDUCED,
    GP_SINGULAR,
    GP_SOLVE,
    P_CODE,
    P_DEV,
    P_ERR,
    P_RATIO,
    P_SENS,
    P_T,
    CompiledStage,
)
from mbsim.integrators import changepoints as cp
from mbsim.integrators.base import quintic_hermite, rms_norm
from mbsim.integrators.rk import ClassicRK4, Dop853, RungeKuttaIntegrator, StageFailure

log = logging.getLogger(__name__)


class Partition:
    """iv: (nv,) independent coordinates; iu: (m_a,) dependent ones; s0: sensitivity;
    C: None, or (nv, nq) the tangent coordinates v = C q (module doc; iv, iu are then the
    coordinate choice at the partition point, kept for comparison only)."""

    __slots__ = ("iv", "iu", "s0", "C")

    def __init__(self, iv, iu, s0, C=None):
        self.iv, self.iu, self.s0, self.C = iv, iu, s0, C

    @property
    def k(self):
        return self.iv.size

    def v(self, x):
        """The independent part of a full vector x (q, qd or qdd)."""
        return x[self.iv] if self.C is None else self.C @ x

    def same(self, other):
        return (self.C is None and other.C is None and np.array_equal(self.iu, other.iu))


class _Residual:
    """The last Newton iterate's Phi (``_raise_newton_failure``'s T)."""

    __slots__ = ("phi",)

    def __init__(self, phi):
        self.phi = phi


def _singular_u(t):
    return StageFailure(f"t = {t:.6g} s: singular Phi_u (the dependent coordinates' Jacobian "
                        f"has a zero pivot)")


def _branch_failure(t, dev):
    return StageFailure(f"t = {t:.6g} s: the dependent coordinates moved {dev:.3g} tolerances "
                        f"from the RK solution (another branch of the constraints)")


class GeneralizedCoordinatePartitioning(RungeKuttaIntegrator):
    formulation = "gcp"
    repartition_ratio = 1.2
    partition_method = "nullspace"

    def __init__(self, system, t0, q0, qd0, t_bound, options=None):
        super().__init__(system, t0, q0, qd0, t_bound, options)
        self.n = system.nq
        self.ratio = float(self.options.get("repartition_ratio", self.repartition_ratio))
        self.method = self.options.get("partition", self.partition_method)
        if self.method not in ("nullspace", "lu"):
            raise ValueError(f"partition: expected nullspace | lu, got {self.method!r}")
        # the change-point policy (changepoints.Policy)
        self.policy = cp.Policy.for_run("gcp", self.rtol, self.atol, self.h_fixed is not None,
                                        exponent=self.error_exponent, n=self.n)
        self.newton_tol = float(self.options.get("newton_tol", self.policy.newton_tol))
        self.counters["repartitions"] = 0
        self.counters["tangent_partitions"] = 0
        self._pred = None  # the full q predicted for the next stage (see _trial)
        qdd, _, _ = system.accelerations(self.q, self.qd, self.t)
        self._ref = (self.t, self.q.copy(), self.qd.copy(), qdd)  # Newton predictor data
        self._ref_prev = None  # the same at the start of the last step (dense output)
        self._last = None  # (t, y, q, qd, qdd, factor) of the latest stage
        self._jac = None
        self._tangent_ok = True  # False once the mass matrix is singular on a tangent space
        self._tangent_wanted = False  # a stage of the failed step was near a change point
        self.part = self._partition(self.t, self.q)
        self._compiled = self._compiled_stage()
        self._c_part = None  # the partition the compiled stage holds
        self._c_calls = 0  # compiled stage calls so far (whose factor its buffers hold)
        self._last_calls = 0  # _c_calls when the latest stage was taken
        self._c_trials = 0  # compiled trials so far (whose stages its buffers hold)
        self._c_accepted = -1  # _c_trials at the last step accepted from a compiled trial
        self._c_last = False  # the last accepted step was a compiled trial
        self._c_end = None  # (sensitivity, measure) of a compiled trial's end (_accept)
        self._last_ratio = 1.0  # the change-point measure of the latest stage's Phi_u
        self.n_err = 2 * self.part.k  # (v, vd); the work integral is not controlled
        # the approach to a change point and the step across it (changepoints.Approach),
        # followed by the measure of Phi_u at the accepted states (None: a new partition)
        self.counters["straddle_steps"] = 0
        self._approach = cp.Approach(cp.stage_times(self.tableau), self.h_fixed, self.policy)
        self._pivot = None  # (_accept)
        self._pivot_iu = None  # u of the last accepted step
        self._start()

    def _compiled_stage(self):
        """The stages, trials and outputs in C (:mod:`mbsim.fast.partition`), unless option
        ``compiled_step`` is false (the Python path, the same equations;
        tests/integrators/test_gcp_compiled.py compares the two), the Jacobian is sparse
        (Phi_u factored by splu) or loads depend on the multipliers (System.reaction_loop:
        the loop between solves that only the Python path has)."""
        s = self.system
        if not self.options.get("compiled_step", True) or s.sparse or s.reaction_loop:
            return None
        stage = CompiledStage(s, self.q, self.t, self.newton_tol, self.policy.newton_iter)
        stage.set_tableau(self.tableau, rtol=self.rtol, atol=self.atol,
                          control=self.tableau.embedded and self.h_fixed is None,
                          tangent=self.policy.tangent, branch_jump=self.policy.branch_jump)
        return stage

    # -- partitioning ----------------------------------------------------------------------
    def _partition(self, t, q, tangent=False):
        """The coordinate partition at q, or tangent coordinates where its Phi_u is near
        singular (or ``tangent``: a stage of the step from q was; module doc)."""
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
        if d.size and d.min() <= self.policy.rank_lost * d.max():
            raise StageFailure("the constraint Jacobian lost rank: no set of dependent "
                               "coordinates (a lock-up or a bifurcation)")
        iv = np.setdiff1d(np.arange(self.n), iu)
        fac = self._factor(J, iu)
        part = None
        if (tangent or self._pivot_ratio(fac) < self.policy.tangent) and self._tangent_ok:
            part = self._tangent_partition(q, J, Jd, iv, iu)
            self._tangent_ok = part is not None
        return part or Partition(iv, iu, self._sensitivity(fac, J, iv))

    def _pivot_ratio(self, fac):
        """The change-point measure from the LU factor of Phi_u
        (:func:`changepoints.measure_from_lu`)."""
        return cp.measure_from_lu(fac, self.system.sparse)

    def _tangent_partition(self, q, J, Jd, iv, iu):
        """Tangent coordinates at q (module doc; :func:`changepoints.tangent_map`); None where the
        mass matrix is singular on the tangent space (a massless motion)."""
        C = cp.tangent_map(self.system, q, Jd)
        if C is None:
            return None
        part = Partition(iv, iu, 0.0, C)
        part.s0 = self._tangent_sensitivity(self._factor_tangent(J, C), iv.size)
        return part

    def _factor_tangent(self, J, C):
        """LU of A = [Phi_q; C] (n x n)."""
        return cp.factor(self.system, J, C)

    def _tangent_sensitivity(self, fac, k):
        """max |T|: as max |Phi_u^-1 Phi_v| for coordinates, how far q moves per unit of v."""
        return float(np.abs(cp.basis(self.system, fac, k)).max(initial=0.0))

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
        return cp.solve(self.system, fac, b)

    # -- the stage function ----------------------------------------------------------------
    def _complete(self, t, v, vd, part):
        """q from Newton on Phi(u, v, t) = 0, qd from the velocity equations; in tangent
        coordinates (part.C) Newton on [Phi(q, t); C q - v] = 0 and A qd = [nu; vd].

        The start is the RK combination of the full stage velocities (``_trial``), exact to
        the local error, so that two Newton steps (correct, confirm) usually suffice."""
        s, (iv, iu), C = self.system, (part.iv, part.iu), part.C
        q = self._predicted(t)
        if self._compiled is not None:
            out = self._compiled_call(t, v, vd, q, part, accelerations=False)
            if out is not None:
                return out[0], out[1], None
        if C is not None:
            q, qd, fac, T = cp.complete(s, t, q, v, vd, C, self.newton_tol,
                                        self.policy.newton_iter)
            if qd is None:
                self._raise_newton_failure(T, t)
            self._jac = T.jac
            return q, qd, fac
        q[iv] = v

        def correction(T, x):  # Newton on u alone: Phi_u du = Phi
            fac = self._factor(T.jac, iu)
            dx = np.zeros(self.n)
            dx[iu] = self._solve(fac, T.phi)
            return dx, fac

        q, T, fac, ok = cp.newton(s, t, q, correction, self.newton_tol,
                                  self.policy.newton_iter)
        if not ok:
            self._raise_newton_failure(T, t)
        nu = T.nu if s.rheonomic else np.zeros(s.m)
        qd = np.empty(self.n)
        qd[iv] = vd
        qd[iu] = self._solve(fac, nu - T.jac[:, iv] @ vd)
        self._jac = T.jac
        return q, qd, fac

    def _predicted(self, t):
        """The Newton start of the stage at t: the RK combination of the stage velocities
        when ``_trial`` set one (``_pred``), else the second-order Taylor predictor from the
        last accepted state."""
        if self._pred is not None:
            q, self._pred = self._pred, None
            return q
        t0, q0, qd0, qdd0 = self._ref
        tau = t - t0
        return q0 + tau * qd0 + (0.5 * tau * tau) * qdd0

    def _compiled_call(self, t, v, vd, q, part, accelerations):
        """(q, qd, qdd, power) of a stage in ``part`` (coordinates or tangent coordinates)
        from the compiled stage (qdd, power None without accelerations), or None where the
        Python loads raised inside it (the caller takes the stage in Python, where the loads
        raise again to be seen).  Raises what the Python stage would."""
        c = self._compiled
        self._hold(part)
        st, q, qd, qdd, power, ratio = c.stage(t, v, vd, q, accelerations)
        self._c_calls += 1
        if st == GP_CALLBACK:
            return None
        if st != GP_OK:
            self._raise_compiled_failure(st, t)
        self._jac = None  # in the compiled stage's buffers until the next call (_factored)
        self._last_ratio = ratio
        return q, qd, qdd, power

    def _hold(self, part):
        """The compiled stage's partition made ``part``."""
        if self._c_part is not part:
            self._compiled.partition(part.iv, part.iu, part.C)
            self._c_part = part

    def _factored(self, fac, calls):
        """(fac, Phi_q) of the latest stage: ``fac`` itself from a Python stage, else the
        compiled stage's, copied out when its buffers still hold it (``calls``: the count of
        compiled calls when the stage was taken), otherwise factored again at its q."""
        if fac is not None:
            return fac, self._jac
        if calls == self._c_calls:
            return self._compiled.factor(), self._compiled.jacobian()
        t, q = self._last[0], self._last[2]
        jac = self.system.terms(q, t, phi=False).jac
        part = self.part
        if part.C is not None:
            return self._factor_tangent(jac, part.C), jac
        return self._factor(jac, part.iu), jac

    def _tangent_accelerations(self, t, q, qd, fac, part):
        """(qdd, power) in tangent coordinates from the reduced equations (module doc;
        :func:`changepoints.accelerations`)."""
        return cp.accelerations(self.system, t, q, qd, fac, part.k)

    def _raise_newton_failure(self, T, t):
        s = self.system
        worst = np.argsort(-np.abs(T.phi))[:3]
        names = s.model.items_of_rows(s.rows[worst])
        raise StageFailure(f"Newton iteration for the dependent coordinates did not "
                           f"converge at t = {t:.6g} s (max |Phi| = "
                           f"{np.abs(T.phi).max():.3g}); constraints: {', '.join(names)}")

    def _rhs(self, t, y, ctx=None):
        part = ctx or self.part
        k = part.k
        out = None
        if self._compiled is not None:
            out = self._compiled_call(t, y[:k], y[k:2 * k], self._predicted(t), part, True)
        if out is not None:
            q, qd, qdd, power = out
            fac = None
        else:
            q, qd, fac = self._complete(t, y[:k], y[k:2 * k], part)
            if part.C is None:
                qdd, _, power = self.system.accelerations(q, qd, t, jac=self._jac)
            else:
                qdd, power = self._tangent_accelerations(t, q, qd, fac, part)
        self._last = (t, y, q, qd, qdd, fac)
        self._last_calls = self._c_calls
        out = np.empty_like(y)
        out[:k], out[k:2 * k], out[-1] = y[k:2 * k], part.v(qdd), power
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
            self._check_singular(t + tab.C[s] * h)
            QD[s] = self._last[3]
        y_new = y + h * (K[:-1].T @ tab.B)
        pred = q0 + h * (QD.T @ tab.B)
        self._pred = pred.copy()
        f_new = self._rhs(t + h, y_new)
        self._check_singular(t + h)
        K[-1] = f_new
        self._QD = (np.vstack([QD, self._last[3]]), q0, pred)  # for _extra_error, dense
        self._check_branch(t + h, self._last[2], pred)
        return y_new, f_new

    def _attempt(self, h):
        """The trial step and its error test in one C call (mbsim/fast/partition.c:
        mb_gcp_trial, the arithmetic of ``_trial``, ``_check_singular``, ``_check_branch``
        and the error norms), then ``_accept``; without the compiled stage, or where a
        Python load raised inside the call (taken again here, where it raises to be seen),
        rk's ``_attempt`` (the stages one by one)."""
        c, part = self._compiled, self.part
        self._c_last = False
        if c is None:
            return super()._attempt(h)
        self._hold(part)
        fixed = self.h_fixed is not None
        c.set_switches(self.policy.tangent if self._tangent_ok else -np.inf,
                       np.inf if fixed else self.policy.branch_jump)
        q0, qd0 = self._ref[1], self._ref[2]
        st = c.trial(self.t, h, self.y, self.f, q0, qd0, self.tableau.embedded and not fixed)
        self._c_calls += 1
        self._c_trials += 1
        if st == GP_CALLBACK:
            return super()._attempt(h)
        if st != GP_OK:
            self._raise_compiled_failure(st, float(c.out[P_T]))
        err = float(c.out[P_ERR])
        if not np.isfinite(err):  # NaN/inf in a stage: reject hard
            raise StageFailure(f"error norm {err} at step {h:.3g} s")
        y_new = c.buffer("y_new").copy()
        if err > 1:
            return err, y_new, None, None, None, None
        self.K[:] = c.buffer("K")
        K, f_new = self.K.copy(), self.K[-1].copy()
        q, qd, qdd = (c.buffer(n).copy() for n in ("q", "qd", "qdd"))
        self._last = (self.t + h, y_new, q, qd, qdd, None)
        self._last_calls = self._c_calls
        self._QD = (c.buffer("QD").copy(), q0, c.buffer("pred_end").copy())
        ctx = self._context()
        self._c_end = (float(c.out[P_SENS]), float(c.out[P_RATIO]))
        try:
            y_acc, f_acc = self._accept(self.t + h, y_new, f_new)
        finally:
            self._c_end = None
        self._c_last, self._c_accepted = True, self._c_trials
        return err, y_new, y_acc, f_acc, K, ctx

    def dense_output_many(self, times):
        """All outputs of the last step at once in C when the step was taken there
        (partition.c: mb_gcp_dense, the arithmetic of ``_dense_output_impl`` without its
        fallback); an output that fails there, and every output of a step whose extra
        stages fail, go through the Python dense output (its quintic Hermite fallback)."""
        if not self._c_last or self._c_accepted != self._c_trials:
            return super().dense_output_many(times)
        times = np.asarray(times, dtype=float)
        k = times.size - int(times.size > 0 and times[-1] == self.t)  # (at t: the state)
        if k == 0:
            return super().dense_output_many(times)
        t0, h, ctx = self._dense_args[0], self._dense_args[1], self._dense_args[5]
        c = self._compiled
        self._hold(ctx)
        status, Q, QD, W, flags = c.dense(t0, h, times[:k])
        self._c_calls += 1
        if status != GP_OK:
            return super().dense_output_many(times)
        if k < times.size:
            Q = np.vstack([Q, self.q])
            QD = np.vstack([QD, self.qd])
            W = np.append(W, self.w)
            flags = np.append(flags, 0)
        return self._redo_flagged(times, Q, QD, W, flags)

    def _raise_compiled_failure(self, st, t):
        """The exception of a failed compiled stage or trial (status GP_*; t the stage's
        time), as its Python stage or check raises it."""
        c = self._compiled
        if st == GP_NEWTON:
            self._raise_newton_failure(_Residual(self.system.fc._phi.copy()), t)
        if st == GP_SINGULAR and c.C is not None:
            raise StageFailure(f"t = {t:.6g} s: singular [Phi_q; C] (the tangent coordinates' "
                               f"matrix has a zero pivot)")
        if st == GP_SINGULAR:
            raise _singular_u(t)
        if st == GP_REDUCED:
            raise StageFailure(f"t = {t:.6g} s: singular reduced mass matrix")
        if st == GP_SOLVE:
            raise solve_error(int(c.out[P_CODE]))
        if st == GP_ALARM:
            raise self._singular_failure(t, float(c.out[P_RATIO]))
        raise _branch_failure(t, float(c.out[P_DEV]))

    def _check_singular(self, t):
        """A stage in coordinates with Phi_u near singular fails the trial, so that the step is
        tried again from its start in tangent coordinates (``_recover``): an accepted point
        need not fall near the change point (a step of DOP853 or RK4 crosses the four-bar's
        flat position, 1e-2 rad wide at the default switch, with stages on both sides)."""
        if self.part.C is None and self._tangent_ok:
            fac = self._last[5]
            ratio = self._last_ratio if fac is None else self._pivot_ratio(fac)
            if ratio < self.policy.tangent:
                raise self._singular_failure(t, ratio)

    def _singular_failure(self, t, ratio):
        """The StageFailure of a stage below the switch; the step is retried from its start
        in tangent coordinates (``_recover``)."""
        self._tangent_wanted = True
        return StageFailure(f"t = {t:.6g} s: Phi_u near singular (pivot ratio {ratio:.3g}); "
                            f"tangent coordinates")

    def _check_branch(self, t, q, pred):
        """Reject a Newton solution q of the dependent coordinates more than the policy's
        ``branch_jump`` tolerances from the RK solution pred of the full q (q' = qd with the
        method's weights, accurate to the local error): it has jumped to another branch of
        the constraints (at a change point, e.g. a parallelogram's flat position).  Fixed
        step: no tolerance to measure it with."""
        if self.h_fixed is not None:
            return
        dev = rms_norm(q - pred, self.atol + self.rtol * np.abs(pred))
        if dev > self.policy.branch_jump:
            raise _branch_failure(t, dev)

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
        v = self.part.v
        return np.concatenate([v(self.q), v(self.qd), [self.w]])

    def _state_from_y(self, t, y, ctx=None):
        last = self._last
        if last is not None and last[0] == t and last[1] is y:
            return last[2], last[3], float(y[-1])
        part = ctx or self.part
        k = part.k
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
                if not ok and res > self.policy.kept_residual:
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
        cur = self.part
        if cur.C is None:
            if self._c_end is not None:  # the compiled trial's, at its end's factor
                sens, self._pivot = self._c_end
            else:
                fac, self._jac = self._factored(fac, self._last_calls)
                self._last = (lt, ly, q, qd, qdd, fac)
                sens = self._sensitivity(fac, self._jac, cur.iv)
                self._pivot = self._pivot_ratio(fac)
            change = self._pivot < self.policy.tangent  # towards a change point
            limit = self.ratio * max(1.0, cur.s0)
        else:  # max |T| grows as 1 / cos of the tangent's rotation since the partition
            if self._c_end is not None:  # the compiled trial's (the coordinates' measure)
                sens, self._pivot = self._c_end
            else:
                fac, self._jac = self._factored(fac, self._last_calls)
                self._last = (lt, ly, q, qd, qdd, fac)
                sens = self._tangent_sensitivity(fac, cur.k)
                # back to coordinates as soon as their Phi_u is no longer near singular
                self._pivot = self._pivot_ratio(self._factor(self._jac, cur.iu))
            limit = self.ratio * cur.s0
            change = self._pivot >= self.policy.tangent
        if change or sens > limit:
            part = self._partition(t, q)
            if part.same(cur):
                cur.s0 = max(sens, part.s0)  # the same set is still the best
            else:
                self._switch(part)
                log.debug("t = %.6g s: coordinates partitioned again (sensitivity %.3g); "
                          "independent: %s", t, sens,
                          "tangent" if part.C is not None else part.iv.tolist())
                v = part.v
                y = np.concatenate([v(q), v(qd), y[-1:]])
                f = np.concatenate([v(qd), v(qdd), f[-1:]])
                self._last = (t, y, q, qd, qdd, fac)
        return y, f

    def _step_impl(self):
        h = self._approach.step(self.h_abs) if self._tangent_ok else None
        if h is not None:
            self.h_abs = h  # a step across the change point ahead (changepoints.Approach)
        iu = self.part.iu
        ok, msg = super()._step_impl()
        if ok:
            # the pivot ratio of the step's Phi_u; after a new choice of u, no measure that
            # compares with the earlier ones
            same = np.array_equal(iu, self.part.iu) and np.array_equal(iu, self._pivot_iu)
            self._pivot_iu = iu
            if self._approach.accepted(self.t, self.h_last, self._pivot if same else None):
                self.counters["straddle_steps"] += 1
        return ok, msg

    def _switch(self, part):
        """Make ``part`` the partition; counters ``repartitions`` (every change) and
        ``tangent_partitions`` (the changes into tangent coordinates)."""
        self.part = part
        self.counters["repartitions"] += 1
        if part.C is not None:
            self.counters["tangent_partitions"] += 1

    def _recover(self):
        """After a failed stage: partition again at the start of the step."""
        t0, q0, qd0, qdd0 = self._ref
        wanted, self._tangent_wanted = self._tangent_wanted, False
        try:
            part = self._partition(t0, q0, tangent=wanted)
        except StageFailure:
            return False
        if part.same(self.part):
            return False
        self._switch(part)
        v = part.v
        self.y = np.concatenate([v(q0), v(qd0), self.y[-1:]])
        self.f = np.concatenate([v(qd0), v(qdd0), self.f[-1:]])
        return True


class GcpRK45(GeneralizedCoordinatePartitioning):
    name = "gcp-rk45"
    description = ("coordinate partitioning (Wehage-Haug), Dormand-Prince 5(4) on (v, vd); "
                   "tangent coordinates near singular positions")
    order = 5


class GcpDop853(GeneralizedCoordinatePartitioning):
    name = "gcp-dop853"
    description = ("coordinate partitioning (Wehage-Haug), DOP853 (order 8) on (v, vd); "
                   "tangent coordinates near singular positions")
    order = 8
    tableau = Dop853


class GcpRK4(GeneralizedCoordinatePartitioning):
    name = "gcp-rk4"
    description = ("coordinate partitioning (Wehage-Haug), classic fixed-step RK4 (needs --step); "
                   "tangent coordinates near singular positions")
    order = 4
    adaptive = False
    tableau = ClassicRK4
