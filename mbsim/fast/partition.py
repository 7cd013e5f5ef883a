"""CompiledStage: the step of the coordinate-partitioning integrators in C.

mbsim/fast/partition.c takes, for :mod:`mbsim.integrators.gcp` on a dense Jacobian, one
stage in one call (:meth:`CompiledStage.stage`: in coordinates the Newton iteration of the
dependent coordinates u on Phi(u, v, t) = 0, the dependent velocities, the equations of
motion and the change-point measure of the last factor of Phi_u; in the tangent coordinates
of a change point, v = C q, Newton on [Phi; C q - v] and the reduced equations), a whole
trial step of the RK tableau in one call (:meth:`CompiledStage.trial`: the stages, the
alarm, the branch test, the error norms, and at an accepted end its sensitivity and
measure), and all outputs of the last accepted step in one call
(:meth:`CompiledStage.dense`).  The step-size control, re-partitioning and every fallback
stay in Python.

What still runs in Python inside a call: the time targets of driven rows and the force
elements that are not compiled, through the callback of :mod:`mbsim.fast.stepper`.  Phi_u
is factored by LAPACK's dgetrf / dgetrs from ``scipy.linalg.cython_lapack``
(:func:`mbsim.fast.implicit.lapack`), the routines ``lu_factor`` / ``lu_solve`` call.
"""

from __future__ import annotations

import ctypes

import numpy as np

from mbsim.fast import _lib
from mbsim.fast.implicit import lapack
from mbsim.fast.stepper import N_K, load_callback

(GP_OK, GP_NEWTON, GP_SINGULAR, GP_SOLVE, GP_CALLBACK, GP_ALARM, GP_BRANCH,
 GP_REDUCED) = range(8)
P_POWER, P_RATIO, P_CODE, P_ERR, P_T, P_DEV, P_SENS = range(7)
COUNTERS = ("function_evaluations", "constraint_evaluations", "factorizations",
            "newton_iterations")
"""partition.c's counts, added to ``system.counters`` after each call."""


class GCP(ctypes.Structure):
    """mb_gcp of partition.c, field for field."""

    _fields_ = (
        [(n, ctypes.c_int64) for n in ("nq", "ma", "k", "max_iter", "kkt", "rheonomic")]
        + [("newton_tol", ctypes.c_double)]
        + [(n, ctypes.c_void_p) for n in
           ("load", "getrf", "getrs", "iv", "iu", "LU", "piv", "x", "out", "count")]
        + [(n, ctypes.c_int64) for n in ("ns", "err_kind")]
        + [(n, ctypes.c_double) for n in ("rtol", "atol", "tangent", "branch_jump")]
        + [(n, ctypes.c_void_p) for n in
           ("A", "B", "C", "E", "E3", "y", "f", "q0", "qd0", "K", "QD", "ys", "y_new", "pred",
            "pred_end", "q", "qd", "qdd")]
        + [(n, ctypes.c_int64) for n in ("dense_kind", "np")]
        + [(n, ctypes.c_void_p) for n in ("P", "AX", "CX", "D", "Fy", "Fq", "Z")]
        + [(n, ctypes.c_void_p) for n in
           ("Ct", "At", "pivA", "T", "p", "R", "pivR", "w", "MT", "ra")]
    )


class CompiledStage:
    """The stages of one coordinate-partitioning run on a dense ``system`` (the sparse
    path factors Phi_u with splu in Python)."""

    def __init__(self, system, q, t, newton_tol, max_iter):
        self.system = s = system
        self.lib = lib = s.fc.lib
        if lib.mb_gcp_size() != ctypes.sizeof(GCP):
            raise _lib.KernelBuildError("mb_gcp in partition.c and mbsim.fast.partition's GCP "
                                        "differ (an edit on one side only)")
        m = s.m
        g = self.g = GCP()
        g.nq, g.ma, g.max_iter = s.nq, m, int(max_iter)
        g.kkt, g.rheonomic, g.newton_tol = int(s.kkt), int(s.rheonomic), float(newton_tol)
        g.getrf, g.getrs = lapack()
        self._buffers = _lib.carve(LU=(m, m), x=max(m, 1), out=7)
        self.LU = self._buffers["LU"][0]  # column-major in C: row c of this view is column c
        g.LU, g.x, g.out = (self._buffers[n][1] for n in ("LU", "x", "out"))
        self.out = self._buffers["out"][0]
        self.piv = np.zeros(max(m, 1), dtype=np.int32)
        g.piv = self.piv.ctypes.data
        n, k = s.nq, s.nq - m  # tangent coordinates' buffers (k = the partition's size)
        self._tangent = _lib.carve(At=(n, n), T=(max(k, 1), n), p=n, R=(max(k, 1), max(k, 1)),
                                   w=n, MT=(max(k, 1), n), ra=max(k, 1))
        for name, (_, address) in self._tangent.items():
            setattr(g, name, address)
        self.pivA, self.pivR = np.zeros(n, dtype=np.int32), np.zeros(max(k, 1), dtype=np.int32)
        g.pivA, g.pivR = self.pivA.ctypes.data, self.pivR.ctypes.data
        self.C = None  # the tangent coordinates' C (kept alive while C points into it)
        self.count = np.zeros(4, dtype=np.int64)
        g.count = self.count.ctypes.data
        self._pending = []
        self._load = load_callback(s, self._pending)
        g.load = ctypes.cast(self._load, ctypes.c_void_p).value if self._load else None
        s.fc.evaluate(q, t)  # allocates the dense Phi_q that mb_terms' mode 1 fills
        self._J = s.fc._J
        self.iv = self.iu = None
        self.ptr = ctypes.addressof(g)

    def partition(self, iv, iu, C=None):
        """The partition of the stages from now on: coordinates iv, iu, or with C (k, nq)
        tangent coordinates v = C q (iv, iu then the coordinate choice whose measure the
        accepted steps report, to go back to)."""
        self.iv = np.ascontiguousarray(iv, dtype=np.int64)
        self.iu = np.ascontiguousarray(iu, dtype=np.int64)
        g = self.g
        g.k, g.iv, g.iu = self.iv.size, self.iv.ctypes.data, self.iu.ctypes.data
        self.C = None if C is None else np.ascontiguousarray(C, dtype=np.float64)
        g.Ct = None if C is None else self.C.ctypes.data

    def stage(self, t, v, vd, q, accelerations=True):
        """(status, q, qd, qdd, power, ratio): q completed from the prediction q (a fresh
        array, not changed), qd, and, with accelerations, qdd and the power (else None);
        ratio the change-point measure of the last Phi_u.  status GP_*: anything but GP_OK
        leaves the rest to the caller (the model keeps the last iterate's Phi)."""
        n = self.system.nq
        block = np.empty(3 * n)
        qo, qd, qdd = block[:n], block[n:2 * n], block[2 * n:]
        qo[:] = q
        v = np.ascontiguousarray(v, dtype=np.float64)
        vd = np.ascontiguousarray(vd, dtype=np.float64)
        st = self.lib.mb_gcp_stage(self.system.c.ptr, self.ptr, t, v.ctypes.data,
                                   vd.ctypes.data, qo.ctypes.data, qd.ctypes.data,
                                   qdd.ctypes.data, int(accelerations))
        self._count()
        power = float(self.out[P_POWER]) if accelerations else None
        return st, qo, qd, qdd if accelerations else None, power, float(self.out[P_RATIO])

    def set_tableau(self, tableau, *, rtol, atol, control, tangent, branch_jump):
        """The trial step's tableau (its error form when ``control``), tolerances, the
        change-point switch (-inf: no test) and the branch test's bound (inf: none)."""
        from mbsim.fast.stepper import DENSE_FORMS, ERROR_FORMS, tableau_arrays

        g, n, ns = self.g, self.system.nq, tableau.n_stages
        err_form = tableau.error_form if control else None
        g.ns, g.err_kind = ns, ERROR_FORMS[err_form]
        g.dense_kind = DENSE_FORMS[tableau.dense_form]
        P = getattr(tableau, "P", None)
        g.np = 0 if P is None else P.shape[1]
        g.rtol, g.atol = rtol, atol
        self.set_switches(tangent, branch_jump)
        self._tableau = tableau_arrays(tableau, err_form)  # the arrays C points into
        for name in ("A", "B", "C", "E", "E3", "P", "AX", "CX", "D"):
            setattr(g, name, self._tableau[name].ctypes.data)
        self._trial = _lib.carve(q0=n, qd0=n, QD=(N_K, n), pred=n, pred_end=n, q=n, qd=n,
                                 qdd=n, Fq=(7, n))
        for name, (_, address) in self._trial.items():
            setattr(g, name, address)
        self._ny = None

    def set_switches(self, tangent, branch_jump):
        self.g.tangent, self.g.branch_jump = tangent, branch_jump

    def _y_buffers(self, ny):
        """y, f, ys, y_new and K (ns + 1, ny) for states of ny values (2 k + 1)."""
        if self._ny != ny:
            k = (ny - 1) // 2
            self._ybuf = _lib.carve(y=ny, f=ny, ys=ny, y_new=ny, K=(N_K, ny), Fy=(7, ny),
                                    Z=(k, self.system.m))
            for name, (_, address) in self._ybuf.items():
                setattr(self.g, name, address)
            self._ny = ny
        return self._ybuf

    def trial(self, t, h, y, f, q0, qd0, control):
        """One trial step in C (partition.c: mb_gcp_trial) from (t, y, f) and the accepted
        state's q0, qd0.  Returns the status GP_*; out[P_ERR] the error norm, out[P_RATIO]
        and out[P_SENS] the end's measure and sensitivity (err <= 1), and the buffers
        (``buffer``) the stages and the step's end."""
        b = self._y_buffers(y.size)
        b["y"][0][:] = y
        b["f"][0][:] = f
        self._trial["q0"][0][:] = q0
        self._trial["qd0"][0][:] = qd0
        st = self.lib.mb_gcp_trial(self.system.c.ptr, self.ptr, t, h, int(control))
        self._count()
        return st

    def buffer(self, name):
        """A trial buffer (a view: copy what must outlive the next call); K and QD: the
        step's ns + 1 rows."""
        a = (self._ybuf if name in self._ybuf else self._trial)[name][0]
        return a[: self.g.ns + 1] if name in ("K", "QD") else a

    def dense(self, t0, h, times):
        """(status, Q, QD, W, flags) at ``times`` inside the last accepted trial
        [t0, t0 + h] (partition.c: mb_gcp_dense), from the buffers that trial left; flags
        (int64) 1 where an output failed."""
        n, k = self.system.nq, times.size
        times = np.ascontiguousarray(times, dtype=np.float64)
        block = np.empty(k * (2 * n + 1))
        Q, QD, W = block[:k * n].reshape(k, n), block[k * n:2 * k * n].reshape(k, n), \
            block[2 * k * n:]
        flags = np.zeros(k, dtype=np.int64)
        st = self.lib.mb_gcp_dense(self.system.c.ptr, self.ptr, t0, h, k, times.ctypes.data,
                                   Q.ctypes.data, QD.ctypes.data, W.ctypes.data,
                                   flags.ctypes.data)
        self._count()
        return st, Q, QD, W, flags

    def _count(self):
        c, counts = self.system.counters, self.count.tolist()
        for name, k in zip(COUNTERS, counts):
            c[name] += k
        self.count[:] = 0
        if self._pending:  # a KeyboardInterrupt met in the callback
            raise self._pending.pop()

    def factor(self):
        """(lu, piv) of the last call's Phi_u, or in tangent coordinates of its A = [Phi_q;
        C], as scipy's ``lu_factor`` returns them (copies)."""
        if self.C is not None:
            return np.array(self._tangent["At"][0].T, order="F"), self.pivA - 1
        return np.array(self.LU.T, order="F"), self.piv[: self.system.m] - 1

    def jacobian(self):
        """Phi_q (m_a, nq) of the last call's last Newton iterate (a copy)."""
        return self._J.copy()
