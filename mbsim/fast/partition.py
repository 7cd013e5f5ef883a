"""CompiledStage: the stage of the coordinate-partitioning integrators in C.

mbsim/fast/partition.c evaluates one stage of :mod:`mbsim.integrators.gcp` in coordinates
(not in tangent coordinates) in one call: the Newton iteration of the dependent coordinates
u on Phi(u, v, t) = 0, the dependent velocities, and the equations of motion; it returns
the change-point measure of the last factor of Phi_u beside them.  The step's combination
of stages, its error test and every fallback stay in Python.

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
from mbsim.fast.stepper import load_callback

GP_OK, GP_NEWTON, GP_SINGULAR, GP_SOLVE, GP_CALLBACK = range(5)
P_POWER, P_RATIO, P_CODE = range(3)
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
        self._buffers = _lib.carve(LU=(m, m), x=max(m, 1), out=3)
        self.LU = self._buffers["LU"][0]  # column-major in C: row c of this view is column c
        g.LU, g.x, g.out = (self._buffers[n][1] for n in ("LU", "x", "out"))
        self.out = self._buffers["out"][0]
        self.piv = np.zeros(max(m, 1), dtype=np.int32)
        g.piv = self.piv.ctypes.data
        self.count = np.zeros(4, dtype=np.int64)
        g.count = self.count.ctypes.data
        self._pending = []
        self._load = load_callback(s, self._pending)
        g.load = ctypes.cast(self._load, ctypes.c_void_p).value if self._load else None
        s.fc.evaluate(q, t)  # allocates the dense Phi_q that mb_terms' mode 1 fills
        self._J = s.fc._J
        self.iv = self.iu = None
        self.ptr = ctypes.addressof(g)

    def partition(self, iv, iu):
        """The coordinate partition of the stages from now on."""
        self.iv = np.ascontiguousarray(iv, dtype=np.int64)
        self.iu = np.ascontiguousarray(iu, dtype=np.int64)
        g = self.g
        g.k, g.iv, g.iu = self.iv.size, self.iv.ctypes.data, self.iu.ctypes.data

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
        c, counts = self.system.counters, self.count.tolist()
        for name, k in zip(COUNTERS, counts):
            c[name] += k
        self.count[:] = 0
        if self._pending:  # a KeyboardInterrupt met in the callback
            raise self._pending.pop()
        power = float(self.out[P_POWER]) if accelerations else None
        return st, qo, qd, qdd if accelerations else None, power, float(self.out[P_RATIO])

    def factor(self):
        """(lu, piv) of the last call's Phi_u as scipy's ``lu_factor`` returns them (copies)."""
        return np.array(self.LU.T, order="F"), self.piv[: self.system.m] - 1

    def jacobian(self):
        """Phi_q (m_a, nq) of the last call's last Newton iterate (a copy)."""
        return self._J.copy()
