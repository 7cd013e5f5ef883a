"""CompiledNewton: the Newton iteration of the implicit index-3 integrators in C.

mbsim/fast/implicit.c takes the whole Newton iteration of one trial step of
generalized-alpha or HHT (:mod:`mbsim.integrators.genalpha`) on a
:class:`~mbsim.fast.dynamics.System`: the predictor, the residuals through the kernels, the
iteration matrix factored at every iterate, the stopping tests; and the finite-difference
tangent K = dr/dq, C = dr/dqd.  Python keeps the step-size control, the local error
estimate and every fallback, and is visited once per trial step.

What still runs in Python inside a call: the time targets of driven rows and the force
elements that are not compiled (laws, rsda, switching laws), through one ctypes callback per
residual (as in :mod:`mbsim.fast.stepper`); and, on the sparse path (large models), the
sparse LU of the iteration matrix, through two more (factor, solve).

The dense iteration matrix is factored by LAPACK's dgetrf / dgetrs from
``scipy.linalg.cython_lapack`` (:func:`lapack`), the routines scipy.linalg's
``lu_factor`` / ``lu_solve`` call: their addresses are handed to C once.
"""

from __future__ import annotations

import ctypes

import numpy as np

from mbsim.fast import _lib
from mbsim.fast.stepper import load_callback

GA_OK, GA_NEWTON, GA_CALLBACK = range(3)
O_POWER, O_T = range(2)
COUNTERS = ("function_evaluations", "constraint_evaluations", "factorizations",
            "newton_iterations")
"""The first four of implicit.c's counts, added to ``system.counters``; the fifth is the
integrator's ``jacobian_evaluations``."""

FACTOR = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_double, ctypes.c_double, ctypes.c_double)
SOLVE = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_int64)


class GA(ctypes.Structure):
    """mb_ga of implicit.c, field for field."""

    _fields_ = (
        [(n, ctypes.c_int64) for n in
         ("nq", "ma", "sparse", "rheonomic", "use_kc", "contraction", "max_newton")]
        + [(n, ctypes.c_double) for n in
           ("am", "af", "gam", "beta", "rtol", "atol", "newton_tol", "kkt_reg", "roundoff")]
        + [(n, ctypes.c_void_p) for n in
           ("load", "factor", "solve", "getrf", "getrs", "mscale", "free", "K", "C", "S",
            "piv", "r", "r0", "x", "w", "out", "count")]
    )


_LAPACK = None


def lapack():
    """(dgetrf, dgetrs) addresses from scipy.linalg.cython_lapack, whose capsules name the
    C signature: checked here to take 32-bit ``int`` sizes and pivots, as implicit.c
    declares them (a build whose signature differs is a KernelBuildError, not a crash)."""
    global _LAPACK
    if _LAPACK is None:
        from scipy.linalg import cython_lapack

        api = ctypes.pythonapi
        get_name, get_pointer = api.PyCapsule_GetName, api.PyCapsule_GetPointer
        get_name.restype, get_name.argtypes = ctypes.c_char_p, [ctypes.py_object]
        get_pointer.restype = ctypes.c_void_p
        get_pointer.argtypes = [ctypes.py_object, ctypes.c_char_p]
        expected = {"dgetrf": "void (int *, int *, D *, int *, int *, int *)",
                    "dgetrs": "void (char *, int *, int *, D *, int *, int *, D *, int *, int *)"}
        out = []
        for name, want in expected.items():
            cap = cython_lapack.__pyx_capi__[name]
            sig = get_name(cap)
            plain = sig.decode().replace("__pyx_t_5scipy_6linalg_13cython_lapack_d", "D")
            if plain != want:
                raise _lib.KernelBuildError(
                    f"scipy.linalg.cython_lapack.{name} has the signature {plain!r}, not "
                    f"{want!r} as mbsim/fast/implicit.c declares it")
            out.append(get_pointer(cap, sig))
        _LAPACK = tuple(out)
    return _LAPACK


class CompiledNewton:
    """The Newton iteration and tangent of one generalized-alpha run on ``system``.

    coef: (am, af, gam, beta); mscale (nq,): the size of M per coordinate; roundoff: the
    round-off of q per unit of max(1, |q|); the rest as GeneralizedAlpha's options."""

    def __init__(self, system, coef, *, rtol, atol, newton_tol, contraction, max_newton,
                 kkt_reg, roundoff, mscale):
        self.system = s = system
        self.lib = lib = s.fc.lib
        if lib.mb_ga_size() != ctypes.sizeof(GA):
            raise _lib.KernelBuildError("mb_ga in implicit.c and mbsim.fast.implicit's GA "
                                        "differ (an edit on one side only)")
        n, m = s.nq, s.m
        g = self.g = GA()
        g.nq, g.ma, g.sparse, g.rheonomic = n, m, int(s.sparse), int(s.rheonomic)
        g.contraction, g.max_newton = int(contraction), int(max_newton)
        g.am, g.af, g.gam, g.beta = coef
        g.rtol, g.atol, g.newton_tol = rtol, atol, newton_tol
        g.kkt_reg, g.roundoff = kkt_reg, roundoff
        dense = 0 if s.sparse else (n + m) * (n + m)
        self._buffers = _lib.carve(mscale=n, r=n, r0=n, x=max(n + m, 2 * n), w=n, out=2,
                                   S=dense)
        for name, (_, address) in self._buffers.items():
            setattr(g, name, address)
        self._buffers["mscale"][0][:] = mscale
        self.out = self._buffers["out"][0]
        self.piv = np.zeros(n + m, dtype=np.int32)
        g.piv = self.piv.ctypes.data
        self.free = np.repeat(~np.asarray(s.model.is_ground, dtype=bool), 7).astype(np.int64)
        g.free = self.free.ctypes.data
        self.count = np.zeros(5, dtype=np.int64)
        g.count = self.count.ctypes.data
        self._pending = []
        self._load = load_callback(s, self._pending)
        g.load = ctypes.cast(self._load, ctypes.c_void_p).value if self._load else None
        if s.sparse:
            self._lu = None
            self._factor_cb, self._solve_cb = FACTOR(self._factor_sparse), SOLVE(self._solve_sparse)
            g.factor = ctypes.cast(self._factor_cb, ctypes.c_void_p).value
            g.solve = ctypes.cast(self._solve_cb, ctypes.c_void_p).value
            self._csr = s.fc.csr_pattern()  # the buffer mb_terms' mode 2 fills
            b, i, j = np.meshgrid(np.arange(s.nb), np.arange(7), np.arange(7), indexing="ij")
            self._bi, self._bj = (7 * b + i).reshape(-1), (7 * b + j).reshape(-1)
        else:
            g.getrf, g.getrs = lapack()
        self.KC = None  # (K, C) the iteration matrix's tangent, kept alive here
        self.factored = False  # a factor exists (solve)
        self.ptr = ctypes.addressof(g)

    def set_tangent(self, KC):
        """(K, C) (nq, nq) in the iteration matrix from now on; None: the simplified matrix."""
        g = self.g
        if KC is None:
            self.KC, g.use_kc, g.K, g.C = None, 0, None, None
            return
        K, C = (np.ascontiguousarray(a, dtype=np.float64) for a in KC)
        self.KC, g.use_kc, g.K, g.C = (K, C), 1, K.ctypes.data, C.ctypes.data

    def _counted(self, status, t):
        c, mine = self.system.counters, self.count.tolist()
        for name, k in zip(COUNTERS, mine):
            c[name] += k
        self.jacobian_evaluations = mine[4]
        self.count[:] = 0
        if self._pending:  # a KeyboardInterrupt (or a sparse solve's error) met in a callback
            raise self._pending.pop()
        if status == GA_CALLBACK:
            self._raise_python_loads(float(self.out[O_T]))
        return status

    def _raise_python_loads(self, t):
        """The Python loads raised inside the C call (the callback returns 1 there): the same
        call again here, at the state C left in the model, raises it where it can be seen."""
        s = self.system
        fc = s.fc
        if fc.funcs:
            fc.targets(t)
        from mbsim import core

        s.apply_python(core.State(s.model, fc._q, fc._qd), t, s._loads)
        raise RuntimeError(f"t = {t:.6g} s: a Python force element failed inside the "
                           f"implicit step and not when called again")

    def newton(self, t1, h, q0, qd0, qdd0, a, lam0):
        """(q, qd, qdd, lam, a1, power) of the step h ending at t1, or None where Newton
        fails (GeneralizedAlpha._newton)."""
        n = self.system.nq
        block = np.empty(4 * n + self.system.m)
        q, qd, qdd, a1 = (block[k * n:(k + 1) * n] for k in range(4))
        lam = block[4 * n:]
        lam[:] = lam0
        arrays = [np.ascontiguousarray(x, dtype=np.float64) for x in (q0, qd0, qdd0, a)]
        st = self.lib.mb_ga_newton(self.system.c.ptr, self.ptr, t1, h,
                                   *(x.ctypes.data for x in arrays), q.ctypes.data,
                                   qd.ctypes.data, qdd.ctypes.data, lam.ctypes.data,
                                   a1.ctypes.data)
        self.factored = self.factored or self.count[2] > 0
        if self._counted(st, t1) != GA_OK:
            return None
        return q, qd, qdd, lam, a1, float(self.out[O_POWER])

    def tangent(self, t, q, qd, qdd, lam):
        """(K, C) (nq, nq): dr/dq, dr/dqd by forward differences (GeneralizedAlpha._tangent)."""
        n = self.system.nq
        K, C = np.empty((n, n)), np.empty((n, n))
        arrays = [np.ascontiguousarray(x, dtype=np.float64) for x in (q, qd, qdd, lam)]
        st = self.lib.mb_ga_tangent(self.system.c.ptr, self.ptr, t,
                                    *(x.ctypes.data for x in arrays), K.ctypes.data,
                                    C.ctypes.data)
        self._counted(st, t)
        return K, C

    def solve(self, b):
        """b (nq + ma,) or (nq + ma, k) solved on the last factor (the round-off probe)."""
        b = np.asarray(b, dtype=np.float64)
        x = np.ascontiguousarray(b.T)  # each right-hand side contiguous
        k = 1 if b.ndim == 1 else b.shape[1]
        if self.lib.mb_ga_solve(self.ptr, x.ctypes.data, k) != GA_OK:
            raise ValueError("the iteration matrix's factor cannot solve")
        return x.T

    # -- the sparse path: the iteration matrix through scipy's sparse LU --------------------
    def _factor_sparse(self, bp, gp, eps):
        import scipy.sparse as sp
        import scipy.sparse.linalg as spla

        try:
            s = self.system
            n, m = s.nq, s.m
            indptr, indices, _, data = self._csr
            J = sp.csr_matrix((data.copy(), indices, indptr), shape=(m, n))
            A = sp.csr_matrix((s._Mb.reshape(-1).copy(), (self._bi, self._bj)), shape=(n, n))
            if self.KC is not None:
                A = A + sp.csr_matrix(gp / bp * self.KC[1] + self.KC[0] / bp)
            S = sp.bmat([[A, J.T], [J, -eps * sp.identity(m)]], format="csc")
            self._lu = spla.splu(S)
        except (RuntimeError, ValueError, ArithmeticError):  # singular, or not finite
            return 1  # Newton fails: the step is cut, as for a dense singular matrix
        except BaseException as exc:  # noqa: BLE001 - anything else: raised after the call
            self._pending.append(exc)
            return 1
        return 0

    def _solve_sparse(self, address, k):
        try:
            N = self.system.nq + self.system.m
            x = np.ctypeslib.as_array(ctypes.cast(address, ctypes.POINTER(ctypes.c_double)),
                                      shape=(int(k), N))
            x[:] = self._lu.solve(np.ascontiguousarray(x.T)).T
        except (RuntimeError, ValueError, ArithmeticError):  # as _factor_sparse
            return 1
        except BaseException as exc:  # noqa: BLE001 - anything else: raised after the call
            self._pending.append(exc)
            return 1
        return 0
