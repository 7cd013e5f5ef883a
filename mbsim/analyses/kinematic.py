"""Kinematic analysis of a driven system with DOF = 0: at each output time solve
Phi(q, t) = 0, Phi_q qd = nu, Phi_q qdd = gamma on the independent rows, and check that the
redundant rows dropped at assembly hold at all three levels (:mod:`mbsim.analyses.redundancy`).

Each output time is one C call (:func:`mbsim.core.kinematic_state`): Newton from a
second-order predictor, then the velocity and acceleration equations on the LU of Phi_q at
the solution, and cond_2(Phi_q) for the ``constraints/condition`` channel.  Where that call
fails (no convergence, a singular or too ill-conditioned Phi_q) the output is solved again
step by step in numpy on the core's terms (:func:`_solve_output`), which names the
constraints involved."""

from __future__ import annotations

import time as _time

import numpy as np
import scipy.linalg as la

from mbsim import core
from mbsim.analyses import redundancy
from mbsim.analyses.assembly import assemble, newton
from mbsim.analyses.common import Recorder, require_dof_zero, singular_rows
from mbsim.errors import AnalysisError, ConvergenceError, SingularJacobianError
from mbsim.options import analysis_options
from mbsim.result import STATUS_INCOMPLETE

DEFAULTS = {"t_start": 0.0, "t_end": 1.0, "step": 0.01, "tol": 1e-10, "max_iter": 25,
            "cond_max": 1e12}


def output_times(t0, t1, step):
    n = int(round((t1 - t0) / step))
    if n < 1 or abs(t0 + n * step - t1) > 1e-9 * max(1.0, abs(t1)):
        n = int(np.ceil((t1 - t0) / step - 1e-9))
    return np.linspace(t0, t1, n + 1) if n >= 1 else np.array([t0])


def solve_square(model, J, rhs, t, what):
    """Solve J x = rhs for square J; a singular J names the joints involved."""
    try:
        lu = la.lu_factor(J, check_finite=False)
    except (la.LinAlgError, ValueError) as exc:  # pragma: no cover - lu_factor warns instead
        raise SingularJacobianError(str(exc), time=t) from exc
    piv = np.abs(np.diag(lu[0]))
    if piv.min() <= 1e-14 * piv.max():
        rows, s = singular_rows(model, J)
        names = model.items_of_rows(rows)
        raise SingularJacobianError(
            f"singular constraint Jacobian in the {what} solve (smallest singular value "
            f"{s[-1]:.3g}, largest {s[0]:.3g}); constraints involved: {', '.join(names)}",
            time=t, items=tuple(names))
    return la.lu_solve(lu, rhs, check_finite=False)


def _solve_output(model, q, t, rows, opt, newton_first, want_cond):
    """(q, qd, qdd, iterations, max |Phi|, cond) at t from the predictor q, step by step with
    dense numpy solves on the core's terms: the path that names what fails (no convergence,
    a lock-up, a singular Phi_q with the joints involved), and the one for row sets that are
    not square."""
    its = 0
    if newton_first:
        q, its, _ = newton(model, q, t, opt["tol"], opt["max_iter"], rows=rows)
    T = core.constraints(model, None, q, t, qd=None, phi=True, jac=True, nu=True)
    J = T.jac[rows]
    c = np.nan
    if want_cond:
        s = np.linalg.svd(J, compute_uv=False)
        c = s[0] / s[-1] if s[-1] > 0 else np.inf
        if c > opt["cond_max"]:
            rws, _ = singular_rows(model, J)
            names = model.items_of_rows(rows[rws])
            raise SingularJacobianError(
                f"constraint Jacobian is singular (condition number {c:.3g} > "
                f"{opt['cond_max']:.3g}): a lock-up or bifurcation; constraints involved: "
                f"{', '.join(names)}", time=t, items=tuple(names))
    qd = solve_square(model, J, T.nu[rows], t, "velocity")
    G = core.gamma(model, None, q, qd, t)
    qdd = solve_square(model, J, G[rows], t, "acceleration")
    return q, qd, qdd, its, np.abs(T.phi).max(), c


def kinematic(model, options=None):
    """Run a kinematic analysis; returns a Result (status incomplete on failure)."""
    run = analysis_options("kinematic", model, options, DEFAULTS)
    opt = dict(run)
    progress = opt.pop("progress", None)  # progress(t, t_end) per output step (mbsim.progress)
    wall0 = _time.perf_counter()
    times = output_times(float(opt["t_start"]), float(opt["t_end"]), float(opt["step"]))
    asm = assemble(model, t=times[0], tol=opt["tol"], hold=run.context.hold)
    rows = asm.active_rows
    require_dof_zero(model, asm.dof, "kinematic analysis")
    rec = Recorder(model)
    cond = []
    q, qd_prev, qdd_prev = asm.q, None, None
    status, message = "complete", ""
    newton_its = 0
    data = core.make_data(model, rows)
    one_call = rows.size == model.nq  # DOF 0 on the active rows: core.kinematic_state
    want_cond = model.nq <= 400
    redundant = asm.redundant_rows.size > 0
    for k, t in enumerate(times):
        try:
            if k > 0:  # second-order predictor from the last solution
                h = t - times[k - 1]
                q = q + h * qd_prev + 0.5 * h * h * qdd_prev
            state = None
            if one_call:
                status_c, qn, qd, qdd, info = core.kinematic_state(
                    model, data, q, t, opt["tol"], opt["max_iter"], want_cond)
                if status_c == 0 and not (want_cond and not info[2] <= opt["cond_max"]):
                    state = qn, qd, qdd, int(info[0]), info[1], info[2]
            if state is None:  # the named diagnosis of what failed, or a DOF > 0 row set
                state = _solve_output(model, q, t, rows, opt, k > 0, want_cond)
            q, qd, qdd, its, residual, c = state
            newton_its += its
            if want_cond:
                cond.append(c)
            if redundant:  # the dropped rows must hold too; a conflict at the first output
                # is the deck's structure (exit 2), later it ends the run (exit 1, data kept)
                T = core.constraints(model, None, q, t, qd=qd, gamma=True, nu=True)
                redundancy.check(model, T.jac, asm.redundant_rows, rows, t, phi=T.phi,
                                 tol=opt["tol"], qd=qd, nu=T.nu, qdd=qdd, gamma=T.gamma,
                                 start=k == 0)
                residual = np.abs(T.phi).max()
            # recording inside the try: at 0.1 ms per output a Ctrl-C (or SIGTERM) lands
            # here as often as in the solve, and must end the run the same way
            rec.add(t, q, qd, qdd, residual=residual)
            qd_prev, qdd_prev = qd, qdd
            if progress is not None:
                progress(t, times[-1])
        except (ConvergenceError, SingularJacobianError, AnalysisError) as exc:
            status, message = STATUS_INCOMPLETE, str(exc)
            break
        except KeyboardInterrupt:  # Ctrl-C: keep the finished output times, marked incomplete
            status = STATUS_INCOMPLETE
            message = f"t = {t:.6g} s: interrupted (Ctrl-C) before t_end = {times[-1]:g} s"
            break
    rec.trim()
    res = rec.result("kinematic", run.context.only)
    if len(rec):
        res.add("constraints/residual", rec.extra["residual"], "", "max |Phi| after Newton")
        if cond:
            res.add("constraints/condition", cond[: len(rec)], "",
                    "condition number of the driven Jacobian Phi_q")
    res.status, res.message = status, message
    res.settings = {k: (float(v) if isinstance(v, (int, float)) else v) for k, v in opt.items()}
    res.counters = {"output_steps": len(rec), "newton_iterations": newton_its}
    res.summary = {"dof": asm.dof, "rank": asm.rank, "redundant": asm.redundant_items,
                   "assembly_iterations": asm.iterations}
    if asm.warnings:
        res.summary["warnings"] = list(asm.warnings)
    res.wall_time = _time.perf_counter() - wall0
    return res
