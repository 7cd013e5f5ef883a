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

Joint friction (:mod:`mbsim.forces.friction`) is a mode of the dynamic run, and outside one
its loads are zero; here the prescribed motion fixes its modes: each axis slips in the
direction of its rate (:func:`friction_mode`), so its load -mu(v) N r sign(v) joins Q, with
the normal load N from the joint's reaction in lam: the loop loads <-> lam is iterated to a
fixed point as in the dynamic run (:func:`mbsim.fast.dynamics.System._reaction_loop`).  An
axis at rest (|v| <= REST_VELOCITY) sticks; the stick's force is then not determined (the
drivers hold the motion whatever it is) and is taken 0, which the summary's warnings say.
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
from mbsim.fast.dynamics import REACTION_ITERATIONS
from mbsim.forces.friction import REST_VELOCITY, JointFriction
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


def multipliers(model, q, qd, qdd, t, rows, Q_extra=None):
    """lam (m,) from Phi_q^T lam = Q - M qdd on the active rows (square, DOF = 0);
    ``Q_extra`` (nq,): generalized forces added to Q (the friction's, :func:`friction_forces`)."""
    data = core.make_data(model, rows)
    J = core.phi_q(model, data, q, t)
    Q = core.generalized_forces(model, data, q, qd, t)
    if Q_extra is not None:
        Q = Q + Q_extra
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


def friction_mode(el, st):
    """The mode of the friction element ``el`` in the prescribed motion at the State ``st``:
    each axis slips in the direction of its rate ('+' / '-'; a ball joint ('slip', w / |w|)),
    an axis slower than REST_VELOCITY sticks ('stick'): the modes of
    :mod:`mbsim.forces.friction`."""
    if el.ball:
        w = el.spin(st)
        n = float(np.sqrt(w @ w))
        return ("slip", *(float(x) for x in w / n)) if n > REST_VELOCITY else "stick"
    modes = ["+" if v > REST_VELOCITY else "-" if v < -REST_VELOCITY else "stick"
             for _, v, _, _ in el.travels(st)]
    return modes[0] if len(modes) == 1 else tuple(modes)


def friction_forces(model, elements, modes, st, t, lam):
    """Q (nq,) of the friction ``elements`` in ``modes`` (name -> mode) at the State ``st``
    with the multipliers ``lam`` (m,) for their normal loads: [F, 2 G^T n'] per body."""
    F, n_local = np.zeros((model.nb, 3)), np.zeros((model.nb, 3))
    for el in elements:
        el.apply_in(modes[el.name], st, t, lam, F, n_local)
    Qp = 2.0 * np.einsum("bji,bj->bi", rot_G(st.p), n_local)
    return np.concatenate([F, Qp], axis=1).reshape(-1)


def multipliers_with_friction(model, q, qd, qdd, t, rows, elements):
    """(lam (m,), modes): :func:`multipliers` with the friction ``elements`` in the modes of
    the motion, their normal loads from lam: the fixed point of lam -> loads -> lam (loads
    repeating to 1e-14 relative, as the dynamic run's reaction loop)."""
    lam = multipliers(model, q, qd, qdd, t, rows)
    if not elements:
        return lam, {}
    st = core.State(model, q, qd)
    modes = {el.name: friction_mode(el, st) for el in elements}
    prev = None
    for _ in range(REACTION_ITERATIONS):
        Qf = friction_forces(model, elements, modes, st, t, lam)
        if prev is not None and np.abs(Qf - prev).max() <= 1e-14 * np.abs(Qf).max(initial=0):
            return lam, modes
        prev = Qf
        lam = multipliers(model, q, qd, qdd, t, rows, Qf)
    raise SingularJacobianError(
        f"the friction loads and the joint reactions did not settle in {REACTION_ITERATIONS} "
        f"iterations at t = {t:.6g} s", time=t,
        items=tuple(el.name for el in elements))


def friction_channels(res, model, elements, q, qd, lam, modes):
    """Add the channels of the friction ``elements`` (which the kinematic analysis, without
    modes, leaves out) in each output's ``modes`` with the multipliers ``lam`` (nt, m); the
    held rows of a stick carry 0 (module doc)."""
    hybrid = [f for f in model.forces if getattr(f, "hybrid", False)]
    rows = {el.name: [] for el in elements}
    for k in range(len(modes)):
        st = core.State(model, q[k], qd[k])
        held = sum(f.hold_count(modes[k].get(f.name)) for f in hybrid)
        lam_all = np.concatenate([lam[k], np.zeros(held)])
        for el in elements:
            rows[el.name].append(el.channels_in(modes[k][el.name], st, res.t[k], lam_all,
                                                modes[k]))
    for el in elements:
        for key, (_, unit) in rows[el.name][0].items():
            data = np.array([np.asarray(r[key][0], float) for r in rows[el.name]])
            res.add(f"forces/{el.name}/{key}", data, unit, f"force element {el.name}: {key}",
                    ("x", "y", "z") if data.ndim == 2 and data.shape[1] == 3 else ())


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
    friction = [el for el in model.forces if isinstance(el, JointFriction)]
    modes = []
    for k in range(nt):
        try:
            lam[k], mk = multipliers_with_friction(model, q[k], qd[k], qdd[k], res.t[k], rows,
                                                   friction)
            modes.append(mk)
        except SingularJacobianError as exc:  # kinematics stops first at a singular Phi_q
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
        if friction:
            friction_channels(res, model, friction, q, qd, lam, modes)
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
    stuck = sorted({el.name for mk in modes for el in friction if "stick" in
                    ([mk[el.name]] if isinstance(mk[el.name], str) else mk[el.name])})
    if stuck:
        summary.setdefault("warnings", []).append(
            f"friction {', '.join(stuck)} at rest at some outputs: the force of a stick is "
            "not determined by the prescribed motion (the drivers hold it), taken 0 there")
    res.summary = summary
    res.status, res.message = status, message
    res.settings = {k: (float(v) if isinstance(v, (int, float)) else v) for k, v in opt.items()}
    res.counters["multiplier_solves"] = nt
    res.wall_time = _time.perf_counter() - wall0
    return res
