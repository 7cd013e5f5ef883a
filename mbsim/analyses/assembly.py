"""Assembly: Newton-Raphson with a line search from the deck's estimates onto Phi(q, t) = 0.

The minimum-norm Newton step dq = -Phi_q^+ Phi works for any DOF (Haug Sec. 4.5 uses the
square case); Euler parameters are renormalised after each step (the normalisation rows
make that a no-op at convergence).  Redundant rows are found by a rank-revealing QR and
reported by joint name: consistent redundancy is a warning (the rows are dropped by the
analyses that need a full-rank Phi_q), a conflict is an error naming the drivers and joints
involved (:mod:`mbsim.analyses.redundancy`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from mbsim import core
from mbsim.analyses import redundancy
from mbsim.analyses.common import (
    DENSE_NQ,
    min_norm_step,
    rank_and_redundant,
    singular_rows,
    weakest_directions,
)
from mbsim.errors import ConvergenceError, DeckError, ModelError, SingularJacobianError, Where
from mbsim.options import HOLD_COORDS

log = logging.getLogger(__name__)  # "mbsim.analyses.assembly": -v shows the iterations


@dataclass
class Assembly:
    q: np.ndarray
    iterations: int
    residual: float  # max |Phi|
    rank: int
    redundant_rows: np.ndarray
    redundant_items: list[str]
    active_rows: np.ndarray  # rows kept (all minus redundant)
    dof: int  # nq - rank
    warnings: list[str] = field(default_factory=list)


def worst_constraints(model, ph, n=5) -> str:
    """'REV2 dot1 = 0.226, ...': the n largest residuals, leaving out those below 1e-6 of
    the largest (round-off does not help the reader)."""
    order = np.argsort(-np.abs(ph))[:n]
    big = np.abs(ph).max(initial=0.0)
    return ", ".join(f"{model.row_label[r]} = {ph[r]:.3g}" for r in order
                     if abs(ph[r]) > 1e-6 * big and ph[r] != 0)


def culprits(model, rows) -> list[str]:
    """Items owning the rows, joints and drivers first (normalisation rows are never the cause
    a user can act on, so they are named only when nothing else is involved)."""
    names = model.items_of_rows(rows)
    user = [n for n in names if not n.startswith(("norm:", "ground:"))]
    return user or names


def closed_loop(model, names) -> tuple[list[str], list[str]] | None:
    """The shortest closed loop of bodies (joined by joints and drivers) through the first of
    ``names`` that lies on one: (bodies, items), or None.  When assembly fails, the worst
    constraints name a joint; the loop through it is what cannot close (a link too short)."""
    edges = [(it.bi, it.bj, it.name) for it in model.items  # joints: a driver on a joint
             if it.kind == "joint" and it.bi >= 0 and it.bj >= 0  # closes no loop of bodies
             and it.bi != it.bj]  # fmt: skip
    adj: dict[int, list[tuple[int, int]]] = {}
    for k, (a, b, _) in enumerate(edges):
        adj.setdefault(a, []).append((b, k))
        adj.setdefault(b, []).append((a, k))
    for name in dict.fromkeys(names):
        for a, b, n in edges:
            if n != name:
                continue
            prev = {a: (None, None)}  # breadth-first from a to b without this joint
            queue = [a]
            while queue and b not in prev:
                node = queue.pop(0)
                for nxt, k in adj[node]:
                    if {node, nxt} != {a, b} and nxt not in prev:  # no parallel joint
                        prev[nxt] = (node, k)
                        queue.append(nxt)
            if b not in prev:
                continue
            bodies, items, node = [b], [], b
            while node != a:
                node, k = prev[node]
                bodies.append(node)
                items.append(edges[k][2])
            items = items + [name]  # items[k] joins bodies[k] and bodies[k + 1] (cyclic)
            grounds = [i for i in bodies if model.is_ground[i]]
            if grounds:  # read from the ground, as the book draws loops
                g = bodies.index(grounds[0])
                bodies, items = bodies[g:] + bodies[:g], items[g:] + items[:g]
            bodies = [model.body_names[i] for i in bodies]
            return bodies + [bodies[0]], items
    return None


def _with_loop(model, exc):
    """The assembly error again, saying which loop cannot close (if the items form one)."""
    found = closed_loop(model, exc.items) if exc.items else None
    if found is None:
        return exc
    bodies, items = found
    text = str(exc)
    prefix = f"t = {exc.time:.6g} s: " if exc.time is not None else ""
    text = text[len(prefix):] if prefix and text.startswith(prefix) else text
    return type(exc)(f"{text}; the loop {' - '.join(bodies)} (through {', '.join(items)}) "
                     "cannot close at the deck's estimates: check its lengths and points",
                     time=exc.time, items=exc.items)


def normalize_q(model, q):
    qq = q.reshape(model.nb, 7).copy()
    qq[:, 3:] /= np.linalg.norm(qq[:, 3:], axis=1, keepdims=True)
    return qq.reshape(-1)


STALL_COND = 1e3
"""A stalled Newton iteration whose residual lies along the weakest singular direction of a
Phi_q with a condition number above this is reported as a lock-up, not as non-convergence."""


def newton(model, q, t=0.0, tol=1e-10, max_iter=50, rows=None, hold=None, polish=0):
    """Solve Phi(q, t) = 0 (rows: the subset to solve); returns (q, iterations, max|Phi|).

    ``hold``: coordinate indices kept at their starting values (extra rows q_k - q0_k = 0),
    e.g. the independent coordinates of a system with DOF > 0 during assembly.
    ``polish``: once max |Phi| < tol, up to this many more full Newton steps, each kept only
    where it at least halves max |Phi|: from a converging iterate one step squares the
    residual, so the iteration ends at the round-off of Phi (where a step no longer halves
    it), whatever tol.
    Raises ConvergenceError naming the worst constraints if ||Phi|| stalls or max_iter passes,
    or SingularJacobianError naming the constraints of the singular direction when it stalls
    where Phi_q is singular (no solution exists there: a lock-up).
    """
    q = normalize_q(model, np.array(q, float))
    hold = np.asarray([] if hold is None else hold, dtype=int)
    qh = q[hold].copy()
    sparse = model.nq >= DENSE_NQ  # sparse Phi_q and steps (mbsim.analyses.common)
    if sparse:
        import scipy.sparse as sp

        Ih = sp.csr_matrix((np.ones(hold.size), (np.arange(hold.size), hold)),
                           shape=(hold.size, model.nq))
    else:
        Ih = np.eye(model.nq)[hold]

    def system(qq):
        if not np.isfinite(qq).all():  # before LAPACK sees inf
            core.require_finite(model, t, q=qq)
        T = core.constraints(model, None, qq, t, sparse=sparse)  # non-finite: named error
        ph, J = T.phi, T.jac
        if rows is not None:
            ph, J = ph[rows], J[rows]
        if hold.size:
            ph = np.concatenate([ph, qq[hold] - qh])
            J = sp.vstack([J, Ih], format="csr") if sparse else np.vstack([J, Ih])
        return ph, J

    def polished(q, ph, J, res, its):
        for _ in range(polish):
            if res == 0.0:
                break
            qn = normalize_q(model, q + min_norm_step(J, -ph))
            phn, Jn = system(qn)
            rn = np.abs(phn).max(initial=0.0)
            if not rn <= 0.5 * res:
                break
            q, ph, J, res, its = qn, phn, Jn, rn, its + 1
        return q, its, res

    ph, J = system(q)
    res = np.abs(ph).max(initial=0.0)
    for it in range(1, max_iter + 1):
        if res < tol:
            return polished(q, ph, J, res, it - 1)
        dq = min_norm_step(J, -ph)
        f0 = ph @ ph
        alpha = 1.0
        while True:
            qn = normalize_q(model, q + alpha * dq)
            phn, Jn = system(qn)
            if phn @ phn <= (1 - 1e-4 * alpha) * f0 or alpha < 1e-3:
                break
            alpha *= 0.5
        q, ph, J = qn, phn, Jn
        res = np.abs(ph).max(initial=0.0)
    if res < tol:
        return polished(q, ph, J, res, max_iter)
    full = core.phi(model, None, q, t)
    # A stall with Phi != 0 ends near a least-squares minimum, J^T Phi = 0: when the residual
    # lies mostly (measured: 64-70 % for the slider-crank's rod too short by 1e-6 to 6e-3 m)
    # along the weakest left singular vector of a (nearly) singular J, no configuration
    # satisfies the constraints at this t (a lock-up: the mechanism cannot pass this
    # position), and the rows of that direction say which constraints are involved.
    U, s = weakest_directions(J)
    cond = s[0] / s[-1] if s[-1] > 0 else np.inf
    along = abs(U[:, -1] @ ph) / max(np.linalg.norm(ph), 1e-300) if J.shape[0] <= J.shape[1] \
        else 0.0
    if cond > STALL_COND and along > 0.5:
        sing, _ = singular_rows(model, J)
        nrow = len(rows) if rows is not None else model.m
        crow = [rows[i] if rows is not None else i for i in sing if i < nrow]
        names = model.items_of_rows(np.asarray(crow, int))
        raise SingularJacobianError(
            f"no configuration satisfies the constraints: Newton stalls at max |Phi| = "
            f"{res:.3g}, the residual along the singular direction of the constraint Jacobian "
            f"(condition number {cond:.3g}): the constraints cannot all hold here (during a run: "
            f"a lock-up, the mechanism cannot pass this position); constraints involved: "
            f"{', '.join(names)}",
            time=t, items=tuple(names))
    raise ConvergenceError(
        f"Newton iteration did not converge in {max_iter} iterations (max |Phi| = {res:.3g}); "
        f"worst constraints: {worst_constraints(model, full)}",
        time=t, items=tuple(model.items_of_rows(np.argsort(-np.abs(full))[:3])),
    )


COORDS = {c: k for k, c in enumerate(HOLD_COORDS)}  # offset in a body's [r, p]


def hold_indices(model, hold) -> list[int]:
    """'collar.y', 'spindle.e2' -> coordinate indices (deck: analysis.assembly.hold, checked
    by the loader; here for holds given by code)."""
    where = Where(model.file, "analysis.assembly.hold")
    out = []
    for h in hold or []:
        body, _, coord = str(h).rpartition(".")
        if body not in model.body_names or coord not in COORDS:
            raise DeckError(f"analysis.assembly.hold: {h!r} is not BODY.COORD with BODY one of "
                            f"{', '.join(model.body_names)} and COORD one of "
                            f"{', '.join(COORDS)}", where)
        out.append(7 * model.body_index(body) + COORDS[coord])
    return out


def assemble(model, q=None, t=0.0, tol=1e-10, max_iter=50, hold=None,
             lapack=True, polish=0) -> Assembly:
    """Put q (default: the deck's estimates) on the constraint manifold and check its rank.

    ``hold`` (the deck's ``analysis.assembly.hold``: :attr:`mbsim.options.DeckContext.hold`
    of the run's options; None: nothing held) names coordinates kept at their estimates,
    'BODY.x|y|z|e0|e1|e2|e3': with DOF > 0 the manifold has many points near the
    estimates, and holding the independent coordinates picks the one the user means.
    ``lapack``: the rank test's QR (:func:`mbsim.analyses.common.rank_and_redundant`).
    ``polish``: Newton steps past tol towards round-off (:func:`newton`).
    """
    q0 = model.q0 if q is None else q
    hold_idx = hold_indices(model, hold)
    try:
        q, its, res = newton(model, q0, t, tol, max_iter, hold=hold_idx, polish=polish)
    except (ConvergenceError, SingularJacobianError) as exc:
        # A rank-deficient Phi_q where Newton stalls means constraints that contradict
        # each other: name them (drivers first) rather than only the residuals.
        qs = normalize_q(model, q0)
        T = core.constraints(model, None, qs, t)
        rank, red = rank_and_redundant(model, T.jac, lapack=lapack)  # dense: C, names need it
        if red.size:
            act = np.setdiff1d(np.arange(model.m), red)
            C = redundancy.dependency(T.jac, red, act)
            k = int(np.argmax(np.abs(T.phi[red])))
            names = redundancy.conflict_items(model, C, red, act, k)
            raise ModelError(
                f"{redundancy.conflict_message(model, names, 'position', abs(T.phi[red][k]))} "
                f"at the deck's estimates (Phi_q rank {rank} of {model.m} rows); {exc}",
                tuple(names)) from exc
        raise _with_loop(model, exc) from None
    log.info("assembly at t = %g s: %d Newton iteration(s) from the estimates, max |Phi| = "
             "%.3g", t, its, res)
    rank, red = rank_and_redundant(model, core.phi_q(model, None, q, t,
                                                            sparse=model.nq >= DENSE_NQ),
                                   lapack=lapack)
    warnings = []
    active = np.setdiff1d(np.arange(model.m), red)
    red_items = culprits(model, red) if red.size else []
    if red.size:
        # Newton solved every row to tol, the dropped ones included: they hold at position
        # level here by construction; the analyses check them along the motion and, with
        # velocities and accelerations, at the start (mbsim.analyses.redundancy)
        warnings.append(f"redundant constraints removed: {', '.join(red_items)} "
                        f"({red.size} equation(s): {', '.join(model.row_label[r] for r in red)})"
                        f"; checked consistent at t = {t:g} s")
    return Assembly(q, its, res, rank, red, red_items, active, model.nq - rank, warnings)
