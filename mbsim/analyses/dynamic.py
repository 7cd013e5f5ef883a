"""Dynamic analysis (Haug Ch. 11): integrate the constrained equations of motion from
consistent initial conditions with one of the integrators of :mod:`mbsim.integrators`.

Output sampling is independent of the step size: the integrator steps freely and its dense
output is evaluated at the output times t_start + k step; at each output the accelerations
and multipliers are solved from the sampled (q, qd).  The equations of motion come from
:mod:`mbsim.fast` (numba, one compiled call per evaluation) when it is available, else from
the numpy :class:`mbsim.integrators.System`; option ``compiled: false`` forces the latter.
Monitors written with the standard body and point channels:

- ``monitors/position_violation``  max |Phi| (all rows)
- ``monitors/velocity_violation``  max |Phi_q qd - nu|
- ``monitors/energy``              T + V (gravity and conservative force elements)
- ``monitors/work_nonconservative`` W_nc(t) = int (Q.qd - lam.nu) dt + V(t) - V(t0): the
  work of damping, actuators, non-potential loads and drivers, so that energy - W_nc stays
  constant (dT/dt = Q.qd - lam.nu along the exact motion)
- ``monitors/step_size``           the step the integrator took across each output time
- ``constraints/lam``              (nt, m) Lagrange multipliers, one column per row
  (components = row labels; zero on redundant rows).
"""

from __future__ import annotations

import difflib
import time as _time

import numpy as np

from mbsim.analyses.common import Recorder, rank_and_redundant, singular_rows
from mbsim.analyses.kinematic import output_times
from mbsim.errors import DeckError
from mbsim.integrators import ALIASES, DEFAULT, INTEGRATORS, System
from mbsim.result import STATUS_INCOMPLETE

DEFAULTS = {"t_start": 0.0, "t_end": 1.0, "step": 0.01, "integrator": DEFAULT, "rtol": 1e-6,
            "atol": 1e-8, "h": None, "max_steps": 1_000_000, "tol": 1e-10, "sparse": None,
            "compiled": True}


def make_system(model, rows, sparse=None, compiled=True):
    """The equations of motion the integrators call: the compiled :mod:`mbsim.fast` path
    (numba) when available and asked for, else :class:`mbsim.integrators.System` (numpy);
    both have the same interface and results."""
    if compiled:
        try:
            from mbsim import fast
        except ImportError:
            fast = None
        if fast is not None:
            return fast.make_system(model, rows, sparse)
    return System(model, rows, sparse)


def integrator_class(name: str):
    """The integrator class for a name (or an alias); unknown names are a usage error."""
    key = ALIASES.get(name, name)
    if key not in INTEGRATORS:
        hint = difflib.get_close_matches(name, list(INTEGRATORS) + list(ALIASES), n=2)
        extra = f"; did you mean {' or '.join(hint)}?" if hint else ""
        raise DeckError(f"unknown integrator {name!r}{extra} (known: {', '.join(INTEGRATORS)})")
    return INTEGRATORS[key]


def dynamic(model, options=None):
    """Run a dynamic analysis; returns a Result (status incomplete, with the data up to the
    failure, when the integrator fails).

    options: t_start, t_end, step (output step, s), integrator (name, see
    ``mbsim list integrators``), rtol, atol, h (fixed step: no error control; a fixed-step
    method without h steps at ``step``), h_max, max_steps, sparse (None: by size), compiled
    (False: the numpy System instead of mbsim.fast), q0/qd0 (a consistent initial state
    instead of the deck's), and the integrator's own options
    (alpha, beta, rho_inf, repartition_ratio, jacobian, newton_tol).
    """
    wall0 = _time.perf_counter()
    opt = dict(DEFAULTS, **(model.spec.analysis.get("dynamic", {}) if model.spec else {}))
    opt.update({k: v for k, v in (options or {}).items() if v is not None})
    progress = opt.pop("progress", None)  # progress(t, t_end) per output (mbsim.progress)
    cls = integrator_class(str(opt["integrator"]))
    t0, t1 = float(opt["t_start"]), float(opt["t_end"])
    times = output_times(t0, t1, float(opt["step"]))
    if not cls.adaptive and opt.get("h") is None:
        opt["h"] = float(opt["step"])
    q, qd, summary = _initial(model, t0, opt)
    rank, red = rank_and_redundant(model, _jac(model, q, t0))
    rows = np.setdiff1d(np.arange(model.m), red)
    system = make_system(model, rows, opt.get("sparse"), bool(opt.get("compiled", True)))
    solver = cls(system, t0, q, qd, t1, opt)
    rec = Recorder(model)
    mon = {k: [] for k in ("pos", "vel", "energy", "work", "h", "lam")}
    V0 = system.energy(q, qd)[1]
    n_out_eval = 0

    def record(t, q, qd, w, h):
        nonlocal n_out_eval
        qdd, lam, _ = system.accelerations(q, qd, t)
        n_out_eval += 1
        T, V = system.energy(q, qd)
        pv, vv = system.violations(q, qd, t)
        lam_all = system.full_lam(lam)
        # monitors first, the output row last: a Ctrl-C in between leaves at most one extra
        # monitor value, trimmed below, never a row without its monitors
        for key, v in (("pos", pv), ("vel", vv), ("energy", T + V), ("work", w + V - V0),
                       ("h", h), ("lam", lam_all)):
            mon[key].append(v)
        rec.add(t, q, qd, qdd)
        if progress is not None:
            progress(t, t1)

    status, message = "complete", ""
    record(t0, q, qd, 0.0, np.nan)
    k = 1
    steps = 0
    try:
        while k < len(times):
            ok, msg = solver.step()
            steps += 1
            if not ok:
                status, message = STATUS_INCOMPLETE, _explain(model, system, solver, msg)
                break
            if k < len(times) and times[k] <= solver.t + 1e-12 * max(1.0, abs(solver.t)):
                dense = solver.dense_output()
                while k < len(times) and times[k] <= solver.t + 1e-12 * max(1.0, abs(solver.t)):
                    tk = min(times[k], solver.t)
                    qk, qdk, wk = (solver.q, solver.qd, solver.w) if tk == solver.t else dense(tk)
                    record(times[k], qk, qdk, wk, solver.h_last)
                    k += 1
            if steps >= int(opt["max_steps"]) and k < len(times):
                status = STATUS_INCOMPLETE
                message = (f"t = {solver.t:.6g} s: max_steps = {int(opt['max_steps'])} reached "
                           f"before t_end = {t1:g} s (step size {solver.h_last:.3g} s)")
                break
    except KeyboardInterrupt:  # Ctrl-C: keep what was computed, marked incomplete
        status = STATUS_INCOMPLETE
        message = f"t = {solver.t:.6g} s: interrupted (Ctrl-C) before t_end = {t1:g} s"
        for v in mon.values():
            del v[len(rec):]
    res = rec.result("dynamic")
    if len(rec):
        res.add("monitors/position_violation", mon["pos"], "", "max |Phi| over all rows")
        res.add("monitors/velocity_violation", mon["vel"], "", "max |Phi_q qd - nu|")
        res.add("monitors/energy", mon["energy"], "J", "kinetic + potential energy T + V")
        res.add("monitors/work_nonconservative", mon["work"], "J",
                "work of non-conservative forces and drivers; energy - work is conserved")
        res.add("monitors/step_size", mon["h"], "s", "integrator step across each output")
        res.add("constraints/lam", mon["lam"], "", "Lagrange multipliers per constraint row",
                model.row_label)
    res.status, res.message = status, message
    res.settings = {k: (float(v) if isinstance(v, (int, float)) and not isinstance(v, bool)
                        else v) for k, v in opt.items()
                    if k not in ("q0", "qd0") and (v is None or np.isscalar(v))}
    res.settings["integrator"] = cls.name
    counters = solver.all_counters()
    counters["function_evaluations"] -= n_out_eval
    counters["output_evaluations"] = n_out_eval
    res.counters = counters
    summary.update({"integrator": cls.name, "formulation": cls.formulation,
                    "dof": model.nq - rank, "rank": rank,
                    "redundant": model.items_of_rows(red) if red.size else [],
                    "sparse": system.sparse, "equations": type(system).__name__,
                    "t_reached": float(solver.t)})
    res.summary = summary
    res.wall_time = _time.perf_counter() - wall0
    return res


def _jac(model, q, t):
    from mbsim import equations as eq

    return eq.phi_q(model, q, t)


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


def _explain(model, system, solver, msg):
    """The integrator's message plus the joints nearest to a singular configuration."""
    try:
        J = system.terms(solver.q, solver.t, phi=False).jac
        J = J.toarray() if hasattr(J, "toarray") else J
        rows, s = singular_rows(model, J)
        names = model.items_of_rows(system.rows[rows])
        cond = s[0] / s[-1] if s[-1] > 0 else np.inf
        return (f"{msg} (last accepted state t = {solver.t:.6g} s; Phi_q condition "
                f"{cond:.3g}; constraints nearest to singular: {', '.join(names)})")
    except (np.linalg.LinAlgError, ValueError):  # the explanation must not hide the failure
        return msg
