"""The one implementation of the equations every analysis calls: free functions over a
constant compiled model and per-call data (MuJoCo's ``mjModel``/``mjData``; Pinocchio's
``f(model, data, q, v)``).

    data = core.make_data(model, rows=None)      # work space of one model on one row set
    core.phi(model, data, q, t)                  # (m_a,) Phi(q, t)
    core.phi_q(model, data, q, t, sparse=False)  # (m_a, nq) Phi_q, dense or CSR
    core.nu(model, data, q, t)                   # (m_a,) Phi_q qd = nu
    core.gamma(model, data, q, qd, t)            # (m_a,) Phi_q qdd = gamma
    core.constraints(model, data, q, t, ...)     # several of them in one evaluation (Terms)
    core.mass_matrix(model, data, q)             # (nq, nq) M = diag(m I, 4 G^T J' G)
    core.applied_forces(model, data, q, qd, t)   # (Q (nq,), F (nb, 3), n_local (nb, 3))
    core.generalized_forces(model, data, q, qd, t)  # Q (nq,)
    core.energy(model, data, q, qd)              # (kinetic, potential)
    core.accelerations(model, data, q, qd, t)    # (qdd (nq,), lam (m,)): THE KKT/Schur solve
    core.project_positions(model, data, q, t)    # the one Newton correction onto Phi = 0
    core.kinematic_state(model, data, q, t)      # q, qd, qdd of a DOF-0 system at t

The equations (Haug 1989, Chs. 9 and 11) are evaluated in C (mbsim/fast/kernels.c,
through :class:`mbsim.fast.System`); the numpy statement of the same equations lives under
tests/reference/ and exists only so the tests can compare the two to round-off.

Data: ``make_data(model, rows)`` builds the C tables and buffers once per (model, row set)
and keeps them on the model, so an analysis that evaluates the constraints at
every output pays the set-up once.  ``data=None`` in any function means
``make_data(model)``: all m rows.  Arrays returned are fresh (the caller may keep them).

Also here, because the force elements and the reference share them: :class:`State` (the
per-evaluation body quantities a force element reads) and :class:`Terms` (what a constraint
evaluation returns).
"""

from __future__ import annotations

import numpy as np

from mbsim.rotations import A as rot_A
from mbsim.rotations import E as rot_E
from mbsim.rotations import G as rot_G


class State:
    """Per-evaluation body quantities: r, p (nb, 3/4), rd, pd, A (nb, 3, 3), omega(_local)."""

    __slots__ = ("A", "_G", "_om", "p", "pd", "r", "rd")

    def __init__(self, model, q, qd=None):
        qq = np.asarray(q, dtype=float).reshape(model.nb, 7)
        self.r, self.p = qq[:, :3], qq[:, 3:]
        self.A = rot_A(self.p)
        if qd is not None:
            vv = np.asarray(qd, dtype=float).reshape(model.nb, 7)
            self.rd, self.pd = vv[:, :3], vv[:, 3:]
        else:
            self.rd = self.pd = None
        self._G = None
        self._om = None

    @property
    def G(self):
        if self._G is None:
            self._G = rot_G(self.p)
        return self._G

    @property
    def omega_local(self):
        """(nb, 3) body-frame angular velocity 2 G pd (Haug eq. 6.3.18)."""
        if self._om is None:
            self._om = 2 * np.einsum("bij,bj->bi", self.G, self.pd)
        return self._om

    @property
    def omega(self):
        """(nb, 3) global angular velocity 2 E pd."""
        return 2 * np.einsum("bij,bj->bi", rot_E(self.p), self.pd)


class States:
    """The body quantities of a series of outputs, computed once for all of them: r, p, rd,
    pd (nt, nb, 3/4), A (nt, nb, 3, 3), omega_local (nt, nb, 3) (time first), and
    ``states[k]``: the :class:`State` of output k sharing these arrays (a force element's
    scalar code reads it without recomputing A, G or omega per output).

    q, qd: (nt, nq); qd None: positions only (rd, pd, omega_local None)."""

    def __init__(self, model, q, qd=None):
        nt = np.shape(q)[0]
        qq = np.asarray(q, dtype=float).reshape(nt, model.nb, 7)
        self.r, self.p = qq[..., :3], qq[..., 3:]
        self.A = rot_A(self.p)
        self.G = rot_G(self.p)
        if qd is not None:
            vv = np.asarray(qd, dtype=float).reshape(nt, model.nb, 7)
            self.rd, self.pd = vv[..., :3], vv[..., 3:]
            self.omega_local = 2 * np.einsum("tbij,tbj->tbi", self.G, self.pd)
        else:
            self.rd = self.pd = self.omega_local = None
        self._each = [None] * nt

    def __len__(self):
        return len(self._each)

    def __getitem__(self, k: int) -> State:
        st = self._each[k]
        if st is None:
            st = State.__new__(State)
            st.r, st.p, st.A, st._G = self.r[k], self.p[k], self.A[k], self.G[k]
            if self.rd is None:
                st.rd = st.pd = st._om = None
            else:
                st.rd, st.pd, st._om = self.rd[k], self.pd[k], self.omega_local[k]
            self._each[k] = st
        return st


class Terms:
    """What a constraint evaluation returns: phi (m_a,), jac (m_a, nq) dense or CSR, nu,
    gamma (m_a,); None for the parts not asked for."""

    __slots__ = ("gamma", "jac", "nu", "phi")


class Data:
    """Per-call work space of one model on one row set (MuJoCo's mjData).

    system: :class:`mbsim.fast.System` on ``rows`` (its C tables and buffers); rows: (m_a,)
    the constraint rows evaluated, in the model's order.  Results of the free functions are
    fresh arrays; the buffers here are overwritten by every call.
    """

    __slots__ = ("__weakref__", "rows", "system")

    def __init__(self, model, rows=None):
        from mbsim.fast import System

        self.system = System(model, rows)
        self.rows = self.system.rows


class _DataCache(dict):
    """rows key -> Data, kept on the Model it belongs to (so it lives and dies with it: the
    cycle model -> cache -> Data -> System -> model is collected with the model); pickled and
    copied empty, since the C buffers belong to one process."""

    def __reduce__(self):
        return (_DataCache, ())


def make_data(model, rows=None) -> Data:
    """The Data of ``model`` on ``rows`` ((m_a,) row numbers; None: all m rows), built once
    per (model, row set) and kept on the model."""
    key_rows = None if rows is None else np.asarray(rows, dtype=np.int64)
    if key_rows is not None and key_rows.size == model.m and \
            np.array_equal(key_rows, np.arange(model.m)):
        key_rows = None
    cache = model.__dict__.get("_core_data")
    if cache is None:
        cache = _DataCache()
        object.__setattr__(model, "_core_data", cache)  # Model is frozen: a cache, not a field
    key = None if key_rows is None else key_rows.tobytes()
    data = cache.get(key)
    if data is None:
        data = cache[key] = Data(model, key_rows)
    return data


def _data(model, data) -> Data:
    return make_data(model) if data is None else data


# -- constraint terms (Haug Ch. 9) -----------------------------------------------------
def constraints(model, data, q, t=0.0, qd=None, phi=True, jac=True, gamma=False, nu=False,
                sparse=False) -> Terms:
    """Phi, Phi_q, nu and gamma on ``data.rows`` at (q, qd, t), only the parts asked for.

    q, qd: (nq,); gamma needs qd.  Returns :class:`Terms` with phi, nu, gamma (m_a,) and jac
    (m_a, nq), dense or CSR (``sparse``).  Non-finite entries (a deck value such as 1e308
    that overflowed) raise an AnalysisError naming the bodies or constraints."""
    sys = _data(model, data).system
    sys.counters["constraint_evaluations"] += 1
    T = sys.fc.constraints(q, t, qd, phi=phi, jac=jac, gamma=gamma, nu=nu, sparse=sparse)
    _check_finite(model, t, sys.rows, T)
    return T


def _check_finite(model, t, rows, T) -> None:
    for key in ("phi", "gamma", "nu"):
        a = getattr(T, key)
        if a is not None and not np.isfinite(a).all():
            full = np.zeros(model.m)
            full[rows] = a
            require_finite(model, t, **{key: full})
    J = T.jac
    if J is not None:
        vals = J.data if hasattr(J, "data") and not isinstance(J, np.ndarray) else J
        if not np.isfinite(vals).all():
            dense = J.toarray() if not isinstance(J, np.ndarray) else J
            full = np.zeros((model.m, model.nq))
            full[rows] = dense
            require_finite(model, t, J=full)


def phi(model, data, q, t=0.0) -> np.ndarray:
    """(m_a,) Phi(q, t) = phi(q) - c(t)."""
    return constraints(model, data, q, t, jac=False).phi


def phi_q(model, data, q, t=0.0, sparse=False):
    """(m_a, nq) Phi_q, dense or CSR."""
    return constraints(model, data, q, t, phi=False, sparse=sparse).jac


def nu(model, data, q, t=0.0) -> np.ndarray:
    """(m_a,) nu = c'(t): Phi_q qd = nu."""
    return constraints(model, data, q, t, phi=False, jac=False, nu=True).nu


def gamma(model, data, q, qd, t=0.0) -> np.ndarray:
    """(m_a,) gamma = -(Phi_q qd)_q qd + c''(t): Phi_q qdd = gamma."""
    return constraints(model, data, q, t, qd=qd, phi=False, jac=False, gamma=True).gamma


# -- masses, forces, energy (Haug Ch. 11) -----------------------------------------------
def mass_blocks(model, data, q) -> np.ndarray:
    """(nb, 7, 7) diagonal blocks of M = diag(m I, 4 G^T J' G)."""
    return _data(model, data).system.mass_blocks(q)


def mass_matrix(model, data, q, sparse=False):
    """(nq, nq) M = diag(m_b I3, 4 G_b^T J'_b G_b), dense or CSR."""
    Mb = mass_blocks(model, data, q)
    if sparse:
        import scipy.sparse as sp

        return sp.block_diag(list(Mb), format="csr")
    return _data(model, data).system.mass_matrix(q)


def applied_forces(model, data, q, qd, t=0.0):
    """(Q, F, n_local): Q (nq,) gravity, force elements and the gyroscopic term
    -2 G^T w'~ J' w'; F (nb, 3) global forces at the centroids and n_local (nb, 3) body
    torques (without the gyroscopic term), so that callers can report them."""
    return _data(model, data).system.loads(q, qd, t)


def generalized_forces(model, data, q, qd, t=0.0) -> np.ndarray:
    """Q (nq,) = [F, 2 G^T (n' - w'~ J' w')] per body."""
    Q = _data(model, data).system.generalized_forces(q, qd, t)
    if not np.isfinite(Q).all():
        require_finite(model, t, Q=Q)
    return Q


def energy(model, data, q, qd=None):
    """(kinetic, potential) energy at (q, qd) (Haug Ch. 11): T = sum 1/2 m |rd|^2 +
    1/2 w'^T J' w', V = -sum m g.r plus the force elements' potentials; kinetic is None
    without qd."""
    st = State(model, q, qd)
    V = -float(np.sum(model.mass * (st.r @ model.gravity)))
    V += sum(el.potential(st) for el in model.forces)
    if qd is None:
        return None, V
    w = st.omega_local
    rot = np.einsum("bi,bij,bj->", w, model.J_local, w)
    return float(0.5 * np.sum(model.mass * np.sum(st.rd ** 2, 1)) + 0.5 * rot), V


def kinetic_energy(model, data, q, qd) -> float:
    return energy(model, data, q, qd)[0]


def potential_energy(model, data, q) -> float:
    return energy(model, data, q)[1]


# -- the equations of motion ----------------------------------------------------------------
def accelerations(model, data, q, qd, t=0.0):
    """(qdd (nq,), lam (m,)): the one solve of the equations of motion (Haug Ch. 11)

        [M  Phi_q^T] [qdd]   [Q    ]
        [Phi_q    0] [lam] = [gamma]

    on ``data.rows`` (e.g. an assembly's active rows); lam is returned on all m rows, 0 on
    the others.  By the Schur complement of the modified mass matrix, or a dense KKT LU when
    some J' is singular (:mod:`mbsim.fast.dynamics`).  Raises AnalysisError on non-finite
    input and :class:`mbsim.fast.SolveError` on a singular system."""
    sys = _data(model, data).system
    qdd, lam, _ = sys.accelerations(q, qd, t)
    if not (np.isfinite(qdd).all() and np.isfinite(lam).all()):
        Q = sys.generalized_forces(q, qd, t)
        T = sys.fc.constraints(q, t, qd, gamma=True)
        full = np.zeros((model.m, model.nq))
        full[sys.rows] = T.jac if isinstance(T.jac, np.ndarray) else T.jac.toarray()
        require_finite(model, t, M=mass_matrix(model, data, q), Q=Q, J=full)
    return qdd, sys.full_lam(lam)


def project_positions(model, data, q, t=0.0, tol=1e-12, max_iter=10):
    """The one Newton correction onto Phi(q, t) = 0 on ``data.rows``: mass-weighted
    least-norm steps dq = -Mt^-1 Phi_q^T S^-1 Phi (the exact Newton step when Phi_q is
    square).  Returns (q, converged, iterations, max|Phi|)."""
    return _data(model, data).system.project_positions(q, t, tol, max_iter)


def kinematic_state(model, data, q, t, tol=1e-10, max_iter=25, cond=False):
    """One output of a kinematic analysis (DOF 0: ``data.rows`` square) in one C call:
    Newton from the predictor q (nq,) onto Phi(q, t) = 0, then Phi_q qd = nu and
    Phi_q qdd = gamma on one LU of Phi_q (Haug Ch. 10).

    Returns (status, q, qd, qdd, info): status 0 ok, 2 singular Phi_q (a zero pivot), 3 no
    convergence in max_iter steps; info (4,) = Newton iterations, max |Phi| on the rows,
    cond_2(Phi_q) (NaN unless ``cond``), smallest/largest LU pivot."""
    return _data(model, data).system.kinematic(q, t, tol, max_iter, cond)


def require_finite(model, t, **arrays) -> None:
    """Input guard: an AnalysisError naming the bodies or constraints whose entries are NaN or
    inf (a deck value such as 1e308 that overflowed), instead of LAPACK's ValueError.

    Keys name the array: ``M`` and ``Q`` (nq rows of 7 per body), ``J``/``gamma``/``nu``/
    ``phi`` (all m constraint rows), ``qd``/``q`` (coordinates)."""
    from mbsim.errors import AnalysisError

    for key, a in arrays.items():
        a = np.asarray(a)
        if np.isfinite(a).all():
            continue
        bad = np.flatnonzero(~np.isfinite(a.reshape(a.shape[0], -1)).all(axis=1))
        if key in ("M", "Q", "q", "qd"):
            names = sorted({model.body_names[r // 7] for r in bad})
            what = {"M": "mass matrix", "Q": "applied forces", "q": "coordinates",
                    "qd": "velocities"}[key]  # fmt: skip
            items = ", ".join(names[:5]) + (", ..." if len(names) > 5 else "")
            raise AnalysisError(f"the {what} of body {items} overflowed to inf/NaN (a deck "
                                "value too large, e.g. 1e308, or a force law that diverges)",
                                time=t, items=tuple(names))  # fmt: skip
        names = list(model.items_of_rows(bad))
        drivers = [n for n in names if model.item(n).kind == "driver"]
        if drivers:  # a driver's function of t: its value or rates are not finite at t
            items = ", ".join(drivers[:5]) + (", ..." if len(drivers) > 5 else "")
            raise AnalysisError(f"the function of driver {items} is not finite here ({key}: a "
                                f"division by zero, a pole or a log of zero at this time, or "
                                f"a deck value too large)", time=t,
                                items=tuple(drivers))  # fmt: skip
        items = ", ".join(names[:5]) + (", ..." if len(names) > 5 else "")
        raise AnalysisError(f"the constraint equations ({key}) of {items} overflowed to "
                            "inf/NaN (a deck value too large, e.g. a point at 1e308)", time=t,
                            items=tuple(names))  # fmt: skip
