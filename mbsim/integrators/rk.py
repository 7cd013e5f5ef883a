"""Explicit Runge-Kutta pairs (tableaus as class data) and the step loop they share.

The loop follows scipy's ``RungeKutta._step_impl`` (Hairer, Norsett & Wanner, *Solving
Ordinary Differential Equations I*, Sec. II.4): local extrapolation, an embedded error
estimate in a scaled RMS norm, step factor 0.9 err^(-1/(p+1)) clipped to [0.2, 5].  A
family (coordinate partitioning, index-1) supplies the first-order system y' = f(t, y) it
integrates and how y maps back to (q, qd, w).
"""

from __future__ import annotations

import numpy as np

from mbsim.integrators import dop853_coefficients as dop
from mbsim.integrators.base import (
    FIRST_STEP_ROOM,
    MAX_REJECTS,
    NUMERICAL_ERRORS,
    Integrator,
    hermite,
    rms_norm,
)


class StageFailure(ArithmeticError):
    """A right-hand side that could not be evaluated (Newton failure, singular matrix)."""


# ------------------------------------------------------------------------------ tableaus
class Tableau:
    """An explicit RK method: c, A, b (Butcher), E (error weights incl. the FSAL stage,
    None for a method without an error estimate) and its dense output."""

    order = 0
    error_order = 0
    n_stages = 0
    C: np.ndarray
    A: np.ndarray
    B: np.ndarray
    E: np.ndarray | None = None
    P: np.ndarray | None = None  # dense output: y = y0 + h K^T P [x, x^2, ...]
    embedded = True  # has an error estimate (False: fixed step only)
    # the forms of error_norm and dense as mbsim/fast/step.c knows them (None: not in C)
    error_form: str | None = "embedded"  # | "dop853" | None (no estimate)
    dense_form: str | None = "poly"  # | "dop853" | "hermite"

    @classmethod
    def error_norm(cls, K, h, scale, noise=None):
        """The scaled norm of the embedded error estimate h K^T E; with ``noise`` (per
        component, the round-off of one stage derivative, independent between stages) the
        part of the estimate that this noise alone can make, h |E|_2 noise, is taken off
        each component first."""
        est = h * (K.T @ cls.E)[: scale.size]
        if noise is not None:
            est = np.maximum(np.abs(est) - h * np.linalg.norm(cls.E) * noise, 0.0)
        return rms_norm(est, scale)

    @classmethod
    def dense(cls, fun, t0, h, y0, y1, K):
        """Interpolant y(t) on [t0, t0 + h]; K holds the stages and f(t0 + h, y1) last."""
        Q = K.T @ cls.P

        def g(t):
            x = (t - t0) / h
            return y0 + h * (Q @ np.cumprod(np.full(Q.shape[1], x)))

        return g


class DormandPrince54(Tableau):
    """Dormand & Prince (1980) 5(4) pair, FSAL, with Shampine's (1986) quartic interpolant."""

    order, error_order, n_stages = 5, 4, 6
    C = np.array([0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1])
    A = np.array([
        [0, 0, 0, 0, 0],
        [1 / 5, 0, 0, 0, 0],
        [3 / 40, 9 / 40, 0, 0, 0],
        [44 / 45, -56 / 15, 32 / 9, 0, 0],
        [19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729, 0],
        [9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656],
    ])
    B = np.array([35 / 384, 0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84])
    E = np.array([-71 / 57600, 0, 71 / 16695, -71 / 1920, 17253 / 339200, -22 / 525, 1 / 40])
    P = np.array([
        [1, -8048581381 / 2820520608, 8663915743 / 2820520608, -12715105075 / 11282082432],
        [0, 0, 0, 0],
        [0, 131558114200 / 32700410799, -68118460800 / 10900136933, 87487479700 / 32700410799],
        [0, -1754552775 / 470086768, 14199869525 / 1410260304, -10690763975 / 1880347072],
        [0, 127303824393 / 49829197408, -318862633887 / 49829197408,
         701980252875 / 199316789632],
        [0, -282668133 / 205662961, 2019193451 / 616988883, -1453857185 / 822651844],
        [0, 40617522 / 29380423, -110615467 / 29380423, 69997945 / 29380423],
    ])


class Dop853(Tableau):
    """Hairer's DOP853: order 8, error estimate from a 5th- and 3rd-order combination,
    7th-order dense output from three extra stages (evaluated only when output is asked)."""

    order, error_order, n_stages = 8, 7, dop.N_STAGES
    error_form, dense_form = "dop853", "dop853"
    A = dop.A[: dop.N_STAGES, : dop.N_STAGES]
    B = dop.B
    C = dop.C[: dop.N_STAGES]
    E3, E5, D = dop.E3, dop.E5, dop.D
    A_EXTRA = dop.A[dop.N_STAGES + 1:]
    C_EXTRA = dop.C[dop.N_STAGES + 1:]

    @classmethod
    def error_norm(cls, K, h, scale, noise=None):
        """Hairer's combination of the 5th- and 3rd-order estimates; ``noise`` as in
        :meth:`Tableau.error_norm`, taken off each."""
        n = scale.size
        err5 = (K.T @ cls.E5)[:n]
        err3 = (K.T @ cls.E3)[:n]
        if noise is not None:
            err5 = np.maximum(np.abs(err5) - np.linalg.norm(cls.E5) * noise, 0.0)
            err3 = np.maximum(np.abs(err3) - np.linalg.norm(cls.E3) * noise, 0.0)
        err5, err3 = err5 / scale, err3 / scale
        e5, e3 = float(err5 @ err5), float(err3 @ err3)
        if e5 == 0 and e3 == 0:
            return 0.0
        return abs(h) * e5 / np.sqrt((e5 + 0.01 * e3) * n)

    @classmethod
    def dense(cls, fun, t0, h, y0, y1, K):
        Kx = np.empty((dop.N_STAGES_EXTENDED, y0.size))
        Kx[: K.shape[0]] = K
        for s, (a, c) in enumerate(zip(cls.A_EXTRA, cls.C_EXTRA), start=cls.n_stages + 1):
            Kx[s] = fun(t0 + c * h, y0 + h * (Kx[:s].T @ a[:s]))
        F = np.empty((dop.INTERPOLATOR_POWER, y0.size))
        dy = y1 - y0
        F[0] = dy
        F[1] = h * Kx[0] - dy
        F[2] = 2 * dy - h * (Kx[cls.n_stages] + Kx[0])
        F[3:] = h * (cls.D @ Kx)

        def g(t):
            x = (t - t0) / h
            y = np.zeros_like(y0)
            for i, f in enumerate(F[::-1]):
                y += f
                y *= x if i % 2 == 0 else 1 - x
            return y + y0

        return g


class ClassicRK4(Tableau):
    """Kutta's classic fourth-order method (fixed step, no error estimate); cubic Hermite
    dense output from the end-point slopes."""

    order, error_order, n_stages = 4, 0, 4
    embedded = False
    error_form, dense_form = None, "hermite"
    C = np.array([0, 1 / 2, 1 / 2, 1])
    A = np.array([[0, 0, 0], [1 / 2, 0, 0], [0, 1 / 2, 0], [0, 0, 1]])
    B = np.array([1 / 6, 1 / 3, 1 / 3, 1 / 6])

    @classmethod
    def dense(cls, fun, t0, h, y0, y1, K):
        return hermite(t0, t0 + h, y0, y1, K[0], K[-1])


# ---------------------------------------------------------------------------- step loop
class RungeKuttaIntegrator(Integrator):
    """An explicit RK family on a first-order system y' = f(t, y).

    A subclass provides ``_rhs(t, y, ctx=None)``, ``_y_from_state()`` (y from self.q,
    self.qd, self.w), ``_state_from_y(t, y, ctx=None)`` (-> q, qd, w), ``n_err`` (leading
    components of y under error control) and may override ``_accept(t, y, f) -> (y, f)``
    (projection, re-partitioning), ``_recover()`` (what to try after a StageFailure before
    shrinking the step), ``_context()`` (what y means during the step, e.g. the
    coordinate partition, kept with the dense output) and ``_attempt(h)`` (the trial, its
    error test and _accept in one: the index-1 family takes it in C, mbsim/fast/step.c).
    """

    tableau = DormandPrince54
    n_err = 0

    def __init__(self, system, t0, q0, qd0, t_bound, options=None):
        super().__init__(system, t0, q0, qd0, t_bound, options)
        tab = self.tableau
        if self.h_fixed is None and not tab.embedded:
            raise ValueError(f"{self.name} is a fixed-step method: give a step h")
        self.K = np.empty((tab.n_stages + 1, 0))
        self._last_failure = ""
        self.error_exponent = -1.0 / (tab.error_order + 1) if tab.error_order else 0.0

    def _start(self):
        """Call at the end of a subclass __init__, once the state is ready."""
        self.y = self._y_from_state()
        self.f = self._rhs(self.t, self.y)
        self.K = np.empty((self.tableau.n_stages + 1, self.y.size))
        if self.h_fixed is not None:
            self.h_abs = self.h_fixed
        elif self.h0 is not None:
            self.h_abs = float(self.h0)
        else:
            self.h_abs = self._initial_step()

    def _scale(self, y, y_new=None):
        n = self.n_err
        a = np.abs(y[:n]) if y_new is None else np.maximum(np.abs(y[:n]), np.abs(y_new[:n]))
        return self.atol + self.rtol * a

    def _initial_step(self):
        """Hairer, Norsett & Wanner (1993) Sec. II.4 starting step (one extra evaluation)."""
        n = self.n_err
        scale = self._scale(self.y)
        d0, d1 = rms_norm(self.y[:n], scale), rms_norm(self.f[:n], scale)
        h0 = 1e-6 if d0 < 1e-5 or d1 < 1e-5 else 0.01 * d0 / d1
        h0 = min(h0, self.t_bound - self.t)
        if not np.isfinite(h0) or h0 <= 0:
            h0 = 1e-6 * max(1.0, self.t_bound - self.t)
        h0 = min(h0, self.t_bound - self.t)
        try:
            f1 = self._rhs(self.t + h0, self.y + h0 * self.f)
        except NUMERICAL_ERRORS:
            return h0
        d2 = rms_norm((f1 - self.f)[:n], scale) / h0
        order = self.tableau.error_order + 1
        dm = max(d1, d2)
        if not np.isfinite(dm):
            return h0
        h1 = max(1e-6, h0 * 1e-3) if dm <= 1e-15 else (0.01 / dm) ** (1 / order)
        # the guess is a start for the controller, never a verdict: a state within its
        # tolerance of zero (d0 ~ 1: a start at rest in coordinates that are zero there, as
        # tangent coordinates can be) makes 0.01 d0 / d1 as small as 1e-18 s, below h_min;
        # start FIRST_STEP_ROOM x the smallest step instead, from which the controller can
        # still reject (factor >= MIN_FACTOR) three times before h_min
        h_floor = min(FIRST_STEP_ROOM * self._min_step(), self.h_max, self.t_bound - self.t)
        return max(min(100 * h0, h1, self.h_max), h_floor)

    def _trial(self, h):
        """One RK step of size h from (t, y); returns y_new, f_new (K filled)."""
        tab, K, t, y = self.tableau, self.K, self.t, self.y
        K[0] = self.f
        for s in range(1, tab.n_stages):
            K[s] = self._rhs(t + tab.C[s] * h, y + h * (K[:s].T @ tab.A[s, :s]))
        y_new = y + h * (K[:-1].T @ tab.B)
        f_new = self._rhs(t + h, y_new)
        K[-1] = f_new
        return y_new, f_new

    def set_work(self, w):
        super().set_work(w)
        self.y[-1] = self.w  # y = (..., w): the integrated power is its last component

    def _step_impl(self):
        t = self.t
        rejected = False
        recovered = False
        rejects = 0
        h_abs = min(self.h_abs, self.h_max)
        while True:
            h = self._clip(h_abs)
            if not np.isfinite(h):
                return self._fail(f"step size is not finite ({h}); the error norm is NaN "
                                  f"(check atol > 0 and the forces)")
            if h < self._min_step() and h < self.t_bound - t:
                why = f"; last failure: {self._last_failure}" if self._last_failure else ""
                return self._fail(f"{self.TOO_SMALL_STEP} ({h:.3g} s){why}")
            if rejects >= MAX_REJECTS:
                why = f"; last failure: {self._last_failure}" if self._last_failure else ""
                return self._fail(f"no progress: {rejects} rejected steps in a row "
                                  f"(step {h:.3g} s){why}")
            try:
                err, y_new, y_acc, f_acc, K, ctx = self._attempt(h)
            except NUMERICAL_ERRORS as exc:
                self.counters["rejected_steps"] += 1
                rejects += 1
                self._last_failure = str(exc)
                if not recovered and self._recover():
                    recovered = True
                    continue
                if self.h_fixed is not None:
                    return self._fail(str(exc))
                h_abs = 0.25 * h
                rejected = True
                continue
            if not self.tableau.embedded or self.h_fixed is not None:
                break
            factor = self._step_factor(err, self.error_exponent, rejected)
            h_abs = h * factor
            if err <= 1:
                break
            rejected = True
            rejects += 1
            self.counters["rejected_steps"] += 1
        self._dense_args = (t, h, self.y, y_new, K, ctx)
        self.t, self.y, self.f, self.h_last = t + h, y_acc, f_acc, h
        self.h_abs = self.h_fixed if self.h_fixed is not None else h_abs
        self.q, self.qd, self.w = self._state_from_y(self.t, self.y)
        return True, ""

    def _attempt(self, h):
        """One trial step of size h from (t, y) and its error test; when accepted (err <= 1)
        the step's end after :meth:`_accept`.  Returns (err, y_new, y_acc, f_acc, K, ctx):
        y_new the end before _accept, K the stages (copy) and ctx as the dense output needs
        them; y_acc, f_acc, K, ctx None when rejected.  Raises what a stage raises."""
        y_new, f_new = self._trial(h)
        err = 0.0
        if self.tableau.embedded and self.h_fixed is None:
            err = max(self._error_norm(h, y_new), self._extra_error(h))
            if not np.isfinite(err):  # NaN/inf in a stage: reject hard
                raise StageFailure(f"error norm {err} at step {h:.3g} s")
        if err > 1:
            return err, y_new, None, None, None, None
        K, ctx = self.K.copy(), self._context()
        y_acc, f_acc = self._accept(self.t + h, y_new, f_new)
        return err, y_new, y_acc, f_acc, K, ctx

    def _accept(self, t, y, f):
        return y, f

    def _error_norm(self, h, y_new) -> float:
        """The embedded error norm of the trial step from (t, y) to y_new (stages in K)."""
        return self.tableau.error_norm(self.K, h, self._scale(self.y, y_new))

    def _extra_error(self, h) -> float:
        """A family's own error norm of the trial step beside the embedded one (0: none)."""
        return 0.0

    def _recover(self):
        return False

    def _context(self):
        return None

    def _dense_output_impl(self):
        t0, h, y0, y1, K, ctx = self._dense_args
        g = self.tableau.dense(lambda t, y: self._rhs(t, y, ctx), t0, h, y0, y1, K)
        # a projection after the step (y != y1) is blended in linearly
        delta = self.y - y1 if ctx is None or ctx is self._context() else 0.0

        def out(t):
            y = g(t)
            if np.any(delta):
                y = y + ((t - t0) / h) * delta
            return self._state_from_y(t, y, ctx)

        return out
