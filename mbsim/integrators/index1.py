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

Near a change point (the flat position of a parallelogram linkage, where the active rows
lose rank) the accelerations of the Schur complement S = Phi_q M^-1 Phi_q^T go wrong: a
stage off the constraints by delta gets an acceleration error ~ delta / sigma_min along the
other branch's direction, and the pivot floor that bounds it (kernels.c) biases the
multiplier there by ~ sigma_min |lam|.  The kernels report the smallest Schur pivot ratio of
every solve (System.pivot_ratio), whose square root is the change-point measure s of
:mod:`mbsim.integrators.changepoints`; a trial step with a stage below the policy's switch
(``Policy.tangent``) is taken again from its start (outside the region: continuity picks the
branch) with every stage in tangent coordinates: the stage's (q, qd) completed onto the
constraints at fixed v = C q, vd = C qd, the accelerations from the reduced equations (no
Schur complement), the error test on (C q, C qd), the step's end and the dense outputs put
on the constraints the same way; the next accepted state above the switch ends it (counter
``tangent_stages``).  A model whose measure is below the switch at the start (its scaling,
or a start at the change point) and one without an M-orthogonal tangent map keep the Schur
path; so does ``drift_bound: false``.

In the region the error test sees round-off, not truncation error, in two places, and the
policy takes each off: the completed stage velocities carry round-off that grows as s falls,
which the full-q part of the error test would read as error, so that part is left out once
a passage's steps are cut below ``Policy.cut`` x its first tangent step (an embedded
estimate of truncation error falls like h^k: what still cuts the step is the round-off;
:meth:`Index1._error_norm`); and where the motion dwells next to the point without crossing
it, the error test takes off what the stages' round-off alone makes, probed by two
completions from q perturbed by ROUNDOFF_ULPS ulps (:meth:`Index1._stage_noise`).  A motion
that approaches the point slowly is given a step across it that keeps its stages clear of
it (:class:`changepoints.Approach`; counter ``straddle_steps``); so is a tangent step that
crosses the point with a stage whose round-off, which its error test cannot see, exceeds
the tolerance (:meth:`Index1._clear_crossing`; the same counter).

Option ``tangent_steps`` (default true; false keeps the Schur path everywhere).  Every
threshold of these rules is the policy's (:class:`changepoints.Policy`, which derives each);
their effect is measured in docs/benchmarks.md (python benchmarks/singular_loops.py,
benchmarks/dead_centre.py).
"""

from __future__ import annotations

import ctypes

import numpy as np

from mbsim.fast import stepper
from mbsim.integrators import base
from mbsim.integrators import changepoints as cp
from mbsim.integrators.base import (
    NUMERICAL_ERRORS,
    ROUNDOFF_ULPS,
    quintic_hermite,
    rms_norm,
)
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
        # the change-point policy (changepoints.Policy; module doc: ``tangent_steps``)
        self.policy = cp.Policy.for_run("index-1", self.rtol, self.atol, self.h_fixed is not None,
                                        bool(self.options.get("tangent_steps", True)),
                                        exponent=self.error_exponent, n=n)
        self.newton_tol = float(self.options.get("newton_tol", self.policy.newton_tol))
        self.counters["tangent_stages"] = 0
        self.counters["noise_limited_steps"] = 0
        self._rng = np.random.default_rng(0)  # signs of the round-off probe (reproducible)
        # ... and of _clear_crossing's probe, apart: the error test's draws stay its own
        self._clear_rng = np.random.default_rng(1)
        self._s = 1.0  # the change-point measure at the latest stage (from its Schur factor)
        self._C = None  # tangent map C (k, nq) of the latest tangent-coordinate step
        self._step_start = (t0, self.q)  # (t, q) at the start of the current step
        self._tangent = False  # the steps' stages are in tangent coordinates
        self._step_tangent = False  # ... the last accepted step's were (dense output)
        self._tangent_h0 = None  # the first tangent step of the passage (_error_norm)
        self._tangent_wanted = False  # a stage of the failed trial was in the region
        self._in_trial = False
        self._trial_s = np.inf
        self._stage_s = []  # the measure at the trial's stages 1.. and its end, in order
        self._v_scale = None  # the error test's scale of (v, vd) in the last tangent trial
        self._h_clear = None  # the step to try next, clear of a crossing (_clear_crossing)
        self._cleared = False  # the current step was moved clear of a crossing
        # the approach to a change point and the step across it (changepoints.Approach)
        self.counters["straddle_steps"] = 0
        self._approach = None
        if self.policy.tangent > 0.0:
            # a measure already below the switch at the start: a switch below it, or none
            # at a start next to the change point (changepoints.Policy.at_start)
            system.accelerations(self.q, self.qd, self.t, self.stab)
            self.policy = self.policy.at_start(cp.measure_from_schur(system.pivot_ratio),
                                               self.rtol)
        if self.policy.tangent > 0.0:
            self._approach = self._new_approach()
        self._compiled = self._compiled_step()
        self._ends_buffer = np.empty(0)  # advance: the C loop's step ends
        self._ends_pointer = None  # (its address, made with the buffer: data_as costs us)
        self._c_last = False  # the last accepted step was taken in C (its buffers hold it)
        self._start()

    def _compiled_step(self):
        """The trial step and dense output in C (:mod:`mbsim.fast.stepper`) for a tableau
        step.c knows, unless option ``compiled_step`` is false (the Python path, the same
        arithmetic; tests/integrators/test_compiled_step.py compares the two).  The
        projection methods project in C; Baumgarte's drift test stays :meth:`_accept`.
        Loads that depend on the multipliers (System.reaction_loop) need the loop between
        solves that only the Python path has."""
        if not (self.options.get("compiled_step", True) and stepper.supports(self.tableau)
                and not self.system.reaction_loop):
            return None
        return stepper.CompiledStep(
            self.system, self.tableau, rtol=self.rtol, atol=self.atol,
            control=self.tableau.embedded and self.h_fixed is None, project=self.project,
            proj_tol=self.proj_tol, stab=self.stab)

    def _new_approach(self):
        return cp.Approach(cp.stage_times(self.tableau), self.h_fixed, self.policy)

    def _y_from_state(self):
        return np.concatenate([self.q, self.qd, [self.w]])

    def _state_from_y(self, t, y, ctx=None):
        n = self.n
        return y[:n], y[n:2 * n], float(y[-1])

    def _rhs(self, t, y, ctx=None):
        n = self.n
        q, qd = y[:n], y[n:2 * n]
        qdd, _, power = self.system.accelerations(q, qd, t, self.stab)
        self._s = s = cp.measure_from_schur(self.system.pivot_ratio)
        self._trial_s = min(self._trial_s, s)
        if self._in_trial:
            self._stage_s.append(s)
        near = s < self.policy.tangent  # (a switch of 0 is off)
        if self._tangent or (not self._in_trial and (self._step_tangent or near)):
            qd, qdd, power = self._tangent_stage(t, q, qd)
        elif near:  # a trial's stage: the step again in tangent coordinates (_recover)
            self._tangent_wanted = True
            raise StageFailure(f"t = {t:.6g} s: active rows near dependent (measure {s:.3g}); "
                               f"tangent coordinates")
        out = np.empty_like(y)
        out[:n], out[n:2 * n], out[-1] = qd, qdd, power
        return out

    def _tangent_stage(self, t, q, qd):
        """(qd, qdd, power) at the stage state (q, qd) put on the constraints in tangent
        coordinates (:meth:`_tangent_complete`), the accelerations from the reduced equations
        (mbsim.integrators.tangent)."""
        if self._C is None:  # a stage outside the trial (end of step, dense output) of a
            # step that was not in tangent coordinates: C at that step's start
            self._C = self._tangent_map(*self._step_start)
        x, qdp, fac = self._tangent_complete(t, q, qd)
        qdd, power = cp.accelerations(self.system, t, x, qdp, fac, self._C.shape[0])
        self.counters["tangent_stages"] += 1
        return qdp, qdd, power

    def _tangent_complete(self, t, q, qd):
        """(q, qd, fac) on Phi = 0, Phi_q qd = nu with the same tangent coordinates v = C q,
        vd = C qd (:func:`changepoints.complete`, as gcp's); fac the LU of A = [Phi_q; C]."""
        C = self._C
        x, qdp, fac, T = cp.complete(self.system, t, q, C @ q, C @ qd, C, self.newton_tol,
                                     self.policy.newton_iter)
        if qdp is None:
            raise StageFailure(f"t = {t:.6g} s: Newton in tangent coordinates did not "
                               f"converge (max |Phi| = {np.abs(T.phi).max():.3g})")
        return x, qdp, fac

    def _error_norm(self, h, y_new):
        """In tangent coordinates: the error of v = C q and vd = C qd (as gcp's), and the
        embedded error of the full q from the stages' completed velocities (gcp's
        _extra_error: a step that (v, vd) accepts can still be off in q across the point);
        not that of the full qd, which near the change point carries the round-off of the
        completion (~eps / sigma_min).  The q scale has a floor of the completion's Newton
        tolerance: Newton stops once a correction is below it, so the completed q is noisy
        to that much.  The policy's two round-off rules (module doc): the noise of (v, vd)
        probed and taken off (:meth:`_stage_noise`) where the norm exceeds ``noise_err``
        and no stage came below ``noise_s``; the q part left out once the passage's steps
        are cut below ``cut`` x its first tangent step."""
        if not self._tangent:
            return super()._error_norm(h, y_new)
        n, C = self.n, self._C
        K = np.hstack([self.K[:, :n] @ C.T, self.K[:, n:2 * n] @ C.T])
        y0 = np.concatenate([C @ self.y[:n], C @ self.y[n:2 * n]])
        y1 = np.concatenate([C @ y_new[:n], C @ y_new[n:2 * n]])
        scale = self.atol + self.rtol * np.maximum(np.abs(y0), np.abs(y1))
        self._v_scale = scale
        err_v = self.tableau.error_norm(K, h, scale)
        if err_v > self.policy.noise_err and self._trial_s >= self.policy.noise_s:
            # what the stages' round-off alone makes is not error (_stage_noise)
            noise = self._stage_noise(self.t + h, y_new)
            if noise is not None:
                floored = self.tableau.error_norm(K, h, scale, noise)
                if err_v > 1.0 >= floored:
                    self.counters["noise_limited_steps"] += 1
                err_v = floored
        if self._tangent_h0 is None:
            self._tangent_h0 = h
        if h < self.policy.cut * self._tangent_h0:
            return err_v
        scale_q = (self.atol + self.newton_tol
                   + self.rtol * np.maximum(np.abs(self.y[:n]), np.abs(y_new[:n])))
        return max(err_v, self.tableau.error_norm(self.K[:, :n], h, scale_q))

    def _stage_noise(self, t, y, rng=None):
        """(2k,) the round-off of a tangent stage's derivative (C qd, C qdd) at y, per
        component: the spread of C qdd between two completions from q perturbed by
        ROUNDOFF_ULPS ulps (random signs), over sqrt 2 (C qd = vd holds to round-off); None
        where a completion fails.

        Next to a change point the completed state lies on a computed constraint set
        u w = eps whose curvature grows as the point nears (changepoints.Approach), so C qdd
        carries noise ~ s^-3.  A motion that dwells there (turning just short of the point)
        meets it at every stage for as long as it dwells, and an error test that counted it
        would cut the steps for the whole turn.  The error norm therefore takes off what
        that noise alone makes (Tableau.error_norm with ``noise``; counter
        ``noise_limited_steps`` when that passes a step), as generalized-alpha's does with
        its Newton round-off.  Not where a stage of the trial came below the policy's
        ``noise_s``: there the noise is that of a crossing, unbounded, and taking it off
        would accept steps onto the other branch.  rng: the signs' generator (default the
        error test's)."""
        n, C = self.n, self._C
        q, qd = y[:n], y[n:2 * n]
        rng = self._rng if rng is None else rng
        ulp = ROUNDOFF_ULPS * np.finfo(float).eps * max(1.0, np.abs(q).max(initial=0.0))
        a = []
        try:
            for _ in range(2):
                qp = q + ulp * rng.choice([-1.0, 1.0], n)
                x, qdp, fac = self._tangent_complete(t, qp, qd)
                a.append(C @ cp.accelerations(self.system, t, x, qdp, fac, C.shape[0])[0])
        except NUMERICAL_ERRORS:
            return None
        k = C.shape[0]
        return np.concatenate([np.zeros(k), np.abs(a[0] - a[1]) / np.sqrt(2.0)])

    def _attempt(self, h):
        """The trial in C (mbsim/fast/step.c) outside tangent coordinates: stages, error
        test, projection and f at the end in one call; where a stage's measure falls below
        the policy's switch (or a Python force element raised) the trial is taken again by
        the Python path, whose policy decides (:meth:`_rhs`)."""
        self._c_last = False
        c = self._compiled
        if c is None or self._tangent:
            out = super()._attempt(h)
            if self._tangent and out[2] is not None:
                h_clear = self._clear_crossing(h, out[1])
                if h_clear is not None:  # the step again, its stages clear of the point
                    self._h_clear, self._cleared = h_clear, True
                    self.counters["straddle_steps"] += 1
                    return np.nextafter(1.0, 2.0), out[1], None, None, None, None
            return out
        t = self.t
        status = c.trial(t, h, self.y, self.f, self.policy.tangent)
        if status in (stepper.ST_ALARM, stepper.ST_CALLBACK):
            return super()._attempt(h)
        out = c.out
        self._trial_s, self._s = float(out[stepper.O_SMIN]), float(out[stepper.O_SLAST])
        err = float(out[stepper.O_ERR])
        if status == stepper.ST_SOLVE:
            raise stepper.solve_error(out[stepper.O_CODE])
        if status == stepper.ST_PROJECTION:
            raise StageFailure(f"projection onto the constraints did not converge at "
                               f"t = {t + h:.6g} s (max |Phi| = {out[stepper.O_RES]:.3g})")
        if status == stepper.ST_NONFINITE:
            raise StageFailure(f"error norm {err} at step {h:.3g} s")
        y_new = c.y_new.copy()
        if status == stepper.ST_REJECTED:
            return err, y_new, None, None, None, None
        y_acc, f_acc = c.y_acc.copy(), c.f_acc.copy()
        if not self.project:  # Baumgarte's drift test (the dense output blends its result)
            y_acc, f_acc = self._accept(t + h, y_acc, f_acc)
            c.y_acc[:] = y_acc
        self._c_last = True
        return err, y_new, y_acc, f_acc, c.stages(), None

    def advance(self, t_stop, max_steps=1):
        """Accepted steps until t >= t_stop in one C call (mbsim/fast/step.c: mb_rk_steps,
        the controller of :meth:`RungeKuttaIntegrator._step_impl` and the watchdog of
        :meth:`Integrator.step`), where the step is the C trial alone: the projection
        methods (Baumgarte's drift test is Python), outside tangent coordinates and the
        approach to a change point.  The steps C leaves (a failed trial, a step the
        controller must give up, the approach's) are taken by :meth:`step`, and so are the
        first step of a run (the driver records its size) and the steps after one below
        the stall floor (the watchdog counts them)."""
        if not self._loop_applies(max_steps):
            return self.step()
        why, steps = self._loop(t_stop, max_steps)
        if why == stepper.LOOP_PYTHON or not steps:
            return self.step()
        return True, ""

    def advance_outputs(self, outputs, max_steps, *, mesh=None, step=None):
        """:meth:`advance` to the last of the output times of ``outputs`` (a
        :class:`~mbsim.fast.stepper.Outputs`: ascending times after t, and the buffers) that
        also gives the outputs on the way, in the same C call: after each accepted step that
        reaches the next output, the outputs up to its end, as :func:`mbsim.analyses.
        trajectory.step_outputs` samples a step (``outputs.project``: each projected and
        checked as :meth:`dense_output_many` does, bit for bit; else the plain interpolant of
        :func:`mbsim.analyses.estimate.interpolant_many`).  ``mesh`` (ascending step ends):
        each step ends at the next mesh point, without error control
        (:class:`mbsim.analyses.estimate.CoarseStepper`); ``step``: the one-step fallback
        (default :meth:`step`).  The loop stops after a step whose outputs need Python (a
        flagged or non-finite output, DOP853's extra stages stopped): that step's outputs
        are left to the driver, whose :meth:`dense_output_many` gives them as before.

        Returns None where the C loop does not apply (the caller takes its own path), else
        (ok, message) as :meth:`advance`; ``outputs.done()`` holds the outputs given, also
        when a Ctrl-C met in the loop's Python loads is raised after it."""
        if not self._loop_applies(max_steps):
            return None
        why, steps = self._loop(float(outputs.times[-1]), max_steps, outputs, mesh)
        if why == stepper.LOOP_PYTHON or not steps:
            return (step or self.step)()
        return True, ""

    def _loop_applies(self, max_steps):
        """Whether :meth:`_loop` may take the next steps (:meth:`advance`)."""
        approach = self._approach if self.policy.tangent > 0.0 else None
        return not (self._compiled is None or not self.project or self._tangent
                    or max_steps < 2 or self.status != "running"
                    or self.counters["steps"] == 0 or self.t >= self.t_bound
                    or self._tiny_steps
                    or (approach is not None and len(approach.points) >= 2))

    def _loop(self, t_stop, max_steps, outputs=None, mesh=None):
        """The C loop (step.c: mb_rk_steps) from the current state until t >= t_stop, and
        the integrator's state after it; returns (LOOP_*, accepted steps).  outputs: a
        :class:`~mbsim.fast.stepper.Outputs` request (its ``k``: the outputs written);
        mesh: the step ends (:meth:`advance_outputs`)."""
        c, approach = self._compiled, self._approach if self.policy.tangent > 0.0 else None
        L = stepper.Loop(
            t=self.t, t_bound=self.t_bound, t_stop=t_stop, h_abs=self.h_abs, h_max=self.h_max,
            h_min=self.h_min, h_fixed=self.h_fixed or 0.0, err_old=self._err_old,
            exponent=self.error_exponent, beta=self.pi_beta, safety=base.SAFETY,
            min_factor=base.MIN_FACTOR, max_factor=base.MAX_FACTOR,
            stall_floor=base.STALL_FLOOR, max_steps=max_steps, max_rejects=base.MAX_REJECTS)
        if approach is not None:  # its measure taken after each step in C (mb_loop.ap)
            L.ap, L.ap_h_far = ctypes.addressof(approach.c), np.nan
        ends = None
        if self.step_ends is not None:
            if self._ends_buffer.size < max_steps:
                self._ends_buffer = np.empty(max_steps)
                self._ends_pointer = self._ends_buffer.ctypes.data_as(
                    ctypes.POINTER(ctypes.c_double))
            ends = self._ends_buffer
            L.ends = self._ends_pointer
        if outputs is not None:
            outputs.attach(L)
        if mesh is not None:
            mesh = np.ascontiguousarray(mesh, dtype=np.float64)
            L.mesh, L.n_mesh, L.k_mesh = mesh.ctypes.data, mesh.size, 0  # (C finds the next)
        try:
            c.steps(self.y, self.f, L)
        finally:  # (also when a Ctrl-C met in the loads is raised after the call: the steps
            # taken and their outputs are kept, the state the last accepted one)
            self._after_loop(L, outputs, ends, mesh is not None)
        return L.why, L.steps

    def _after_loop(self, L, outputs, ends, mesh):
        """The integrator's state after the C loop ``L`` (:meth:`_loop`)."""
        c, approach = self._compiled, self._approach if self.policy.tangent > 0.0 else None
        why = L.why
        if outputs is not None:
            outputs.k = L.k_out
        if L.steps:
            if ends is not None:
                self.step_ends.extend(ends[:L.steps].tolist())
            self.counters["steps"] += L.steps
            self.counters["rejected_steps"] += L.rejected
            self.t, self.t_old, self.h_last = L.t, L.t_old, L.h_last
            self.h_abs, self._err_old = L.h_abs, L.err_old
            if mesh:
                self.h_fixed = L.h_fixed
            n = self.n
            if why == stepper.LOOP_PYTHON:  # (t, y, f): the last accepted state
                self.y, self.f = c.y.copy(), c.f.copy()
                self._c_last = False
            else:
                self._dense_args = (L.t_old, L.h_last, c.y.copy(), c.y_new.copy(),
                                    c.stages(), None)
                self.y, self.f = c.y_acc.copy(), c.f_acc.copy()
                self._c_last = True
                self._step_start = (L.t_old, self._dense_args[2][:n])
            self._s, self._C, self._step_tangent = L.s, None, False
            self.q, self.qd, self.w = self._state_from_y(self.t, self.y)
            if approach is not None:  # the rest of accepted() for the loop's steps
                if not np.isnan(L.ap_h_far):  # the last of those clear of the approach
                    approach.measured(None, L.ap_h_far, None, True)
                if why == stepper.LOOP_NEAR:  # the last step's state belongs to it
                    approach.measured(self.t, self.h_last, self._s, False)
            tiny = why == stepper.LOOP_TINY
            self._tiny_steps = (self._tiny_steps + 1 if L.steps == 1 else 1) if tiny else 0
            if self.t >= self.t_bound:
                self.status = "finished"

    def dense_output_many(self, times):
        """All outputs of the last step at once, in C when the step was taken there (module
        :mod:`mbsim.fast.stepper`); an output whose projection C cannot vouch for (the
        checks of :meth:`_dense_output_impl`) and a step whose extra stages meet the policy
        go through the Python dense output."""
        if not self._c_last or self._step_tangent:
            return super().dense_output_many(times)
        times = np.asarray(times, dtype=float)
        k = times.size - int(times.size > 0 and times[-1] == self.t)  # (at t: the state)
        if k == 0:
            return super().dense_output_many(times)
        t0, h = self._dense_args[:2]
        status, Q, QD, W, flags = self._compiled.dense(t0, h, times, k)
        if status != stepper.ST_ACCEPTED:
            return super().dense_output_many(times)
        if k < times.size:
            Q[k], QD[k], W[k] = self.q, self.qd, self.w
        return self._redo_flagged(times, Q, QD, W, flags)

    def _clear_crossing(self, h, y_new):
        """The step to take instead of an accepted tangent step of size h (end y_new) that
        crosses the change point with a stage too close to it, or None.  The error test of a
        tangent step does not see the round-off of a stage next to the point: the embedded
        pair's two solutions share that stage, and its round-off cancels in their
        difference.  So where the stages show a crossing (changepoints.crossing_in_step),
        the round-off of the stage nearest the point is probed (:meth:`_stage_noise`) and
        carried to the step's end (changepoints.Policy.stage_reach) in the error test's
        units; where it exceeds the tolerance, the step is tried again at the longest step
        no longer than h whose stages all clear the point (changepoints.clear_of_crossing,
        the round-off of the others from the probe by its law s^-3), once per step.  A
        motion that dwells next to the point (no crossing, or no step clears it) and a stage
        below the policy's ``noise_s`` (where a probe measures nothing) keep the step."""
        tab = self.tableau
        if (self._cleared or self.h_fixed is not None or self._v_scale is None
                or len(self._stage_s) != tab.n_stages):
            return None
        n = self.n
        s_stages = np.asarray(self._stage_s)  # stages 1 .. n_stages - 1, then the end
        self.system.accelerations(self.y[:n], self.y[n:2 * n], self.t, self.stab)
        s0 = cp.measure_from_schur(self.system.pivot_ratio)  # (a function of q alone)
        crossing = cp.crossing_in_step(tab.C[1:], s_stages[:-1], s0, s_stages[-1], h)
        if crossing is None:
            return None
        reach = cp.Policy.stage_reach(tab, h)
        live = np.flatnonzero(reach[1:].max(axis=1) > 0.0) + 1
        i = int(live[np.argmin(s_stages[live - 1])])  # the stage nearest the point
        s_i = float(s_stages[i - 1])
        if s_i < self.policy.noise_s:
            return None
        if i == tab.n_stages:
            t_i, y_i = self.t + h, y_new
        else:
            t_i, y_i = self.t + tab.C[i] * h, self.y + h * (self.K[:i].T @ tab.A[i, :i])
        noise = self._stage_noise(t_i, y_i, self._clear_rng)
        if noise is None:
            return None
        k = self._C.shape[0]
        scale_v, scale_vd = self._v_scale[:k], self._v_scale[k:]
        unit = s_i ** 3 * np.array([rms_norm(noise[k:], scale_vd), rms_norm(noise[k:], scale_v)])
        if float((reach[i] * unit).max()) <= s_i ** 3:
            return None  # within the tolerance
        return cp.clear_of_crossing(np.append(tab.C, 1.0), reach * unit, *crossing, h)

    def _clip(self, h):
        if self._h_clear is not None:  # (one trial: the step of _clear_crossing)
            h, self._h_clear = self._h_clear, None
        return super()._clip(h)

    def _tangent_map(self, t, q):
        s = self.system
        J = s.terms(q, t, phi=False).jac
        C = cp.tangent_map(s, q, J.toarray() if s.sparse else J)
        if C is None:
            raise StageFailure(f"t = {t:.6g} s: singular mass matrix on the tangent space")
        return C

    def _trial(self, h):
        self._in_trial = True
        self._trial_s = np.inf  # the smallest measure of the trial's stages
        self._stage_s = []
        try:
            return super()._trial(h)
        finally:
            self._in_trial = False

    def _recover(self):
        """A stage in the region: the step again from its start, every stage in tangent
        coordinates with C from the start (outside the region: continuity picks the branch)."""
        wanted, self._tangent_wanted = self._tangent_wanted, False
        if not wanted or self._tangent:
            return False
        try:
            self._C = self._tangent_map(self.t, self.q)
        except StageFailure:  # no tangent coordinates here: the Schur path for this run
            self.policy = self.policy.off()
            return True
        self._tangent = True
        self._tangent_h0 = None  # the passage's first tangent step (_error_norm)
        self.f = self._rhs(self.t, self.y)
        return True

    def _step_impl(self):
        if not self._tangent:
            # a C kept from an earlier passage (or built for the last step's dense output)
            # belongs to another configuration: a new one is taken where it is needed
            self._C = None
        self._step_start = (self.t, self.q)
        self._step_tangent = False  # (the last step's dense output has been taken)
        self._cleared, self._h_clear = False, None
        approach = self._approach if self.policy.tangent > 0.0 else None
        h = approach.step(self.h_abs) if approach else None
        if h is not None:
            self.h_abs = h  # a step across the change point ahead (changepoints.Approach)
        ok, msg = super()._step_impl()
        self._step_tangent = self._tangent
        if ok and approach and approach.accepted(self.t, self.h_last, self._s):
            self.counters["straddle_steps"] += 1
        if ok and self._tangent and self._s >= self.policy.tangent:
            self._tangent = False  # the accepted state is outside the region
            self.f = self._rhs(self.t, self.y)
        return ok, msg

    def _project(self, t, q, qd):
        """(q, qd) put back on Phi = 0 and Phi_q qd = nu; a projection that does not reach
        its tolerance (near a singular position) is a failed stage: the step is retried
        smaller."""
        s = self.system
        q, ok, its, res = s.project_positions(q, t, tol=self.proj_tol)
        if not ok and res > cp.Policy.projection_kept(self.proj_tol):
            raise StageFailure(f"projection onto the constraints did not converge at "
                               f"t = {t:.6g} s (max |Phi| = {res:.3g})")
        return q, s.project_velocities(q, qd, t)

    def _accept(self, t, y, f):
        if self._tangent:
            return self._tangent_accept(t, y)
        if not self.project:
            return y, f
        n = self.n
        q, qd = self._project(t, y[:n], y[n:2 * n])
        y = np.concatenate([q, qd, y[-1:]])
        return y, self._rhs(t, y)

    def _tangent_accept(self, t, y):
        """In tangent coordinates the step's end is put on the constraints as its stages
        are (:meth:`_tangent_complete`), for every index-1 method."""
        n = self.n
        q, qd, _ = self._tangent_complete(t, y[:n], y[n:2 * n])
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
        tolerance, as on smooth motions; the step's own end is never affected.  In a tangent
        step the sample is completed at fixed v = C q as the step's stages are; where that
        moves q by more than the policy's ``branch_jump`` tolerances the interpolant is off the
        constraints by that much (on the four cranks at rtol 2e-11, 2.5e-3 s from a flat
        position: 5.9e-5 m off, an output 1.2e-4 m off with the step's ends right), and the
        quintic Hermite interpolant of the step's ends (q, qd, qdd: fifth order; as gcp's
        fallback) is completed instead (1.4e-11 m there); an integration to the output (a
        new run of this class from the step's start, which next to the change point crawls
        towards it) is the last resort."""
        out = super()._dense_output_impl()
        if not self.project:
            return out
        t0, _, y0 = self._dense_args[:3]
        n, s = self.n, self.system
        scale = self._scale(y0, self.y)[:n]
        last = {"t": t0, "y": y0, "h": None}  # last state known to the step's accuracy

        tangent_step = self._step_tangent
        hermite5 = None
        if tangent_step:  # the fallback interpolant of a tangent step's outputs (doc above)
            K0 = self._dense_args[4][0]  # y' at the step's start
            hermite5 = quintic_hermite((t0, y0[:n], y0[n:2 * n], K0[n:2 * n]),
                                       (self.t, self.y[:n], self.y[n:2 * n], self.f[n:2 * n]))

        def completed(t, q, qd):  # None: no completion, or one onto the other branch
            try:
                qp, qdp, _ = self._tangent_complete(t, q, qd)
            except StageFailure:
                return None
            return (qp, qdp) if rms_norm(qp - q, scale) <= self.policy.branch_jump else None

        def projected(t):
            q, qd, w = out(t)
            if tangent_step:  # as the step's stages and end (_tangent_accept)
                done = completed(t, q, qd) or completed(t, hermite5(t), hermite5(t, 1))
                if done is not None:
                    return done[0], done[1], w
            else:
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
        if sub.policy != self.policy and self.policy.tangent > 0.0:
            # a start next to the change point, where a new run would lower its switch or
            # keep the Schur path (Policy.at_start): this run's policy (the start is on its
            # branch)
            sub.policy = self.policy
            sub._approach = sub._new_approach()
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
        if not self.drift_bound:  # Baumgarte (1972) alone: no tangent coordinates either
            self.policy = self.policy.off()
        self.counters["drift_projections"] = 0

    def _accept(self, t, y, f):
        if self._tangent:
            return self._tangent_accept(t, y)
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

