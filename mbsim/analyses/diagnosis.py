"""Failure diagnosis of a dynamic run: what is special where the integrator stopped.

- :func:`explain`: the integrator's message plus the constraints nearest to a singular
  configuration and the force elements whose load jumps at the last accepted state;
- :func:`switching_forces`: the force elements whose law switches on the motion there;
- :func:`dropped_rows_conflict`: the rows a run dropped as redundant that no longer hold;
- :func:`accelerations_lstsq`: qdd and lam at a singular configuration (minimum norm);
- :func:`jacobian`: Phi_q at (q, t), for the choice of the independent rows.
"""

from __future__ import annotations

import numpy as np

from mbsim.analyses import redundancy
from mbsim.analyses.common import singular_rows
from mbsim.integrators.base import NUMERICAL_ERRORS


def accelerations_lstsq(model, system, q, qd, t):
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


def jacobian(model, q, t):
    """Phi_q (m, nq) at (q, t): all rows (CSR from DENSE_NQ coordinates)."""
    from mbsim import core
    from mbsim.analyses.common import DENSE_NQ

    return core.phi_q(model, None, q, t, sparse=model.nq >= DENSE_NQ)


def dropped_rows_conflict(model, system, t, q, ph, tol, cache):
    """The message when the rows this system dropped as redundant do not hold where its
    active rows do, else None (redundancy.position_bound, at the larger of the active rows'
    violation and the Newton tolerance).  ``cache``: {id(system): (red, C, row norms of
    C)}: C is found once per row set and found again at q before a violation is reported
    (the dependency turns with the mechanism)."""
    rows = system.rows[system.rows < model.m]  # not the rows a hybrid mode holds
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
        C = redundancy.dependency(jacobian(model, q, t), red, rows)
        cache[key] = (red, C, np.abs(C).sum(axis=1))
    red, C, cnorm = cache[key]
    k, r = worst(C, cnorm)
    if k is not None and not fresh:
        C = redundancy.dependency(jacobian(model, q, t), red, rows)
        cache[key] = (red, C, np.abs(C).sum(axis=1))
        k, r = worst(C, cache[key][2])
    if k is None:
        return None
    items = redundancy.conflict_items(model, C, red, rows, k)
    return (f"t = {t:.6g} s: the redundant constraints of {', '.join(items)} no longer hold "
            f"(residual {r[k]:.3g}, the independent rows hold to {level:.3g}): the motion "
            f"followed the independent rows onto another branch (past a singular position) "
            f"or the constraints conflict; from here it is not the mechanism's motion")


SINGULAR_CONDITION = 1e6  # Phi_q condition from which a failure blames the constraints
SWITCH_PROBE = 1e-9  # s: the states probed either side of a failure along the motion
SWITCH_JUMP = 1e-2  # relative change of an element's load across the probe that is a jump


def explain(model, system, solver, msg):
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
        # (the system's own model: in a mode that holds a joint, its rows go past model.m)
        names = ", ".join(system.model.items_of_rows(system.rows[rows]))
        notes.append(f"Phi_q condition {cond:.3g}; constraints nearest to singular: {names}"
                     if cond >= SINGULAR_CONDITION else
                     f"Phi_q condition {cond:.3g}, not near singular (its weakest rows: "
                     f"{names})")
    except (np.linalg.LinAlgError, ValueError):  # the explanation must not hide the failure
        pass
    jumps = switching_forces(model, system, solver.q, solver.qd, solver.t)
    if jumps:
        notes.append(f"force elements whose load jumps there: {', '.join(jumps)} (a law "
                     f"that switches on the motion: where the motion stays at the switch, "
                     f"a sliding mode, no step passes it)")
    if not notes:
        return msg
    return f"{msg} (last accepted state t = {solver.t:.6g} s; {'; '.join(notes)})"


def switching_forces(model, system, q, qd, t):
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
