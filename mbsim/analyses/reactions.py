"""Joint reaction forces and torques from the Lagrange multipliers (Haug Sec. 11.6).

The one generic reaction formula: every joint, whatever its type, reacts through its rows of
Phi_q.  The constraint force on body b from the k rows of one item is the generalized force

    Q^c_b = -Phi_{q_b}^T lam_k        (7,) = [force (3), Euler-parameter part (4)]

(Haug Ch. 11; the equations of motion read M qdd + Phi_q^T lam = Q).  Its parts are

    F_b     = -Phi_{r_b}^T lam_k                  force at the centroid, global frame
    n'_b    = -1/2 G_b Phi_{p_b}^T lam_k          torque about the centroid, body frame

(Q_p = 2 G^T n' and G G^T = I; any part of Phi_p^T lam along p, e.g. from the exact
derivative of A(p) used in :func:`mbsim.rotations.B`, is annihilated by G, since G p = 0).
Moved to the joint point P (body coordinates s'_P) the same load is the force F_b at P and

    n'_P    = n'_b - s'_P~ (A_b^T F_b)            torque about P, body frame

and in the item's joint frame (columns f, g, h of C_b, body coordinates) the components are
C_b^T (A_b^T F_b) and C_b^T n'_P.  These are the loads the joint applies *to* body b.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mbsim import core
from mbsim.rotations import A as rot_A
from mbsim.rotations import G as rot_G

FRAME_AXES = ("f", "g", "h")


@dataclass
class Reaction:
    """Loads one constraint item applies to one of its bodies, over nt times.

    force, torque: (nt, 3) global frame; torque about the joint point P.
    force_local, torque_local: (nt, 3) components in the item's joint frame (f, g, h) on
    that body.  body: body index; side: 'i' or 'j'.
    """

    item: str
    side: str
    body: int
    force: np.ndarray
    torque: np.ndarray
    force_local: np.ndarray
    torque_local: np.ndarray


def reactions(model, q, lam, t=0.0, kinds=("joint",)) -> list[Reaction]:
    """Reaction loads of every item of the given kinds, on body i and on body j.

    Parameters
    ----------
    model : compiled Model.
    q : (nq,) or (nt, nq) generalized coordinates.
    lam : (m,) or (nt, m) Lagrange multipliers (rows in ``model.items`` order, as in
        ``constraints/lam`` of a dynamic or inverse result).
    t : scalar or (nt,) times; Phi_q of the joints does not depend on t, drivers' rows do
        not enter (their effort is :func:`driver_effort`), but t is passed through.
    kinds : item kinds to report: 'joint' (default), 'driver', 'ground'.

    Returns
    -------
    list of :class:`Reaction`, one per (item, body) in item order, i before j.  Arrays have
    the time axis first; a single (nq,) q gives nt = 1.
    """
    Q = np.atleast_2d(np.asarray(q, float))
    L = np.atleast_2d(np.asarray(lam, float))
    nt = Q.shape[0]
    tt = np.broadcast_to(np.asarray(t, float), (nt,))
    data = core.make_data(model)
    jac = np.stack([core.phi_q(model, data, Q[k], tt[k]) for k in range(nt)])
    P = Q.reshape(nt, model.nb, 7)[:, :, 3:]
    out: list[Reaction] = []
    for it in model.items:
        if it.kind not in kinds:
            continue
        rows = it.rows
        for side, b, s_loc, C in (("i", it.bi, it.P_i, it.C_i), ("j", it.bj, it.P_j, it.C_j)):
            if b < 0:
                continue
            out.append(rows_reaction(it.name, side, int(b), jac[:, rows, 7 * b: 7 * b + 7],
                                     L[:, rows], P[:, b], s_loc, C))
    return out


def rows_reaction(item, side, b, Jb, lam_k, p_b, s_loc, C, A=None, G=None) -> Reaction:
    """The :class:`Reaction` on body ``b`` of constraint rows with Jacobian columns ``Jb``
    (nt, k, 7) of that body and multipliers ``lam_k`` (nt, k); p_b (nt, 4) its Euler
    parameters, s_loc (3,) the joint point and C (3, 3) the joint frame (columns f, g, h) in
    body coordinates (C None: the body frame); A (nt, 3, 3), G (nt, 3, 4): A(p_b), G(p_b)
    when the caller has them.  The one formula of the module doc (also the per-step normal
    load of :mod:`mbsim.forces.friction`)."""
    Qc = -(np.swapaxes(Jb, 1, 2) @ lam_k[:, :, None])[:, :, 0]  # (nt, 7) Haug Ch. 11
    F = Qc[:, :3]
    G = rot_G(p_b) if G is None else G
    A = rot_A(p_b) if A is None else A  # (nt, 3, 3)
    n_c = 0.5 * (G @ Qc[:, 3:, None])[:, :, 0]
    F_loc = (np.swapaxes(A, 1, 2) @ F[:, :, None])[:, :, 0]  # A^T F
    s = np.broadcast_to(s_loc, F_loc.shape)
    sxF = s[:, _C1] * F_loc[:, _C2] - s[:, _C2] * F_loc[:, _C1]  # s' x (A^T F)
    n_P = n_c - sxF
    C = np.eye(3) if C is None else C
    return Reaction(item=item, side=side, body=b, force=F, torque=(A @ n_P[:, :, None])[:, :, 0],
                    force_local=F_loc @ C, torque_local=n_P @ C)


_C1, _C2 = [1, 2, 0], [2, 0, 1]  # cross product components: (a x b)_k = a_C1 b_C2 - a_C2 b_C1


def driver_effort(model, lam, t) -> dict[str, np.ndarray]:
    """Force or torque each driver applies to its body j (body i for one-body drivers).

    effort = -lam_d dPhi_d/dx (Haug Sec. 11.6): x is the driven measure (rotation: the angle
    from g_i to g_j about f_i, N m about f_i; translation: f_i . (P_j - P_i), N along f_i;
    distance: |P_j - P_i|, N along P_j - P_i, positive pushing the points apart, so a link
    in tension reads negative; absolute: a global coordinate, N along that axis).  Body i
    receives the opposite load.  lam: (nt, m); t: (nt,).  Returns name -> (nt,).
    """
    L = np.atleast_2d(np.asarray(lam, float))
    tt = np.atleast_1d(np.asarray(t, float))
    out = {}
    for it in model.items:
        if it.kind != "driver":
            continue
        x = np.asarray(it.func(tt), float) + 0.0 * tt  # the driven measure equals its target
        out[it.name] = -L[:, it.rows[0]] * it.driver.dphi_dx(x)
    return out


def add_reaction_channels(result, model, q, lam, t=None) -> None:
    """Write ``joints/<name>/force_i`` ... and ``drivers/<name>/torque|force`` into result.

    Usable after any analysis that stored q and ``constraints/lam`` (dynamic, inverse).
    """
    t = result.t if t is None else t
    xyz = ("x", "y", "z")
    for r in reactions(model, q, lam, t):
        s = r.side
        base = f"joints/{r.item}/"
        body = model.body_names[r.body]
        result.add(base + f"force_{s}", r.force, "N",
                   f"reaction force of {r.item} on {body}, global", xyz)
        result.add(base + f"torque_{s}", r.torque, "N m",
                   f"reaction torque of {r.item} on {body} about its joint point, global", xyz)
        result.add(base + f"force_{s}_local", r.force_local, "N",
                   f"reaction force of {r.item} on {body}, joint frame on {body}", FRAME_AXES)
        result.add(base + f"torque_{s}_local", r.torque_local, "N m",
                   f"reaction torque of {r.item} on {body} about its joint point, joint frame",
                   FRAME_AXES)
    efforts = driver_effort(model, lam, t)
    for it in model.items:
        if it.kind != "driver":
            continue
        what = "torque" if it.driver.effort_unit == "N m" else "force"
        body = model.body_names[it.bj if it.bj >= 0 else it.bi]
        result.add(f"drivers/{it.name}/{what}", efforts[it.name], it.driver.effort_unit,
                   f"{what} driver {it.name} applies to {body} along its positive direction")
