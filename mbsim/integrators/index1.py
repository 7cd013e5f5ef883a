"""Index-1 integrators: the ODE y = (q, qd, w), y' = (qd, qdd(q, qd, t), power) with qdd from
the equations of motion (Haug Sec. 11.3), integrated by an explicit RK pair.

The position and velocity constraints are then only invariants that drift; two remedies:

- Baumgarte (1972): gamma -> gamma - 2 alpha dPhi/dt - beta^2 Phi, so that the drift obeys
  a damped second-order equation (alpha, beta in 1/s; class data, options override).  The
  damping does not bound the drift, and near a singular position it is not enough: see
  :class:`Baumgarte` for the drift bound it is given here.
- Projection (Hairer, Lubich & Roche; Eich 1993): after each accepted step q is put back on
  Phi = 0 by a mass-weighted Newton projection and qd onto Phi_q qd = nu; the right-hand
  side is re-evaluated there (FSAL), and the dense output blends the correction in.
"""

from __future__ import annotations

import numpy as np

from mbsim.integrators.base import rms_norm
from mbsim.integrators.rk import ClassicRK4, Dop853, RungeKuttaIntegrator, StageFailure


class Index1(RungeKuttaIntegrator):
    formulation = "index-1"
    baumgarte: tuple[float, float] | None = None
    project = False

    def __init__(self, system, t0, q0, qd0, t_bound, options=None):
        super().__init__(system, t0, q0, qd0, t_bound, options)
        n = system.nq
        self.n = n
        self.n_err = 2 * n
        if self.baumgarte is not None:
            self.stab = (float(self.options.get("alpha", self.baumgarte[0])),
                         float(self.options.get("beta", self.baumgarte[1])))
        else:
            self.stab = None
        # projection tolerance: well below the local error asked for
        self.proj_tol = float(self.options.get("projection_tol",
                                               min(1e-10, max(1e-14, 1e-3 * self.atol))))
        if self.project:
            self.counters["output_steps"] = 0  # steps of outputs integrated to (dense output)
        self._start()

    def _y_from_state(self):
        return np.concatenate([self.q, self.qd, [self.w]])

    def _state_from_y(self, t, y, ctx=None):
        n = self.n
        return y[:n], y[n:2 * n], float(y[-1])

    def _rhs(self, t, y, ctx=None):
        n = self.n
        q, qd = y[:n], y[n:2 * n]
        qdd, _, power = self.system.accelerations(q, qd, t, self.stab)
        out = np.empty_like(y)
        out[:n], out[n:2 * n], out[-1] = qd, qdd, power
        return out

    def _project(self, t, q, qd):
        """(q, qd) put back on Phi = 0 and Phi_q qd = nu; a projection that does not reach
        its tolerance (near a singular position) is a failed stage: the step is retried
        smaller."""
        s = self.system
        q, ok, its, res = s.project_positions(q, t, tol=self.proj_tol)
        if not ok and res > max(1e3 * self.proj_tol, 1e-11):
            raise StageFailure(f"projection onto the constraints did not converge at "
                               f"t = {t:.6g} s (max |Phi| = {res:.3g})")
        return q, s.project_velocities(q, qd, t)

    def _accept(self, t, y, f):
        if not self.project:
            return y, f
        n = self.n
        q, qd = self._project(t, y[:n], y[n:2 * n])
        y = np.concatenate([q, qd, y[-1:]])
        return y, self._rhs(t, y)

    def _dense_output_impl(self):
        """The RK interpolant; with projection, each sampled state is projected too, so that
        outputs satisfy the constraints as the steps do (not only to the local error).

        The projection removes the interpolant's error normal to the constraint set to first
        order only; what it leaves along the set is of the order of the projection's
        nonlinear part, the Newton corrections after the first (linear, M-orthogonal) one.
        Where that part exceeds the tolerance (scaled RMS norm > 1), or the projection does
        not converge, the interpolant is not to be trusted: its extra stages (DOP853's three
        are evaluated without error control at unprojected states) met accelerations that
        are not reliable, as near a singular position, where the index-1 accelerations
        amplify a stage state's drift by ~1/sigma_min(Phi_q)^2 (the four parallel cranks of
        issue 11 at rtol 1e-7: an extra stage 1e-4 rad from the flat position left the
        interpolant 3e-2 m off the constraints, and 2.6e-4 m off along them after the
        projection).  There the output is integrated to instead (:meth:`_integrate_to`).
        The test costs nothing where the first Newton step already reaches the projection
        tolerance, as on smooth motions; the step's own end is never affected."""
        out = super()._dense_output_impl()
        if not self.project:
            return out
        t0, _, y0 = self._dense_args[:3]
        n, s = self.n, self.system
        scale = self._scale(y0, self.y)[:n]
        last = {"t": t0, "y": y0, "h": None}  # last state known to the step's accuracy

        def projected(t):
            q, qd, w = out(t)
            try:
                qp, qdp = self._project(t, q, qd)
            except StageFailure:
                qp = None
            if qp is not None and rms_norm(qp - q, scale) > 1.0:
                q1 = s.project_positions(q, t, tol=self.proj_tol, max_iter=1)[0]
                if rms_norm(qp - q1, scale) > 1.0:
                    qp = None
            if qp is not None:
                return qp, qdp, w
            y = self._integrate_to(t, last)
            return y[:n], y[n:2 * n], float(y[-1])

        return projected

    def _integrate_to(self, t, last):
        """y at t from the state ``last`` (t, y, h: first step or None), by a fresh
        integrator of this class with this one's options (error control, projection after
        each step); ``last`` moves to t.  A failure there is a failure of the output."""
        t_s, y_s = last["t"], last["y"]
        n = self.n
        opt = dict(self.options, h0=last["h"] or self.h_last or None)
        sub = type(self)(self.system, t_s, y_s[:n], y_s[n:2 * n], t, opt)
        while sub.t < t:
            ok, msg = sub.step()
            if not ok:
                raise StageFailure(f"output at t = {t:.6g} s: {msg}")
        self.counters["output_steps"] += sub.counters["steps"]
        y = sub.y.copy()
        y[-1] += y_s[-1]
        last.update(t=t, y=y, h=sub.h_abs)
        return y


class Baumgarte(Index1):
    """Baumgarte stabilisation with a bound on the drift.

    Baumgarte's term damps the drift (Phi, Phi_q qd - nu) at the rates alpha, beta; the
    drift that each step's local error adds is not bounded by the step's error test, which
    sees q and qd only.  Near a singular position that drift decides the motion: there the
    independent rows' solution set can cross another branch (the four parallel cranks of
    issue 11 at their flat positions: the 41 rows chosen let the coupler rotate), and
    the index-1 equations follow the drifted set Phi = c, which near a crossing u w = 0 is
    the hyperbola u w = c: it turns onto the other branch within |u| ~ sqrt(|c|) of the
    crossing instead of passing it.  A coarse step steps over that turn, a fine one (tight
    tolerance, or the error estimate's companion run) follows it.

    So the drift is measured after each accepted step as the state's distance from the
    constraint set, the mass-weighted Newton corrections dq = M^-1 Phi_q^T S^-1 Phi and
    dqd = M^-1 Phi_q^T S^-1 (Phi_q qd - nu), S = Phi_q M^-1 Phi_q^T (Haug Sec. 11.3), in the
    error scale of q and qd: near a singular position the same Phi gives a correction
    amplified ~1/sigma_min(Phi_q).  Where it exceeds the tolerance (norm > 1) the state is
    projected onto the constraints as in :class:`Projection` (post-stabilisation, Ascher,
    Chin, Petzold & Reich 1995); otherwise the step is the plain Baumgarte step (on the seed
    decks at the default tolerance 0.5-8 % of the steps are projected).  Option
    ``drift_bound``: False gives the unbounded method of Baumgarte (1972)."""

    name = "baumgarte"
    description = ("index-1 with Baumgarte stabilisation (alpha = beta = 10/s), "
                   "Dormand-Prince 5(4), projection where the drift exceeds the tolerance")
    order = 5
    baumgarte = (10.0, 10.0)

    def __init__(self, system, t0, q0, qd0, t_bound, options=None):
        super().__init__(system, t0, q0, qd0, t_bound, options)
        self.drift_bound = bool(self.options.get("drift_bound", True))
        self.counters["drift_projections"] = 0

    def _accept(self, t, y, f):
        if not self.drift_bound:
            return y, f
        n = self.n
        q, qd = y[:n], y[n:2 * n]
        dq, dqd = self.system.drift(q, qd, t)  # the drift, in coordinates (class doc)
        scale = self._scale(y)
        if max(rms_norm(dq, scale[:n]), rms_norm(dqd, scale[n:2 * n])) <= 1.0:
            return y, f
        self.counters["drift_projections"] += 1
        q, qd = self._project(t, q, qd)
        y = np.concatenate([q, qd, y[-1:]])
        return y, self._rhs(t, y)


class Projection(Index1):
    name = "projection"
    description = "index-1, Dormand-Prince 5(4), projection of q and qd after each step"
    order = 5
    project = True


class ProjectionDop853(Index1):
    name = "projection-dop853"
    description = "index-1, DOP853 (order 8), projection of q and qd after each step"
    order = 8
    tableau = Dop853
    project = True


class RK4Projection(Index1):
    name = "rk4"
    description = "index-1, classic fixed-step RK4 (needs --step), projection after each step"
    order = 4
    adaptive = False
    tableau = ClassicRK4
    project = True

