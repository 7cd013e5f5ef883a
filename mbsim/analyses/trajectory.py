"""The driver of a dynamic run: set-up, stepping, row re-selection and recording.

- :class:`Prepared`: what every integration of one analysis shares (the method, the output
  times, the consistent initial state, the independent rows at t_start);
- :class:`Stepper`: the integrator on the independent rows, chosen again when a step fails
  where that choice no longer holds, with the modes of the hybrid force elements and the
  rows those modes hold; it restarts at every event (:mod:`mbsim.events`);
- :func:`integrate` / :func:`trajectory`: step to t_end and record the state at the output
  times from the dense output (:class:`Trajectory`), so output sampling never constrains
  the step size;
- :func:`build_result`: the channels and monitors of a kept run at its outputs (the
  accelerations and multipliers solved from the sampled (q, qd)), its counters and summary.

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
"""

from __future__ import annotations

import difflib
import logging
import time as _time

import numpy as np

from mbsim.analyses.common import Recorder, rank_and_redundant
from mbsim.analyses.diagnosis import accelerations_lstsq, dropped_rows_conflict, explain, jacobian
from mbsim.analyses.kinematic import output_times
from mbsim.errors import DeckError, Where
from mbsim.events import MAX_EVENTS, MAX_EVENTS_AT_ONE_TIME, Context, Watch, extend_model
from mbsim.fast.stepper import Outputs
from mbsim.integrators import ALIASES, INTEGRATORS, System
from mbsim.integrators.base import NUMERICAL_ERRORS, IntegratorFailure
from mbsim.integrators.system import SolveError
from mbsim.options import NO_DECK
from mbsim.result import STATUS_INCOMPLETE

log = logging.getLogger(__name__)


def make_system(model, rows, sparse=None, modes=None):
    """The equations of motion the integrators call: :class:`mbsim.integrators.System`
    (the C kernels of :mod:`mbsim.fast`); ``modes``: of the hybrid force elements."""
    return System(model, rows, sparse, modes)


def integrator_class(name: str):
    """The integrator class for a name (or an alias); unknown names are a usage error."""
    key = ALIASES.get(name, name)
    if key not in INTEGRATORS:
        hint = difflib.get_close_matches(name, list(INTEGRATORS) + list(ALIASES), n=2)
        extra = f"; did you mean {' or '.join(hint)}?" if hint else ""
        raise DeckError(f"unknown integrator {name!r}{extra} (known: {', '.join(INTEGRATORS)})")
    return INTEGRATORS[key]


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
        self._stacked = None  # stacked(): (n, t, q, qd) as arrays, dropped by every change

    def add(self, t, q, qd, w, h, system):
        # the state first, t last: a Ctrl-C in between leaves lists of unequal length, which
        # __len__ and trim() reduce to the complete outputs
        self._stacked = None
        self.q.append(np.array(q, float))
        self.qd.append(np.array(qd, float))
        self.w.append(float(w))
        self.h.append(float(h))
        self.systems.append(system)
        self.t.append(float(t))

    def add_many(self, ts, Q, QD, W, h, system):
        """:meth:`add` of the outputs ``ts`` (k,) at once: Q, QD (k, nq) fresh arrays (their
        rows are kept, not copied), W (k,), h the step across them (a number: one step) or
        each one's (k,)."""
        self._stacked = None
        self.q.extend(Q)
        self.qd.extend(QD)
        self.w.extend(np.asarray(W, dtype=float).tolist())
        self.h.extend(np.broadcast_to(np.asarray(h, dtype=float), (len(ts),)).tolist())
        self.systems.extend([system] * len(ts))
        self.t.extend(np.asarray(ts, dtype=float).tolist())

    def __len__(self):
        return min(len(self.t), len(self.q), len(self.qd), len(self.systems))

    def trim(self, n=None):
        n = len(self) if n is None else n
        self._stacked = None
        for v in (self.t, self.q, self.qd, self.w, self.h, self.systems):
            del v[n:]

    def stacked(self, n=None):
        """(t (n,), q (n, nq), qd (n, nq)) of the first n outputs (default all) as arrays,
        stacked once for the span, the loads, the bulk outputs and the recorder (read
        only: shared by them)."""
        n = len(self) if n is None else n
        if self._stacked is None or self._stacked[0] != n:
            nq = self.q[0].size if n else 0
            t, q, qd = (np.array(self.t[:n], dtype=float), np.array(self.q[:n]).reshape(n, nq),
                        np.array(self.qd[:n]).reshape(n, nq))
            for a in (t, q, qd):
                a.flags.writeable = False
            self._stacked = (n, t, q, qd)
        return self._stacked[1:]

    @property
    def complete(self):
        return self.status == "complete"


def trajectory(run, times, q0, qd0, max_steps, progress=None):
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

    def record_many(ts, Q, QD, W, h):
        tr.add_many(ts, Q, QD, W, h, run.system)
        for t in ts if progress is not None else ():  # once per output, as record
            progress(float(t), t1)

    try:
        record(times[0], q0, qd0, 0.0, np.nan)
        tr.status, tr.message = integrate(run, times, record, max_steps, record_many)
    except KeyboardInterrupt:  # Ctrl-C: keep what was computed, marked incomplete
        tr.status, tr.interrupted = STATUS_INCOMPLETE, True
        tr.message = (f"t = {run.solver.t:.6g} s: interrupted (Ctrl-C) before "
                      f"t_end = {t1:g} s")
    tr.trim()
    if len(tr.h) > 1 and not np.isfinite(tr.h[0]):  # the step across t_start: the first one
        tr.h[0] = run.first_step or 0.0
    tr.cpu = _time.process_time() - cpu0
    return tr


class Prepared:
    """What every integration of one dynamic analysis shares: the method, the output
    times, the consistent initial state and the independent rows chosen at t_start."""

    def __init__(self, model, opt, context=NO_DECK):
        self.cpu0 = _time.process_time()
        self.context = context  # the run's DeckContext: the assembly's hold, outputs: only:
        self.cls = integrator_class(str(opt["integrator"]))
        t0, t1 = float(opt["t_start"]), float(opt["t_end"])
        self.times = output_times(t0, t1, float(opt["step"]))
        self.q0, self.qd0, self.summary = initial_conditions(model, t0, opt, context.hold)
        self.rank, self.red = rank_and_redundant(model, jacobian(model, self.q0, t0))
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


def main_trajectory(model, prep, opt, progress=None):
    """The run's own integration with options ``opt`` over ``prep``'s output times."""
    run = prep.stepper(model, opt)
    return trajectory(run, prep.times, prep.q0, prep.qd0, int(opt["max_steps"]), progress)


def initial_conditions(model, t0, opt, hold=None):
    """(q, qd, summary) from options q0/qd0 or the initial-condition analysis (``hold``: the
    coordinates its assembly keeps at their estimates)."""
    if opt.get("q0") is not None:
        q = np.array(opt["q0"], dtype=float)
        qd = np.zeros(model.nq) if opt.get("qd0") is None else np.array(opt["qd0"], float)
        return q, qd, {"initial": "given"}
    from mbsim.analyses.initial import initial_state

    q, qd, _, _, info = initial_state(model, t0, tol=float(opt["tol"]), hold=hold)
    summary = {"initial": "deck"}
    if info.get("warnings"):
        summary["warnings"] = list(info["warnings"])
    return q, qd, summary


def output_loads(model, forces, t, q, qd):
    """(nt, 2, nb, 3): the loads (F, n_local) of the force elements ``forces`` (the ones the
    C kernels do not evaluate: System.py_forces) at every output, each element's
    ``loads_many`` once for all outputs; None without such elements.  t (nt,), q, qd
    (nt, nq)."""
    if not forces or len(t) == 0 or any(getattr(el, "hybrid", False) for el in forces):
        return None  # hybrid elements: in each output's modes, inside output_row
    from mbsim import core

    states = core.States(model, q, qd)
    out = np.zeros((len(t), 2, model.nb, 3))
    F, n_local = out[:, 0], out[:, 1]
    for el in forces:
        el.loads_many(states, t, F, n_local)
    return out


def output_row(model, system, t, q, qd, loads=None):
    """(qdd, lam, Phi, Phi_q qd - nu) at one output, the last three on every row of the
    system's model: the model's m rows, then the rows its hybrid modes hold (their
    multipliers are the elements' holding forces, for their channels); loads: (2, nb, 3)
    the Python force elements' loads there (:func:`output_loads`), None: computed here."""
    try:
        qdd, lam, _ = system.accelerations(q, qd, t, loads=loads)
    except NUMERICAL_ERRORS:  # exactly at a singular position: least squares
        qdd, lam = accelerations_lstsq(model, system, q, qd, t)
    ph, v = system.residuals(q, qd, t)
    return qdd, system.full_lam(lam), ph, v


def output_targets(fc, t):
    """(nt, nf, 3): the time targets of the driven rows (FastConstraints.targets) at every
    output time ``t`` (nt,), each function once for all outputs where it takes an array,
    else output by output; None without driven rows."""
    from mbsim.fast.constraints import target

    if not fc.funcs:
        return None
    nt = len(t)
    tv = np.empty((nt, len(fc.funcs), 3))
    for n, (f, sq) in enumerate(fc.funcs):
        try:
            v, d1, d2 = (np.broadcast_to(np.asarray(g(t), dtype=float), (nt,))
                         for g in (f, f.d1, f.d2))
        except Exception:  # noqa: BLE001 - a scalar-only function: one output at a time
            v, d1, d2 = (np.array([float(g(x)) for x in t]) for g in (f, f.d1, f.d2))
        tv[:, n, 0], tv[:, n, 1], tv[:, n, 2] = target(v, d1, d2, sq)
    return tv


def output_rows(system, t, q, qd, loads=None):
    """:func:`output_row` at every output in one C call (mbsim/fast/outputs.c), for a run
    whose outputs share one system without hybrid elements or multiplier-dependent loads:
    (done, qdd (nt, nq), lam (nt, m), Phi (nt, m), Phi_q qd - nu (nt, m)); ``done`` < nt:
    the output where a factorisation failed (the arrays hold the ones before it; the caller
    evaluates it again with :func:`output_row`).  t (nt,), q, qd (nt, nq); loads (nt, 2, nb,
    3) the Python force elements' loads (:func:`output_loads`)."""
    from mbsim.fast import _lib

    nt, nq, m, ma = len(t), system.nq, system.model.m, system.m
    Q = np.ascontiguousarray(q, dtype=np.float64)
    QD = np.ascontiguousarray(qd, dtype=np.float64)
    tv = output_targets(system.fc, np.asarray(t, dtype=float))
    if loads is not None:
        loads = np.ascontiguousarray(loads, dtype=np.float64)
    qdd, lam = np.empty((nt, nq)), np.empty((nt, ma))
    ph, v = np.empty((nt, m)), np.empty((nt, m))
    status = np.zeros(1, dtype=np.int64)
    done = int(_lib.library().mb_outputs(
        system.c.ptr, int(system.kkt), nt, len(system.fc.funcs), Q.ctypes.data,
        QD.ctypes.data, None if tv is None else tv.ctypes.data,
        None if loads is None else loads.ctypes.data, qdd.ctypes.data, lam.ctypes.data,
        ph.ctypes.data, v.ctypes.data, status.ctypes.data))
    c = system.counters  # as output_row's two calls count them
    c["function_evaluations"] += done
    c["constraint_evaluations"] += 2 * done
    c["factorizations"] += done
    if not system.all_rows:
        full = np.zeros((nt, m))
        full[:, system.rows] = lam
        lam = full
    return done, qdd, lam, ph, v


def bulk_outputs(tr, n, loads):
    """:func:`output_rows` of the first n outputs of ``tr`` when they allow it (one system,
    no hybrid elements, no multiplier-dependent loads, the Python loads known), else None."""
    if n == 0:
        return None
    system = tr.systems[0]
    if (system.hybrid or system.reaction_loop or (system.py_forces and loads is None)
            or len(set(map(id, tr.systems[:n]))) > 1):
        return None
    t, q, qd = tr.stacked(n)
    return output_rows(system, t, q, qd, loads)


def build_result(model, prep, opt, tr, span):
    """The Result of a run: the standard channels and monitors at the outputs of ``tr``
    and its summary (the error estimate is added by
    :func:`mbsim.analyses.estimate.attach_estimate`).  ``span``: :func:`motion_span` of
    ``tr``, m."""
    cpu0 = _time.process_time()
    cls, run = prep.cls, tr.run
    status, message = tr.status, tr.message
    counters = run.all_counters()  # before the outputs' own evaluations
    rec = Recorder(model)
    lam, pos, vel = [], [], []
    n = len(tr)
    dropped: dict = {}
    stopped = None  # the message of a stop found while the outputs are recorded
    drift_limit = DRIFT_FACTOR * (float(opt["rtol"]) * max(1.0, span) + float(opt["atol"]))
    hybrid = bool(run.hybrid)
    loads = output_loads(model, tr.systems[0].py_forces if n else (), *tr.stacked(n))
    bulk = bulk_outputs(tr, n, loads)  # all outputs in one C call where it can
    done = bulk[0] if bulk is not None else 0
    start = 0
    if done and not hybrid and tr.systems[0].rows.size == model.m:
        # no rows dropped (dropped_rows_conflict has nothing to check): the outputs before
        # the first drift recorded at once; the loop below reports that one
        pos_all = np.abs(bulk[3][:done]).max(axis=1, initial=0.0)
        start = int(np.argmax(pos_all > drift_limit)) if np.any(pos_all > drift_limit) else done
        t_all, q_all, qd_all = tr.stacked(n)
        rec.add_many(t_all[:start], q_all[:start], qd_all[:start], bulk[1][:start])
        lam.extend(bulk[2][:start, :model.m])
        pos.extend(pos_all[:start].tolist())
        vel.extend(np.abs(bulk[4][:start]).max(axis=1, initial=0.0).tolist())
    try:
        for k in range(start, n):
            try:
                if k < done:
                    qdd, la, ph, v = bulk[1][k], bulk[2][k], bulk[3][k], bulk[4][k]
                else:
                    qdd, la, ph, v = output_row(model, tr.systems[k], tr.t[k], tr.q[k],
                                                tr.qd[k], None if loads is None else loads[k])
            except NUMERICAL_ERRORS as exc:
                if k == 0:
                    raise DeckError(f"the equations of motion cannot be solved at t_start = "
                                    f"{tr.t[0]:g} s: {exc}", Where(model.file, "bodies")) from exc
                status, message = STATUS_INCOMPLETE, (f"t = {tr.t[k]:.6g} s: evaluating the "
                                                      f"outputs failed: {exc}")
                break
            if np.abs(ph).max(initial=0.0) > drift_limit:  # drift the method did not hold
                row = int(np.argmax(np.abs(ph)))
                label = tr.systems[k].model.row_label[row]  # a held row too
                status, message = STATUS_INCOMPLETE, (
                    f"t = {tr.t[k]:.6g} s: constraint drift: |Phi| = {abs(ph[row]):.3g} "
                    f"({label}) is over {DRIFT_FACTOR:g} x the tolerance "
                    f"({drift_limit:.3g}): {cls.name} did not hold the constraints, the motion "
                    f"has left the mechanism (baumgarte: keep its drift bound; or tighten rtol)")
                stopped = message
                break
            stopped = dropped_rows_conflict(model, tr.systems[k], tr.t[k], tr.q[k], ph,
                                             float(opt["tol"]), dropped)
            if stopped is not None:  # the outputs before it are right; this one is not
                status, message = STATUS_INCOMPLETE, stopped
                break
            lam.append(la[:model.m])
            pos.append(float(np.abs(ph).max(initial=0.0)))
            vel.append(float(np.abs(v).max(initial=0.0)))
            if hybrid:  # each output's modes and multipliers (held rows too): their channels
                rec.add(tr.t[k], tr.q[k], tr.qd[k], qdd, modes=tr.systems[k].modes, lam_all=la)
            else:
                rec.add(tr.t[k], tr.q[k], tr.qd[k], qdd)
    except KeyboardInterrupt:  # Ctrl-C while the outputs are evaluated: keep those done
        status = STATUS_INCOMPLETE
        message = message or f"t = {tr.t[len(rec)]:.6g} s: interrupted (Ctrl-C)"
    n = len(rec)
    if n < len(tr):
        tr.trim(n)
    if not tr.complete and not tr.interrupted and stopped is None:
        message = explain(model, run.system, run.solver, message)
    res = rec.result("dynamic", prep.context.only)
    if n:
        from mbsim.analyses.common import kinetic_energies, potential_energies

        kin = rec.kinematics()
        V = potential_energies(model, rec.q, kin, rec.states() if model.forces else None)
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
    if run.events:
        add_events(res, model, run.events, n and tr.t[n - 1])
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
    if run.events:
        summary["events"] = event_summary(run.events, n and tr.t[n - 1])
    cpu_run = prep.cpu + tr.cpu + _time.process_time() - cpu0
    summary["cpu"] = cpu_run
    res.summary = summary
    return res


def _kept_events(events, t_last):
    """The events up to the last output (the run's outputs may stop short of its end)."""
    return [e for e in events if e["t"] <= t_last + 1e-12 * max(1.0, abs(t_last))]


def add_events(res, model, events, t_last):
    """The located events up to the last output as arrays of ``res``: events/time (ne,),
    events/q, events/qd (ne, nq) and the names 'owner: name' (names['events'])."""
    kept = _kept_events(events, t_last)
    if not kept:
        return
    res.arrays["events/time"] = (np.array([e["t"] for e in kept]), {"unit": "s"})
    res.arrays["events/q"] = (np.array([e["q"] for e in kept]), {
        "description": "generalized coordinates at each event (r, p per body)"})
    res.arrays["events/qd"] = (np.array([e["qd"] for e in kept]), {
        "description": "their rates at each event"})
    res.names["events"] = [f"{e['owner']}: {e['name']}" if e["owner"] != e["name"]
                           else e["name"] for e in kept]


MAX_SUMMARY_EVENTS = 200


def event_summary(events, t_last):
    """The summary's events: time, name, action (and the mode change), the first
    MAX_SUMMARY_EVENTS of them (all are in the file's arrays)."""
    kept = _kept_events(events, t_last)
    out = []
    for e in kept[:MAX_SUMMARY_EVENTS]:
        item = {"t": float(e["t"]), "event": e["name"], "action": e["action"]}
        if e["owner"] != e["name"]:
            item["element"] = e["owner"]
        if "from" in e:
            item["mode"] = f"{e['from']} -> {e['to']}"
        out.append(item)
    return out


MAX_ROW_CHANGES = 20  # re-selections of the independent rows in one run
DRIFT_FACTOR = 1e3
"""A run whose constraint violation (all rows) exceeds this x (rtol x max(1 m, the motion's
span) + atol) ends there, incomplete, naming the time and the row.  The methods hold the
constraints to their Newton or projection tolerance, or (baumgarte with its drift bound)
within 10 rtol: a violation 1000 x the tolerance is drift the method did not control, and
the motion past it is not the mechanism's (baumgarte without its bound on the four parallel
cranks: 1.2e-5 at the flat position of t = 0.297 s, the motion 7 mm off at 0.32 s)."""


def motion_span(model, tr):
    """m: the largest range of any body's centroid coordinate over the outputs of ``tr``."""
    n = len(tr)
    if n == 0:
        return 0.0
    Q = tr.stacked(n)[1].reshape(n, model.nb, 7)[:, :, :3]
    return float(np.max(np.ptp(Q, axis=0), initial=0.0))


class Stepper:
    """The integrator of a run with its equations of motion on the independent constraint
    rows, and what to do when a step fails.

    The redundant rows are found by QR with column pivoting of Phi_q at t_start and
    removed.  When the integrator fails (or stalls) at a configuration where that choice no
    longer holds (the rank of Phi_q changed, or another set of rows is now the independent
    one), the rows are chosen again at the last accepted state and the integrator restarts
    there with its last step size: ``changes`` lists when and which rows became redundant.
    A failure with the same rows still independent is final.

    With events (the deck's, or hybrid force elements: ``watch``), :meth:`on_event` notes
    each located event, sets the modes it changes, appends the rows those modes hold
    (:func:`mbsim.events.extend_model`) and restarts the integration at the event."""

    def __init__(self, model, cls, opt, t0, q, qd, t1, rows, system=None):
        self.model, self.cls, self.opt, self.t1 = model, cls, opt, t1
        self.rows = rows
        # hybrid elements' modes and the constraint rows those modes hold (mbsim.events);
        # the events located so far (dicts: t, name, owner, action, from, to, q, qd)
        self.modes: dict = {}
        self.holds: list = []
        self.events: list[dict] = []
        self.hybrid = tuple(el for el in model.forces if getattr(el, "hybrid", False))
        self.watch = Watch(model.events) if (model.events or self.hybrid) else None
        # ``system``: another run's equations of motion on the same rows, reused (the
        # coarse companion of the error estimate shares the run's: no second set-up)
        self.system = self._system(rows) if system is None or self.hybrid else system
        if self.hybrid:
            ctx = Context(self.system, t0, q, qd)
            self.modes = {el.name: el.initial_mode(ctx) for el in self.hybrid}
            self.holds = [h for el in self.hybrid for h in el.holds(self.modes[el.name], ctx)]
            self.system = self._system(rows)
            if self.holds:
                q, qd = self._consistent(self.system, t0, q, qd)
        self.solver = cls(self.system, t0, q, qd, t1, opt)
        self.h_max = self.solver.h_max  # the option's; events may lower it step by step
        self.changes: list[dict] = []
        self._retired: list[dict] = []  # counters of the integrators before a restart
        self.first_step = None
        # t at the end of every accepted step: the run's mesh (for the coarse error
        # estimate, mbsim.analyses.estimate.coarse_estimate)
        self.step_ends: list[float] = []
        self.solver.step_ends = self.step_ends
        self._same_time = 0  # events in a row without time moving on
        self._last_event_t = None
        if self.watch is not None:
            self.watch.reset(self, t0, q, qd)

    def _system(self, rows, modes=None, holds=None):
        """The equations of motion on the independent rows ``rows`` of the model plus the
        rows the modes hold, with the hybrid elements in ``modes`` (default: the run's)."""
        modes = self.modes if modes is None else modes
        holds = self.holds if holds is None else holds
        model = extend_model(self.model, holds)
        if holds:  # rows None: all of the model's
            rows = np.concatenate([np.arange(self.model.m) if rows is None else rows,
                                   np.arange(self.model.m, model.m)])
        system = (make_system(model, rows, self.opt.get("sparse"), modes) if modes
                  else make_system(model, rows, self.opt.get("sparse")))
        system.family = self
        return system

    def system_for(self, modes, ctx):
        """A system with the hybrid elements in ``modes`` at the state ``ctx`` (a mode
        candidate tested at an event: :meth:`mbsim.events.Context.trial`)."""
        return self._system(self.rows, modes, self._holds_for(modes, ctx))

    def _holds_for(self, modes, ctx):
        holds = []
        for el in self.hybrid:
            if modes.get(el.name) == self.modes.get(el.name):
                holds += [h for h in self.holds if h.owner == el.name]
            else:
                holds += el.holds(modes.get(el.name), ctx)
        return holds

    @staticmethod
    def _consistent(system, t, q, qd):
        """(q, qd) projected onto the constraints of ``system`` (mass-weighted): at a mode
        change the held rows start from the state's own values, so the projection only
        removes the relative velocity the stick stops (within the event's location)."""
        q, ok, _, res = system.project_positions(q, t)
        if not ok:
            raise SolveError(f"the held rows cannot be met at t = {t:.6g} s (max |Phi| "
                             f"{res:.3g})")
        return q, system.project_velocities(q, qd, t)

    def on_event(self, ev):
        """Act on the located event ``ev`` (:class:`mbsim.events.Event`): note it, change
        the modes of the hybrid elements whose switches fired (and of those whose optional
        ``joins(mode, ctx)`` gives a new mode: elements on the same switching surface whose
        own switch was located a round-off later, mbsim.forces.switching) and restart the
        integration at the event with them.  Returns the switch of a ``stop`` action, else
        None."""
        s = self.solver
        ctx = Context(self.system, ev.t, ev.q, ev.qd)
        modes, stop = dict(self.modes), None
        owners = {el.name: el for el in self.hybrid}
        for sw in ev.fired:
            rec = {"t": ev.t, "name": sw.name, "owner": sw.owner, "action": sw.action,
                   "q": ev.q, "qd": ev.qd}
            if sw.action == "switch":
                el = owners[sw.owner]
                new = el.next_mode(modes.get(el.name), sw, ctx)
                text = getattr(el, "mode_text", str)
                rec["from"], rec["to"] = text(modes.get(el.name)), text(new)
                modes[el.name] = new
            elif sw.action == "stop" and stop is None:
                stop = sw
            self.events.append(rec)
        fired = {sw.owner for sw in ev.fired}
        for el in self.hybrid:  # elements that change with the fired ones (``joins``)
            join = getattr(el, "joins", None)
            new = None if join is None or el.name in fired else join(modes.get(el.name), ctx)
            if new is not None:
                self.events.append({"t": ev.t, "name": "joins", "owner": el.name,
                                    "action": "switch", "q": ev.q, "qd": ev.qd,
                                    "from": str(modes.get(el.name)), "to": str(new)})
                modes[el.name] = new
        if len(self.events) > MAX_EVENTS:
            raise SolveError(f"more than {MAX_EVENTS} events (last: {ev.fired[0].name} at "
                             f"t = {ev.t:.6g} s): a law that chatters")
        if stop is not None:
            return stop
        same = self._last_event_t is not None and ev.t <= self._last_event_t
        self._same_time = self._same_time + 1 if same else 0
        self._last_event_t = ev.t
        if self._same_time > MAX_EVENTS_AT_ONE_TIME:
            raise SolveError(f"{MAX_EVENTS_AT_ONE_TIME} mode changes at t = {ev.t:.6g} s "
                             f"without the time moving on ({ev.fired[0].name}): no mode is "
                             f"consistent there")
        holds = self._holds_for(modes, ctx)
        changed = [h.label for h in holds] != [h.label for h in self.holds] or any(
            a.target != b.target for a, b in zip(holds, self.holds))
        self.modes, self.holds = modes, holds
        system = self._system(self.rows)
        q, qd = ev.q, ev.qd
        if changed:
            q, qd = self._consistent(system, ev.t, q, qd)
        # the first step after an event is chosen afresh (the law has just changed: the
        # step before it says nothing about the one after)
        opt = dict(self.opt, h0=None)
        solver = self.cls(system, ev.t, q, qd, self.t1, opt)
        solver.set_work(ev.w)
        solver.step_ends = self.step_ends
        self._retired.append(s.all_counters())
        self.system, self.solver = system, solver
        self.watch.reset(self, ev.t, q, qd)
        return None

    def step(self):
        ok, msg = self.solver.step()
        if ok and self.first_step is None:
            self.first_step = self.solver.h_last
        return ok, msg

    def advance(self, t_stop, max_steps):
        """Accepted steps until t >= t_stop (Integrator.advance); the first one alone."""
        if self.first_step is None:
            return self.step()
        return self.solver.advance(t_stop, max_steps)

    def restart(self, message) -> bool:
        """Re-select the rows at the last accepted state; True when the run goes on."""
        s, model = self.solver, self.model
        if len(self.changes) >= MAX_ROW_CHANGES:
            return False
        try:
            rank, red = rank_and_redundant(model, jacobian(model, s.q, s.t))
        except NUMERICAL_ERRORS:
            return False
        rows = np.setdiff1d(np.arange(model.m), red)
        if np.array_equal(rows, self.rows):
            return False
        opt = dict(self.opt, h0=s.h_last or None)
        try:
            system = self._system(rows)
            solver = self.cls(system, s.t, s.q, s.qd, self.t1, opt)
        except NUMERICAL_ERRORS:  # the new rows do not solve here either: the failure stands
            return False
        solver.set_work(s.w)
        solver.step_ends = self.step_ends
        self._retired.append(s.all_counters())
        names = model.items_of_rows(red) if red.size else []
        self.changes.append({"t": float(s.t), "rank": int(rank), "redundant": names,
                             "after": message})
        log.info("t = %.6g s: independent rows chosen again (rank %d; redundant: %s) after: %s",
                 s.t, rank, ", ".join(names) or "none", message)
        self.rows, self.system, self.solver = rows, system, solver
        if self.watch is not None:
            self.watch.reset(self, s.t, s.q, s.qd)
        return True

    def all_counters(self) -> dict:
        out = self.solver.all_counters()
        for old in self._retired:
            for k, v in old.items():
                out[k] = out.get(k, 0) + v
        out["row_changes"] = len(self.changes)
        if self.watch is not None:
            out["events"] = len(self.events)
        return out


def step_outputs(solver, ts):
    """The states at the output times ``ts`` (in the last accepted step of ``solver``, up to
    round-off past its end): (Q (k, nq), QD (k, nq), W (k,), failure), all the step's
    outputs at once (Integrator.dense_output_many); failure None, or the message of the
    first time whose dense output failed, the arrays then holding the times before it.
    (The one place the driver calls the integrators' dense output.)"""
    ts = np.minimum(np.asarray(ts, dtype=float), solver.t)
    try:
        Q, QD, W = solver.dense_output_many(ts)
    except IntegratorFailure as exc:  # the outputs before the failed one are kept
        done = exc.done if exc.done is not None else (np.empty((0, solver.q.size)),) * 2 + (
            np.empty(0),)
        return done[0], done[1], done[2], str(exc)
    except NUMERICAL_ERRORS as exc:
        n = solver.q.size
        return (np.empty((0, n)), np.empty((0, n)), np.empty(0),
                f"t = {ts[0]:.6g} s: evaluating the outputs failed: {exc}")
    return Q, QD, W, None


def _record_bulk(request, times, k, record, record_many):
    """Record the outputs of an Outputs request (times[k:] on): (the next k, failure
    message or None) (:func:`integrate`)."""
    Q, QD, W, H = request.done()
    try:
        if record_many is None:
            for i in range(len(W)):
                record(times[k], Q[i], QD[i], W[i], H[i])
                k += 1
        elif len(W):
            record_many(times[k:k + len(W)], Q, QD, W, H)
            k += len(W)
    except NUMERICAL_ERRORS as exc:  # the output's own accelerations, energies
        return k, f"t = {times[k]:.6g} s: evaluating the outputs failed: {exc}"
    return k, None


ADVANCE_STEPS = 10000  # steps per call of Integrator.advance at most (a Ctrl-C waits for it)
OUTPUT_WINDOW = 1024  # outputs asked of one call of advance_outputs at most (its buffers)
OUTPUT_LOOP = True  # the outputs given by the integrator's step loop where it can
"""(advance_outputs, index-1 projection methods in C); False: one call per output time and
the outputs sampled here (step_outputs), as before (tests/analyses/test_output_loop.py
compares the two)."""


def integrate(run, times, record, max_steps, record_many=None):
    """Step ``run`` (a :class:`Stepper`) to times[-1], calling ``record(t, q, qd, w, h)`` at
    times[1:] (or ``record_many(ts, Q, QD, W, h)`` once for the outputs of a step, or of
    the many steps of one call of the integrator's ``advance_outputs``: then h (k,)).

    Without events, an integrator with ``advance_outputs`` (index-1 projection methods in C)
    takes the steps of up to OUTPUT_WINDOW outputs in one call and gives their outputs; what
    it leaves (the outputs of a step that needs the Python dense output) is sampled here as
    before (:func:`step_outputs`).

    With events (``run.watch``) the steps are taken one at a time and each is searched for
    events (:meth:`mbsim.events.Watch.check`); at an event the outputs before it come from
    the step, the run restarts there in its new modes (:meth:`Stepper.on_event`), and a
    ``stop`` event ends the run with one last output at the event's time.

    Returns (status, message); every numerical failure (a step, the dense output, a stall)
    ends as ('incomplete', message with the time), never as an exception."""
    k, steps = 1, 0
    watch = run.watch
    while k < len(times):
        before = run.solver.counters["steps"]
        chunk = 1 if watch is not None else int(max(1, min(ADVANCE_STEPS, max_steps - steps)))
        if watch is not None and run.hybrid:
            run.solver.h_max = watch.step_limit(run, run.h_max)
        many = None
        if watch is None and OUTPUT_LOOP and run.first_step is not None:
            advance_outputs = getattr(run.solver, "advance_outputs", None)
            if advance_outputs is not None:
                request = Outputs(times[k:k + OUTPUT_WINDOW], run.solver.q.size, project=True)
                try:
                    many = advance_outputs(request, chunk)
                except KeyboardInterrupt:  # the outputs reached are kept (trajectory())
                    _record_bulk(request, times, k, record, record_many)
                    raise
        if many is None:
            ok, msg = run.advance(times[k], chunk)
        else:  # the outputs of the steps taken, given by the loop: recorded first
            ok, msg = many
            k, failure = _record_bulk(request, times, k, record, record_many)
            if failure is not None:
                return STATUS_INCOMPLETE, failure
        steps += max(1, run.solver.counters["steps"] - before)
        if not ok:
            if run.restart(msg):
                continue
            return STATUS_INCOMPLETE, msg
        solver = run.solver
        t_end = solver.t
        ev = None
        if watch is not None and solver.t_old is not None:
            try:
                ev = watch.check(run)
            except (*NUMERICAL_ERRORS, IntegratorFailure) as exc:
                return STATUS_INCOMPLETE, (f"t = {solver.t:.6g} s: evaluating the events "
                                           f"failed: {exc}")
            if ev is not None:
                t_end = ev.t
        eps = 1e-12 * max(1.0, abs(t_end))
        if k < len(times) and times[k] <= t_end + eps:
            j = int(np.searchsorted(times, t_end + eps, side="right"))
            Q, QD, W, failure = step_outputs(solver, times[k:j])
            try:
                if record_many is None:
                    for i in range(len(W)):
                        record(times[k], Q[i], QD[i], W[i], solver.h_last)
                        k += 1
                elif len(W):
                    record_many(times[k:k + len(W)], Q, QD, W, solver.h_last)
                    k += len(W)
            except NUMERICAL_ERRORS as exc:  # the output's own accelerations, energies
                return STATUS_INCOMPLETE, (f"t = {times[k]:.6g} s: evaluating the outputs "
                                           f"failed: {exc}")
            if failure is not None:
                return STATUS_INCOMPLETE, failure
        if ev is not None:
            try:
                stop = run.on_event(ev)
            except NUMERICAL_ERRORS as exc:
                return STATUS_INCOMPLETE, f"t = {ev.t:.6g} s: after the event: {exc}"
            if stop is not None:
                if ev.t > times[k - 1] + eps:  # the state at the stop as the last output
                    record(ev.t, ev.q, ev.qd, ev.w, solver.h_last)
                return "complete", f"stopped by event {stop.name} at t = {ev.t:.9g} s"
        if steps >= max_steps and k < len(times):
            return STATUS_INCOMPLETE, (f"t = {solver.t:.6g} s: max_steps = {max_steps} reached "
                                       f"before t_end = {times[-1]:g} s (step size "
                                       f"{solver.h_last:.3g} s)")
    return "complete", ""
