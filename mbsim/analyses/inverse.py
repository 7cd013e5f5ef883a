"""Inverse dynamics of a driven system with DOF = 0 (Haug Sec. 11.6).

At every output time the kinematic analysis gives (q, qd, qdd) (its solve loop, singularity
checks and failure handling are reused as they are: :func:`mbsim.analyses.kinematic.kinematic`).
The equations of motion M qdd + Phi_q^T lam = Q then leave only lam unknown; with DOF = 0
Phi_q (active rows) is square and nonsingular wherever the kinematics succeeded, so

    Phi_q^T lam = Q - M qdd                                        (Haug Ch. 11)

is *solved* (LU, the factors of the kinematic Jacobian; not least squares).  From lam:

- each driver's effort, effort = -lam_d dPhi_d/dx: the force/torque the driver applies to its
  body j along (about) its positive direction, channel ``drivers/<name>/torque|force``
  (:func:`mbsim.analyses.reactions.driver_effort`), and its power effort * dx/dt;
- each joint's reaction force and torque at its joint point, on body i and on body j, global
  and in the joint frame (:func:`mbsim.analyses.reactions.reactions`);
- ``constraints/lam`` (all rows) and ``constraints/condition`` (cond Phi_q, from kinematics).
"""

from __future__ import annotations

import time as _time

import numpy as np
import scipy.linalg as la

from mbsim import core
from mbsim.analyses.assembly import assemble
from mbsim.analyses.common import require_dof_zero
from mbsim.analyses.kinematic import DEFAULTS as KIN_DEFAULTS
from mbsim.analyses.kinematic import kinematic
from mbsim.analyses.reactions import add_reaction_channels
from mbsim.errors import SingularJacobianError
from mbsim.options import analysis_options
from mbsim.result import STATUS_INCOMPLETE, Result
from mbsim.rotations import G as rot_G

DEFAULTS = dict(KIN_DEFAULTS)


def states_from_result(model, res: Result):
    """Rebuild q, qd, qdd (nt, nq) from a result's body channels (exact, no differencing).

    pd = 1/2 G^T omega' and pdd = 1/2 G^T omegad' - |pd|^2 p (Haug eq. 6.3.18 and Ch. 6: the
    inverse of omega' = 2 G pd on p^T pd = 0, and p^T pdd = -pd^T pd).
    """
    nt, nb = len(res.t), model.nb
    q = np.zeros((nt, nb, 7))
    qd = np.zeros((nt, nb, 7))
    qdd = np.zeros((nt, nb, 7))
    for b, name in enumerate(model.body_names):
        def ch(key, name=name):
            return res.channel(f"bodies/{name}/{key}").data

        p = ch("p")
        Gm = rot_G(p)  # (nt, 3, 4)
        pd = 0.5 * np.einsum("tji,tj->ti", Gm, ch("omega_local"))
        pdd = (0.5 * np.einsum("tji,tj->ti", Gm, ch("omegad_local"))
               - np.sum(pd * pd, 1)[:, None] * p)
        q[:, b, :3], q[:, b, 3:] = ch("r"), p
        qd[:, b, :3], qd[:, b, 3:] = ch("rd"), pd
        qdd[:, b, :3], qdd[:, b, 3:] = ch("rdd"), pdd
    return q.reshape(nt, -1), qd.reshape(nt, -1), qdd.reshape(nt, -1)


def multipliers(model, q, qd, qdd, t, rows):
    """lam (m,) from Phi_q^T lam = Q - M qdd on the active rows (square, DOF = 0)."""
    data = core.make_data(model, rows)
    J = core.phi_q(model, data, q, t)
    Q = core.generalized_forces(model, data, q, qd, t)
    Mb = core.mass_blocks(model, data, q)
    rhs = Q - np.einsum("bij,bj->bi", Mb, qdd.reshape(model.nb, 7)).reshape(-1)
    lu = la.lu_factor(J, check_finite=False)
    piv = np.abs(np.diag(lu[0]))
    if piv.min() <= 1e-14 * piv.max():
        names = model.items_of_rows(rows[np.argsort(piv)[:3]])
        raise SingularJacobianError(
            "singular constraint Jacobian in the multiplier solve; constraints involved: "
            + ", ".join(names), time=t, items=tuple(names))
    lam = np.zeros(model.m)
    lam[rows] = la.lu_solve(lu, rhs, trans=1, check_finite=False)
    return lam


def inverse(model, options=None) -> Result:
    """Inverse dynamics over [t_start, t_end] every ``step`` (options as for kinematic).

    Returns the kinematic channels plus driver efforts, joint reactions, ``constraints/lam``.
    Raises DeckError (one line, at the deck's drivers) if they leave DOF != 0.  A kinematic failure
    (lock-up, singular Jacobian) gives status 'incomplete', its message naming time and
    joints, with every channel kept up to the last good time.
    """
    run = analysis_options("inverse", model, options, DEFAULTS)
    opt = dict(run)
    progress = opt.pop("progress", None)  # progress(t, t_end) per output step (mbsim.progress)
    wall0 = _time.perf_counter()
    asm = assemble(model, t=float(opt["t_start"]), tol=opt["tol"], hold=run.context.hold)
    require_dof_zero(model, asm.dof, "inverse dynamics")
    kin_opt = {k: opt[k] for k in KIN_DEFAULTS}
    if progress is not None:
        kin_opt["progress"] = progress
    res = kinematic(model, run.within("kinematic", kin_opt, KIN_DEFAULTS))
    res.mode = "inverse"
    status, message = res.status, res.message
    q, qd, qdd = states_from_result(model, res)
    nt = len(res.t)
    lam = np.zeros((nt, model.m))
    rows = asm.active_rows
    for k in range(nt):
        try:
            lam[k] = multipliers(model, q[k], qd[k], qdd[k], res.t[k], rows)
        except SingularJacobianError as exc:  # pragma: no cover - kinematics stops first
            status, message, nt = STATUS_INCOMPLETE, str(exc), k
            break
        except KeyboardInterrupt:  # Ctrl-C: the outputs with their multipliers are kept
            status, nt = STATUS_INCOMPLETE, k
            message = (f"t = {res.t[k]:.6g} s: interrupted (Ctrl-C) while computing the "
                       f"reactions, before t_end = {float(opt['t_end']):g} s")
            break
    if nt < len(res.t):  # keep every channel to the same length
        res.t = res.t[:nt]
        for ch in res.channels.values():
            ch.data = ch.data[:nt]
        q, lam = q[:nt], lam[:nt]
    summary = dict(res.summary)
    if nt:
        res.add("constraints/lam", lam, "", "Lagrange multipliers (rows as in the model)",
                model.row_label)
        add_reaction_channels(res, model, q, lam)
        for it in model.items:
            if it.kind != "driver":
                continue
            what = "torque" if it.driver.effort_unit == "N m" else "force"
            eff = res.channel(f"drivers/{it.name}/{what}").data
            rate = np.asarray(it.func.d1(res.t), float) + 0.0 * res.t
            res.add(f"drivers/{it.name}/power", eff * rate, "W",
                    f"power of driver {it.name} (effort times the rate of its measure)")
            k = int(np.argmax(np.abs(eff)))
            summary[f"peak_{what}_{it.name}"] = float(eff[k])
            summary[f"peak_{what}_{it.name}_time"] = float(res.t[k])
        if "constraints/condition" in res.channels:
            c = res.channel("constraints/condition").data
            summary["condition_max"] = float(np.max(c))
            summary["condition_max_time"] = float(res.t[int(np.argmax(c))])
    if asm.redundant_items:  # one line: the rows removed, and what that means for lam
        summary["warnings"] = [
            "; ".join(asm.warnings) + "; their reactions are not unique (their rows carry "
            "lam = 0, the others carry the load)"]
    res.summary = summary
    res.status, res.message = status, message
    res.settings = {k: (float(v) if isinstance(v, (int, float)) else v) for k, v in opt.items()}
    res.counters["multiplier_solves"] = nt
    res.wall_time = _time.perf_counter() - wall0
    return res
