"""Dynamic analysis (Haug Ch. 11): integrate the constrained equations of motion from
consistent initial conditions with one of the integrators of :mod:`mbsim.integrators`,
and estimate the global error of what it computed.

Output sampling is independent of the step size: the integrator steps freely and its dense
output is evaluated at the output times t_start + k step; at each output the accelerations
and multipliers are solved from the sampled (q, qd).

Global error estimate (on by default, option ``error_estimate``).  After the run, a
*companion* integration of the same model with the same method repeats it more accurately:
an adaptive method at the tolerances divided by ``estimate_ratio`` (rho, default 5), a
fixed-step method at half the step.  The difference of the two at the output times
estimates the global error of the run (Shampine 1985, "global error estimation by
reintegration"; Hairer, Norsett & Wanner I, Sec. II.12):

- adaptive: err ~ |y - y_c|; the companion's own error is about rho^-0.9 of the run's
  (tolerance proportionality), so the estimate is low by at most that fraction; a method
  whose error grows as rtol^kappa with kappa < 1 (generalized-alpha, HHT: 2/3) has a
  companion only rho^kappa more accurate: err ~ |y - y_c| / (1 - rho^-kappa);
- fixed step h, method of order p: err ~ |y - y_c| 2^p / (2^p - 1) (Richardson).

It costs one more integration (about rho^(1/(p+1)) of the run's steps for an adaptive
method of order p: 1.2x for DOP853, 1.3x for Dormand-Prince 5(4); 2x for a fixed step),
without output post-processing.  It can be wrong where the error does not shrink with the
tolerance: steps limited by h_max or by stability rather than accuracy, chaotic motion over
long times, a solution that jumps branch at a bifurcation.  ``accuracy`` (a position error
in m, orientation in rad) chooses the tolerance from it (:func:`_accuracy_run`).

Monitors written with the standard body and point channels:

- ``monitors/position_violation``  max |Phi| (all rows)
- ``monitors/velocity_violation``  max |Phi_q qd - nu|
- ``monitors/energy``              T + V (gravity and conservative force elements)
- ``monitors/work_nonconservative`` W_nc(t) = int (Q.qd - lam.nu) dt + V(t) - V(t0): the
  work of damping, actuators, non-potential loads and drivers, so that energy - W_nc stays
  constant (dT/dt = Q.qd - lam.nu along the exact motion)
- ``monitors/step_size``           the step the integrator took across each output time
  (at t_start: the first step it took)
- ``constraints/lam``              (nt, m) Lagrange multipliers, one column per row
  (components = row labels; zero on redundant rows)
- ``error/position``, ``error/orientation``, ``error/velocity``,
  ``error/angular_velocity``: the estimated global error at each output time (max over
  bodies and output points).
"""

from __future__ import annotations

import difflib
import logging
import math
import time as _time

import numpy as np

from mbsim.analyses import redundancy
from mbsim.analyses.common import Recorder, rank_and_redundant, singular_rows
from mbsim.analyses.kinematic import output_times
from mbsim.errors import DeckError, Where
from mbsim.integrators import ALIASES, DEFAULT, INTEGRATORS, System
from mbsim.integrators.base import NUMERICAL_ERRORS, IntegratorFailure
from mbsim.result import STATUS_INCOMPLETE

log = logging.getLogger(__name__)

DEFAULTS = {"t_start": 0.0, "t_end": 1.0, "step": 0.01, "integrator": DEFAULT, "rtol": 1e-6,
            "atol": None, "h": None, "max_steps": 1_000_000, "tol": 1e-10, "sparse": None,
            "error_estimate": True, "estimate_ratio": 5.0, "accuracy": None}

ACCURACY_START = 3e-3
"""--accuracy: first tolerance = this x the requested error (rtol = atol).  The ratio true
error / rtol of projection-dop853 on the reference problems is 1-650 at loose and 1-220 at
tight tolerances (largest on the fast top: orientation phase error over 300 rad of spin),
so tol/300 meets the request at the first attempt on all but the loosest top request, and
for an order-8 method a tolerance 100x tighter than needed costs only ~100^(1/9) = 1.7x
the steps, less than a missed attempt (benchmarks/accuracy.py; 0.2 missed on 12 of 15
cases and cost 2.5-3.7x the cheapest pair)."""
ACCURACY_MARGIN = 0.5  # a refinement aims at this fraction of the request
ATOL_PER_RTOL = 1e-2  # atol when not given: rtol / 100 (as mbsim bench's ladder)
ESTIMATE_STEPS = 10  # the companion run may take at most this x the run's steps (+100)

def make_system(model, rows, sparse=None):
    """The equations of motion the integrators call: :class:`mbsim.integrators.System`
    (the C kernels of :mod:`mbsim.fast`)."""
    return System(model, rows, sparse)


def integrator_class(name: str):
    """The integrator class for a name (or an alias); unknown names are a usage error."""
    key = ALIASES.get(name, name)
    if key not in INTEGRATORS:
        hint = difflib.get_close_matches(name, list(INTEGRATORS) + list(ALIASES), n=2)
        extra = f"; did you mean {' or '.join(hint)}?" if hint else ""
        raise DeckError(f"unknown integrator {name!r}{extra} (known: {', '.join(INTEGRATORS)})")
    return INTEGRATORS[key]




def check_tolerances(opt, file=None):
    """rtol, atol, accuracy, estimate_ratio must be finite numbers in their ranges: a deck or
    usage error otherwise (exit 2), never a run that hangs or a traceback."""
    def bad(key, v, want):
        opt_name = "--" + key.replace("_", "-")
        raise DeckError(f"expected {want}, got {v!r} (deck key or option {opt_name})",
                        Where(file or "<options>", f"analysis.dynamic.{key}"))

    for key in ("rtol", "atol"):
        v = opt.get(key)
        if v is None:
            continue
        try:
            x = float(v)
        except (TypeError, ValueError):
            bad(key, v, "a number")
        if not (math.isfinite(x) and 0 < x < 1):
            bad(key, v, "a number in (0, 1), e.g. 1e-6 (0 would ask for exact arithmetic)")
    if opt.get("accuracy") is not None:
        try:
            x = float(opt["accuracy"])
        except (TypeError, ValueError):
            bad("accuracy", opt["accuracy"], "a position error in m")
        if not (math.isfinite(x) and 0 < x < 1):
            bad("accuracy", opt["accuracy"], "a position error in m (and rad) in (0, 1), e.g. 1e-6")
    try:
        r = float(opt.get("estimate_ratio", 5.0))
    except (TypeError, ValueError):
        r = float("nan")
    if not (math.isfinite(r) and r > 1):
        bad("estimate_ratio", opt.get("estimate_ratio"), "a number > 1, e.g. 5")
    for key in ("step", "h", "h_max"):
        v = opt.get(key)
        if v is not None and not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            bad(key, v, "a positive time in s")


def dynamic(model, options=None):
    """Run a dynamic analysis; returns a Result (status incomplete, with the data up to the
    failure, when the integrator fails).

    options: t_start, t_end, step (output step, s), integrator (name, see
    ``mbsim list integrators``), rtol, atol, h (fixed step: no error control; a fixed-step
    method without h steps at ``step``), h_max, max_steps, sparse (None: by size), q0/qd0 (a
    consistent initial state instead of the deck's), error_estimate (bool, default True),
    estimate_ratio (rho, default 5), accuracy (the position error wanted, m, and
    orientation error, rad: chooses the tolerances, see :func:`_accuracy_run`), and the
    integrator's own options (alpha, beta, rho_inf, repartition_ratio, jacobian,
    newton_tol).
    """
    wall0 = _time.perf_counter()
    deck_opt = model.spec.analysis.get("dynamic", {}) if model.spec else {}
    given = {k: v for k, v in (options or {}).items() if v is not None}
    opt = dict(DEFAULTS, **deck_opt)
    opt.update(given)
    progress = opt.pop("progress", None)  # progress(t, t_end) per output (mbsim.progress)
    check_tolerances(opt, model.file)
    if opt.get("atol") is None:  # follows rtol: 1e-8 at the default rtol 1e-6 (m, rad, m/s)
        opt["atol"] = ATOL_PER_RTOL * float(opt["rtol"])
    # NaN and overflow are detected and reported by the integrators (non-finite error norms,
    # states), so numpy's RuntimeWarning lines would only be noise on stderr
    with np.errstate(all="ignore"):
        if opt.get("accuracy") is not None:
            res = _accuracy_with_fallback(model, opt, progress, given, deck_opt)
        else:
            res = _single_run(model, opt, progress)
    res.wall_time = _time.perf_counter() - wall0
    return res


class Trajectory:
    """What one integration produced at the output times: t, q, qd, w (work of the
    non-conservative forces), h (the step across each output) and the equations of motion
    (the Stepper's system, i.e. its row set) in use there.  Recording only this during the
    integration keeps a run that is not kept (the companion, a missed ``accuracy`` attempt)
    cheap; the channels of the kept run are computed afterwards, vectorised where they can
    be (:func:`_build_result`)."""

    def __init__(self):
        self.t, self.q, self.qd, self.w, self.h, self.systems = [], [], [], [], [], []
        self.status, self.message, self.cpu = "complete", "", 0.0
        self.interrupted = False
        self.run = None  # the Stepper

    def add(self, t, q, qd, w, h, system):
        # the state first, t last: a Ctrl-C in between leaves lists of unequal length, which
        # __len__ and trim() reduce to the complete outputs
        self.q.append(np.array(q, float))
        self.qd.append(np.array(qd, float))
        self.w.append(float(w))
        self.h.append(float(h))
        self.systems.append(system)
        self.t.append(float(t))

    def __len__(self):
        return min(len(self.t), len(self.q), len(self.qd), len(self.systems))

    def trim(self, n=None):
        n = len(self) if n is None else n
        for v in (self.t, self.q, self.qd, self.w, self.h, self.systems):
            del v[n:]

    @property
    def complete(self):
        return self.status == "complete"


def _trajectory(run, times, q0, qd0, max_steps, progress=None):
    """Integrate ``run`` (a :class:`Stepper`) over ``times`` recording a
    :class:`Trajectory`; a Ctrl-C ends it as incomplete with what was computed."""
    cpu0 = _time.process_time()
    tr = Trajectory()
    tr.run = run
    t1 = float(times[-1])

    def record(t, q, qd, w, h):
        tr.add(t, q, qd, w, h, run.system)
        if progress is not None:
            progress(t, t1)

    try:
        record(times[0], q0, qd0, 0.0, np.nan)
        tr.status, tr.message = _integrate(run, times, record, max_steps)
    except KeyboardInterrupt:  # Ctrl-C: keep what was computed, marked incomplete
        tr.status, tr.interrupted = STATUS_INCOMPLETE, True
        tr.message = (f"t = {run.solver.t:.6g} s: interrupted (Ctrl-C) before "
                      f"t_end = {t1:g} s")
    tr.trim()
    if len(tr.h) > 1 and not np.isfinite(tr.h[0]):  # the step across t_start: the first one
        tr.h[0] = run.first_step or 0.0
    tr.cpu = _time.process_time() - cpu0
    return tr


class _Prepared:
    """What every integration of one dynamic analysis shares: the method, the output
    times, the consistent initial state and the independent rows chosen at t_start."""

    def __init__(self, model, opt):
        self.cpu0 = _time.process_time()
        self.cls = integrator_class(str(opt["integrator"]))
        t0, t1 = float(opt["t_start"]), float(opt["t_end"])
        self.times = output_times(t0, t1, float(opt["step"]))
        self.q0, self.qd0, self.summary = _initial(model, t0, opt)
        self.rank, self.red = rank_and_redundant(model, _jac(model, self.q0, t0))
        self.rows = np.setdiff1d(np.arange(model.m), self.red)
        self.cpu = _time.process_time() - self.cpu0

    def stepper(self, model, opt):
        t0 = float(self.times[0])
        try:
            return Stepper(model, self.cls, opt, t0, self.q0.copy(), self.qd0.copy(),
                           float(self.times[-1]), self.rows)
        except NUMERICAL_ERRORS as exc:
            raise DeckError(f"the equations of motion cannot be solved at t_start = {t0:g} s "
                            f"({self.cls.name}): {exc}", Where(model.file, "bodies")) from exc


def _main_trajectory(model, prep, opt, progress=None):
    run = prep.stepper(model, opt)
    return _trajectory(run, prep.times, prep.q0, prep.qd0, int(opt["max_steps"]), progress)


def _single_run(model, opt, progress=None):
    """One integration with its error estimate: the Result of :func:`dynamic`."""
    opt = dict(opt)
    prep = _Prepared(model, opt)
    if not prep.cls.adaptive and opt.get("h") is None:
        opt["h"] = float(opt["step"])
    tr = _main_trajectory(model, prep, opt, progress)
    est = None
    if tr.interrupted:  # the user asked to stop: not another integration now
        est = {"method": "not computed: the run was interrupted", "position": None,
               "reason": "the run was interrupted (Ctrl-C or SIGTERM) before t_end"}
    elif opt.get("error_estimate", True) and len(tr) >= 2:
        est = _estimate(model, prep, opt, tr)
    return _build_result(model, prep, opt, tr, est)


def _output_row(model, system, t, q, qd):
    """(qdd, lam over all rows, Phi (m,), Phi_q qd - nu (m,)) at one output."""
    try:
        qdd, lam, _ = system.accelerations(q, qd, t)
    except NUMERICAL_ERRORS:  # exactly at a singular position: least squares
        qdd, lam = _accelerations_lstsq(model, system, q, qd, t)
    ph, v = system.residuals(q, qd, t)
    return qdd, system.full_lam(lam), ph, v


def _dropped_rows_conflict(model, system, t, q, ph, tol, cache):
    """The message when the rows this system dropped as redundant do not hold where its
    active rows do, else None (redundancy.position_bound, at the larger of the active rows'
    violation and the Newton tolerance).  ``cache``: {id(system): (red, C, row norms of
    C)}: C is found once per row set and found again at q before a violation is reported
    (the dependency turns with the mechanism)."""
    rows = system.rows
    if rows.size == model.m:
        return None
    level = max(float(np.abs(ph[rows]).max(initial=0.0)), tol)

    def worst(C, cnorm):
        r = np.abs(ph[red])
        bound = redundancy.position_bound(cnorm, level)
        return (None, r) if np.all(r <= bound) else (int(np.argmax(r / bound)), r)

    key = id(system)
    fresh = key not in cache
    if fresh:
        red = np.setdiff1d(np.arange(model.m), rows)
        C = redundancy.dependency(_jac(model, q, t), red, rows)
        cache[key] = (red, C, np.abs(C).sum(axis=1))
    red, C, cnorm = cache[key]
    k, r = worst(C, cnorm)
    if k is not None and not fresh:
        C = redundancy.dependency(_jac(model, q, t), red, rows)
        cache[key] = (red, C, np.abs(C).sum(axis=1))
        k, r = worst(C, cache[key][2])
    if k is None:
        return None
    items = redundancy.conflict_items(model, C, red, rows, k)
    return (f"t = {t:.6g} s: the redundant constraints of {', '.join(items)} no longer hold "
            f"(residual {r[k]:.3g}, the independent rows hold to {level:.3g}): the motion "
            f"followed the independent rows onto another branch (past a singular position) "
            f"or the constraints conflict; from here it is not the mechanism's motion")


def _build_result(model, prep, opt, tr, est):
    """The Result of a run: the standard channels and monitors at the outputs of ``tr``,
    its summary, and the error estimate ``est`` (a dict of :func:`_estimate`, or None)."""
    cpu0 = _time.process_time()
    cls, run = prep.cls, tr.run
    status, message = tr.status, tr.message
    counters = run.all_counters()  # before the outputs' own evaluations
    rec = Recorder(model)
    lam, pos, vel = [], [], []
    n = len(tr)
    dropped: dict = {}
    stopped = None  # the message of a stop found while the outputs are recorded
    span = _motion_span(model, tr)
    drift_limit = DRIFT_FACTOR * (float(opt["rtol"]) * max(1.0, span) + float(opt["atol"]))
    try:
        for k in range(n):
            try:
                qdd, la, ph, v = _output_row(model, tr.systems[k], tr.t[k], tr.q[k], tr.qd[k])
            except NUMERICAL_ERRORS as exc:
                if k == 0:
                    raise DeckError(f"the equations of motion cannot be solved at t_start = "
                                    f"{tr.t[0]:g} s: {exc}", Where(model.file, "bodies")) from exc
                status, message = STATUS_INCOMPLETE, (f"t = {tr.t[k]:.6g} s: evaluating the "
                                                      f"outputs failed: {exc}")
                break
            if np.abs(ph).max(initial=0.0) > drift_limit:  # drift the method did not hold
                row = int(np.argmax(np.abs(ph)))
                status, message = STATUS_INCOMPLETE, (
                    f"t = {tr.t[k]:.6g} s: constraint drift: |Phi| = {abs(ph[row]):.3g} "
                    f"({model.row_label[row]}) is over {DRIFT_FACTOR:g} x the tolerance "
                    f"({drift_limit:.3g}): {cls.name} did not hold the constraints, the motion "
                    f"has left the mechanism (baumgarte: keep its drift bound; or tighten rtol)")
                stopped = message
                break
            stopped = _dropped_rows_conflict(model, tr.systems[k], tr.t[k], tr.q[k], ph,
                                             float(opt["tol"]), dropped)
            if stopped is not None:  # the outputs before it are right; this one is not
                status, message = STATUS_INCOMPLETE, stopped
                break
            lam.append(la)
            pos.append(float(np.abs(ph).max(initial=0.0)))
            vel.append(float(np.abs(v).max(initial=0.0)))
            rec.add(tr.t[k], tr.q[k], tr.qd[k], qdd)
    except KeyboardInterrupt:  # Ctrl-C while the outputs are evaluated: keep those done
        status = STATUS_INCOMPLETE
        message = message or f"t = {tr.t[len(rec)]:.6g} s: interrupted (Ctrl-C)"
    n = len(rec)
    if n < len(tr):
        tr.trim(n)
    if not tr.complete and not tr.interrupted and stopped is None:
        message = _explain(model, run.system, run.solver, message)
    res = rec.result("dynamic")
    if n:
        from mbsim.analyses.common import kinetic_energies, potential_energies

        kin = rec.kinematics()
        V = potential_energies(model, rec.q, kin)
        energy = kinetic_energies(model, kin) + V
        res.add("monitors/position_violation", pos, "", "max |Phi| over all rows")
        res.add("monitors/velocity_violation", vel, "", "max |Phi_q qd - nu|")
        res.add("monitors/energy", energy, "J", "kinetic + potential energy T + V")
        res.add("monitors/work_nonconservative", np.array(tr.w) + V - V[0], "J",
                "work of non-conservative forces and drivers; energy - work is conserved")
        res.add("monitors/step_size", np.nan_to_num(np.array(tr.h), nan=0.0), "s",
                "integrator step across each output (t_start: the first step)")
        res.add("constraints/lam", lam, "", "Lagrange multipliers per constraint row",
                model.row_label)
    res.status, res.message = status, message
    res.settings = {k: (float(v) if isinstance(v, (int, float)) and not isinstance(v, bool)
                        else v) for k, v in opt.items()
                    if k not in ("q0", "qd0") and (v is None or np.isscalar(v))}
    res.settings["integrator"] = cls.name
    counters["output_evaluations"] = n
    res.counters = counters
    summary = dict(prep.summary)
    rank, red = prep.rank, prep.red
    summary.update({"integrator": cls.name, "formulation": cls.formulation,
                    "rtol": float(opt["rtol"]), "atol": float(opt["atol"]),
                    "h": None if opt.get("h") is None else float(opt["h"]),
                    "dof": model.nq - rank, "rank": rank,
                    "redundant": model.items_of_rows(red) if red.size else [],
                    "row_changes": run.changes,
                    "sparse": run.system.sparse, "equations": "C kernels (mbsim.fast)",
                    "t_reached": float(run.solver.t)})
    cpu_run = prep.cpu + tr.cpu + _time.process_time() - cpu0
    summary["cpu"] = cpu_run
    if est is not None:
        est = dict(est)
        est["relative_cost"] = est.get("cpu", 0.0) / max(cpu_run, 1e-9)
        summary["error_estimate"] = {k: v for k, v in est.items()
                                     if k != "channels" and not k.startswith("_")}
        for name, data, unit, desc in _error_channels(est, len(prep.times), n):
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
    res.summary = summary
    return res


MAX_ROW_CHANGES = 20  # re-selections of the independent rows in one run
DRIFT_FACTOR = 1e3
"""A run whose constraint violation (all rows) exceeds this x (rtol x max(1 m, the motion's
span) + atol) ends there, incomplete, naming the time and the row.  The methods hold the
constraints to their Newton or projection tolerance, or (baumgarte with its drift bound)
within 10 rtol: a violation 1000 x the tolerance is drift the method did not control, and
the motion past it is not the mechanism's (baumgarte without its bound on the four parallel
cranks: 1.2e-5 at the flat position of t = 0.297 s, the motion 7 mm off at 0.32 s)."""


def _motion_span(model, tr):
    """m: the largest range of any body's centroid coordinate over the outputs of ``tr``."""
    n = len(tr)
    if n == 0:
        return 0.0
    Q = np.array(tr.q[:n]).reshape(n, model.nb, 7)[:, :, :3]
    return float(np.max(np.ptp(Q, axis=0), initial=0.0))


class Stepper:
    """The integrator of a run with its equations of motion on the independent constraint
    rows, and what to do when a step fails.

    The redundant rows are found by QR with column pivoting of Phi_q at t_start and
    removed.  When the integrator fails (or stalls) at a configuration where that choice no
    longer holds (the rank of Phi_q changed, or another set of rows is now the independent
    one), the rows are chosen again at the last accepted state and the integrator restarts
    there with its last step size: ``changes`` lists when and which rows became redundant.
    A failure with the same rows still independent is final."""

    def __init__(self, model, cls, opt, t0, q, qd, t1, rows):
        self.model, self.cls, self.opt, self.t1 = model, cls, opt, t1
        self.rows = rows
        self.system = make_system(model, rows, opt.get("sparse"))
        self.solver = cls(self.system, t0, q, qd, t1, opt)
        self.changes: list[dict] = []
        self._retired: list[dict] = []  # counters of the integrators before a restart
        self.first_step = None

    def step(self):
        ok, msg = self.solver.step()
        if ok and self.first_step is None:
            self.first_step = self.solver.h_last
        return ok, msg

    def restart(self, message) -> bool:
        """Re-select the rows at the last accepted state; True when the run goes on."""
        s, model = self.solver, self.model
        if len(self.changes) >= MAX_ROW_CHANGES:
            return False
        try:
            rank, red = rank_and_redundant(model, _jac(model, s.q, s.t))
        except NUMERICAL_ERRORS:
            return False
        rows = np.setdiff1d(np.arange(model.m), red)
        if np.array_equal(rows, self.rows):
            return False
        opt = dict(self.opt, h0=s.h_last or None)
        try:
            system = make_system(model, rows, opt.get("sparse"))
            solver = self.cls(system, s.t, s.q, s.qd, self.t1, opt)
        except NUMERICAL_ERRORS:  # the new rows do not solve here either: the failure stands
            return False
        solver.w = s.w
        self._retired.append(s.all_counters())
        names = model.items_of_rows(red) if red.size else []
        self.changes.append({"t": float(s.t), "rank": int(rank), "redundant": names,
                             "after": message})
        log.info("t = %.6g s: independent rows chosen again (rank %d; redundant: %s) after: %s",
                 s.t, rank, ", ".join(names) or "none", message)
        self.rows, self.system, self.solver = rows, system, solver
        return True

    def all_counters(self) -> dict:
        out = self.solver.all_counters()
        for old in self._retired:
            for k, v in old.items():
                out[k] = out.get(k, 0) + v
        out["row_changes"] = len(self.changes)
        return out


def _integrate(run, times, record, max_steps):
    """Step ``run`` (a :class:`Stepper`) to times[-1], calling ``record(t, q, qd, w, h)`` at
    times[1:].

    Returns (status, message); every numerical failure (a step, the dense output, a stall)
    ends as ('incomplete', message with the time), never as an exception."""
    k, steps = 1, 0
    while k < len(times):
        ok, msg = run.step()
        steps += 1
        if not ok:
            if run.restart(msg):
                continue
            return STATUS_INCOMPLETE, msg
        solver = run.solver
        eps = 1e-12 * max(1.0, abs(solver.t))
        if times[k] <= solver.t + eps:
            try:
                dense = solver.dense_output_safe()
                while k < len(times) and times[k] <= solver.t + eps:
                    tk = min(times[k], solver.t)
                    qk, qdk, wk = (solver.q, solver.qd, solver.w) if tk == solver.t else dense(tk)
                    record(times[k], qk, qdk, wk, solver.h_last)
                    k += 1
            except IntegratorFailure as exc:
                return STATUS_INCOMPLETE, str(exc)
            except NUMERICAL_ERRORS as exc:  # the output's own accelerations, energies
                return STATUS_INCOMPLETE, (f"t = {times[k]:.6g} s: evaluating the outputs "
                                           f"failed: {exc}")
        if steps >= max_steps and k < len(times):
            return STATUS_INCOMPLETE, (f"t = {solver.t:.6g} s: max_steps = {max_steps} reached "
                                       f"before t_end = {times[-1]:g} s (step size "
                                       f"{solver.h_last:.3g} s)")
    return "complete", ""


ERROR_UNITS = {
    "position": ("m", "estimated global error of positions (bodies, output points)"),
    "orientation": ("rad", "estimated global error of orientations (rotation angle)"),
    "velocity": ("m/s", "estimated global error of centroid and point velocities"),
    "angular_velocity": ("rad/s", "estimated global error of angular velocities")}


def _companion_options(cls, opt):
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
        kappa = cls.tolerance_exponent
        # error ~ rtol^kappa: the companion's own error is rho^-kappa of the run's, and
        # |y - y_c| ~ (1 - rho^-kappa) err.  For tolerance-proportional methods (kappa = 1)
        # the difference is taken as it is: measured est/err 0.8-2.7 (benchmarks/accuracy.py)
        factor = 1.0 if kappa >= 1.0 else 1.0 / (1.0 - rho ** -kappa)
        method = (f"companion run at rtol/{rho:g} = {copt['rtol']:.3g}, "
                  f"atol/{rho:g} = {copt['atol']:.3g}")
        if factor != 1.0:
            method += (f", times 1/(1 - {rho:g}^-kappa) = {factor:.3g} (error ~ "
                       f"rtol^kappa, kappa = {kappa:.3g})")
    return copt, factor, method


def _estimate(model, prep, opt, tr, companion=None):
    """The global error estimate of the run ``tr`` (module doc): a companion integration
    (or the given one, a Trajectory at the companion's options) and the differences at the
    output times.  Returns a dict for the summary, with the companion as ``_companion``.

    An estimate covers every output of the run or it is none: a companion that stops
    before the run's last output (where the run went on) is integrated again with another
    method (:func:`_fallback_companion`); if that stops too, the dict has ``position`` None
    and the ``reason``, and no partial figures."""
    cpu0 = _time.process_time()
    copt, factor, method = _companion_options(prep.cls, opt)
    times = np.asarray(tr.t, float)
    spent = 0.0  # CPU of a companion computed before (a promoted run's: its own)
    if companion is None:
        limit = _companion_step_limit(opt, tr)
        try:
            run = Stepper(model, prep.cls, copt, float(times[0]), prep.q0.copy(),
                          prep.qd0.copy(), float(times[-1]), prep.rows)
            companion = _trajectory(run, times, prep.q0, prep.qd0, limit)
        except NUMERICAL_ERRORS as exc:
            companion = _failed_trajectory(times, f"could not start ({exc})")
        if companion.interrupted:
            return {"method": method, "position": None, "cpu": _time.process_time() - cpu0,
                    "reason": "the companion run was interrupted (Ctrl-C) before it finished"}
    else:
        spent = companion.cpu
    first = None
    if len(companion) < len(tr):  # stopped where the run did not: another method
        first = companion.message or "it stopped early"
        alt = _fallback_companion(model, prep, opt, tr)
        if alt is not None:
            companion, copt, factor, method = alt
            method += f" (the companion at the run's method stopped: {first})"
    n = min(len(companion), len(tr))
    out = {"method": method, "cpu": spent + _time.process_time() - cpu0,
           "steps": int(companion.run.all_counters()["steps"]) if companion.run else 0,
           "_companion": companion, "_copt": copt}
    if n < len(tr):
        out["position"] = None
        out["reason"] = (f"the companion run stopped at t = "
                         f"{times[n - 1] if n else times[0]:.6g} s before the run's last "
                         f"output t = {times[len(tr) - 1]:.6g} s ({companion.message or first})"
                         "; an estimate that does not cover the run is not given")
        log.info("error estimate: none (%s)", out["reason"])
        return out
    err = state_differences(model, np.array(tr.q[:n]), np.array(tr.qd[:n]),
                            np.array(companion.q[:n]), np.array(companion.qd[:n]))
    out["channels"] = {key: factor * err[key] for key in ERROR_UNITS}
    for key in ERROR_UNITS:
        out[key] = float(np.max(out["channels"][key]))
    log.info("error estimate: position %.3g m, orientation %.3g rad (%s)", out["position"],
             out["orientation"], method)
    return out


def _companion_step_limit(opt, tr):
    return min(int(opt["max_steps"]),
               ESTIMATE_STEPS * int(tr.run.all_counters().get("steps", 0)) + 100)


def _failed_trajectory(times, message):
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


def _fallback_companion(model, prep, opt, tr):
    """(trajectory, options, factor, description) of a companion that reaches every output
    of ``tr`` when the first one stopped: the run's method at rtol/FALLBACK_RATIO, then the
    FALLBACK_COMPANIONS at FALLBACK_TIGHTER x the companion's tolerance; None when none
    does.  Only for error-controlled runs: a fixed-step run's companion is its own method at
    h/2 (Richardson), which another method cannot replace."""
    if opt.get("h") is not None or not prep.cls.adaptive:
        return None
    copt, _, _ = _companion_options(prep.cls, opt)
    kappa = prep.cls.tolerance_exponent
    tries = [(prep.cls, dict(copt, rtol=float(opt["rtol"]) / FALLBACK_RATIO,
                             atol=float(opt["atol"]) / FALLBACK_RATIO),
              1.0 / (1.0 - FALLBACK_RATIO ** -kappa))]
    tighter = dict(copt, rtol=max(copt["rtol"] * FALLBACK_TIGHTER, 2.5e-14),
                   atol=max(copt["atol"] * FALLBACK_TIGHTER, 1e-300))
    tries += [(INTEGRATORS[n], tighter, 1.0) for n in FALLBACK_COMPANIONS
              if INTEGRATORS[n] is not prep.cls]
    times = np.asarray(tr.t, float)
    for cls, o, factor in tries:
        try:
            run = Stepper(model, cls, o, float(times[0]), prep.q0.copy(), prep.qd0.copy(),
                          float(times[-1]), prep.rows)
            comp = _trajectory(run, times, prep.q0, prep.qd0, _companion_step_limit(opt, tr))
        except NUMERICAL_ERRORS:
            continue
        if comp.interrupted:
            return None
        if len(comp) >= len(tr):
            how = f", times {factor:.3g}" if factor != 1.0 else ""
            return comp, o, factor, (f"companion run with {cls.name} at rtol {o['rtol']:.3g}, "
                                     f"atol {o['atol']:.3g}{how}")
    return None


def _error_channels(est, nt, n):
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
    |omega - omega_c| (rad/s).  Q, QD, Qc, QDc: (nt, nq)."""
    from mbsim.rotations import A as rot_A
    from mbsim.rotations import E as rot_E

    nt, nb = Q.shape[0], model.nb
    X, V = Q.reshape(nt, nb, 7), QD.reshape(nt, nb, 7)
    Xc, Vc = Qc.reshape(nt, nb, 7), QDc.reshape(nt, nb, 7)
    r, p, rc, pc = X[..., :3], X[..., 3:], Xc[..., :3], Xc[..., 3:]
    pos = np.linalg.norm(r - rc, axis=2).max(axis=1)
    # rotation from the companion's orientation to the run's: vector part of conj(pc) (x) p
    vec = (pc[..., :1] * p[..., 1:] - p[..., :1] * pc[..., 1:]
           - np.cross(pc[..., 1:], p[..., 1:]))
    s = np.linalg.norm(vec, axis=2) / np.maximum(
        np.linalg.norm(p, axis=2) * np.linalg.norm(pc, axis=2), 1e-300)
    ori = (2 * np.arcsin(np.clip(s, 0.0, 1.0))).max(axis=1)
    pf, pcf = p.reshape(-1, 4), pc.reshape(-1, 4)
    w = 2 * np.einsum("kij,kj->ki", rot_E(pf), V[..., 3:].reshape(-1, 4)).reshape(nt, nb, 3)
    wc = 2 * np.einsum("kij,kj->ki", rot_E(pcf), Vc[..., 3:].reshape(-1, 4)).reshape(nt, nb, 3)
    vel = np.linalg.norm(V[..., :3] - Vc[..., :3], axis=2).max(axis=1)
    angv = np.linalg.norm(w - wc, axis=2).max(axis=1)
    if model.outputs:
        A = rot_A(pf).reshape(nt, nb, 3, 3)
        Ac = rot_A(pcf).reshape(nt, nb, 3, 3)
        for _, b, sl in model.outputs:
            sg, sgc = A[:, b] @ sl, Ac[:, b] @ sl
            pos = np.maximum(pos, np.linalg.norm(r[:, b] + sg - rc[:, b] - sgc, axis=1))
            vp = V[:, b, :3] + np.cross(w[:, b], sg)
            vpc = Vc[:, b, :3] + np.cross(wc[:, b], sgc)
            vel = np.maximum(vel, np.linalg.norm(vp - vpc, axis=1))
    return {"position": pos, "orientation": ori, "velocity": vel, "angular_velocity": angv}


def _accuracy_with_fallback(model, opt, progress, given, deck_opt):
    """``accuracy``: the deck's integrator is a preference, one asked for by the caller
    (``--integrator``, the API's options) a requirement.  When the preferred method cannot
    deliver (the run stops, or no estimate covers it, or the request is missed), the
    default method is tried and the better of the two kept, saying so."""
    explicit = {k for k in ("integrator", "h") if k in given or (k == "h" and k in deck_opt)}
    res = _accuracy_run(model, opt, progress, explicit)
    acc = res.summary["accuracy"]
    name = str(opt["integrator"])
    if ("integrator" in explicit or acc["met"] or acc.get("interrupted")
            or INTEGRATORS.get(ALIASES.get(name, name)) is INTEGRATORS[DEFAULT]):
        return res
    why = (res.message if not res.complete else acc.get("reason")
           or f"estimated {acc['estimate']:.3g} after {acc['runs']} run(s)")
    log.info("accuracy: the deck's integrator %s did not deliver (%s); trying %s", name, why,
             DEFAULT)
    alt = _accuracy_run(model, dict(opt, integrator=DEFAULT, h=None), progress, set())
    alt_acc = alt.summary["accuracy"]
    better = alt_acc["met"] or (alt.complete and not res.complete) or (
        alt.complete and math.isfinite(alt_acc["estimate"])
        and not alt_acc["estimate"] >= acc["estimate"])
    if not better:
        return res
    alt_acc["fallback"] = (f"the deck's integrator {name} could not deliver it ({why}); "
                           f"{DEFAULT} used instead")
    alt_acc["cpu"] += acc["cpu"]
    alt.summary.setdefault("warnings", []).append(f"--accuracy: {alt_acc['fallback']}")
    return alt


def _accuracy_run(model, opt, progress, explicit):
    """``accuracy`` = TOL: the run whose estimated position (m) and orientation (rad) errors
    are at most TOL.

    The integrator is the user's, else the default.  An adaptive method starts at
    rtol = atol = ACCURACY_START x TOL, a fixed-step one at its step; the error estimate of
    that run (its companion at rtol/rho, or h/2) decides.  If it missed, the tolerance (or
    step) is refined once by the measured ratio, assuming the error proportional to
    rtol^kappa (the method's tolerance_exponent; h^p for a fixed step) and aiming at
    ACCURACY_MARGIN x TOL; when that refinement is no tighter than the companion's own
    setting, the companion (already computed, and about rho^kappa times more accurate)
    becomes the run and only a new companion is integrated.  Only the kept run's channels
    are computed."""
    tol = float(opt["accuracy"])
    opt = dict(opt, error_estimate=True)
    prep = _Prepared(model, opt)
    cls = prep.cls
    fixed = (not cls.adaptive) or ("h" in explicit and opt.get("h") is not None)
    if fixed:
        opt["h"] = float(opt.get("h") or opt["step"])
    else:
        opt["rtol"] = opt["atol"] = ACCURACY_START * tol
    tr = _main_trajectory(model, prep, opt, progress)
    history, cpu, est, companion = [], prep.cpu, None, None
    while len(tr) >= 2 and not tr.interrupted:
        est = _estimate(model, prep, opt, tr, companion)
        e = (math.nan if est.get("position") is None
             else max(est["position"], est["orientation"]))
        cpu += tr.cpu + est.get("cpu", 0.0)
        history.append({"rtol": float(opt["rtol"]), "atol": float(opt["atol"]),
                        "h": opt.get("h"), "estimate": e, "status": tr.status,
                        "promoted": companion is not None})
        if e <= tol or not tr.complete or len(history) == 2 or est.get("position") is None:
            break
        ratio = min(max(ACCURACY_MARGIN * tol / e, 1e-4), 0.5)
        new = dict(opt)
        if fixed:
            new["h"] = float(opt["h"]) * ratio ** (1.0 / max(cls.order, 1))
        else:  # error ~ rtol^kappa (Integrator.tolerance_exponent)
            ratio = ratio ** (1.0 / cls.tolerance_exponent)
            new["rtol"] = max(float(opt["rtol"]) * ratio, 1e-13)
            new["atol"] = max(float(opt["atol"]) * ratio, 1e-15)
        copt, comp = est["_copt"], est["_companion"]
        promote = comp.complete and (new["h"] >= copt["h"] if fixed
                                     else new["rtol"] >= copt["rtol"])
        log.info("accuracy %.3g: estimate %.3g missed; %s", tol, e,
                 "the companion becomes the run" if promote else
                 f"refining (rtol {new['rtol']:.3g}, h {new.get('h')})")
        if promote:
            opt, tr, companion = dict(copt, h0=opt.get("h0")), comp, None
        else:
            opt, companion = new, None
            tr = _main_trajectory(model, prep, opt, progress)
    if est is not None:
        est = {k: v for k, v in est.items() if not k.startswith("_")}
    res = _build_result(model, prep, opt, tr, est)
    e = history[-1]["estimate"] if history else math.nan
    # met: the run reached t_end and an estimate covering all of it is within the request
    met = bool(res.complete and e <= tol)
    res.summary["accuracy"] = {
        "requested": tol, "integrator": cls.name, "rtol": float(opt["rtol"]),
        "atol": float(opt["atol"]), "h": opt.get("h"), "runs": len(history),
        "estimate": e, "met": met, "cpu": cpu, "history": history,
        "interrupted": bool(tr.interrupted)}
    if not math.isfinite(e):
        why = (est or {}).get("reason") or (est or {}).get("method") or "no run to compare"
        res.summary["accuracy"]["reason"] = str(why)
    if res.complete and not met:
        res.summary.setdefault("warnings", []).append(
            f"accuracy {tol:g} not reached: estimated error {e:.3g} after {len(history)} runs"
            if math.isfinite(e) else
            f"accuracy {tol:g} not checked: no error estimate covers the run "
            f"({res.summary['accuracy']['reason']})")
    res.settings["accuracy"] = tol
    return res


def _accelerations_lstsq(model, system, q, qd, t):
    """qdd and lam at a configuration where the active rows are singular (a change point):
    the minimum-norm solution of the KKT equations on all rows."""
    import scipy.linalg as la

    from mbsim import core

    T = core.constraints(model, None, q, t, qd=qd, phi=False, gamma=True)
    Q = system.generalized_forces(q, qd, t)
    M = core.mass_matrix(model, None, q)
    J, g = T.jac, T.gamma
    n, m = model.nq, J.shape[0]
    K = np.zeros((n + m, n + m))
    K[:n, :n], K[:n, n:], K[n:, :n] = M, J.T, J
    sol = la.lstsq(K, np.concatenate([Q, g]), cond=1e-12)[0]
    return sol[:n], sol[n:][system.rows]

def _jac(model, q, t):
    from mbsim import core
    from mbsim.analyses.common import DENSE_NQ

    return core.phi_q(model, None, q, t, sparse=model.nq >= DENSE_NQ)


def _initial(model, t0, opt):
    """(q, qd, summary) from options q0/qd0 or the initial-condition analysis."""
    if opt.get("q0") is not None:
        q = np.array(opt["q0"], dtype=float)
        qd = np.zeros(model.nq) if opt.get("qd0") is None else np.array(opt["qd0"], float)
        return q, qd, {"initial": "given"}
    from mbsim.analyses.initial import initial_state

    q, qd, _, _, info = initial_state(model, t0, tol=float(opt["tol"]))
    summary = {"initial": "deck"}
    if info.get("warnings"):
        summary["warnings"] = list(info["warnings"])
    return q, qd, summary


SINGULAR_CONDITION = 1e6  # Phi_q condition from which a failure blames the constraints
SWITCH_PROBE = 1e-9  # s: the states probed either side of a failure along the motion
SWITCH_JUMP = 1e-2  # relative change of an element's load across the probe that is a jump


def _explain(model, system, solver, msg):
    """The integrator's message plus what is special at the last accepted state: the
    constraints nearest to a singular configuration (said to be near singular only where
    Phi_q's condition is at least SINGULAR_CONDITION), and the force elements whose load
    jumps there (a law that switches on the sign of a velocity or a coordinate, as a valve
    or dry friction: where the motion stays at the switch no step passes it, and the step
    size collapses)."""
    notes = []
    try:
        J = system.terms(solver.q, solver.t, phi=False).jac
        J = J.toarray() if hasattr(J, "toarray") else J
        rows, s = singular_rows(model, J)
        cond = s[0] / s[-1] if s[-1] > 0 else np.inf
        names = ", ".join(model.items_of_rows(system.rows[rows]))
        notes.append(f"Phi_q condition {cond:.3g}; constraints nearest to singular: {names}"
                     if cond >= SINGULAR_CONDITION else
                     f"Phi_q condition {cond:.3g}, not near singular (its weakest rows: "
                     f"{names})")
    except (np.linalg.LinAlgError, ValueError):  # the explanation must not hide the failure
        pass
    jumps = _switching_forces(model, system, solver.q, solver.qd, solver.t)
    if jumps:
        notes.append(f"force elements whose load jumps there: {', '.join(jumps)} (a law "
                     f"that switches on the motion: where the motion stays at the switch, "
                     f"a sliding mode, no step passes it)")
    if not notes:
        return msg
    return f"{msg} (last accepted state t = {solver.t:.6g} s; {'; '.join(notes)})"


def _switching_forces(model, system, q, qd, t):
    """Names of the force elements whose load differs by more than SWITCH_JUMP of its size
    between the states SWITCH_PROBE s before and after (q, qd, t) along the motion (Taylor
    steps with the accelerations there).  A smooth law changes by its rate x 2e-9 s there:
    1e-6 relative for a 1e7 N/m spring at 10 m/s against a 1e3 N load."""
    try:
        qdd = system.accelerations(q, qd, t)[0]
    except NUMERICAL_ERRORS:
        return []
    from mbsim import core

    e = SWITCH_PROBE
    states = [(q + sg * e * qd + 0.5 * e * e * qdd, qd + sg * e * qdd, t + sg * e)
              for sg in (-1.0, 1.0)]
    out = []
    for el in model.forces:
        loads = []
        try:
            for qs, vs, ts in states:
                F, n = np.zeros((model.nb, 3)), np.zeros((model.nb, 3))
                el.apply(core.State(model, qs, vs), ts, F, n)
                loads.append(np.concatenate([F.ravel(), n.ravel()]))
        except Exception:  # noqa: BLE001 - the explanation must not hide the failure
            continue
        size = max(np.abs(loads[0]).max(), np.abs(loads[1]).max())
        if size > 0 and np.abs(loads[1] - loads[0]).max() > SWITCH_JUMP * size:
            out.append(el.name or type(el).__name__)
    return out
