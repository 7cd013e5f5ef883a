"""Redundant constraint rows: dropped only when they are consistent, named when they conflict.

An over-constrained model (a planar loop of revolute joints built from spatial joints, two
parallel cranks) has rows of Phi_q that depend on the others; the analyses solve with the
independent ("active") rows only.  That is right only if the dropped rows hold wherever
the active ones do.  Writing the dependency found at q as

    Phi_q[red] = C Phi_q[act]                                             (C: nred x nact)

the dropped rows must satisfy, to first order in the active rows' residuals,

    position       |Phi[red]|                       <= (1 + |C|) x the Newton tolerance
    velocity       |Phi_q[red] qd - nu[red]|        (the velocity equation Phi_q qd = nu)
    acceleration   |Phi_q[red] qdd - gamma[red]|    (the acceleration equation)

For consistent redundancy (the rows are functions of the others near the manifold,
Phi[red] = g(Phi[act]) with g(0) = 0) the velocity and acceleration residuals of the
dropped rows are those of the active rows times C, plus round-off: relative to the size of
the terms (max over the rows of |Phi_q| |qd| + |nu|) they stay near eps x cond(Phi_q[act]).  A
driver that over-determines the mechanism (DOF -1: a rotation driver on the crank and a
translation driver on the slider) breaks them by O(1) relative.  CONSISTENT_REL sits
between the two with margins of several decades either side.

Conflicts found at the start of an analysis are the deck's structure (ModelError, exit 2);
found along the motion they end the run there (InconsistentConstraintsError, exit 1, the
results up to the last consistent output kept).
"""

from __future__ import annotations

import numpy as np

from mbsim.errors import AnalysisError, ModelError

CONSISTENT_REL = 1e-6
"""Largest residual of a dropped row at velocity or acceleration level, relative to the size
of its terms, that is still consistent.  Consistent redundancy leaves eps x cond(Phi_q) x
(1 + |C|): below 1e-8 for a condition number up to 1e6 and |C| up to 1e2 (the analyses stop
before a condition of 1e12 in any case); an over-determined mechanism leaves O(1)."""

POSITION_FACTOR = 10.0
"""The dropped rows' position residuals may reach (1 + |C|) x POSITION_FACTOR x the Newton
tolerance: Newton stops with |Phi[act]| < tol, and Phi[red] = C Phi[act] + O(|Phi[act]|^2)."""

DEPENDENCY_CUT = 1e-8
"""Coefficients of C below this fraction of a row's largest take no part in the conflict
that row names (round-off of the least-squares fit of C)."""


DEPENDENCY_SPARSE_NQ = 100
"""Coordinates from which :func:`dependency` solves sparse whatever J's storage (set-up
passes a dense Phi_q below mbsim.analyses.common.DENSE_NQ): the parallel four-bar's
dependency took 0.3 / 0.7 / 99 / 51 to 960 ms dense against 4.8 / 1.8 / 2.7 / 19 ms sparse
at nq 42 / 70 / 91 / 301 (CPU at load 8-9 on 2 cores; the dense SVD's time scatters with
the load, the largest figure is a run's end under cProfile)."""

SPARSE_PIVOT_RATIO = float(np.sqrt(np.finfo(float).eps))
"""Smallest pivot of the augmented system's sparse LU, relative to its largest, that
:func:`dependency` takes; below it the dense SVD decides.  The LU's pivots are no
rank-revealing measure: active rows that depend on each other left 3e-11 to 3e-19 on the
parallel four-bar (tests/analyses/test_redundancy_sparse.py), independent ones 5e-5 (40
loops), 9e-5 and 7e-8 with the cranks 1e-3 and 1e-6 rad from flat; sqrt(eps) = 1.5e-8 keeps
the sparse solve where the rows are well apart from dependent and the SVD's minimum-norm
answer near dependence."""


def position_bound(cnorm, level):
    """(nred,) largest |Phi[red]| that is consistent where the kept rows hold to ``level``
    (cnorm: (nred,) row sums of |C|; POSITION_FACTOR)."""
    return (1.0 + cnorm) * POSITION_FACTOR * level


class InconsistentConstraintsError(AnalysisError):
    """Redundant constraint rows that do not hold where the others do (names the items)."""


def dependency(J: np.ndarray, red: np.ndarray, act: np.ndarray) -> np.ndarray:
    """C (nred, nact) with J[red] = C J[act] in the least-squares sense (J: Phi_q, (m, nq)).

    Below DEPENDENCY_SPARSE_NQ coordinates (a dense J): numpy's lstsq (SVD).  From it on, or
    for a sparse J (CSR): :func:`_dependency_sparse`, one sparse LU of the augmented system,
    where the SVD of the dense (nq, nact) block cost 0.4-1.0 CPU s on the 40-loop four-bar
    (nq 301, 300 active and 159 dropped rows; at set-up and again at the end of a run)
    against about 20 ms; the dense SVD stays where the LU's pivots find the active rows near
    dependent (SPARSE_PIVOT_RATIO)."""
    if red.size == 0:
        return np.zeros((0, act.size))
    if hasattr(J, "toarray") or J.shape[1] >= DEPENDENCY_SPARSE_NQ:
        C = _dependency_sparse(J, red, act)
        if C is not None:
            return C
        J = J.toarray() if hasattr(J, "toarray") else J
    C = np.linalg.lstsq(J[act].T, J[red].T, rcond=None)[0]
    return C.T


def _dependency_sparse(J, red, act):
    """C (nred, nact) as :func:`dependency` for a sparse J, or None where the active rows are
    (numerically) dependent.  The least-squares problem min |A x - b| with A = J[act]^T
    (nq, nact), b = J[red]^T is the augmented system (Bjorck, Numerical Methods for Least
    Squares Problems, 1996, Sec. 2.5.3)

        [ a I   A ] [ r / a ]   [ b ]
        [ A^T   0 ] [   x   ] = [ 0 ]

    solved by one sparse LU for all nred right-hand sides, a = max |J|.  The LU alone
    leaves an error ~ u cond(J[act])^2 in x where a is far from sigma_min (1e-3 against the
    SVD at cond 3e6, the parallel four-bar 1e-5 rad from flat); two steps of iterative
    refinement with the same LU bring it to u cond (7e-11 there, 5e-13 on 40 loops at cond
    8e3; tests/analyses/test_redundancy_sparse.py)."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    J = sp.csr_matrix(J)
    A = J[act].T.tocsc()
    nq, na = A.shape
    a = float(np.abs(J.data).max(initial=0.0)) or 1.0
    K = sp.bmat([[a * sp.identity(nq, format="csc"), A], [A.T, None]], format="csc")
    rhs = np.zeros((nq + na, red.size))
    rhs[:nq] = J[red].T.toarray()
    try:
        lu = spla.splu(K)
    except RuntimeError:  # exactly singular: the active rows depend on each other
        return None
    d = np.abs(lu.U.diagonal())
    if d.min(initial=np.inf) <= SPARSE_PIVOT_RATIO * d.max(initial=0.0):
        return None
    x = lu.solve(rhs)
    for _ in range(2):  # iterative refinement: the LU alone loses u cond^2 (docstring)
        x += lu.solve(rhs - K @ x)
    x = x[nq:]
    return x.T if np.all(np.isfinite(x)) else None


def conflict_items(model, C, red, act, k) -> list[str]:
    """The items whose rows make up dropped row red[k]'s dependency, drivers first."""
    c = np.abs(C[k])
    # no active row (every row dropped): the row conflicts with nothing else
    top = c.max(initial=0.0)
    rows = [red[k]] + [act[i] for i in np.flatnonzero(c > DEPENDENCY_CUT * max(top, 1e-300))]
    names = model.items_of_rows(np.asarray(rows, int))
    user = [n for n in names if not n.startswith(("norm:", "ground:"))] or names
    kind = {it.name: it.kind for it in model.items}
    return [n for n in user if kind.get(n) == "driver"] + \
        [n for n in user if kind.get(n) != "driver"]


def conflict_message(model, items, level, residual, scale=None) -> str:
    """'drivers crank and push over-determine the mechanism (DOF -1): ...'."""
    kind = {it.name: it.kind for it in model.items}
    drivers = [n for n in items if kind.get(n) == "driver"]
    dof = model.nq - model.m
    rel = f", {residual / scale:.3g} of the size of the terms" if scale else ""
    tail = (f"the constraints of {', '.join(items)} depend on each other and do not hold "
            f"together at {level} level: residual {residual:.3g}{rel}")
    if len(drivers) >= 2:
        head = (f"drivers {', '.join(drivers[:-1])} and {drivers[-1]} over-determine the "
                f"mechanism (DOF {dof})")
    elif drivers:
        others = [n for n in items if n not in drivers]
        head = (f"driver {drivers[0]} conflicts with {', '.join(others) or 'the joints'} "
                f"(DOF {dof})")
    else:
        head = f"conflicting constraints {', '.join(items)} (DOF {dof})"
    return f"{head}: {tail}"


def check(model, J, red, act, t, *, phi=None, tol=1e-10, qd=None, nu=None, qdd=None,
          gamma=None, qdd_terms=None, start=True):
    """Raise if the dropped rows ``red`` do not hold at the levels given.

    J: (m, nq) Phi_q at q over all rows; phi: (m,) Phi(q, t); qd, nu: velocity level (nu over
    all rows); qdd, gamma: acceleration level (gamma over all rows); qdd_terms: (nq,) the
    size of the terms qdd is the sum of (applied and constraint forces' accelerations), which
    sets the acceleration level's scale where qdd itself is small (at rest under load: qdd =
    0, its round-off that of the terms).  ``start``: a conflict is
    the deck's structure (ModelError) when True, a failure along the motion at t
    (InconsistentConstraintsError) when False.
    """
    red, act = np.asarray(red, int), np.asarray(act, int)
    if red.size == 0:
        return
    C = dependency(J, red, act)
    cnorm = np.abs(C).sum(axis=1)  # (nred,) infinity norm of each row of C
    levels = []
    if phi is not None:
        levels.append(("position", np.abs(phi[red]), position_bound(cnorm, tol), None))
    for name, x, rhs, terms in (("velocity", qd, nu, None), ("acceleration", qdd, gamma,
                                                             qdd_terms)):
        if x is None or rhs is None:
            continue
        r = np.abs(J[red] @ x - rhs[red])
        # the size of the terms of every row: a dropped row whose own terms vanish (its
        # direction at rest) still carries the others' round-off
        size = np.abs(x) if terms is None else np.maximum(np.abs(x), terms)
        scale = np.full(red.size, max(float(np.max(np.abs(J) @ size + np.abs(rhs),
                                                      initial=0.0)), 1e-300))
        levels.append((name, r, CONSISTENT_REL * (1.0 + cnorm) * scale, scale))
    for level, r, bound, scale in levels:
        bad = np.flatnonzero(r > bound)
        if bad.size == 0:
            continue
        k = int(bad[np.argmax(r[bad] / bound[bad])])
        items = conflict_items(model, C, red, act, k)
        msg = conflict_message(model, items, level, float(r[k]),
                               None if scale is None else float(scale[k]))
        if start:
            raise ModelError(f"{msg}; at t = {t:.6g} s: remove a driver or a joint",
                             tuple(items))
        raise InconsistentConstraintsError(
            f"{msg}: the redundant constraints conflict here, the motion cannot go on "
            f"consistently", time=t, items=tuple(items))
