"""FastDynamics(model, rows): the equations of motion of mbsim.integrators.system.System,
compiled, with the same method names and signatures (see :mod:`mbsim.fast` for plugging in).

Per call of :meth:`FastDynamics.accelerations`: the Python time targets and Python force
elements (if any), then one compiled call that evaluates the constraints, the applied
forces (gravity, TSDA, constant forces/torques, the gyroscopic term), assembles the Schur
matrix Phi_q Mt^-1 Phi_q^T of the modified mass matrix in envelope form, factors and solves.
Models with a singular J' (e.g. the four-bar's Izz = 0, Table 12.3.1) have no Mt^-1: they
solve the full KKT matrix by dense LU instead (``self.kkt``).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import reverse_cuthill_mckee

from mbsim import equations as eq
from mbsim.fast import _compiled as C
from mbsim.fast.constraints import FastConstraints


def _solve_error(message):
    from mbsim.integrators.system import SolveError  # the integrators catch this class

    return SolveError(message)


class FastDynamics:
    """One model's equations of motion on its active rows, compiled; a stand-in for
    :class:`mbsim.integrators.system.System` (same attributes, counters and methods).

    model: compiled Model; rows: (m_a,) active (independent) constraint rows, default all;
    sparse: CSR Jacobians from :meth:`terms`; None chooses as System does (its SPARSE_NQ).
    """

    def __init__(self, model, rows=None, sparse=None):
        self.model = model
        nb = model.nb
        self.nb, self.nq = nb, model.nq
        self.rows = np.ascontiguousarray(
            np.arange(model.m) if rows is None else rows, dtype=np.int64
        )
        self.all_rows = self.rows.size == model.m
        self.m = self.rows.size
        if sparse is None:  # the same choice as System's (CSR Jacobians for GCP's LU)
            from mbsim.integrators.system import SPARSE_NQ

            sparse = model.nq >= SPARSE_NQ
        self.fc = FastConstraints(model, self.rows, sparse)
        self.sparse = self.fc.sparse
        self.rheonomic = any(it.kind == "driver" or it.func is not None for it in model.items)
        pos = {int(r): k for k, r in enumerate(self.rows)}
        self.norm_pos = np.full(nb, -1, dtype=np.int64)
        for it in model.items:
            if it.kind == "normalization":
                self.norm_pos[it.bi] = pos.get(int(it.rows[0]), -1)
        self.counters = {
            "function_evaluations": 0,
            "constraint_evaluations": 0,
            "factorizations": 0,
            "newton_iterations": 0,
        }
        self.bt, self.singular = body_table(model)
        self.kkt = bool(self.singular)  # no exact Mt^-1: dense LU of the KKT matrix
        self.ei, self.ef, self.py_forces = element_tables(model.forces)
        self.sidx, self.inc, self.pairs = schur_structure(self.fc.rb, self.rows, nb)
        self._no_loads = np.zeros((2, nb, 3))  # (F, n') of the Python force elements
        self._no_jac = np.zeros((0, 14))
        self._par0 = np.zeros(3)  # Baumgarte (alpha, beta, on)
        fc = self.fc  # the model arguments of the compiled call
        self._static = (fc.ci, fc.cf, fc.rb, self.sidx, self.inc, self.pairs, self.bt)
        self._static += (self.norm_pos, self.ei, self.ef)

    # -- constraint terms on the active rows -----------------------------------------------
    def terms(self, q, t, qd=None, phi=True, jac=True, gamma=False, nu=False):
        """Phi, Phi_q (dense or csr), gamma, nu on the active rows (fresh arrays)."""
        self.counters["constraint_evaluations"] += 1
        return self.fc.constraints(q, t, qd, phi=phi, jac=jac, gamma=gamma, nu=nu)

    def nu(self, q, t):
        if not self.rheonomic:
            return np.zeros(self.m)
        return self.terms(q, t, phi=False, jac=False, nu=True).nu

    # -- forces and masses -----------------------------------------------------------------
    def _python_loads(self, q, qd, t):
        """(2, nb, 3): forces F and body torques n' of the force elements that are not
        compiled, from their own ``apply``."""
        if not self.py_forces:
            return self._no_loads
        st = eq.State(self.model, q, qd)
        loads = np.zeros((2, self.nb, 3))
        for el in self.py_forces:
            el.apply(st, t, loads[0], loads[1])
        return loads

    def applied_forces(self, st, t) -> np.ndarray:
        """Q (nq,) at the state st (:class:`mbsim.equations.State`) as System.applied_forces
        and :func:`mbsim.equations.applied_forces`: gravity, force elements, gyroscopic term."""
        q = np.concatenate([st.r, st.p], axis=1).reshape(-1)
        qd = np.concatenate([st.rd, st.pd], axis=1).reshape(-1)
        return self.generalized_forces(q, qd, t)

    def generalized_forces(self, q, qd, t=0.0) -> np.ndarray:
        """Q (nq,) at (q, qd, t): :meth:`applied_forces` without building a State."""
        q, qd = self._vector(q, "q"), self._vector(qd, "qd")
        Q = np.empty(self.nq)
        C.applied_forces(q, qd, self.bt, self.ei, self.ef, self._python_loads(q, qd, t), Q)
        return Q

    def mass_matrix(self, q) -> np.ndarray:
        """M (nq, nq) = diag(m I, 4 G^T J' G) (mbsim.equations.mass_matrix)."""
        Mb = np.empty((self.nb, 7, 7))
        C.mass_blocks(self._vector(q, "q"), self.bt, Mb)
        M = np.zeros((self.nq, self.nq))
        for b in range(self.nb):
            M[7 * b : 7 * b + 7, 7 * b : 7 * b + 7] = Mb[b]
        return M

    # -- accelerations ---------------------------------------------------------------------
    def accelerations(self, q, qd, t, baumgarte=None, jac=None):
        """Solve the equations of motion at (q, qd, t); returns (qdd, lam, power) as
        System.accelerations: lam (m_a,) on the active rows, power = Q.qd - lam.nu.
        baumgarte: (alpha, beta); jac: Phi_q on the active rows when the caller has it."""
        c = self.counters
        c["function_evaluations"] += 1
        c["constraint_evaluations"] += 1
        c["factorizations"] += 1
        q, qd = self._vector(q, "q"), self._vector(qd, "qd")
        fc = self.fc
        tv = fc.targets(t) if fc.funcs else fc.tv
        loads = self._python_loads(q, qd, t)
        if baumgarte is None:
            par = self._par0
        else:
            par = np.array([baumgarte[0], baumgarte[1], 1.0])
        Jg = self._no_jac if jac is None else self._compact(jac)
        qdd = np.empty(self.nq)
        lam = np.empty(self.m)
        try:
            status, power = C.accelerations(
                q, qd, tv, *self._static, loads, par, self.kkt, Jg, qdd, lam
            )
        except np.linalg.LinAlgError as exc:  # the KKT path's LU
            raise _solve_error(f"singular KKT matrix ({exc})") from exc
        if status != C.STATUS_OK:
            raise _solve_error(
                "singular constraint Jacobian (Phi_q M^-1 Phi_q^T not positive definite)"
            )
        return qdd, lam, power

    def _vector(self, x, name):
        return self.fc.vector(x, name)

    def _compact(self, jac):
        """Compact (m, 14) rows from a Jacobian on the active rows (dense or sparse)."""
        if jac.shape != (self.m, self.nq):
            raise ValueError(f"jac: expected shape ({self.m}, {self.nq}), got {jac.shape}")
        Jc = np.zeros((self.model.m, 14))
        rb = self.fc.rb
        if not sp.issparse(jac):
            C.gather_dense(np.ascontiguousarray(jac, dtype=np.float64), rb, self.rows, Jc)
            return Jc
        coo = sp.coo_matrix(jac)
        coo.sum_duplicates()
        r = self.rows[coo.row]
        body, c = coo.col // 7, coo.col % 7
        slot = np.where(body == rb[r, 0], 0, 1)
        if np.any(body != rb[r, slot]):
            raise ValueError("jac: entries outside the columns of the rows' bodies")
        Jc[r, 7 * slot + c] = coo.data
        return Jc

    def full_lam(self, lam):
        """(m,) multipliers on all rows, zero on the redundant ones."""
        if self.all_rows:
            return lam
        out = np.zeros(self.model.m)
        out[self.rows] = lam
        return out

    # -- projections -----------------------------------------------------------------------
    def _correction(self, q, rhs):
        """Mt^-1 Phi_q^T S^-1 rhs with Phi_q of the last constraint evaluation (identity
        metric when some J' is singular)."""
        self.counters["factorizations"] += 1
        dq = np.empty(self.nq)
        rhs = np.ascontiguousarray(rhs, dtype=np.float64)
        args = (self.fc.Jc, self.bt, self.kkt, self.sidx, self.inc, self.pairs, rhs, dq)
        ok = C.schur_project(q, *args)
        if not ok:
            raise _solve_error(
                "singular constraint Jacobian (Phi_q M^-1 Phi_q^T not positive definite)"
            )
        return dq

    def project_positions(self, q, t, tol=1e-12, max_iter=10):
        """Mass-weighted Newton projection of q onto Phi(q, t) = 0 (dq = -Mt^-1 Phi_q^T S^-1
        Phi).  Returns (q, converged, iterations, max|Phi|)."""
        q = self._vector(q, "q").copy()
        res = np.inf
        for it in range(max_iter + 1):
            self.counters["constraint_evaluations"] += 1
            self.fc.compact(q, t, jac=True)
            phi = self.fc.phi_all[self.rows]
            res = float(np.abs(phi).max(initial=0.0))
            if res <= tol:
                return q, True, it, res
            if it == max_iter:
                break
            self.counters["newton_iterations"] += 1
            q -= self._correction(q, phi)
        return q, False, max_iter, res

    def project_velocities(self, q, qd, t):
        """Mass-weighted projection of qd onto Phi_q qd = nu."""
        self.counters["constraint_evaluations"] += 1
        q = self._vector(q, "q")
        rhs = self._velocity_residual(q, qd, t)[self.rows]
        return qd - self._correction(q, rhs)

    def _velocity_residual(self, q, qd, t):
        """(m,) Phi_q qd - nu on all rows (phi_all, Jc left in the buffers)."""
        fc = self.fc
        fc.compact(q, t, jac=True)
        v = np.empty(fc.m)
        C.jac_times(fc.Jc, fc.rb, self._vector(qd, "qd"), v)
        return v - fc.nu_all

    def violations(self, q, qd, t):
        """(max |Phi|, max |Phi_q qd - nu|) over all rows."""
        v = self._velocity_residual(q, qd, t)
        return float(np.abs(self.fc.phi_all).max(initial=0.0)), float(np.abs(v).max(initial=0.0))

    def energy(self, q, qd):
        """(T, V): kinetic and potential energy (Haug eq. 11.x)."""
        return eq.kinetic_energy(self.model, q, qd), eq.potential_energy(self.model, q)


def body_table(model):
    """bt (nb, NB) (module doc of :mod:`mbsim.fast._compiled`) and the names of the bodies
    without an exact Mt^-1: J' singular (smallest eigenvalue <= 1e-12 x largest) or m <= 0."""
    nb = model.nb
    bt = np.zeros((nb, C.NB))
    singular = []
    for b in range(nb):
        J = np.asarray(model.J_local[b], dtype=float)
        ev = np.linalg.eigvalsh(0.5 * (J + J.T))
        m = float(model.mass[b])
        bt[b, 0] = m
        bt[b, 1:10] = J.reshape(-1)
        if ev.min() <= 1e-12 * max(ev.max(), 0.0) or ev.max() <= 0.0 or m <= 0.0:
            singular.append(model.body_names[b])
        else:
            bt[b, 10:19] = np.linalg.inv(J).reshape(-1)
            bt[b, 23] = 1.0 / m
        bt[b, 19] = 4.0 * np.trace(J) / 3.0
        bt[b, 20:23] = m * np.asarray(model.gravity, dtype=float)
    return np.ascontiguousarray(bt), tuple(singular)


def element_tables(forces):
    """(ei (ne, 3), ef (ne, 9), python elements): TSDA with k, c, L0 (no law, no actuator)
    and constant point forces and torques are compiled; every other element keeps its
    Python ``apply``."""
    from mbsim.forces.elements import TSDA, PointForce, Torque

    ei, ef, py = [], [], []
    for el in forces:
        cls = type(el)
        if cls is TSDA and el.law is None and el.actuator is None:
            ei.append((C.EL_TSDA, el.bi, el.bj))
            ef.append(np.concatenate([el.si, el.sj, [el.k, el.c, el.L0]]))
        elif cls is PointForce and el.vec is not None:
            ei.append((C.EL_FORCE_LOCAL if el.local else C.EL_FORCE, el.b, -1))
            ef.append(np.concatenate([el.vec, el.s, np.zeros(3)]))
        elif cls is Torque and el.vec is not None:
            ei.append((C.EL_TORQUE_LOCAL if el.local else C.EL_TORQUE, el.bj, el.bi))
            ef.append(np.concatenate([el.vec, np.zeros(6)]))
        else:
            py.append(el)
    ei = np.array(ei, dtype=np.int64).reshape(-1, 3)
    ef = np.array(ef, dtype=np.float64).reshape(-1, 9)
    return ei, ef, tuple(py)


def schur_structure(rb, rows, nb):
    """(sidx (4, m_a), inc (ninc, 3), pairs (np, 3)) of the Schur matrix on ``rows`` (module
    doc of :mod:`mbsim.fast._compiled`): reverse Cuthill-McKee order, envelope, incidences
    (row, column offset, body) and the products that fill the envelope."""
    ma = rows.size
    inc = [(u, 7 * s, rb[r, s]) for u, r in enumerate(rows) for s in range(2) if rb[r, s] >= 0]
    inc = np.array(sorted(inc, key=lambda x: (x[2], x[0], x[1])), dtype=np.int64).reshape(-1, 3)
    rows_bodies = sp.csr_matrix((np.ones(len(inc)), (inc[:, 0], inc[:, 2])), shape=(ma, nb))
    graph = (rows_bodies @ rows_bodies.T).tocsr()
    order = (
        reverse_cuthill_mckee(graph, symmetric_mode=True).astype(np.int64)
        if ma
        else np.zeros(0, dtype=np.int64)
    )
    pos = np.empty(ma, dtype=np.int64)
    pos[order] = np.arange(ma)
    fc = np.arange(ma, dtype=np.int64)  # first column of each envelope row (position space)
    g = graph.tocoo()
    np.minimum.at(fc, pos[g.row], pos[g.col])
    width = np.arange(ma) - fc + 1
    off = np.concatenate([[0], np.cumsum(width)[:-1]]).astype(np.int64) if ma else fc.copy()
    pairs = []
    for b in range(nb):
        mine = np.flatnonzero(inc[:, 2] == b)
        for g1 in mine:
            pu = pos[inc[g1, 0]]
            for g2 in mine:
                pv = pos[inc[g2, 0]]
                if pu >= pv:
                    pairs.append((off[pu] + pv - fc[pu], g1, g2))
    pairs = np.array(pairs, dtype=np.int64).reshape(-1, 3)
    sidx = np.ascontiguousarray(np.stack([np.asarray(rows, dtype=np.int64), order, fc, off]))
    return sidx, inc, pairs
