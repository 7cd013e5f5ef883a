"""Index-1 integrators: the ODE y = (q, qd, w), y' = (qd, qdd(q, qd, t), power) with qdd from
the equations of motion (Haug Sec. 11.3), integrated by an explicit RK pair.

The position and velocity constraints are then only invariants that drift; two remedies:

- Baumgarte (1972): gamma -> gamma - 2 alpha dPhi/dt - beta^2 Phi, so that the drift obeys
  a damped second-order equation (alpha, beta in 1/s; class data, options override).
- Projection (Hairer, Lubich & Roche; Eich 1993): after each accepted step q is put back on
  Phi = 0 by a mass-weighted Newton projection and qd onto Phi_q qd = nu; the right-hand
  side is re-evaluated there (FSAL), and the dense output blends the correction in.
"""

from __future__ import annotations

import numpy as np

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
        outputs satisfy the constraints as the steps do (not only to the local error)."""
        out = super()._dense_output_impl()
        if not self.project:
            return out

        def projected(t):
            q, qd, w = out(t)
            q, qd = self._project(t, q, qd)
            return q, qd, w

        return projected


class Baumgarte(Index1):
    name = "baumgarte"
    description = ("index-1 with Baumgarte stabilisation (alpha = beta = 10/s), "
                   "Dormand-Prince 5(4)")
    order = 5
    baumgarte = (10.0, 10.0)


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

