"""Global error estimate of a dynamic run (on by default, option ``error_estimate``).

After the run, a *companion* integration of the same model with the same method is
compared with it at the output times (Shampine 1985, "global error estimation by
reintegration"; Hairer, Norsett & Wanner I, Sec. II.4 and II.12).  Which companion
(option ``estimate_method``):

- ``coarse`` (default) for projection-dop853, projection, genalpha and hht
  (:data:`COARSE_FAMILIES`): the run's method without error control on the run's own mesh
  coarsened by two, whose error is 2^p times the run's (order p), so err ~ |y - y_c| /
  (2^p - 1) (:func:`coarse_estimate`).  It takes half the run's steps, none rejected, and
  samples its plain interpolant: 0.2-0.65 of the run's CPU on the reference problems,
  where the companion at rtol/5 took 0.73-1.8.  Est / true error there 0.3-2
  (tests/integrators/test_error_estimate.py, tests/analyses/test_estimate.py).  A run
  that met a change point (a singular position, :data:`CHANGE_POINT_COUNTERS`), and a
  generalized-alpha run of a model with redundant constraints
  (:data:`COARSE_NEEDS_INDEPENDENT_ROWS`), get the companion below: a doubled step across
  a singular position is not in the asymptotic regime (four parallel cranks at rtol 1e-7:
  35x the true error).
- ``tighter`` (and for every other method, or when the coarse companion does not reach
  every output): the same method repeats the run more accurately, an adaptive method at
  the tolerances divided by ``estimate_ratio`` (rho, default 5), a fixed-step method at
  half the step:

  - adaptive: err ~ |y - y_c|; the companion's own error is about rho^-0.9 of the run's
    (tolerance proportionality), so the estimate is low by at most that fraction; a method
    whose error grows as rtol^kappa with kappa < 1 (generalized-alpha, HHT: 2/3 at and
    above rtol 1e-6, :meth:`~mbsim.integrators.base.Integrator.error_ratio`) has a
    companion only rho^kappa more accurate: err ~ |y - y_c| / (1 - rho^-kappa);
  - fixed step h, method of order p: err ~ |y - y_c| 2^p / (2^p - 1) (Richardson).

  It costs about rho^(1/(p+1)) of the run's steps for an adaptive method of order p (1.2x
  for DOP853, 1.3x for Dormand-Prince 5(4)); 2x for a fixed step.

Either can be wrong where the error does not shrink with the step or tolerance: steps
limited by h_max or by stability rather than accuracy, chaotic motion over long times, a
solution that jumps branch at a bifurcation.

At a change point (a rank loss of Phi_q: a run with a CHANGE_POINT_COUNTERS counter, or one
whose outputs show the change-point measure s falling below (eps / rtol)^(1/3) between them,
:func:`outputs_measure`) the state is fixed by the constraints only to their round-off,
eps x size / s, and a run at a tight tolerance ends with an error at that floor whatever its
tolerance (the four parallel cranks at rtol 1e-10: 2.3e-11 ... 2.5e-9 m, depending on the
BLAS kernel).  There the companion's difference is one noise term against another, so:

- the estimate is at least the passage's round-off floor (:func:`roundoff_floor`), and
  the method string says so with the figures;
- a companion that stops at the passage where the run did not (tighter than the run, its
  steps crawl on the round-off, and a tighter retry does no better) is retried with the
  other methods at the run's own tolerance (:func:`fallback_companion`): their difference
  is the larger of two errors of about the tolerance; only when every retry stops is there
  no estimate (NaN in the file), with that reason.

An estimate covers every output of the run or it is none (:func:`estimate`).  Channels
written: ``error/position``, ``error/orientation``, ``error/velocity``,
``error/angular_velocity``: the estimated global error at each output time (max over
bodies and output points).
"""

from __future__ import annotations

import logging
import math
import time as _time

import numpy as np

from mbsim.analyses.trajectory import OUTPUT_WINDOW, Stepper, Trajectory, trajectory
from mbsim.fast import stepper
from mbsim.integrators import INTEGRATORS
from mbsim.integrators.base import NUMERICAL_ERRORS
from mbsim.integrators.changepoints import DEFAULT_RTOL, EPS, Policy
from mbsim.integrators.genalpha import GeneralizedAlpha
from mbsim.integrators.rk import RungeKuttaIntegrator
from mbsim.result import STATUS_INCOMPLETE

log = logging.getLogger(__name__)

ESTIMATE_STEPS = 10  # the companion run may take at most this x the run's steps (+100)

ERROR_UNITS = {
    "position": ("m", "estimated global error of positions (bodies, output points)"),
    "orientation": ("rad", "estimated global error of orientations (rotation angle)"),
    "velocity": ("m/s", "estimated global error of centroid and point velocities"),
    "angular_velocity": ("rad/s", "estimated global error of angular velocities")}


def companion_options(cls, opt):
    """(options, Richardson factor, description) of the companion run of a run with
    ``opt`` (module doc)."""
    copt = dict(opt)
    copt["h0"] = None
    rho = float(opt.get("estimate_ratio", 5.0))
    if opt.get("h") is not None:  # fixed step: half of it, Richardson's factor
        copt["h"] = 0.5 * float(opt["h"])
        factor = 2.0 ** cls.order / (2.0 ** cls.order - 1.0)
        method = (f"companion run at h/2 = {copt['h']:.3g} s, Richardson factor "
                  f"2^p/(2^p - 1) = {factor:.3g} (p = {cls.order})")
    else:
        copt["rtol"] = max(float(opt["rtol"]) / rho, 2.5e-14)
        copt["atol"] = max(float(opt["atol"]) / rho, 1e-300)
        # error ~ rtol^kappa: the companion's own error is rho^-kappa of the run's, and
        # |y - y_c| ~ (1 - rho^-kappa) err.  For tolerance-proportional methods (kappa = 1)
        # the difference is taken as it is: measured est/err 0.8-2.7 (benchmarks/accuracy.py)
        ratio = cls.error_ratio(float(opt["rtol"]), copt["rtol"])  # rho^-kappa
        kappa = math.log(ratio) / -math.log(rho) if 0.0 < ratio < 1.0 else 0.0
        factor = 1.0 if ratio <= 1.0 / rho * (1.0 + 1e-9) else 1.0 / (1.0 - ratio)
        method = (f"companion run at rtol/{rho:g} = {copt['rtol']:.3g}, "
                  f"atol/{rho:g} = {copt['atol']:.3g}")
        if factor != 1.0:
            method += (f", times 1/(1 - {rho:g}^-kappa) = {factor:.3g} (error ~ "
                       f"rtol^kappa, kappa = {kappa:.3g})")
    return copt, factor, method


COARSE_FAMILIES = ("projection-dop853", "projection", "genalpha", "hht")
"""The error-controlled one-step methods whose estimate is the coarse companion
(:func:`coarse_estimate`): methods of a fixed order whose global error on a mesh scales as
its step to the power p: the projected Runge-Kutta pairs and the index-3
generalized-alpha family (p = 2 for positions and velocities, Arnold & Bruls 2007; the
second only without redundant constraints, :data:`COARSE_NEEDS_INDEPENDENT_ROWS`).  Their
error as a function of the *tolerance* (generalized-alpha: rtol^(2/3) above rtol 1e-6) does
not enter: the companion takes the run's own mesh.  The others keep the companion at rtol / rho:
Baumgarte (its drift term does not scale with the step), and the coordinate-partitioning
pairs, whose dependent-coordinate Newton iteration fails on doubled steps (heavy top,
gcp-dop853 at rtol 1e-5: |Phi| 0.24 at t = 0.09 s), so that the companion at rtol / rho
would follow a wasted coarse run.

Generalized-alpha on the reference problems (heavy top, pendulum, slider-crank; the four
parallel cranks at 1e-4 and 1e-6 without the rule below) at rtol 1e-3, 1e-4, 1e-6:
est / true 0.44-1.02 in position, 0.51-1.22 in velocity, the companion 0.48-0.64 of the
run's CPU; the companion at rtol/5 gave 0.86-1.32 for 1.2-1.8 of the run's CPU (the heavy
top at 1e-3, whose doubled steps fail Newton, gets it either way).  HHT on the same three:
0.56-2.1 in position, 0.47-2.2 in velocity, 0.47-0.66 of the run's CPU (rtol/5: 0.93-1.27,
1.3-1.7)."""

COARSE_NEEDS_INDEPENDENT_ROWS = ("genalpha", "hht")
"""Methods that do not detect a singular position (a change of rank of Phi_q, where a
doubled step can leave the run's branch): for these the coarse companion needs a model
without redundant constraint rows at t_start, the mechanisms whose rank can change (the
four parallel cranks, generalized-alpha at rtol 1e-3: the coarse companion left the
branch at t = 0.85 s, est / true 24; with the companion at rtol/5 0.91).  A mechanism
without redundant rows can still meet a singular position; there this estimate is too
large (the safe side), not too small."""


COARSE_MIN_STEPS = 4  # fewer accepted steps: the companion at rtol / rho instead
CHANGE_POINT_COUNTERS = ("tangent_stages", "straddle_steps", "output_steps", "row_changes",
                         "events")
"""Counters of a run that met a change point (a singular position): tangent-coordinate
stages, steps placed across it, outputs integrated to because the interpolant was not to be
trusted, rows chosen again.  Such a run gets the companion at rtol / rho: on a doubled step
across a singular position the error is not 2^p times the run's (four parallel cranks,
projection-dop853 at rtol 1e-7, one tangent stage and 5 outputs integrated to: the coarse
estimate was 35x the true error, the companion at rtol/5 0.97x)."""
INTERRUPTED = {}  # coarse_estimate's mark of a companion stopped by Ctrl-C
COARSE_LOOP = True
"""The coarse companion's steps and outputs in the integrator's C loop where it can
(Index1.advance_outputs with its mesh, the outputs unprojected as :func:`interpolant_many`
gives them); False: one Python call per step, as before (tests/analyses/test_output_loop.py
compares the two)."""


class CoarseStepper(Stepper):
    """The run's method without error control on the run's own mesh coarsened by two
    (``mesh``: every other step end of the run, t0 first, the run's last step end last)."""

    def __init__(self, model, cls, opt, t0, q, qd, t1, rows, mesh, system=None):
        self.mesh = np.asarray(mesh, float)
        # newton_contraction: generalized-alpha stops its Newton iteration on the remaining
        # error (GeneralizedAlpha._newton): the companion is compared, not kept, and its
        # doubled steps often meet the tolerance on what is left one iteration before the
        # correction itself falls below it
        opt = dict(opt, h=float(self.mesh[1] - self.mesh[0]), h0=None, newton_contraction=True)
        super().__init__(model, cls, opt, t0, q, qd, t1, rows, system)

    def step(self):
        s = self.solver
        eps = 1e-12 * max(1.0, abs(s.t))
        k = int(np.searchsorted(self.mesh, s.t + eps, side="right"))
        h = (self.mesh[k] if k < self.mesh.size else s.t_bound) - s.t
        s.h_fixed = s.h_abs = h  # the next coarse step (the integrators' fixed step)
        return super().step()


def interpolant(solver):
    """``f(t) -> (q, qd, w)`` over the last step of ``solver``: the method's own
    interpolant, without the projection of each sample that the index-1 families add
    (:meth:`mbsim.integrators.index1.Index1._dense_output_impl`); the companion's outputs
    are compared, not kept, and a projection would cost as much as the interpolation."""
    if isinstance(solver, RungeKuttaIntegrator):
        return RungeKuttaIntegrator._dense_output_impl(solver)
    return solver.dense_output()


def interpolant_many(solver, times):
    """(Q (k, nq), QD (k, nq)): :func:`interpolant` of the last step of ``solver`` at all
    of ``times`` (inside the step) at once; in one C call (mbsim/fast/step.c:
    mb_rk_dense with the projection switched off: the same interpolant, the projection's
    correction at the step's end blended in linearly) when the step was taken there."""
    c = getattr(solver, "_compiled", None)
    if c is not None and getattr(solver, "_c_last", False) and not solver._step_tangent:
        t0, h = solver._dense_args[:2]
        project, c.r.project = c.r.project, 0
        try:
            status, Q, QD, _, _ = c.dense(t0, h, times)
        finally:
            c.r.project = project
        if status == stepper.ST_ACCEPTED:
            return Q, QD
    dense = interpolant(solver)
    if isinstance(solver, GeneralizedAlpha):  # cubic Hermite in q and qd: all times at once
        Q, QD, _ = dense(np.asarray(times, dtype=float))
        return Q, QD
    Q, QD = np.empty((len(times), solver.q.size)), np.empty((len(times), solver.q.size))
    for i, t in enumerate(times):
        Q[i], QD[i] = dense(t)[:2]
    return Q, QD


def coarse_estimate(model, prep, opt, tr, near=None):
    """(channels, description) of the coarse estimate of the run ``tr``, or (None, why);
    ``near``: :func:`outputs_measure` of the run, or None.

    On a mesh h(t) = H theta(t) the global error of a method of order p is
    H^p e(t) + O(H^(p+1)); the run's mesh coarsened by two (every other step end) gives
    2^p times the run's error, so at the mesh points |y - y_coarse| / (2^p - 1) estimates
    the run's error (Richardson extrapolation on the step-size sequence; Hairer, Norsett &
    Wanner I, Sec. II.4 and II.12).  The companion takes half the run's steps, none
    rejected, and its outputs are its interpolant's (:func:`interpolant`), compared with the
    run's outputs as they are (the run's interpolation error, of the same order, is part of
    the estimate).  Applies to complete runs of :data:`COARSE_FAMILIES` methods with at
    least COARSE_MIN_STEPS steps that met no change point: no CHANGE_POINT_COUNTERS, and
    the change-point measure s between the outputs nowhere below :func:`near_measure`,
    (eps / rtol)^(1/3), where three solves' round-off reaches the tolerance (a run whose steps
    pass the point without a tangent stage: the four parallel cranks at rtol 1e-7 with
    the Python step; under OpenBLAS Prescott the coarse estimate was 34x the true error
    there).  Returns :data:`INTERRUPTED` when Ctrl-C stopped it."""
    cls, run = prep.cls, tr.run
    if cls.name not in COARSE_FAMILIES or opt.get("h") is not None:
        return None, f"{cls.name} is not estimated on a coarse mesh"
    if run is None or not tr.complete or len(run.step_ends) < COARSE_MIN_STEPS:
        return None, "the run is incomplete or too short for a coarse mesh"
    if cls.name in COARSE_NEEDS_INDEPENDENT_ROWS and prep.red.size:
        return None, (f"redundant constraints ({', '.join(model.items_of_rows(prep.red))}): "
                      f"{cls.name} does not detect the singular positions they allow, where "
                      f"a doubled step is not in the asymptotic regime")
    counters = run.all_counters()
    passed = [k for k in CHANGE_POINT_COUNTERS if counters.get(k)]
    if passed:
        return None, (f"the run passed a change point ({', '.join(passed)}): a doubled step "
                      f"there is not in the asymptotic regime")
    if near is not None and near[3].min() < near_measure(opt):
        return None, (f"the run passed next to a change point (measure s = "
                      f"{near[3].min():.2g} between outputs, below (eps / rtol)^(1/3) = "
                      f"{near_measure(opt):.2g}): a doubled step there is not in the "
                      f"asymptotic regime")
    t0 = float(tr.t[0])
    ends = [t0] + run.step_ends
    mesh = np.array(ends[::2] + ([ends[-1]] if (len(ends) - 1) % 2 else []))
    times = np.asarray(tr.t, float)
    n = len(times)
    Qc, QDc = np.empty((n, model.nq)), np.empty((n, model.nq))
    Qc[0], QDc[0] = prep.q0, prep.qd0
    k, steps = 1, 0
    # the run's equations of motion (its rows: no change point, so no row change), shared;
    # their counters are the run's, so the companion's work is taken off them again
    system = run.system if np.array_equal(run.system.rows, prep.rows) else None
    counted = dict(system.counters) if system is not None else None
    try:
        comp = CoarseStepper(model, cls, opt, t0, prep.q0.copy(), prep.qd0.copy(),
                             float(mesh[-1]), prep.rows, mesh, system)
        if (system is not None and not (system.hybrid or system.reaction_loop)
                and isinstance(comp.solver, GeneralizedAlpha)):
            # the run's finite-difference tangent at the common start, not computed again
            # (GeneralizedAlpha.offer_tangent compares the inputs)
            comp.solver.offer_tangent(getattr(run.solver, "first_tangent", None))
        while k < n:
            if steps > 2 * mesh.size + 100:
                return None, "the coarse companion took more steps than its mesh has"
            many = None
            if COARSE_LOOP and comp.first_step is not None:
                advance_outputs = getattr(comp.solver, "advance_outputs", None)
                if advance_outputs is not None:  # the steps and their outputs in C
                    before = comp.solver.counters["steps"]
                    request = stepper.Outputs(times[k:k + OUTPUT_WINDOW], model.nq,
                                              project=False)
                    many = advance_outputs(request, 2 * mesh.size + 101 - steps, mesh=mesh,
                                           step=comp.step)
            if many is None:
                steps += 1
                ok, msg = comp.step()
            else:
                ok, msg = many
                Q, QD = request.done()[:2]
                Qc[k:k + len(Q)], QDc[k:k + len(Q)] = Q, QD
                k += len(Q)
                steps += max(1, comp.solver.counters["steps"] - before)
            if not ok:
                if comp.restart(msg):
                    continue
                return None, f"the coarse companion stopped: {msg}"
            s = comp.solver
            eps = 1e-12 * max(1.0, abs(s.t))
            j = int(np.searchsorted(times, s.t + eps, side="right"))
            if j > k:  # the outputs in this step (after the C loop: those it left of its
                # last step): the interpolant, at t itself the state
                inside = times[k:j] < s.t
                i = k + int(np.count_nonzero(inside))
                if i > k:
                    Qc[k:i], QDc[k:i] = interpolant_many(s, times[k:i])
                Qc[i:j], QDc[i:j] = s.q, s.qd
                k = j
    except NUMERICAL_ERRORS as exc:
        return None, f"the coarse companion failed: {exc}"
    except KeyboardInterrupt:  # Ctrl-C: no estimate, and no other companion either
        return INTERRUPTED, "the companion run was interrupted (Ctrl-C) before it finished"
    finally:
        if counted is not None:
            system.counters.update(counted)
    factor = 1.0 / (2.0 ** cls.order - 1.0)
    diff = state_differences(model, np.array(tr.q), np.array(tr.qd), Qc, QDc)
    channels = {key: factor * diff[key] for key in ERROR_UNITS}
    method = (f"companion on the run's mesh coarsened by 2 ({mesh.size - 1} steps), "
              f"difference / (2^p - 1) = {factor:.3g} (p = {cls.order})")
    channels["_steps"] = comp.all_counters()["steps"]
    return channels, method


def estimate(model, prep, opt, tr, companion=None):
    """The global error estimate of the run ``tr`` (module doc): a companion integration
    (or the given one, a Trajectory at the companion's options) and the differences at the
    output times.  Returns a dict for the summary, with the companion as ``_companion``.

    An estimate covers every output of the run or it is none: a companion that stops
    before the run's last output (where the run went on) is integrated again with another
    method (:func:`fallback_companion`); if that stops too, the dict has ``position`` None
    and the ``reason``, and no partial figures."""
    cpu0 = _time.process_time()
    copt, factor, method = companion_options(prep.cls, opt)
    times = np.asarray(tr.t, float)
    spent = 0.0  # CPU of a companion computed before (a promoted run's: its own)
    coarse, why = None, None
    near = outputs_measure(model, prep, tr)
    if companion is None and opt.get("estimate_method", "coarse") == "coarse":
        coarse, why = coarse_estimate(model, prep, opt, tr, near)
    if coarse is INTERRUPTED:
        return {"method": "coarse companion", "position": None, "reason": why,
                "cpu": _time.process_time() - cpu0}
    if coarse is not None:
        steps = coarse.pop("_steps")
        out = {"method": why, "cpu": _time.process_time() - cpu0, "steps": int(steps),
               "_companion": None, "_copt": None, "channels": coarse}
        for key in ERROR_UNITS:
            out[key] = float(np.max(coarse[key]))
        log.info("error estimate: position %.3g m, orientation %.3g rad (%s)",
                 out["position"], out["orientation"], why)
        return out
    if why is not None:
        log.info("error estimate: no coarse companion (%s)", why)
    if companion is None:
        limit = companion_step_limit(opt, tr)
        try:
            run = Stepper(model, prep.cls, copt, float(times[0]), prep.q0.copy(),
                          prep.qd0.copy(), float(times[-1]), prep.rows)
            companion = trajectory(run, times, prep.q0, prep.qd0, limit)
        except NUMERICAL_ERRORS as exc:
            companion = failed_trajectory(times, f"could not start ({exc})")
        if companion.interrupted:
            return {"method": method, "position": None, "cpu": _time.process_time() - cpu0,
                    "reason": "the companion run was interrupted (Ctrl-C) before it finished"}
    else:
        spent = companion.cpu
    first, passed = None, passed_change_point(tr, near, opt)
    short = len(companion) < len(tr)
    restarted = None if short else restart_beyond(companion, tr)
    if short or restarted:  # stopped, or failed and restarted, where the run did not
        first = (companion.message or "it stopped early") if short else restarted
        alt = fallback_companion(model, prep, opt, tr, passed)
        if alt is not None:
            companion, copt, factor, method = alt
            method += (f" (the companion at the run's method "
                       f"{'stopped' if short else 'restarted'}: {first})")
        elif short:
            first += ("; no other companion (FALLBACK_COMPANIONS) reached the run's last "
                      "output either")
        else:
            method += (f" (it restarted: {first}; no other companion (FALLBACK_COMPANIONS) "
                       f"reached the run's last output)")
    n = min(len(companion), len(tr))
    out = {"method": method, "cpu": spent + _time.process_time() - cpu0,
           "steps": int(companion.run.all_counters()["steps"]) if companion.run else 0,
           "_companion": companion, "_copt": copt}
    if n < len(tr):
        out["position"] = None
        out["reason"] = (f"the companion run stopped at t = "
                         f"{times[n - 1] if n else times[0]:.6g} s before the run's last "
                         f"output t = {times[len(tr) - 1]:.6g} s ({first or companion.message})"
                         "; an estimate that does not cover the run is not given")
        log.info("error estimate: none (%s)", out["reason"])
        return out
    err = state_differences(model, np.array(tr.q[:n]), np.array(tr.qd[:n]),
                            np.array(companion.q[:n]), np.array(companion.qd[:n]))
    out["channels"] = {key: factor * err[key] for key in ERROR_UNITS}
    if passed and near is None:
        method += "; the change point's round-off floor is not computed for this model"
        out["method"] = method
    elif passed:  # at least the passage's round-off floor (roundoff_floor)
        floor = roundoff_floor(near)
        k0 = first_near_output(near, opt)
        for key in ("position", "orientation"):
            out["channels"][key][k0:] = np.maximum(out["channels"][key][k0:], floor[key])
        method += (f"; at least the round-off floor of the change point passed, "
                   f"{floor['position']:.2g} m and {floor['orientation']:.2g} rad "
                   f"(eps x size / s, s = {near[0]:.2g} the smallest "
                   f"change-point measure at an output, size {floor['size']:.3g} m)")
        out["method"] = method
    for key in ERROR_UNITS:
        out[key] = float(np.max(out["channels"][key]))
    log.info("error estimate: position %.3g m, orientation %.3g rad (%s)", out["position"],
             out["orientation"], method)
    return out


def restart_beyond(companion, tr):
    """What made the companion choose its rows again (Stepper.restart, after a step that
    failed) where the run did not, as text; None where it restarted no more often than the
    run.  Such a companion went on from a state where its method had failed, often a
    change point passed in the round-off regime, and its difference from the run then says
    more about that passage than about the run's error (the four parallel cranks under HHT
    at rtol 1e-10: the companion at 2e-11 failed at the second flat position, t = 0.297 s,
    went on with other rows and a phase error of 1.3e-5 m/s, and its estimate was 145 x the
    run's true error, 6.2e-8 m): it is replaced as a companion that stops is."""
    mine = companion.run.changes if companion.run is not None else []
    theirs = tr.run.changes if tr.run is not None else []
    if len(mine) <= len(theirs):
        return None
    first = mine[len(theirs)]
    return (f"it failed at t = {first['t']:.6g} s ({first['after']}) and went on only after "
            f"choosing its rows again")


def outputs_measure(model, prep, tr):
    """(s_min, size, s, s_between) of the run ``tr``: s (n,) the change-point measure at
    each output, sigma_min / sigma_max of Phi_q on the rows independent at t_start (measure
    1 of :mod:`mbsim.integrators.changepoints`, here from a singular value decomposition
    rather than a factor's pivots), s_min its smallest value, size (m) the largest |r| of a
    centroid or the motion's span, the scale of the positions' round-off, and s_between
    (n,) s with each local minimum replaced by the smallest value between its neighbours:
    s is linear in the distance to the point, |x - x0| a, so three outputs around the
    minimum give its vertex, s_k - |s_(k-1) - s_(k+1)| / 2 (at least 0): a fast crossing
    between two outputs is seen (the four parallel cranks at rtol 1e-7 cross at 0.3 s
    between outputs of s 2.4e-3).

    None for a model of DENSE_NQ or more coordinates (a dense SVD per output would cost
    more than the run), and for a model without redundant rows at t_start unless the run's
    counters show a change point: the rank of such a model's Phi_q can fall only where the
    mechanism locks (as for COARSE_NEEDS_INDEPENDENT_ROWS, an estimate there errs on the
    large side), and the SVDs, about 0.1 ms per output on the vehicle deck, would double
    the coarse estimate's cost."""
    from mbsim.analyses.common import DENSE_NQ
    from mbsim.analyses.diagnosis import jacobian

    n = len(tr)
    if n == 0 or model.nq >= DENSE_NQ or prep.rows.size == 0:
        return None
    counters = tr.run.all_counters() if tr.run is not None else {}
    if not prep.red.size and not any(counters.get(k) for k in CHANGE_POINT_COUNTERS):
        return None
    s = np.ones(n)
    for k in range(n):
        J = jacobian(model, tr.q[k], tr.t[k])
        J = (J.toarray() if hasattr(J, "toarray") else np.asarray(J))[prep.rows]
        sv = np.linalg.svd(J, compute_uv=False)
        s[k] = sv[-1] / sv[0] if sv[0] > 0 else 1.0
    R = np.array(tr.q[:n]).reshape(n, model.nb, 7)[:, :, :3]
    size = max(float(np.linalg.norm(R, axis=2).max()), float(np.ptp(R, axis=0).max()))
    return float(s.min()), size, s, vertices(s)


def vertices(s):
    """s (n,) with each interior local minimum replaced by the vertex of the V through it
    and its neighbours, s_k - |s_(k-1) - s_(k+1)| / 2, at least 0 (:func:`outputs_measure`)."""
    s = np.asarray(s, float)
    out = s.copy()
    if s.size >= 3:
        k = 1 + np.flatnonzero((s[1:-1] <= s[:-2]) & (s[1:-1] <= s[2:]))
        out[k] = np.maximum(s[k] - 0.5 * np.abs(s[k - 1] - s[k + 1]), 0.0)
    return out


def near_measure(opt):
    """The measure s below which a state is next to a change point: Policy.law(rtol) =
    (eps / rtol)^(1/3), where the round-off of three solves through a factor of pivot
    ratio s (q, qd, qdd) reaches the tolerance; for a fixed step the law at the default rtol
    (the policy's fixed-step switch)."""
    return Policy.law(DEFAULT_RTOL if opt.get("h") is not None else float(opt["rtol"]))


def passed_change_point(tr, near, opt):
    """True when the run met a change point: a CHANGE_POINT_COUNTERS counter, or an output
    whose measure is below :func:`near_measure`."""
    counters = tr.run.all_counters() if tr.run is not None else {}
    return bool(any(counters.get(k) for k in CHANGE_POINT_COUNTERS)
                or (near is not None and near[3].min() < near_measure(opt)))


def first_near_output(near, opt):
    """Index of the first output next to a change point (0 when none is known)."""
    if near is None:
        return 0
    k = np.flatnonzero(near[3] < near_measure(opt))
    return int(k[0]) if k.size else 0


def roundoff_floor(near):
    """{'position' (m), 'orientation' (rad), 'size' (m)}: the round-off floor of a passage
    of a change point, below which no companion can resolve the run's error.  Next to the
    point the constraints fix the state to the round-off of one solve through a factor of
    pivot ratio s, eps / s relative, that is eps x size / s in position and eps / s in
    orientation; at the point itself (s -> 0) the two branches of Phi = 0 meet and the
    residual eps x size fixes them only to sqrt(eps) x size, so s is taken at least
    sqrt(eps): the floor is at most sqrt(eps) x size (1.5e-8 m on a 1 m mechanism).  s is
    the smallest measure at an output (:func:`outputs_measure`), so the floor is that of
    the nearest output, a lower bound of the passage's own; what the motion then makes of
    it (measured on the four parallel cranks: 2.3e-11 ... 2.5e-9 m at the end, depending on
    the BLAS kernel) is in the companion's difference.  Zero when no measure is known."""
    if near is None:
        return {"position": 0.0, "orientation": 0.0, "size": math.nan}
    s = max(near[0], math.sqrt(EPS))
    return {"position": EPS * near[1] / s, "orientation": EPS / s, "size": near[1]}


def companion_step_limit(opt, tr):
    return min(int(opt["max_steps"]),
               ESTIMATE_STEPS * int(tr.run.all_counters().get("steps", 0)) + 100)


def failed_trajectory(times, message):
    tr = Trajectory()
    tr.status, tr.message = STATUS_INCOMPLETE, f"t = {times[0]:.6g} s: {message}"
    return tr


FALLBACK_COMPANIONS = ("projection-dop853", "gcp-dop853", "projection", "gcp-rk45")
"""Other methods tried, in this order, for a companion whose run's own method stopped early
(after the run's method at rtol/2): the default first (index-1 with projection: no partition
to lose near a singular position), then the other formulation of the same order, then the
lower-order pairs, each at FALLBACK_TIGHTER x the companion's tolerance."""
FALLBACK_TIGHTER = 1e-2
"""Another method's error at the same tolerance is not the run's method's: on the governor
at rtol 1e-6 projection-dop853 is 1.1e-11 m off, gcp-dop853 7.3e-9 m and Dormand-Prince 5(4)
2.9e-9 m.  At 100x the companion's tolerance (error ~ rtol for these tolerance-proportional
methods) their own error is at most about the run's, so the difference bounds the run's
error within a factor of about 2 rather than measuring the companion."""
FALLBACK_RATIO = 2.0
"""The run's own method is tried again at rtol/2 first: a companion that failed for being
too tight (h_min near round-off) often passes there.  Its difference is (1 - 2^-kappa) of
the run's error, so it is multiplied by 1/(1 - 2^-kappa) (2 for kappa = 1)."""


def fallback_companion(model, prep, opt, tr, passed=False):
    """(trajectory, options, factor, description) of a companion that reaches every output
    of ``tr`` when the first one stopped: the run's method at rtol/FALLBACK_RATIO, then the
    FALLBACK_COMPANIONS at FALLBACK_TIGHTER x the companion's tolerance; None when none
    does.  Only for error-controlled runs: a fixed-step run's companion is its own method at
    h/2 (Richardson), which another method cannot replace.

    ``passed``: the run met a change point (:func:`passed_change_point`).  There a companion
    tighter than the run stops where the run did not because the passage's round-off, not
    the tolerance, limits its steps (the four parallel cranks at rtol 1e-10 under OpenBLAS
    Prescott: the companions at 2e-11, 5e-11 and the three others at 2e-13 all crawled
    at 1e-9 s steps, 19 s of CPU for a 0.13 s run), and a tighter one does no better; so
    only the FALLBACK_COMPANIONS are tried, at the run's own tolerance: the difference of
    two independent errors of about the tolerance, the larger of the two (an overestimate
    where the other method is the less accurate), kept at least the passage's round-off
    floor by :func:`estimate`."""
    if opt.get("h") is not None or not prep.cls.adaptive:
        return None
    copt, _, _ = companion_options(prep.cls, opt)
    ratio = prep.cls.error_ratio(float(opt["rtol"]), float(opt["rtol"]) / FALLBACK_RATIO)
    tries = [(prep.cls, dict(copt, rtol=float(opt["rtol"]) / FALLBACK_RATIO,
                             atol=float(opt["atol"]) / FALLBACK_RATIO),
              1.0 / (1.0 - ratio))]
    tighter = dict(copt, rtol=max(copt["rtol"] * FALLBACK_TIGHTER, 2.5e-14),
                   atol=max(copt["atol"] * FALLBACK_TIGHTER, 1e-300))
    if passed:  # other methods at the run's own tolerance only (docstring)
        tries, tighter = [], dict(copt, rtol=float(opt["rtol"]), atol=float(opt["atol"]))
    tries += [(INTEGRATORS[n], dict(tighter, integrator=n), 1.0) for n in FALLBACK_COMPANIONS
              if INTEGRATORS[n] is not prep.cls]
    times = np.asarray(tr.t, float)
    for cls, o, factor in tries:
        try:
            run = Stepper(model, cls, o, float(times[0]), prep.q0.copy(), prep.qd0.copy(),
                          float(times[-1]), prep.rows)
            comp = trajectory(run, times, prep.q0, prep.qd0, companion_step_limit(opt, tr))
        except NUMERICAL_ERRORS:
            continue
        if comp.interrupted:
            return None
        if len(comp) >= len(tr):
            how = f", times {factor:.3g}" if factor != 1.0 else ""
            same = (", the run's own tolerance: the difference is the larger of two errors"
                    if cls is not prep.cls and o["rtol"] >= float(opt["rtol"]) else "")
            return comp, o, factor, (f"companion run with {cls.name} at rtol {o['rtol']:.3g}, "
                                     f"atol {o['atol']:.3g}{how}{same}")
    return None


def error_channels(est, nt, n):
    """(name, data, unit, description) of the error/* channels of an estimate over the n
    outputs of a run of nt output times (only when the run and its companion both
    reached every output: a partial estimate is in the summary only)."""
    chans = est.get("channels") or {}
    if n != nt or not chans:
        return []
    out = []
    for key, (unit, desc) in ERROR_UNITS.items():
        e = np.asarray(chans[key], float)
        if e.size != n:
            return []
        out.append((f"error/{key}", e, unit, desc))
    return out


def state_differences(model, Q, QD, Qc, QDc):
    """Per output time (nt,): max over bodies and output points of |r - r_c| (position, m),
    the rotation angle between the orientations (rad), |velocity differences| (m/s) and
    |omega - omega_c| (rad/s).  Q, QD, Qc, QDc: (nt, nq).

    Cross products, norms and omega = 2 E(p) pd are written out by components: on the
    (nt, nb) arrays of a run np.cross and building E cost ~10 numpy calls each.  The same
    values but omega's sum of four products, whose order einsum's loop chooses (even by
    the arrays' alignment): |omega - omega_c| to round-off of omega."""
    from mbsim.rotations import A as rot_A

    nt, nb = Q.shape[0], model.nb
    X, V = Q.reshape(nt, nb, 7), QD.reshape(nt, nb, 7)
    Xc, Vc = Qc.reshape(nt, nb, 7), QDc.reshape(nt, nb, 7)
    r, p, rc, pc = X[..., :3], X[..., 3:], Xc[..., :3], Xc[..., 3:]
    pos = _norm(r - rc).max(axis=1)
    # rotation from the companion's orientation to the run's: vector part of conj(pc) (x) p
    vec = pc[..., :1] * p[..., 1:] - p[..., :1] * pc[..., 1:] - _cross(pc[..., 1:], p[..., 1:])
    s = _norm(vec) / np.maximum(np.linalg.norm(p, axis=2) * np.linalg.norm(pc, axis=2), 1e-300)
    ori = (2 * np.arcsin(np.clip(s, 0.0, 1.0))).max(axis=1)
    w, wc = _omega(p, V[..., 3:]), _omega(pc, Vc[..., 3:])
    vel = _norm(V[..., :3] - Vc[..., :3]).max(axis=1)
    angv = _norm(w - wc).max(axis=1)
    if model.outputs:
        for _, b, sl in model.outputs:
            A, Ac = rot_A(p[:, b]), rot_A(pc[:, b])
            sg = A[..., 0] * sl[0] + A[..., 1] * sl[1] + A[..., 2] * sl[2]  # A s'
            sgc = Ac[..., 0] * sl[0] + Ac[..., 1] * sl[1] + Ac[..., 2] * sl[2]
            pos = np.maximum(pos, _norm(r[:, b] + sg - rc[:, b] - sgc))
            vp = V[:, b, :3] + _cross(w[:, b], sg)
            vpc = Vc[:, b, :3] + _cross(wc[:, b], sgc)
            vel = np.maximum(vel, _norm(vp - vpc))
    return {"position": pos, "orientation": ori, "velocity": vel, "angular_velocity": angv}


def _norm(x):
    """|x| over the last axis of length 3 (..., 3)."""
    return np.sqrt(x[..., 0] * x[..., 0] + x[..., 1] * x[..., 1] + x[..., 2] * x[..., 2])


def _cross(a, b):
    """a x b over the last axis (..., 3)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def _omega(p, pd):
    """omega = 2 E(p) pd (..., 3), E = [-e, e~ + e0 I] (Haug eq. 6.3.17)."""
    e0, e1, e2, e3 = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    d0, d1, d2, d3 = pd[..., 0], pd[..., 1], pd[..., 2], pd[..., 3]
    out = np.empty(p.shape[:-1] + (3,))
    out[..., 0] = 2 * (-e1 * d0 + e0 * d1 - e3 * d2 + e2 * d3)
    out[..., 1] = 2 * (-e2 * d0 + e3 * d1 + e0 * d2 - e1 * d3)
    out[..., 2] = 2 * (-e3 * d0 - e2 * d1 + e1 * d2 + e0 * d3)
    return out


def attach_estimate(model, res, est, nt, span):
    """Add the estimate ``est`` (a dict of :func:`estimate`) to the Result ``res`` of a run
    of ``nt`` output times whose motion spans ``span`` m: the summary's
    ``error_estimate`` (with its cost relative to the run's), the error/* channels when it
    covers every output, the file attribute (NaN and the reason when there is none) and a
    warning when it is large against the motion."""
    summary = res.summary
    est = dict(est)
    est["relative_cost"] = est.get("cpu", 0.0) / max(summary["cpu"], 1e-9)
    summary["error_estimate"] = {k: v for k, v in est.items()
                                 if k != "channels" and not k.startswith("_")}
    for name, data, unit, desc in error_channels(est, nt, len(res.t)):
        res.add(name, data, unit, desc)
    if est.get("position") is None:  # no estimate: NaN, and why, in the file
        res.attrs["error_estimate"] = math.nan
        res.attrs["error_estimate_reason"] = str(est.get("reason") or est.get("method"))
    else:
        res.attrs["error_estimate"] = float(est["position"])
        if est["position"] > 0.01 * max(span, 1e-3) or est["orientation"] > 0.05:
            summary.setdefault("warnings", []).append(
                f"the estimated error is large (position {est['position']:.3g} m against "
                f"a motion of {span:.3g} m, orientation {est['orientation']:.3g} rad): "
                f"tighten --rtol, or ask for it with --accuracy")
