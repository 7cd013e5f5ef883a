"""System(model, rows): the constrained equations of motion the integrators call.

Equations of motion (Haug Ch. 11, Euler-parameter form):

    M(q) qdd + Phi_q^T lam = Q(q, qd, t),    Phi_q qdd = gamma(q, qd, t)

solved by the Schur complement of a *modified* mass matrix.  The Euler-parameter block
M_p = 4 G^T J' G is singular along p; the normalisation row p^T p = 1 fixes p^T pdd =
gamma_norm / 2, so adding c p p^T pdd to both sides changes nothing:

    Mt_p = 4 G^T J' G + c p p^T,   Qt_p = Q_p + c p gamma_norm / 2,   c = 4 tr(J') / 3.

With s = p^T p, [G; p^T] [G; p^T]^T = s I, hence the exact block inverse

    Mt_p^-1 = (G^T J'^-1 G / 4 + p p^T / c) / s^2,

and lam = (Phi_q Mt^-1 Phi_q^T)^-1 (Phi_q Mt^-1 Qt - gamma), qdd = Mt^-1 (Qt - Phi_q^T lam).
Only the m x m Schur matrix S is factored, never the (nq + m) KKT matrix: S is assembled
body by body in the envelope of its reverse Cuthill-McKee ordering and factored in it as
L D L^T (George and Liu 1981, Ch. 4: envelope Cholesky without its square roots), so a chain
costs O(m b^2), b its bandwidth.  Models
with a singular J' (the four-bar's Izz = 0, Table 12.3.1) have no Mt^-1: their accelerations
solve the full KKT matrix by dense LU (``self.kkt``) and the projections use the identity
metric (min-norm corrections).

Per call of :meth:`System.accelerations`: the Python time targets and Python force elements
(if any), then one C call (mbsim/fast/kernels.c, ``mb_accelerations``) that evaluates the
constraints, the applied forces (gravity, TSDA, constant forces/torques, tires, the gyroscopic
term), assembles S, factors and solves.

Tables (besides the constraint tables of :mod:`mbsim.fast.constraints`), built once:

- ``bt`` (nb, NB) float64 per body: mass (col 0), J' (1-9, row-major), J'^-1 (10-18,
  zero when J' is singular), c = 4 tr(J') / 3 (19), weight m g (20-22), 1 / m (23);
- ``ei`` (ne, 3) int64 / ``ef`` (ne, NEF) float64 per compiled force element: kind
  (``EL_*``), bodies b1, b2 and data (TSDA: s_i', s_j', k, c, L0; force: vector, s'; torque:
  vector; tire: :meth:`mbsim.forces.tire.Tire.table_row`, 13 numbers, the widest, zeros
  after the others' data); other elements are applied in Python and arrive as ``loads``
  (2, nb, 3): their forces F and body-frame torques n';
- ``sidx`` (4, m_a) int64: active rows (in the caller's order), the fill-reducing order of
  the Schur matrix (``order[k]``: the active row at position k, reverse Cuthill-McKee),
  the envelope's first column ``fc`` and offset ``off`` per position;
- ``inc`` (ninc, 3) int64: the incidences (active row u, column offset of the body in the
  row's compact Jacobian (0: body i, 7: body j), body), grouped by body; offset + ``CROSS``:
  a row's incidence on a body held by its own rows (the ground), left out of S
  (:func:`schur_structure`);
- ``pairs`` (np, 4) int64: one line per (incidence g_u, incidence g_v) of the same body
  with pos(u) >= pos(v): envelope index of S[u, v], g_u, g_v, and the columns of the
  product (Mt^-1 Phi_q^T)[g_u] . Phi_q[g_v] that can be nonzero (``pair_codes``).  The
  other products are exact zeros, which the C code skips (adding +-0 to a sum that starts
  at +0 changes no bit).
"""

from __future__ import annotations

import numpy as np

from mbsim import core
from mbsim.fast.constraints import KERNEL_CODE, KERNELS, FastConstraints, model_table
from mbsim.fast.ordering import reverse_cuthill_mckee, row_graph

NB = 24
EL_TSDA, EL_FORCE, EL_FORCE_LOCAL, EL_TORQUE, EL_TORQUE_LOCAL, EL_TIRE = range(6)
NEF = 13
"""Columns of ``ef`` (kernels.c's NEF): the tire's data, the widest.  One table for every
kind (rather than a table of tires beside it): one loop over the elements in the model's
order in ``mb_applied_forces`` and one pointer in mb_model; the others' rows end in zeros."""
STATUS_OK, STATUS_NOT_PD, STATUS_SINGULAR = range(3)


REACTION_ITERATIONS = 60  # fixed-point iterations of the loop loads <-> multipliers


class SolveError(Exception):
    """A factorisation that failed inside a step (the integrator turns it into a message)."""


_NOT_PD = "singular constraint Jacobian (Phi_q M^-1 Phi_q^T not positive definite)"


def solve_error(status):
    """The SolveError of a failed mb_accelerations (its STATUS_* code)."""
    return SolveError("singular KKT matrix" if status == STATUS_SINGULAR else _NOT_PD)


class System:
    """One model's equations of motion on its active constraint rows, with counters.

    model: compiled Model; rows: (m_a,) active (independent) constraint rows, default all;
    sparse: CSR Jacobians from :meth:`terms`; None chooses by size (nq >= SPARSE_NQ).
    Arrays returned by the methods are fresh.
    """

    def __init__(self, model, rows=None, sparse=None, modes=None):
        self.model = model
        nb, nq = model.nb, model.nq
        self.nb, self.nq = nb, nq
        self.rows = np.ascontiguousarray(
            np.arange(model.m) if rows is None else rows, dtype=np.int64
        )
        self.all_rows = self.rows.size == model.m
        self.m = ma = self.rows.size
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
        self.bt, self.singular = model_table(model, "bodies", body_table, model)
        self.kkt = bool(self.singular)  # no exact Mt^-1: dense LU of the KKT matrix
        # smallest pivot / diagonal of the Schur factor at the last accelerations() (1 for
        # the KKT path): ~ (sigma_min / sigma)^2 of the active rows, small near a change point
        self.pivot_ratio = 1.0
        self.ei, self.ef, self.py_forces = model_table(model, "elements", element_tables,
                                                       model.forces)
        # hybrid elements (mbsim.events): their modes in this system, and whether their
        # loads depend on the multipliers (the loop solved in accelerations())
        self.hybrid = tuple(el for el in self.py_forces if getattr(el, "hybrid", False))
        self.modes = dict(modes or {})
        self.reaction_loop = any(getattr(el, "reactions", False) for el in self.hybrid)
        self._py_plain = tuple(el for el in self.py_forces if el not in self.hybrid)
        self._lam_known = None  # (m,) multipliers on all rows, the loop's last iterate
        self.family = None  # the run (Stepper) that builds systems for other modes
        # the symbolic analysis of S (order, envelope, products): once per row set; on the
        # sparse path (large models), bodies held by their own active rows (the ground) are
        # left out of S where that pays (schur_structure)
        held = held_bodies(model, self.rows) if self.sparse and not self.kkt else ()
        self.sidx, self.inc, self.pairs = model_table(
            model, ("schur", self.rows.tobytes(), held), schur_structure, self.fc.rb,
            self.rows, nb, self.fc.ci, held)
        # the model's struct (shared with self.fc) gets the dynamics tables and buffers
        c = self.c = self.fc.c
        nenv = _env_size(self.sidx)
        ninc = self.inc.shape[0]
        c.size(ninc=ninc, npairs=self.pairs.shape[0], nenv=nenv, ne=self.ei.shape[0])
        c.set(sidx=self.sidx, inc=self.inc, pairs=self.pairs, bt=self.bt, nrm=self.norm_pos,
              ei=self.ei, ef=self.ef)
        nk = nq + ma if self.kkt else 0
        # the buffers, zeros carved from one allocation (c.zeros); after mb_applied_forces:
        # F (nb, 3) global forces, n (nb, 3) body torques with the gyroscopic term, w (nb, 3)
        # body-frame angular velocities
        # env (nenv,): the factor L D L^T of S in its envelope, 1 / D_ii on the diagonal
        (self._loads, self._par, self._Jg, self._rhs, self._Q, self._qdd, self._lam, self._dq,
         self._out, _, _, _, _, _, self._env, _, _, _, _, _, self._F, self._n, self._w,
         self._Mb) = c.zeros(
            loads=(2, nb, 3), par=3, Jg=(model.m, 14), rhs=ma, Q=nq, qdd=nq, lam=ma, dq=nq,
            out=2, Qt=nq, g=ma, Mi=(nb, 4, 4), XG=(ninc, 8), JG=(ninc, 8), env=nenv,
            srhs=ma, z=ma, K=nk * nk, kr=nk, A=(nb, 3, 3), F=(nb, 3), n=(nb, 3), w=(nb, 3),
            Mb=(nb, 7, 7))
        self._out[:] = 1.0
        c.set(kp=np.zeros(nk, np.int64))
        self._v = np.zeros(model.m)
        lib = self.fc.lib
        self._acc, self._project = lib.mb_accelerations, lib.mb_project
        self._forces, self._mass = lib.mb_applied_forces, lib.mb_mass_blocks
        self._jac_times, self._gather_dense = lib.mb_jac_times, lib.mb_gather_dense

    # -- constraint terms on the active rows -----------------------------------------------
    def terms(self, q, t, qd=None, phi=True, jac=True, gamma=False, nu=False):
        """Phi, Phi_q (dense or csr), gamma, nu on the active rows (fresh arrays; None for
        the parts not asked for)."""
        self.counters["constraint_evaluations"] += 1
        return self.fc.constraints(q, t, qd, phi=phi, jac=jac, gamma=gamma, nu=nu)

    def nu(self, q, t):
        """nu = c'(t) on the active rows (zero for a scleronomic model)."""
        if not self.rheonomic:
            return np.zeros(self.m)
        return self.terms(q, t, phi=False, jac=False, nu=True).nu

    # -- forces and masses -----------------------------------------------------------------
    def _load(self, q, qd, t, loads=None):
        """q, qd, the time targets and the Python elements' loads into the C inputs;
        ``loads`` (2, nb, 3): those loads (F, n_local) when already computed (for many
        outputs at once: ForceElement.loads_many)."""
        fc = self.fc
        fc.load(q, t, qd)
        if self.py_forces:
            if loads is not None:
                self._loads[:] = loads
                return
            self.apply_python(core.State(self.model, fc._q, fc._qd), t, self._loads)

    def apply_python(self, st, t, loads):
        """The Python force elements' loads at ``st`` into ``loads`` (2, nb, 3), zeroed
        first; hybrid elements in this system's modes, with the multipliers of the last
        accelerations (the reaction loop's iterate)."""
        loads[:] = 0.0
        for el in self.hybrid:
            el.apply_in(self.modes.get(el.name), st, t, self._lam_known, loads[0], loads[1])
        for el in self._py_plain:
            el.apply(st, t, loads[0], loads[1])

    def applied_forces(self, st, t) -> np.ndarray:
        """Q (nq,) at the state st (:class:`mbsim.core.State`) as
        :func:`mbsim.core.applied_forces`: gravity, force elements, gyroscopic term."""
        q = np.concatenate([st.r, st.p], axis=1).reshape(-1)
        qd = np.concatenate([st.rd, st.pd], axis=1).reshape(-1)
        return self.generalized_forces(q, qd, t)

    def generalized_forces(self, q, qd, t=0.0) -> np.ndarray:
        """Q (nq,) at (q, qd, t): :meth:`applied_forces` without building a State."""
        self._load(q, qd, t)
        self._forces(self.c.ptr)
        return self._Q.copy()

    def loads(self, q, qd, t=0.0):
        """(Q (nq,), F (nb, 3), n_local (nb, 3)): the generalized forces and their parts,
        F the global forces at the centroids and n_local the body torques without the
        gyroscopic term (as :func:`mbsim.core.applied_forces` reports them)."""
        Q = self.generalized_forces(q, qd, t)
        w = self._w
        gyro = np.cross(w, np.einsum("bij,bj->bi", self.model.J_local, w))
        return Q, self._F.copy(), self._n + gyro

    def mass_blocks(self, q) -> np.ndarray:
        """(nb, 7, 7) diagonal blocks of M = diag(m I, 4 G^T J' G) (Haug Ch. 11)."""
        self.fc.vector(q, "q", self.fc._q)
        self._mass(self.c.ptr)
        return self._Mb.copy()

    def mass_matrix(self, q) -> np.ndarray:
        """M (nq, nq) = diag(m I, 4 G^T J' G) (Haug Ch. 11)."""
        Mb = self.mass_blocks(q)
        M = np.zeros((self.nq, self.nq))
        for b in range(self.nb):
            M[7 * b : 7 * b + 7, 7 * b : 7 * b + 7] = Mb[b]
        return M

    # -- accelerations ---------------------------------------------------------------------
    def accelerations(self, q, qd, t, baumgarte=None, jac=None, loads=None):
        """Solve the equations of motion at (q, qd, t); returns (qdd, lam, power).

        lam: (m_a,) multipliers of the active rows; power = Q.qd - lam.nu, the rate of
        work of applied and driving forces (the kinetic energy's rate).  baumgarte: (alpha,
        beta) replaces gamma by gamma - 2 alpha Phi_dot - beta^2 Phi (Baumgarte 1972).
        jac: Phi_q on the active rows at q when the caller has it (coordinate
        partitioning).  loads: (2, nb, 3) the Python force elements' loads at (q, qd, t)
        when the caller has them (:meth:`_load`)."""
        c = self.counters
        c["function_evaluations"] += 1
        c["constraint_evaluations"] += 1
        c["factorizations"] += 1
        self._load(q, qd, t, loads)
        par = self._par
        if baumgarte is None:
            par[2] = 0.0
        else:
            par[0], par[1], par[2] = baumgarte[0], baumgarte[1], 1.0
        if jac is not None:
            self._compact(jac)
        self._solve(jac is not None)
        if self.reaction_loop and loads is None:
            self._reaction_loop(q, qd, t, jac is not None)
        self.pivot_ratio = float(self._out[1])
        return self._qdd.copy(), self._lam.copy(), float(self._out[0])

    def _solve(self, have_jac):
        status = self._acc(self.c.ptr, self.kkt, have_jac)
        if status != STATUS_OK:
            raise solve_error(status)

    def _reaction_loop(self, q, qd, t, have_jac):
        """Loads that depend on the multipliers (friction with the joint's reaction as its
        normal force): fixed-point iteration loads(lam) -> solve -> lam until the loads
        repeat to round-off (1e-14 relative).  It contracts by about mu x (pin radius or
        bearing lever) / (the lever of the body's inertia), small for the friction
        coefficients and bearing sizes of real joints (the seed's pendulum: about 5
        iterations per evaluation); a loop that does not settle in REACTION_ITERATIONS is a
        SolveError (the run ends incomplete, saying so)."""
        loads, fc = self._loads, self.fc
        prev = loads.copy()
        st = core.State(self.model, fc._q, fc._qd)
        for _ in range(REACTION_ITERATIONS):
            self._lam_known = self.full_lam(self._lam.copy())
            self.apply_python(st, t, loads)
            scale = float(np.abs(loads).max(initial=0.0))
            if np.abs(loads - prev).max(initial=0.0) <= 1e-14 * scale:
                return
            prev[:] = loads
            self._solve(have_jac)
        raise SolveError(f"the friction loads and the joint reactions did not settle in "
                         f"{REACTION_ITERATIONS} iterations at t = {t:.6g} s")

    def _compact(self, jac):
        """Compact rows (into Jg) from a Jacobian on the active rows (dense or sparse)."""
        if jac.shape != (self.m, self.nq):
            raise ValueError(f"jac: expected shape ({self.m}, {self.nq}), got {jac.shape}")
        Jc = self._Jg
        if isinstance(jac, np.ndarray):  # dense; scipy.sparse imported only for sparse jac
            J = np.ascontiguousarray(jac, dtype=np.float64)
            self._gather_dense(self.c.ptr, J.ctypes.data, Jc.ctypes.data)
            return
        import scipy.sparse as sp

        coo = sp.coo_matrix(jac)
        coo.sum_duplicates()
        rb = self.fc.rb
        r = self.rows[coo.row]
        body, col = coo.col // 7, coo.col % 7
        slot = np.where(body == rb[r, 0], 0, 1)
        if np.any(body != rb[r, slot]):
            raise ValueError("jac: entries outside the columns of the rows' bodies")
        Jc[self.rows] = 0.0
        Jc[r, 7 * slot + col] = coo.data

    def kinematic(self, q, t, tol=1e-10, max_iter=25, cond=False):
        """One output of a kinematic analysis (DOF 0: the active rows square, m_a = nq), in
        one C call (``mb_kinematic``): Newton from the predictor q onto Phi(q, t) = 0, then
        Phi_q qd = nu and Phi_q qdd = gamma on the LU of Phi_q at the solution.

        Returns (status, q, qd, qdd, info): status 0 ok, 2 a zero pivot (singular Phi_q),
        3 no convergence in max_iter steps; info (4,) = Newton iterations, max |Phi| on the
        active rows, cond_2(Phi_q) (NaN unless ``cond``; Lanczos on J^T J and on its
        inverse), smallest / largest LU pivot."""
        if self.m != self.nq:
            raise ValueError(f"kinematic: the active rows must be square, got {self.m} rows "
                             f"for {self.nq} coordinates")
        if getattr(self, "_kin", None) is None:
            n = self.nq
            self._kin = (np.zeros(3 * n * n + 4 * n), np.zeros(n, dtype=np.int64),
                         np.zeros(4))
        work, piv, info = self._kin
        fc = self.fc
        fc.load(q, t)
        self.counters["constraint_evaluations"] += 1
        status = self.fc.lib.mb_kinematic(self.c.ptr, float(tol), int(max_iter), bool(cond),
                                          work.ctypes.data, piv.ctypes.data, info.ctypes.data)
        self.counters["newton_iterations"] += int(info[0])
        self.counters["factorizations"] += int(info[0]) + 1
        return status, fc._q.copy(), fc._qd.copy(), self._qdd.copy(), info.copy()

    def apply_minv(self, q, X) -> np.ndarray:
        """Mt^-1 X at q: X (nq,) or (nq, k), Mt the modified mass matrix (module doc)."""
        X = np.asarray(X, dtype=np.float64)
        Xt = np.ascontiguousarray(X.reshape(self.nq, -1).T)  # (k, nq) rows
        Yt = np.empty_like(Xt)
        self.fc.vector(q, "q", self.fc._q)
        self.fc.lib.mb_apply_minv(self.c.ptr, 0, Xt.shape[0], Xt.ctypes.data, Yt.ctypes.data)
        return Yt.T.reshape(X.shape)

    def full_lam(self, lam):
        """(m,) multipliers on all rows, zero on the redundant ones."""
        if self.all_rows:
            return lam
        out = np.zeros(self.model.m)
        out[self.rows] = lam
        return out

    # -- projections -----------------------------------------------------------------------
    def _correction(self, rhs):
        """Mt^-1 Phi_q^T S^-1 rhs with Phi_q of the last constraint evaluation, at the q
        loaded then (identity metric when some J' is singular)."""
        self.counters["factorizations"] += 1
        self._rhs[:] = rhs
        if self._project(self.c.ptr, self.kkt) != STATUS_OK:
            raise SolveError(_NOT_PD)
        return self._dq

    def least_energy_velocities(self, q, t, Y):
        """(qd0, B, r) on the active rows at (q, t), with one factorisation of S for all of
        it: qd0 = Mt^-1 Phi_q^T S^-1 nu, the velocities of least kinetic energy that meet
        Phi_q qd = nu; B = Y - Mt^-1 Phi_q^T S^-1 Phi_q Y (nq, k), each column of Y (nq, k)
        moved into null(Phi_q) along the least-energy direction; r the factor's smallest
        pivot ratio (~ (sigma_min / sigma_max)^2 of Phi_q; 1 on the KKT path)."""
        qd0 = self.project_velocities(q, np.zeros(self.nq), t).copy()  # factors S at q
        r = 1.0 if self.kkt else float(self._out[1])
        B = np.array(Y, dtype=np.float64).reshape(self.nq, -1)
        if not B.shape[1]:
            return qd0, B, r
        Yt = np.ascontiguousarray(B.T)
        v, lib, ptr = self._v, self.fc.lib, self.c.ptr
        for k in range(Yt.shape[0]):
            self._jac_times(ptr, Yt[k].ctypes.data, v.ctypes.data)  # Phi_q of the compact
            if self.kkt:  # (the KKT path keeps no factor to solve on again)
                B[:, k] -= self._correction(v[self.rows])
                continue
            self._rhs[:] = v[self.rows]
            lib.mb_project_factored(ptr)
            B[:, k] -= self._dq
        return qd0, B, r

    def project_positions(self, q, t, tol=1e-12, max_iter=10):
        """Mass-weighted Newton projection of q onto Phi(q, t) = 0 (dq = -Mt^-1 Phi_q^T S^-1
        Phi).  Returns (q, converged, iterations, max|Phi|)."""
        q = self.fc.vector(q, "q")
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
            q -= self._correction(phi)
        return q, False, max_iter, res

    def project_velocities(self, q, qd, t):
        """Mass-weighted projection of qd onto Phi_q qd = nu."""
        self.counters["constraint_evaluations"] += 1
        rhs = self._velocity_residual(q, qd, t)[self.rows]
        return self.fc._qd - self._correction(rhs)

    def drift(self, q, qd, t):
        """(dq, dqd): the mass-weighted first Newton corrections that project_positions and
        project_velocities would make at (q, qd), i.e. how far the state is from the
        constraint set in coordinates (one constraint evaluation)."""
        self.counters["constraint_evaluations"] += 1
        v = self._velocity_residual(q, qd, t)[self.rows]
        dq = self._correction(self.fc.phi_all[self.rows]).copy()  # _correction's buffer
        return dq, self._correction(v).copy()

    def _velocity_residual(self, q, qd, t):
        """(m,) Phi_q qd - nu on all rows (phi_all, Jc left in the buffers; qd loaded)."""
        fc = self.fc
        fc.compact(q, t, jac=True)
        fc.vector(qd, "qd", fc._qd)
        self._jac_times(self.c.ptr, fc._qd.ctypes.data, self._v.ctypes.data)
        return self._v - fc.nu_all

    def residuals(self, q, qd, t):
        """(Phi, Phi_q qd - nu): (m,) each, over all rows (copies)."""
        v = self._velocity_residual(q, qd, t)
        return self.fc.phi_all.copy(), v.copy()

    def violations(self, q, qd, t):
        """(max |Phi|, max |Phi_q qd - nu|) over all rows."""
        ph, v = self.residuals(q, qd, t)
        return float(np.abs(ph).max(initial=0.0)), float(np.abs(v).max(initial=0.0))

    def energy(self, q, qd):
        """(T, V): kinetic and potential energy (Haug Ch. 11)."""
        return core.energy(self.model, None, q, qd)


def _env_size(sidx):
    """Entries of the envelope (rows fc..k of each position k)."""
    n = sidx.shape[1]
    return int(sidx[3, n - 1] + n - sidx[2, n - 1]) if n > 0 else 0


def body_table(model):
    """bt (nb, NB) (module doc) and the names of the bodies
    without an exact Mt^-1: J' singular (smallest eigenvalue <= 1e-12 x largest) or m <= 0."""
    nb = model.nb
    bt = np.zeros((nb, NB))
    singular = []
    for b in range(nb):
        J = np.asarray(model.J_local[b], dtype=float)
        scale = float(np.abs(J).max())  # the test below is scale-free; 1e308 must not overflow
        ok = np.isfinite(scale) and scale > 0.0
        Js = J / scale if ok else J
        ev = np.linalg.eigvalsh(0.5 * (Js + Js.T)) if ok else np.zeros(1)
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
    """(ei (ne, 3), ef (ne, NEF), python elements): TSDA with k, c, L0 (no law, no
    actuator), constant point forces and torques, and tires are compiled; every other
    element keeps its Python ``apply``."""
    from mbsim.forces.elements import TSDA, PointForce, Torque
    from mbsim.forces.tire import Tire

    ei, ef, py = [], [], []
    for el in forces:
        cls = type(el)
        if cls is TSDA and el.law is None and el.actuator is None:
            ei.append((EL_TSDA, el.bi, el.bj))
            ef.append(np.concatenate([el.si, el.sj, [el.k, el.c, el.L0]]))
        elif cls is PointForce and el.vec is not None:
            ei.append((EL_FORCE_LOCAL if el.local else EL_FORCE, el.b, -1))
            ef.append(np.concatenate([el.vec, el.s]))
        elif cls is Torque and el.vec is not None:
            ei.append((EL_TORQUE_LOCAL if el.local else EL_TORQUE, el.bj, el.bi))
            ef.append(el.vec)
        elif cls is Tire:
            ei.append((EL_TIRE, el.b, -1))
            ef.append(el.table_row())
        else:
            py.append(el)
    rows = np.zeros((len(ef), NEF))
    for k, row in enumerate(ef):
        rows[k, : len(row)] = row
    return np.array(ei, dtype=np.int64).reshape(-1, 3), rows, tuple(py)


TIRE_OUTPUTS = (("F", 3), ("n_local", 3), ("sc", 3), ("v", 3), ("u", 3), ("F_ver", 1),
                ("F_lat", 1), ("F_roll", 1), ("alpha", 1), ("saturated", 1),
                ("deflection", 1), ("speed", 1))
"""What kernels.c's tire_law writes per tire and state, in its order (TIRE_OUT = 22)."""
TIRE_OUT = sum(n for _, n in TIRE_OUTPUTS)


def tire_states(b, table, q, qd) -> dict:
    """The tire law (kernels.c ``tire_law``; mbsim/forces/tire.py's module doc) of the
    tires on bodies ``b`` (ne,) with data ``table`` (ne, NEF) (their ef rows) at the states
    q, qd (..., nb, 7): {quantity: (..., ne, 3) for F, n_local, sc, v, u; (..., ne) for
    F_ver, F_lat, F_roll, alpha, saturated (1.0 or 0.0), deflection, speed}, views of one
    fresh array.  One C call (``mb_tire_states``) for every state and tire."""
    from mbsim.fast import _lib

    b = np.ascontiguousarray(b, dtype=np.int64)
    table = np.ascontiguousarray(table, dtype=np.float64)
    q = np.ascontiguousarray(q, dtype=np.float64)
    qd = np.ascontiguousarray(qd, dtype=np.float64)
    lead, nb = q.shape[:-2], q.shape[-2]
    nt, ne = int(np.prod(lead, dtype=np.int64)), b.size
    if q.ndim < 2 or q.shape[-1] != 7 or qd.shape != q.shape:
        raise ValueError(f"q, qd: expected (..., nb, 7) each, got {q.shape}, {qd.shape}")
    if table.shape != (ne, NEF) or (ne and not 0 <= b.min() <= b.max() < nb):
        raise ValueError(f"tires on bodies {b.tolist()} of {nb} with data {table.shape}: "
                         f"expected bodies in [0, {nb}) and data ({ne}, {NEF})")
    out = np.empty((*lead, ne, TIRE_OUT))
    _lib.library().mb_tire_states(nt, nb, ne, b.ctypes.data, table.ctypes.data,
                                  q.ctypes.data, qd.ctypes.data, out.ctypes.data)
    result, k = {}, 0
    for name, n in TIRE_OUTPUTS:
        result[name] = out[..., k : k + n] if n > 1 else out[..., k]
        k += n
    return result


# Columns of one body's 7 (r: bits 0-2, p: bits 3-6) where a kernel's row of Phi_q can be
# nonzero, by kernel code (mbsim/fast/kernels.c, its k_* functions): a function of the
# equation e of the kernel and the side (0: body i, 1: body j) -> bit mask.  A kernel not
# listed: every column.
ALL_COLUMNS, P_COLUMNS = 0x7F, 0x78
KERNEL_ROWS = dict(zip(range(len(KERNELS)), (1, 1, 3, 1, 1, 1, 6, 1)))  # kernels.c's NE
KERNEL_COLUMNS = {
    KERNEL_CODE["dot1"]: lambda e, side: P_COLUMNS,  # a_j^T B(p_i, a_i'): p only
    KERNEL_CODE["spherical"]: lambda e, side: 1 << e | P_COLUMNS,  # [-+I, -+B]: r unit e
    KERNEL_CODE["angle"]: lambda e, side: P_COLUMNS,
    KERNEL_CODE["absolute"]: None,  # e_axis^T, B[axis]: the axis from ci (below)
    KERNEL_CODE["ground"]: lambda e, side: 1 << e if e < 3 else 1 << (e + 1),  # r_e, e_(e-2)
    KERNEL_CODE["normalization"]: lambda e, side: P_COLUMNS,  # 2 p^T
}


def column_masks(ci, m):
    """(m, 2) int64: for each row and side of the compact Phi_q (Jc's columns 0-6, 7-13) the
    bit mask of the columns the kernels can write (``KERNEL_COLUMNS``; every column for
    the other kernels)."""
    masks = np.full((m, 2), ALL_COLUMNS, dtype=np.int64)
    for code, row, flag in ci[:, [0, 3, 4]]:  # kernel code, first row, flag (axis)
        if code == KERNEL_CODE["absolute"]:
            masks[row] = 1 << flag | P_COLUMNS
        elif code in KERNEL_COLUMNS:
            for e in range(KERNEL_ROWS[code]):
                masks[row + e] = [KERNEL_COLUMNS[code](e, side) for side in (0, 1)]
    return masks


def pair_codes(mask_u, mask_v):
    """kernels.c's pair_dot codes of the products (Mt^-1 Phi_q^T)[g_u] . Phi_q[g_v] of pairs
    of incidences on one body whose rows of Phi_q can be nonzero in the columns ``mask_u``,
    ``mask_v`` (arrays of ``column_masks``): a product can be nonzero where g_v's row can,
    and, in the r columns (where Mt^-1 is diagonal), where g_u's can too.  The code is the r
    column (0-2, 7: none) where that leaves at most one r column and all four p columns;
    else -1 - the mask."""
    mask = np.asarray(mask_v, dtype=np.int64) & (np.asarray(mask_u, dtype=np.int64) | P_COLUMNS)
    r = mask & ~P_COLUMNS
    coded = ((mask & P_COLUMNS) == P_COLUMNS) & np.isin(r, (0, 1, 2, 4))
    column = np.select([r == 1, r == 2, r == 4], [0, 1, 2], 7)
    return np.where(coded, column, -1 - mask).astype(np.int64)


def held_bodies(model, rows):
    """(bodies,) held by their own active rows alone: a ``ground`` item's six rows and the
    body's normalisation row all in ``rows`` fix its coordinates (qdd_b = 0 whatever the
    other rows do), so S needs none of its other incidences (:func:`schur_structure`)."""
    active = set(int(r) for r in rows)
    own = {}
    for it in model.items:
        if it.kind in ("ground", "normalization") and it.bj < 0:
            own.setdefault(it.bi, []).append((it.kind, all(int(r) in active for r in it.rows)))
    return tuple(sorted(b for b, kinds in own.items()
                        if ("ground", True) in kinds and ("normalization", True) in kinds))


def schur_structure(rb, rows, nb, ci=None, held=()):
    """(sidx (4, m_a), inc (ninc, 3), pairs (np, 4)) of the Schur matrix on ``rows`` (module
    doc): reverse Cuthill-McKee order, envelope, incidences (row, column offset, body) and
    the products that fill the envelope, with the columns they need (``pair_codes`` of the
    kernels' columns, ``column_masks(ci)``; without ``ci`` every column).

    held: bodies fixed by their own rows (:func:`held_bodies`).  A held body b has qdd_b = 0,
    so the other rows' entries in its columns change neither their S nor the moving bodies'
    accelerations: only its own rows' multipliers carry them (Haug Ch. 11, body b's
    block: Phi_b^T lam_b = Qt_b - sum over the other rows u of Phi_ub^T lam_u).  Such an
    incidence is kept with column offset + CROSS (kernels.c: no Mt^-1 product, no entry of
    S; ``fixed_body_multipliers`` adds its reaction to the own rows' multipliers).  A
    ground joined by many rows (the parallel four-bar's 41 pivots) otherwise couples all
    of them in S.  The cut structure is kept where it at least halves the envelope cost
    (HELD_GAIN), so a model where it does not pay factors exactly as before."""
    plain = _schur_structure(rb, rows, nb, ci, ())
    if not held:
        return plain
    cut = _schur_structure(rb, rows, nb, ci, held)
    return cut if HELD_GAIN * _envelope_cost(cut[0]) <= _envelope_cost(plain[0]) else plain


HELD_GAIN = 2.0
"""Envelope cost ratio (plain / cut) from which :func:`schur_structure` leaves held bodies
out of S: the factorization is then at most half the work, which on the large models that
reach it (the sparse path) is most of an evaluation (the 40-loop four-bar: 6.6e6 -> 2.1e6
squared widths, 2.2 -> 0.53 ms per accelerations call).  Below it, the model keeps the
factorization, and round-off, it had (chains: ratio 1.03 at 64 links).  The envelope is not
the whole cost: the cut adds a solve (``fixed_body_multipliers``: the ground's own rows
balance the other rows' reactions on it) and the loops over its incidences.  Forced on the
16-link chain (10 of 71 rows; envelope 2291 -> 2060, ratio 1.11; 485 -> 458 products) an
evaluation is slower, not faster: 8.24 -> 8.62 us per ``mb_accelerations`` (best of 40 x
1000 calls, the two structures interleaved in one process; medians 9.00 -> 9.58)."""


CROSS = 14
"""Column-offset flag of an incidence left out of S (:func:`schur_structure`, kernels.c)."""


def _envelope_cost(sidx):
    """sum of squared row widths of the envelope: the multiply-adds of its Cholesky x 2."""
    width = np.arange(sidx.shape[1]) - sidx[2] + 1
    return int((width * width).sum())


def _schur_structure(rb, rows, nb, ci, held):
    ma = rows.size
    masks = None if ci is None else column_masks(ci, rb.shape[0])
    # (u, 7 s, body) for each row position u and side s with a body, sorted by body, u, s
    bodies = np.asarray(rb, dtype=np.int64)[np.asarray(rows, dtype=np.int64)].reshape(ma, 2)
    inc = np.stack([np.repeat(np.arange(ma, dtype=np.int64), 2),
                    np.tile(np.array([0, 7], dtype=np.int64), ma), bodies.reshape(-1)], axis=1)
    inc = inc[inc[:, 2] >= 0]
    inc = np.ascontiguousarray(inc[np.lexsort((inc[:, 1], inc[:, 0], inc[:, 2]))])
    # a held body's own rows are on it alone (side 0, no body j); its other incidences are
    # left out of S and appended after the sort (below)
    is_cross = (np.isin(inc[:, 2], np.asarray(held, dtype=np.int64))
                & ~((inc[:, 1] == 0) & (bodies[inc[:, 0], 1] < 0)))
    cross, inc = inc[is_cross], np.ascontiguousarray(inc[~is_cross])
    cols = (np.full(len(inc), ALL_COLUMNS, dtype=np.int64) if masks is None else
            masks[np.asarray(rows)[inc[:, 0]], inc[:, 1] // 7])  # (ninc,) each incidence's
    indptr, indices = row_graph(inc, ma)  # numpy alone: `mbsim check` imports no scipy
    order = reverse_cuthill_mckee(indptr, indices)
    pos = np.empty(ma, dtype=np.int64)
    pos[order] = np.arange(ma)
    fc = np.arange(ma, dtype=np.int64)  # first column of each envelope row (position space)
    np.minimum.at(fc, pos[np.repeat(np.arange(ma), np.diff(indptr))], pos[indices])
    width = np.arange(ma) - fc + 1
    off = np.concatenate([[0], np.cumsum(width)[:-1]]).astype(np.int64) if ma else fc.copy()
    # per body b < nb in turn, its incidences g1 (outer) x g2 (inner) where pu >= pv: inc is
    # sorted by body, so body b's incidences are the run first[b] .. first[b] + run[b] - 1,
    # and g1 x g2 in that order is each g1 repeated run[b] times beside g2 over the run
    body = inc[:, 2]
    mine = np.flatnonzero(body < nb)
    run = np.bincount(body[mine], minlength=nb)
    first = np.cumsum(run) - run
    reps = run[body[mine]]
    start = np.cumsum(reps) - reps
    g1 = np.repeat(mine, reps)
    g2 = np.repeat(first[body[mine]] - start, reps) + np.arange(int(reps.sum()))
    pu, pv = pos[inc[g1, 0]], pos[inc[g2, 0]]
    keep = pu >= pv
    g1, g2, pu, pv = g1[keep], g2[keep], pu[keep], pv[keep]
    pairs = np.ascontiguousarray(
        np.stack([off[pu] + pv - fc[pu], g1, g2, pair_codes(cols[g1], cols[g2])], axis=1),
        dtype=np.int64)
    sidx = np.ascontiguousarray(np.stack([np.asarray(rows, dtype=np.int64), order, fc, off]))
    inc, pairs = with_held_incidences(inc, cross, pairs)
    return sidx, inc, pairs


def with_held_incidences(inc, cross, pairs):
    """(inc, pairs) with the incidences ``cross`` (on held bodies, left out of S) flagged by
    CROSS and placed after each body's own incidences (its group kept: kernels.c), the
    pairs' incidence numbers renumbered for that order."""
    if not len(cross):
        return inc, pairs
    inc = np.concatenate([inc, np.asarray(cross, dtype=np.int64) + np.array([0, CROSS, 0])])
    inc = inc[np.lexsort((inc[:, 0], inc[:, 1] >= CROSS, inc[:, 2]))]
    new = np.empty(inc.shape[0], dtype=np.int64)
    regular = np.flatnonzero(inc[:, 1] < CROSS)
    new[:regular.size] = regular
    if pairs.size:
        pairs[:, 1:3] = new[pairs[:, 1:3]]
    return inc, pairs
