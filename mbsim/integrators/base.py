"""The integrator contract (after scipy's ``OdeSolver``) and the step-size controller.

An integrator advances a constrained multibody state (q, qd) of a
:class:`~mbsim.integrators.system.System` one accepted step at a time; the dynamic analysis
(:mod:`mbsim.analyses.dynamic`) drives it and samples its dense output at the output times,
so output sampling never constrains the step size.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from mbsim.integrators.system import SolveError  # singular matrices

SAFETY = 0.9  # times the asymptotically optimal step (Hairer, Norsett & Wanner, Sec. II.4)
MIN_FACTOR = 0.2  # largest decrease of the step after a rejected step
MAX_FACTOR = 5.0  # largest increase after an accepted step
FIRST_STEP_ROOM = MIN_FACTOR ** -3  # the first step is at least this x h_min (rk._initial_step)
MAX_REJECTS = 100  # rejected trials in a row before a step loop gives up (no progress)
STALL_FLOOR = 1e-11  # an accepted step below this x max(1, |t|) makes no real progress
# round-off of q: |Phi| at a converged Newton iterate is 0.5-1 ulp of max(1, |q|) (measured);
# generalized-alpha's Newton test and the round-off probes of genalpha and index-1 use it
ROUNDOFF_ULPS = 4
STALL_STEPS = 200  # ... and that many of them in a row is a stall


class IntegratorFailure(Exception):
    """A failure outside a step (dense output); the dynamic analysis turns it into an
    incomplete result.  ``done``: (Q, QD, W) of the outputs before the failed one, when
    several were asked at once (:meth:`Integrator.dense_output_many`), else None."""

    def __init__(self, message, done=None):
        super().__init__(message)
        self.done = done


NUMERICAL_ERRORS = (SolveError, ArithmeticError, np.linalg.LinAlgError, ValueError)
"""What a numerical failure of the equations of motion may raise: singular matrices, NaN
checks of LAPACK (ValueError), overflow.  Stage failures of the RK families derive from
ArithmeticError so that they are caught here too."""


class Integrator(ABC):
    """Base class of the multibody integrators.

    Contract of an integrator type (a class registered in ``INTEGRATORS``):

    1. Class data: ``name`` (the registry and ``--integrator`` name), ``description`` (one
       line for ``mbsim list integrators``), ``order`` (global order of q in h),
       ``tolerance_exponent`` (kappa: the global error of an adaptive run grows as
       rtol^kappa; 1 for the Runge-Kutta pairs, whose local extrapolation and error-per-step
       control make the error proportional to the tolerance, and for generalized-alpha
       below its reference rtol; :meth:`error_ratio` gives the ratio between two
       tolerances, for a family whose kappa depends on rtol),
       ``adaptive`` (True: has an error estimate and controls its step from rtol/atol;
       every integrator also takes a fixed step ``h``), ``formulation`` ('gcp' | 'index-1' |
       'index-3').  Family facts (tableaus, alpha parameters) are class data too.
    2. ``__init__(system, t0, q0, qd0, t_bound, options)``: ``system`` is a
       :class:`~mbsim.integrators.system.System`; (q0, qd0) satisfy Phi = 0 and
       Phi_q qd = nu; ``options`` holds rtol, atol, h (fixed step: no error control),
       h0 (first step), h_max, h_min and the family's own settings.  Subclasses call
       ``super().__init__`` first, then prepare their state.
    3. ``_step_impl() -> (ok, message)``: take one accepted step from ``t`` towards
       ``t_bound`` (never past it) and update ``t``, ``q``, ``qd``, ``w`` (the integrated
       power Q.qd - lam.nu, see :meth:`System.power`) and ``h_last``; store what the dense
       output needs.  Add to ``self.counters['rejected_steps']`` for every rejected trial.
       A numerical failure (Newton divergence, singular matrix, step below h_min) returns
       ``(False, message)`` with the time and the joints involved; it never raises, prints
       or exits.
    4. ``_dense_output_impl() -> callable``: ``f(t) -> (q, qd, w)`` for t in the last step
       [t_old, t]; ``dense_output_many(times) -> (Q, QD, W)`` evaluates it at all output
       times of the step at once (the driver's call; a family may do it in C).
    5. ``advance(t_stop, max_steps) -> (ok, message)``: several accepted steps at once up
       to the next output time (the driver's call; default: one :meth:`step`).
    6. Counters: ``self.counters`` (steps, rejected_steps, plus the family's own, e.g.
       repartitions) merge with ``system.counters`` (function_evaluations, factorizations,
       newton_iterations, ...) in :meth:`all_counters`.
    """

    name = ""
    description = ""
    order = 0
    tolerance_exponent = 1.0
    adaptive = True
    formulation = ""

    pi_beta = 0.04  # step-size controller memory (Hairer's DOPRI5/DOP853 default)

    TOO_SMALL_STEP = "step size fell below h_min"

    def __init__(self, system, t0, q0, qd0, t_bound, options=None):
        opt = dict(options or {})
        self.system = system
        self.t = float(t0)
        self.t_old = None
        self.t_bound = float(t_bound)
        self.q = np.array(q0, dtype=float)
        self.qd = np.array(qd0, dtype=float)
        self.w = 0.0
        self.rtol = float(opt.get("rtol", 1e-6))
        self.atol = float(opt.get("atol", 1e-8))
        self.h_fixed = opt.get("h")
        self.h_fixed = None if self.h_fixed is None else float(self.h_fixed)
        self.h_max = float(opt.get("h_max") or np.inf)
        # default: steps below 1e-12 of the span mean a singularity, not accuracy
        self.h_min = float(opt.get("h_min") or 1e-12 * max(1.0, abs(self.t_bound - self.t)))
        self.h0 = opt.get("h0")
        self.h_last = 0.0
        self.options = opt
        self.status = "running"
        self._err_old = 1e-4
        self.counters = {"steps": 0, "rejected_steps": 0}
        self._tiny_steps = 0
        # the end time of every accepted step, when the caller sets a list here (the run's
        # mesh, for the coarse error estimate); None: not recorded
        self.step_ends = None

    @classmethod
    def error_ratio(cls, rtol, rtol_other):
        """err(rtol_other) / err(rtol) of two adaptive runs (same model, atol / rtol alike):
        (rtol_other / rtol)^kappa.  A family whose exponent depends on rtol overrides it."""
        return (float(rtol_other) / float(rtol)) ** cls.tolerance_exponent

    @classmethod
    def rtol_for_error_ratio(cls, rtol, ratio):
        """The rtol whose error is ``ratio`` (< 1) times the error at ``rtol``: the inverse
        of :meth:`error_ratio` (closed form for a constant kappa, else bisection in log
        rtol: error_ratio increases with rtol_other)."""
        if cls.error_ratio.__func__ is Integrator.error_ratio.__func__:
            return float(rtol) * ratio ** (1.0 / cls.tolerance_exponent)
        lo, hi = np.log(float(rtol)) - 60.0, np.log(float(rtol))
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            if cls.error_ratio(rtol, np.exp(mid)) > ratio:
                hi = mid
            else:
                lo = mid
        return float(np.exp(0.5 * (lo + hi)))

    # -- what the driver calls ------------------------------------------------------------
    def step(self):
        """Advance by one accepted step; returns (ok, message).

        Never raises for a numerical failure: an exception from the equations of motion
        (singular matrix, NaN, Newton failure) that a family did not turn into a rejected
        step ends here as ``(False, message)``, and so does a step loop that makes no
        progress (:meth:`_check_progress`)."""
        if self.status != "running":
            return False, "integrator is not running"
        if self.t >= self.t_bound:
            self.status = "finished"
            return True, ""
        t = self.t
        try:
            ok, message = self._step_impl()
        except NUMERICAL_ERRORS as exc:
            ok, message = self._fail(f"{type(exc).__name__}: {exc}")
        if ok:
            ok, message = self._check_progress(t)
        if not ok:
            self.status = "failed"
            return False, message
        self.t_old = t
        self.counters["steps"] += 1
        if self.step_ends is not None:
            self.step_ends.append(self.t)
        if self.t >= self.t_bound:
            self.status = "finished"
        return True, ""

    def advance(self, t_stop, max_steps=1):
        """Accepted steps until t >= t_stop, at least one and at most ``max_steps``; returns
        (ok, message) as :meth:`step`.  The outputs before t_stop lie in no step but the
        last, so the driver samples the last step only.  This default takes one step; a
        family that can take several at once overrides it (index-1: in C)."""
        return self.step()

    def dense_output_safe(self):
        """The dense output, with failures as values: ``f(t) -> (q, qd, w)`` or raises
        :class:`IntegratorFailure` with the time and the reason (a dense output may solve
        the constraints again, e.g. coordinate partitioning's Newton iteration)."""
        try:
            dense = self._dense_output_impl()
        except NUMERICAL_ERRORS as exc:
            raise IntegratorFailure(f"t = {self.t:.6g} s: dense output failed: {exc}") from exc

        def out(t):
            try:
                q, qd, w = dense(t)
            except NUMERICAL_ERRORS as exc:
                raise IntegratorFailure(
                    f"t = {t:.6g} s: dense output failed: {exc}") from exc
            if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd))):
                raise IntegratorFailure(f"t = {t:.6g} s: the state is not finite (NaN or inf)")
            return q, qd, w

        return out

    def _check_progress(self, t_before):
        """Stall watchdog: fail instead of crawling.  A step loop stalls when accepted steps
        become negligible against t (below ``STALL_FLOOR`` x max(1, |t|), ``STALL_STEPS`` in
        a row) or when the state stops being finite; rejected trials in a row are bounded
        by the families themselves (``MAX_REJECTS``)."""
        h = self.t - t_before
        if not (np.isfinite(self.t) and np.all(np.isfinite(self.q))
                and np.all(np.isfinite(self.qd))):
            return self._fail("the state is not finite (NaN or inf) after a step")
        if h < STALL_FLOOR * max(1.0, abs(self.t)) and self.t < self.t_bound:
            self._tiny_steps += 1
            if self._tiny_steps >= STALL_STEPS:
                return self._fail(
                    f"no progress: {STALL_STEPS} accepted steps in a row below "
                    f"{STALL_FLOOR:g} x max(1, |t|) (last step {h:.3g} s)")
        else:
            self._tiny_steps = 0
        return True, ""

    def dense_output(self):
        return self._dense_output_impl()

    def set_work(self, w):
        """Continue the integrated power ``w`` of a run restarted with this integrator (a
        change of rows or of modes): the run's work monitor goes on from there."""
        self.w = float(w)

    def dense_output_many(self, times):
        """(Q (k, nq), QD (k, nq), W (k,)): the state at each of ``times`` (ascending, in
        the last step [t_old, t]; at t itself the accepted state), failures as
        :class:`IntegratorFailure` (as :meth:`dense_output_safe`) carrying the outputs
        before the failed one (``done``).  Families that can
        evaluate all outputs of a step at once override it (index-1: in C)."""
        times = np.asarray(times, dtype=float)
        k = times.size
        Q, QD, W = np.empty((k, self.q.size)), np.empty((k, self.q.size)), np.empty(k)
        try:
            dense = self.dense_output_safe() if np.any(times != self.t) else None
            for i, t in enumerate(times):
                Q[i], QD[i], W[i] = (self.q, self.qd, self.w) if t == self.t else dense(t)
        except IntegratorFailure as exc:
            exc.done = (Q[:i], QD[:i], W[:i]) if dense is not None else None
            raise
        return Q, QD, W

    def _redo_flagged(self, times, Q, QD, W, flags):
        """The outputs of a compiled dense output completed: those ``flags`` marks taken by
        :meth:`dense_output_safe` (a family's Python dense output with its fallbacks), then
        every row checked finite; failures as :class:`IntegratorFailure` carrying the
        outputs before the failed one.  Returns (Q, QD, W)."""
        redo = np.flatnonzero(flags)
        dense = self.dense_output_safe() if redo.size else None
        for i in redo:  # (one Python dense output: the outputs integrated to share a start)
            try:
                Q[i], QD[i], W[i] = dense(times[i])
            except IntegratorFailure as exc:
                exc.done = (Q[:i], QD[:i], W[:i])
                raise
        if not (np.isfinite(Q).all() and np.isfinite(QD).all()):
            i = int(np.argmin(np.isfinite(Q).all(axis=1) & np.isfinite(QD).all(axis=1)))
            raise IntegratorFailure(f"t = {times[i]:.6g} s: the state is not finite "
                                    f"(NaN or inf)", done=(Q[:i], QD[:i], W[:i]))
        return Q, QD, W

    def all_counters(self) -> dict:
        out = dict(self.system.counters)
        out.update(self.counters)
        return out

    # -- helpers for subclasses ------------------------------------------------------------
    def _min_step(self):
        return max(self.h_min, 10 * abs(np.nextafter(self.t, np.inf) - self.t))

    def _clip(self, h):
        """A trial step: at most h_max, ending exactly at t_bound when close to it."""
        h = min(h, self.h_max, self.t_bound - self.t)
        if self.t_bound - (self.t + h) < 1e-12 * max(1.0, abs(self.t_bound)):
            h = self.t_bound - self.t
        return h

    def _step_factor(self, err, exponent, rejected):
        """Step-size factor from the scaled error norm err (<= 1 accepted) and the exponent
        -1/k (k: order of the error estimate + 1), with Hairer's stabilised (PI) controller
        of DOPRI5/DOP853: h_new = h safety err^(-1/k + 0.75 beta) err_old^beta."""
        beta = self.pi_beta
        if err <= 1:
            e = max(err, 1e-10)
            factor = SAFETY * e ** (exponent + 0.75 * beta) * self._err_old ** beta
            factor = min(MAX_FACTOR, factor)
            if rejected:
                factor = min(1.0, factor)
            self._err_old = max(err, 1e-4)
        else:
            factor = max(MIN_FACTOR, SAFETY * err ** (exponent + 0.75 * beta))
        return factor

    def _fail(self, message):
        return False, f"t = {self.t:.6g} s: {message}"

    @abstractmethod
    def _step_impl(self):
        """One step (contract above): returns (ok, message)."""

    @abstractmethod
    def _dense_output_impl(self):
        """Interpolant of the last step (contract above)."""


def rms_norm(x, scale) -> float:
    """Scaled RMS norm sqrt(mean((x/scale)^2)) (Hairer, Norsett & Wanner eq. II.4.11)."""
    z = x / scale
    return float(np.sqrt(np.dot(z, z) / max(1, z.size)))


def hermite(t0, t1, y0, y1, f0, f1):
    """Cubic Hermite interpolant on [t0, t1] from values y and slopes f; returns g(t)."""
    h = t1 - t0

    def g(t):
        x = (t - t0) / h
        h00 = (1 + 2 * x) * (1 - x) ** 2
        h10 = x * (1 - x) ** 2
        h01 = x * x * (3 - 2 * x)
        h11 = x * x * (x - 1)
        return h00 * y0 + h10 * h * f0 + h01 * y1 + h11 * h * f1

    return g


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
