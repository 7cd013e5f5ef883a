"""Implicit index-3 generalized-alpha (Arnold & Bruls 2007, "Convergence of the
generalized-alpha scheme for constrained mechanical systems", Multibody Syst. Dyn. 18).

Step n -> n+1 with the acceleration-like variable a:

    q1  = q + h qd + h^2 (1/2 - beta) a + h^2 beta a1
    qd1 = qd + h (1 - gam) a + h gam a1
    (1 - am) a1 + am a = (1 - af) qdd1 + af qdd
    M(q1) qdd1 + Phi_q(q1)^T lam1 = Q(q1, qd1, t1),   Phi(q1, t1) = 0   (index 3)

solved for (q1, lam1) by Newton with the iteration matrix (scaled by 1/beta'):

    [ M + gam'/beta' C + K/beta'   Phi_q^T ] [dq ]   [ -r / beta' ]
    [ Phi_q                        0       ] [dmu] = [ -Phi       ],   lam += beta' dmu

beta' = (1 - am) / (beta h^2 (1 - af)), gam' = gam / (beta h); K = dr/dq, C = dr/dqd of the
residual r = M qdd + Phi_q^T lam - Q by finite differences (``jacobian: fd``, the default up
to ``FD_MAX_NQ`` coordinates: stiff springs, small inertias under large reactions), refreshed
when Newton stalls; ``jacobian: none`` keeps the simplified matrix [M, Phi_q^T; Phi_q, 0].
The Euler-parameter normalisation rows are part of Phi, so |p| = 1 at every step.

Local error estimate: q1 minus its cubic Hermite extrapolation from the last two accepted
states (a predictor of order 3, so the difference is the O(h^3) local error of the
corrector), controlled with the exponent -1/3.  q and qd are smooth where the accelerations
of an index-3 scheme oscillate along the constraint normals, which makes qdd-based
estimates (Zienkiewicz & Xie 1991) unusable here.  HHT-alpha is the member am = 0, af = alpha.

Tolerance proportionality.  Held to the tolerances per step (local error h^3 ~ tol), an
order-2 method takes steps h ~ tol^(1/3) and ends with a global error ~ h^2 ~ tol^(2/3)
(measured on Andrews' squeezer, rtol = atol 3e-11 -> 3e-12: the largest error over the run
falls 4.4-4.5x, 10^(2/3) = 4.6).  Below ``REFERENCE_RTOL`` the local error is therefore
held to f x (atol + rtol |q|) with f = (rtol / REFERENCE_RTOL)^(1/2) (:meth:`tolerance_factor`):
the local tolerance ~ rtol^(3/2), h ~ rtol^(1/2), the global error ~ rtol, at about
(REFERENCE_RTOL / rtol)^(1/6) the steps of per-step control (4.6x at rtol 1e-10).  At and
above REFERENCE_RTOL (the default rtol) nothing changes, so runs at the usual tolerances
keep their cost and results.  The limit is round-off: the tightened atol stops at
NOISE_MARGIN x the round-off of q (:meth:`__init__`) and, where a step's estimate exceeds
the tolerance, the tightened tolerance stops at that step's round-off floor
(:meth:`_noise_floor`: large near a singular position); below that the estimate measures
noise, and with atol at 1e-13 f = 3e-16 m Andrews' squeezer at rtol 1e-11 rejected 6359
steps and ended 4.8e-9 m off.  Measured on Andrews' squeezer (benchmarks/andrews.py):
error 3.5e-11 m at rtol 1e-10 (before 5.6e-10), 3.7e-11 m at rtol = atol = 3e-11 (before
9.0e-10), at 4.6x and 5.7x the steps.  Variable steps: the acceleration-like a_n
approximates qdd(t_n + (am - af) h_n), an offset proportional to the step that made it, so
a step h after a step h_last first rescales that offset to h (:meth:`_shifted_a`); without
it every change of step size left an error of order |h - h_last| h^2 qddd in q that the
local error estimate does not see, and below rtol 1e-10 (where the controller changes h at
every step by small factors over 1e5-2.5e5 steps) the error stopped falling: HHT on
Andrews' squeezer ended 2.27e-10 m off at rtol 1e-11 (largest along the run 2.65e-10 m),
worse than a uniform grid of as many steps (1.10e-10 m); with it 1.7e-11 m (largest 5.5e-11
m) at the same 249827 steps (benchmarks/andrews.py --integrators hht --settings
1e-10,1e-11 --along 30 --fixed).
"""

from __future__ import annotations

import numpy as np

from mbsim.fast.implicit import CompiledNewton
from mbsim.integrators.base import (
    MAX_REJECTS,
    ROUNDOFF_ULPS,
    Integrator,
    IntegratorFailure,
    hermite,
    rms_norm,
)

# relative regularisation of the Newton matrix's zero block, eps = KKT_REG |Phi_q|^2 / |A|: near
# a change point of the mechanism (kept rows nearly dependent) the plain matrix is
# numerically singular and the iteration stalled (issue 11); only the iteration matrix
# changes, never the residual, so the converged step is the same (mbsim/fast/implicit.c)
KKT_REG = 1e-10
REFERENCE_RTOL = 1e-6  # below it the local tolerance shrinks as rtol^(3/2) (module doc)
NOISE_MARGIN = 10.0  # the tightened atol: not below this x the round-off of q (module doc)


class GeneralizedAlpha(Integrator):
    name = "genalpha"
    description = ("implicit index-3 generalized-alpha (Arnold-Bruls), rho_inf = 0.8, "
                   "Newton on (q, lam), error-controlled step")
    order = 2
    # below REFERENCE_RTOL the local tolerance is rtol^(3/2) / REFERENCE_RTOL^(1/2) and the
    # global error ~ rtol (module doc); at and above it the error per step is held to the
    # tolerances and the global error grows as rtol^(2/3) (PER_STEP_EXPONENT; error / rtol
    # 44 -> 536 from rtol 1e-6 to 1e-10 on the slider-crank before the change)
    tolerance_exponent = 1.0
    PER_STEP_EXPONENT = 2.0 / 3.0
    formulation = "index-3"
    rho_inf = 0.8
    max_newton = 10
    pi_beta = 0.1
    FD_MAX_NQ = 200  # finite-difference tangent up to this many coordinates (2 nq residuals)

    @classmethod
    def tolerance_factor(cls, rtol):
        """f: a step's local error is held to f (atol + rtol |q|) (module doc):
        (rtol / REFERENCE_RTOL)^(1/2) below REFERENCE_RTOL, 1 at and above it."""
        return float(np.sqrt(min(1.0, max(float(rtol), 0.0) / REFERENCE_RTOL)))

    @classmethod
    def error_ratio(cls, rtol, rtol_other):
        """err(rtol_other) / err(rtol): the global error ~ (rtol f(rtol))^(2/3), the
        internal tolerance to the power PER_STEP_EXPONENT (so ~ rtol below
        REFERENCE_RTOL, ~ rtol^(2/3) above it)."""
        def internal(r):
            return float(r) * cls.tolerance_factor(r)

        return (internal(rtol_other) / internal(rtol)) ** cls.PER_STEP_EXPONENT

    @classmethod
    def coefficients(cls, rho):
        """(am, af, gamma, beta) of Chung & Hulbert (1993) for spectral radius rho."""
        am = (2 * rho - 1) / (rho + 1)
        af = rho / (rho + 1)
        gam = 0.5 + af - am
        return am, af, gam, 0.25 * (gam + 0.5) ** 2

    def __init__(self, system, t0, q0, qd0, t_bound, options=None):
        super().__init__(system, t0, q0, qd0, t_bound, options)
        s = system
        self.coef = self.coefficients(float(self.options.get("rho_inf", self.rho_inf)))
        self.qdd, self.lam, self.power = s.accelerations(self.q, self.qd, self.t)
        self._mscale = self._mass_scale(s.mass_blocks(self.q))  # round-off test of Newton
        self.a = self.qdd.copy()
        jac = self.options.get("jacobian", "auto")
        self.use_fd = (jac == "fd") or (jac == "auto" and s.nq <= self.FD_MAX_NQ)
        # (t, q, qd, qdd, lam, K, C): the first tangent of this run, and the one another run
        # of the same system offers for the same start (:meth:`offer_tangent`)
        self.first_tangent = None
        self._offered = None
        self.counters["jacobian_evaluations"] = 0
        self.newton_tol = float(self.options.get("newton_tol", 1e-3))
        # stop Newton on its remaining error, not on its last correction (the coarse
        # companion of the error estimate: :meth:`_newton`)
        self.newton_contraction = bool(self.options.get("newton_contraction", False))
        self._core = CompiledNewton(
            s, self.coef, rtol=self.rtol, atol=self.atol, newton_tol=self.newton_tol,
            contraction=self.newton_contraction, max_newton=self.max_newton,
            kkt_reg=KKT_REG, roundoff=ROUNDOFF_ULPS * np.finfo(float).eps,
            mscale=self._mscale)
        # the tolerances a step is held to: f (atol, rtol) (module doc)
        self.tol_factor = f = self.tolerance_factor(self.rtol)
        # the tightened atol stops at NOISE_MARGIN x the round-off of q (ROUNDOFF_ULPS ulp of
        # max(1, |q|), the Newton test's): coordinates that stay at zero (a planar
        # mechanism's z, p1, p2) carry only that noise, and a smaller atol made it decide
        # the steps (Andrews at rtol 1e-11: 6359 rejected steps, error 4.8e-9 m)
        noise = NOISE_MARGIN * ROUNDOFF_ULPS * np.finfo(float).eps * max(
            1.0, np.abs(self.q).max(initial=0.0))
        self.atol_step = min(self.atol, max(f * self.atol, noise))
        self.rtol_step = f * self.rtol
        if self.h_fixed is not None:
            self.h_abs = self.h_fixed
        elif self.h0 is not None:
            self.h_abs = float(self.h0)
        else:  # second-order start: h^2 |qdd| ~ tolerance
            scale = self.atol_step + self.rtol_step * np.abs(self.q)
            d = rms_norm(self.qdd, scale)
            self.h_abs = min(self.h_max, 0.1 * (t_bound - t0), np.sqrt(1.0 / max(d, 1e-12)))
        self._dense = None
        self._rng = np.random.default_rng(0)  # signs of the round-off probe (reproducible)
        self._prev = None  # (t, q, qd) of the accepted state before the current one

    # -- the Newton iteration (mbsim/fast/implicit.c) ----------------------------------------
    def offer_tangent(self, tangent):
        """Take ``tangent`` (another run's :attr:`first_tangent`, None: nothing) as this
        run's first tangent where it was computed at this run's first state.

        K and C are a function of (q, qd, qdd, lam, t) and the system only (forward
        differences with steps fixed by q and qd), so at equal inputs on the same system
        they are the same to the bit: the error estimate's coarse companion, which starts
        where the run started (mbsim.analyses.estimate.coarse_estimate), takes the run's
        instead of repeating its 2 nq residual evaluations.  The caller shares the system
        (no hybrid elements or multiplier-dependent loads: their loads depend on more
        than the state); the inputs are compared here."""
        self._offered = tangent

    def _tangent(self, q, qd, qdd, lam, t):
        """K = dr/dq, C = dr/dqd of the residual r = M qdd + Phi_q^T lam - Q by forward
        differences (non-ground coordinates; implicit.c); the first one kept as
        :attr:`first_tangent`, or taken from :meth:`offer_tangent`."""
        key = (t, q, qd, qdd, lam)
        if self.first_tangent is None:
            given = self._offered
            self._offered = None
            if given is not None and given[0] == t and all(
                    np.array_equal(a, b) for a, b in zip(given[1:5], key[1:])):
                self.first_tangent = given
                return given[5], given[6]
            K, C = self._tangent_fd(q, qd, qdd, lam, t)
            self.first_tangent = (t, q.copy(), qd.copy(), qdd.copy(), lam.copy(), K, C)
            return K, C
        return self._tangent_fd(q, qd, qdd, lam, t)

    def _tangent_fd(self, q, qd, qdd, lam, t):
        K, C = self._core.tangent(t, q, qd, qdd, lam)
        self.counters["jacobian_evaluations"] += self._core.jacobian_evaluations
        return K, C

    @property
    def KC(self):
        """(K, C) the finite-difference residual Jacobians in the iteration matrix, or None
        (kept by the compiled iteration, which reads them)."""
        return self._core.KC

    def _set_tangent(self, KC):
        self._core.set_tangent(KC)

    def _newton(self, h, shift=True):
        """(q, qd, qdd, lam, a1, power) of the step h, or None where Newton fails
        (mbsim/fast/implicit.c: mb_ga_newton; tests/reference/genalpha_newton.py is the
        same iteration in numpy).

        Newton on (q, lam) from the predictor of the step equations (module doc), with the
        iteration matrix factored at every iterate.  Stopping tests on the scaled correction
        err_k = |dq_k| (rms over atol + rtol |q|): err_k <= newton_tol, the run's test; with
        ``newton_contraction`` (the option the coarse companion of the error estimate sets,
        mbsim.analyses.estimate.CoarseStepper) also the remaining error bound theta/(1 -
        theta) err_k <= newton_tol, theta = err_k / err_(k-1) the observed contraction
        (Hairer & Wanner II, Sec. IV.8, eq. (8.10)).  The first bounds the error before the
        last correction, the second the error after it: the same tolerance on what is left.
        Measured on the vehicle's companion (steps of 2 h): err_1 median 2e-3 above
        newton_tol in 19 of 29 steps, where err_2 was <= 5e-6; the run's own steps meet
        err_1 <= newton_tol.  Two more stops, for round-off: both residuals (|Phi| and the
        coordinate change r / (beta' M) the dynamic residual implies) at the round-off of q
        (near a singular position the corrections dq ~ eps / sigma_min(Phi_q) are noise and
        never meet the test on dq, issue 11); and corrections at 64 ulp of q.  Not
        contracting by 0.9 from the third iterate on, or no stop in ``max_newton``: None."""
        a = self._shifted_a(h) if shift else self.a
        return self._core.newton(self.t + h, h, self.q, self.qd, self.qdd, a, self.lam)

    def _shifted_a(self, h):
        """(nq,) the acceleration-like variable for a step h after a step h_last.

        a_n = qdd(t_n + (am - af) h_last) + O(h^2) (Arnold & Bruls 2007): its offset from
        qdd_n is proportional to the step that made it, and the step equations assume the
        offset of the step they take.  After a change of step size the offset is rescaled
        to h: a = qdd_n + (a_n - qdd_n) h / h_last (a_n - qdd_n = (am - af) h_last qddd +
        O(h^2)); unchanged at a fixed step.  Without it each change of h costs an error of
        order |h - h_last| h^2 qddd in q that the local error estimate does not see (module
        doc).  Steps of a prescribed mesh (``h_fixed``: the fixed-step runs, the coarse
        companion of the error estimate, whose mesh takes every other step of the run) keep
        a_n as they are: there the rescaled offset carried the index-3 oscillation of a_n
        into the predictor and the slider-crank's coarse companion at rtol 1e-3 stopped
        (Newton at h = 0.0185 s).  So does the retry of a rejected step (``_newton``'s
        ``shift``): the rescale mixes qdd_n into the predictor, and next to a singular
        position qdd_n carries the Newton's round-off eps / sigma_min(Phi_q), which a
        rejection there is a sign of (under OpenBLAS Prescott genalpha on the four cranks
        at rtol 1e-10 cut its retries to h_min at the first flat position)."""
        if self.h_fixed is not None or not self.h_last or h == self.h_last:
            return self.a
        return self.qdd + (self.a - self.qdd) * (h / self.h_last)

    @staticmethod
    def _mass_scale(Mb):
        """(nq,) the size of M per coordinate: each body's mass on its r, and the Frobenius
        norm of its rotational block 4 G^T J' G on its p (= 4 |J'|_F for |p| = 1, whatever
        the orientation; the block is singular along p, its rows can vanish)."""
        m_tr = np.abs(Mb[:, :3, :3]).max(axis=(1, 2))
        m_rot = np.sqrt((Mb[:, 3:, 3:] ** 2).sum(axis=(1, 2)))
        return np.repeat(np.stack([m_tr, m_rot], axis=1), [3, 4], axis=1).reshape(-1)

    def _step_impl(self):
        rejected = False
        refreshed = False
        h_abs = self.h_abs
        am, af, gam, beta = self.coef
        rejects = 0
        why = ""  # what cut the step in this call: said only where it was seen
        while True:
            h = self._clip(h_abs)
            if not np.isfinite(h):
                return self._fail(f"step size is not finite ({h})")
            if h < self._min_step() and h < self.t_bound - self.t:
                since = (f"after a step of {self.h_last:.3g} s" if self.h_last else
                         "the first of a start or restart (as after an event)")
                return self._fail(f"{self.TOO_SMALL_STEP} ({h:.3g} s): " + (
                    why or f"the step proposed at t = {self.t:.12g} s, {since}, is below it "
                    f"before any trial"))
            if rejects >= MAX_REJECTS:
                return self._fail(f"no progress: {rejects} rejected steps in a row "
                                  f"(step {h:.3g} s)")
            rejects += 1
            if self.use_fd and self.KC is None:
                self._set_tangent(self._tangent(self.q, self.qd, self.qdd, self.lam, self.t))
            res = self._newton(h, shift=not rejected)
            if res is None:
                why = "Newton iteration of the implicit step does not converge"
                self.counters["rejected_steps"] += 1
                if self.use_fd and not refreshed:
                    self._set_tangent(self._tangent(self.q, self.qd, self.qdd, self.lam, self.t))
                    refreshed = True
                    continue
                if self.h_fixed is not None:
                    return self._fail(f"Newton iteration of the implicit step (h = {h:.3g} s) "
                                      f"does not converge")
                h_abs = 0.25 * h
                rejected = True
                continue
            q, qd, qdd, lam, a1, power = res
            if self.h_fixed is not None:
                h_next = self.h_fixed
                break
            est = q - self._predict(self.t + h)
            qmax = np.maximum(np.abs(q), np.abs(self.q))
            given = self.atol + self.rtol * qmax
            scale = self.atol_step + self.rtol_step * qmax
            err = rms_norm(est, scale)
            if not np.isfinite(err):
                err = 1e10  # NaN/inf in the step: reject hard
            elif err > 1:
                # a tolerance below what the constraint solve can attain here (near a singular
                # position) is met at that attainable level instead of cutting h to h_min
                floor = self._noise_floor(q, h)
                if floor is not None and self.tol_factor < 1.0:
                    # the tightened tolerance stops at the step's round-off floor (and at the
                    # given tolerances): below it the estimate measures noise.  (10 x the
                    # floor here took Andrews at rtol 1e-10 from 5.1e-11 to 6.4e-10 m)
                    scale = np.minimum(given, np.maximum(scale, floor))
                    err = rms_norm(est, scale)
                if floor is not None and err > 1:
                    e2 = rms_norm(np.maximum(np.abs(est) - floor, 0.0), scale)
                    if e2 <= 1:
                        err = e2
                        self.counters["noise_limited_steps"] = (
                            self.counters.get("noise_limited_steps", 0) + 1)
            factor = self._step_factor(err, -1.0 / 3.0, rejected)
            h_next = h * factor
            if err <= 1:
                break
            h_abs = h_next
            rejected = True
            why = f"the local error estimate stays above the tolerance ({err:.3g} x it)"
            self.counters["rejected_steps"] += 1
        t0 = self.t
        self._prev = (t0, self.q, self.qd)
        self._dense = (t0, t0 + h, self.q, q, self.qd, qd, self.qdd, qdd, self.w)
        self.w += 0.5 * h * (self.power + power)
        self.t, self.q, self.qd, self.qdd, self.lam, self.a = t0 + h, q, qd, qdd, lam, a1
        self.power, self.h_last, self.h_abs = power, h, h_next
        return True, ""

    def _noise_floor(self, q, h):
        """(nq,) the part of the local error estimate that round-off alone makes: the
        corrections dq that Phi's round-off (the level the Newton iteration's round-off test
        accepts, ROUNDOFF_ULPS; random signs, two draws) produces through the last Newton
        matrix, times the weights with which the estimate q1 - p(t1)
        takes it from q1 and from the two previous states (Hermite extrapolation: their q
        and their qd, whose noise is gam/(beta h) dq).  Near a singular position
        (sigma_min(Phi_q) -> 0) it grows as eps / sigma_min; elsewhere it is ~ulp of q."""
        if not self._core.factored:
            return None
        solve = self._core.solve
        s = self.system
        n, m = s.nq, s.m
        if m == 0:
            return None
        rng = self._rng
        rhs = np.zeros((n + m, 2))
        rhs[n:] = (ROUNDOFF_ULPS * np.finfo(float).eps * max(1.0, np.abs(q).max())
                   * rng.choice([-1.0, 1.0], size=(m, 2)))
        dq = np.abs(np.asarray(solve(rhs))[:n]).max(axis=1)
        if not np.all(np.isfinite(dq)):
            return None
        am, af, gam, beta = self.coef
        if self._prev is None:
            weight = 1.0 + gam / beta  # q1 and the previous state's qd
        else:
            tp = self._prev[0]
            x = (self.t + h - tp) / (self.t - tp)
            w = np.array([(1 + 2 * x) * (1 - x) ** 2, x * x * (3 - 2 * x)])  # q_prev, q
            v = np.array([x * (1 - x) ** 2, x * x * (x - 1)]) * gam / beta  # their qd
            weight = float(np.sqrt(1.0 + np.sum(w * w) + np.sum(v * v)))
        return weight * dq

    def _predict(self, t):
        """q(t) extrapolated: cubic Hermite through the last two accepted states, or the
        Taylor polynomial q + tau qd + tau^2/2 qdd before the second step."""
        if self._prev is None:
            tau = t - self.t
            return self.q + tau * self.qd + (0.5 * tau * tau) * self.qdd
        tp, qp, vp = self._prev
        return hermite(tp, self.t, qp, self.q, vp, self.qd)(t)

    def dense_output_many(self, times):
        """(Q (k, nq), QD (k, nq), W (k,)) at all of ``times`` in the last step at once:
        :meth:`_dense_output_impl`'s cubic Hermite polynomials at all the times together
        (one product of the (k, 4) weights with the step's end values), the accepted
        state at t itself, and the failure of :meth:`Integrator.dense_output_many` at the
        first output whose state is not finite (the outputs before it kept)."""
        times = np.asarray(times, dtype=float)
        if self._dense is None or times.ndim != 1:
            return super().dense_output_many(times)
        Q, QD, W = self._dense_output_impl()(times)
        if times.size and times[-1] == self.t:  # (ascending: only the last ones can be t)
            at_end = times == self.t
            Q[at_end], QD[at_end], W[at_end] = self.q, self.qd, self.w
        if not (np.isfinite(Q).all() and np.isfinite(QD).all()):
            bad = ~(np.isfinite(Q).all(axis=1) & np.isfinite(QD).all(axis=1))
            i = int(np.argmax(bad))
            raise IntegratorFailure(
                f"t = {times[i]:.6g} s: the state is not finite (NaN or inf)",
                (Q[:i], QD[:i], W[:i]))
        return Q, QD, W

    def _dense_output_impl(self):
        """``f(t) -> (q, qd, w)`` over the last step: cubic Hermite interpolation of q from
        (q, qd) and of qd from (qd, qdd) at both ends (:func:`~mbsim.integrators.base.hermite`),
        w linear; t a time (results (nq,)) or a 1-D array or column of k times (results
        (k, nq)): the weights (k, 4) times the end values (4, nq), one product for all the
        step's outputs (to a few ulp of hermite's sum of four products)."""
        t0, t1, q0, q1, v0, v1, a0, a1, w0 = self._dense
        h = t1 - t0
        ends = np.stack([q0, v0, q1, v1, v0, a0, v1, a1]).reshape(2, 4, -1)
        w1 = self.w

        def out(t):
            t = np.asarray(t, dtype=float)
            x = ((t.reshape(-1) if t.ndim == 2 else t) - t0) / h
            xm = 1.0 - x
            wq = np.stack([(1.0 + 2.0 * x) * xm * xm, h * x * xm * xm, x * x * (3.0 - 2.0 * x),
                           h * x * x * (x - 1.0)], axis=-1)  # h00, h h10, h01, h h11
            return wq @ ends[0], wq @ ends[1], xm * w0 + x * w1

        return out


class HHT(GeneralizedAlpha):
    name = "hht"
    description = ("implicit index-3 HHT-alpha (generalized-alpha with am = 0), "
                   "rho_inf = 0.8, error-controlled step")

    @classmethod
    def coefficients(cls, rho):
        """HHT (Hilber, Hughes & Taylor 1977): alpha = (1 - rho)/(1 + rho) in [0, 1/3]."""
        alpha = min(1.0 / 3.0, max(0.0, (1 - rho) / (1 + rho)))
        gam = 0.5 + alpha
        return 0.0, alpha, gam, 0.25 * (1 + alpha) ** 2
