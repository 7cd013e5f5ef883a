"""FastConstraints(model): Phi, Phi_q, gamma and nu of a Model in one C call.

Built once per Model (and row selection): the kernel Blocks are flattened into the tables
of mbsim/fast/kernels.c (``ci``, ``cf``: one line per basic constraint, layout below), the
output buffers and the CSR pattern are allocated and handed to C once (an ``mb_model``
struct, :mod:`mbsim.fast._lib`); every evaluation is then one C call (``mb_terms``) that
evaluates all kernels and fills the dense or CSR Jacobian of the rows asked for.  Time
targets (driver functions) stay Python callables: f, f', f'' of the few time-dependent
rows are evaluated here and passed in as ``tv`` (nf, 3).

Tables (k = 0 .. nc-1):

- ``ci`` (nc, NI) int64: kernel code (``KERNELS``), body i, body j (-1: one body), first
  global row, flag (dot2: 1 when a is on body j; absolute: axis 0/1/2), time-target index
  (-1: none), the body of each of the three vector slots (-1: slot unused);
- ``cf`` (nc, NF) float64: the three body-fixed vectors (columns 0-8, the kernel's
  arguments in the slots listed in ``VECTORS``) and up to six constant targets (9-14);
- ``Jc`` (m, 14): the compact Jacobian, columns 0-6 d Phi_r / d[r_i, p_i], 7-13
  d Phi_r / d[r_j, p_j].
"""

from __future__ import annotations

import numpy as np

from mbsim.core import Terms
from mbsim.fast import _lib

KERNELS = ("dot1", "dot2", "spherical", "distance", "angle", "absolute", "ground", "normalization")
KERNEL_CODE = {name: code for code, name in enumerate(KERNELS)}
"""kernel name -> code in ``ci[:, 0]`` (the enum of kernels.c)."""
VECTORS = {
    "dot1": (("ai", "i"), ("aj", "j")),
    "dot2": (("a", "i"), ("si", "i"), ("sj", "j")),  # a on body j when the flag says so
    "spherical": (None, ("si", "i"), ("sj", "j")),
    "distance": (None, ("si", "i"), ("sj", "j")),
    "angle": (("gi", "i"), ("hi", "i"), ("gj", "j")),
    "absolute": (("s", "i"),),
    "ground": (),
    "normalization": (),
}
"""kernel name -> per vector slot 0, 1, 2 (cf[:, 0:3], 3:6, 6:9): (Block.vecs key, body)."""
I_SLOT, NI, F_CONST, NF = 6, 9, 9, 15

SPARSE_NQ = 250  # CSR Jacobians from about 35 bodies on (measured crossover, spherical chain)


class FastConstraints:
    """Constraint evaluation in C (kernels.c) of one model on a fixed set of rows.

    model: compiled :class:`mbsim.model.Model`; rows: (m_a,) the rows to return (e.g. an
    assembly's active rows), default all m, in the model's order; sparse: the Jacobian as
    CSR (fixed pattern) instead of dense; None chooses by size (nq >= ``SPARSE_NQ``).

    Two ways to evaluate:

    - :meth:`evaluate`: results in buffers owned by this object (no allocation; valid until
      the next call; copy what you keep);
    - :meth:`constraints`: fresh arrays (:class:`mbsim.core.Terms`)
      restricted to ``rows``.
    """

    def __init__(self, model, rows=None, sparse=None):
        self.model = model
        self.m, self.nq, self.nb = model.m, model.nq, model.nb
        self.rows = np.ascontiguousarray(
            np.arange(model.m) if rows is None else rows, dtype=np.int64
        )
        if self.rows.ndim != 1 or np.any((self.rows < 0) | (self.rows >= model.m)):
            raise ValueError(f"rows: expected row numbers in [0, {model.m}), got {rows!r}")
        self.sparse = (model.nq >= SPARSE_NQ) if sparse is None else bool(sparse)
        self.ci, self.cf, self.rb, self.funcs = model_table(model, "flatten", flatten, model)
        self.lib = _lib.library()
        m, ma, nq = self.m, self.rows.size, self.nq
        self.c = _lib.Model(nb=self.nb, nq=nq, m=m, ma=ma, nc=self.ci.shape[0])
        self.c.set(ci=self.ci, cf=self.cf, rb=self.rb, rows=self.rows)
        # inputs: q, qd (copied in per call), tv (nf, 3): c(t), c'(t), c''(t); all m rows:
        # phi, compact Phi_q (m, 14), gamma, nu; the rows `rows`: phi_a, gamma_a, nu_a
        (self._q, self._qd, self.tv, self.phi_all, self.Jc, self.gamma_all, self.nu_all,
         self._phi, self._gamma, self._nu) = self.c.zeros(
            q=nq, qd=nq, tv=(len(self.funcs), 3), phi=m, Jc=(m, 14), gamma=m, nu=m, phi_a=ma,
            gamma_a=ma, nu_a=ma)
        self._J = None  # dense (m_a, nq), allocated on first use (pattern-only writes)
        self._csr = None  # (indptr, indices, dpos, data), built on first use

    # -- time targets ----------------------------------------------------------------------
    def targets(self, t: float, derivatives: bool = True) -> np.ndarray:
        """tv (nf, 3): c(t) (f^2 for squared targets), c'(t), c''(t) of the driven rows."""
        tv = self.tv
        for n, (f, sq) in enumerate(self.funcs):
            v = float(f(t))
            if derivatives:
                tv[n] = target(v, float(f.d1(t)), float(f.d2(t)), sq)
            else:
                tv[n, 0] = v * v if sq else v
        return tv

    # -- evaluation ------------------------------------------------------------------------
    def load(self, q, t, qd=None):
        """Copy q (and qd) into the C inputs and evaluate the time targets at t."""
        self.vector(q, "q", self._q)
        if qd is not None:
            self.vector(qd, "qd", self._qd)
        if self.funcs:
            self.targets(t)

    def compact(self, q, t=0.0, qd=None, jac=True, gamma=False):
        """All m rows into the buffers phi_all, Jc (m, 14), gamma_all, nu_all (module
        doc); returns nothing."""
        if gamma and qd is None:
            raise ValueError("gamma needs the velocities qd")
        self.load(q, t, qd)
        self.lib.mb_constraints(self.c.ptr, bool(jac), bool(gamma))

    def vector(self, x, name="q", out=None) -> np.ndarray:
        """x copied into ``out`` (default: a fresh (nq,) float64 array); a wrong shape is
        an error here (the C code does not check bounds)."""
        if np.shape(x) != (self.nq,):
            raise ValueError(f"{name}: expected shape ({self.nq},), got {np.shape(x)}")
        if out is None:
            return np.array(x, dtype=np.float64)
        out[:] = x
        return out

    def evaluate(self, q, t=0.0, qd=None, jac=True, gamma=False, sparse=None) -> Terms:
        """Phi, Phi_q, gamma (when asked; needs qd) and nu on ``rows`` at (q, qd, t), in this
        object's buffers: Terms(phi (m_a,), jac (m_a, nq) dense or csr, gamma, nu)."""
        if gamma and qd is None:
            raise ValueError("gamma needs the velocities qd")
        self.load(q, t, qd)
        sparse = self.sparse if sparse is None else sparse
        mode = 0 if not jac else (2 if sparse else 1)
        if mode == 1 and self._J is None:
            (self._J,) = self.c.set(J=np.zeros((self.rows.size, self.nq)))
        if mode == 2:
            indptr, indices, _, data = self.csr_pattern()
        self.lib.mb_terms(self.c.ptr, bool(jac), bool(gamma), mode)
        T = Terms()
        T.phi, T.nu = self._phi, self._nu
        T.gamma = self._gamma if gamma else None
        T.jac = None
        if mode == 1:
            T.jac = self._J
        elif mode == 2:
            T.jac = _csr(data, indices, indptr, (self.rows.size, self.nq))
        return T

    def constraints(
        self, q, t=0.0, qd=None, phi=True, jac=True, gamma=False, nu=False, sparse=None
    ) -> Terms:
        """Phi, Phi_q, gamma, nu on ``rows``: fresh arrays, None for the
        parts not asked for; the Jacobian dense or CSR (``sparse``, default as built)."""
        T = self.evaluate(q, t, qd, jac=jac, gamma=gamma, sparse=sparse)
        T.phi = T.phi.copy() if phi else None
        T.nu = T.nu.copy() if nu else None
        T.gamma = T.gamma.copy() if gamma else None
        if jac:
            T.jac = T.jac.copy()
        return T

    def csr_pattern(self):
        """(indptr, indices, dpos, data) of the CSR Jacobian on ``rows``: per row the 7 or 14
        columns of its bodies, sorted; dpos (m_a, 14) the place of each compact entry."""
        if self._csr is None:
            rows, rb = self.rows, self.rb
            indptr = np.zeros(rows.size + 1, dtype=np.int64)
            indices, dpos = [], np.full((rows.size, 14), -1, dtype=np.int64)
            for k, r in enumerate(rows):
                cols = [7 * rb[r, 0] + c for c in range(7)]
                if rb[r, 1] >= 0:
                    cols += [7 * rb[r, 1] + c for c in range(7)]
                uniq = sorted(set(cols))
                where = {c: indptr[k] + n for n, c in enumerate(uniq)}
                dpos[k, : len(cols)] = [where[c] for c in cols]
                indices += uniq
                indptr[k + 1] = indptr[k] + len(uniq)
            indices = np.array(indices, dtype=np.int32)
            dpos, data = self.c.set(dpos=dpos, data=np.zeros(indices.size))
            self._csr = (indptr.astype(np.int32), indices, dpos, data)
        return self._csr


def target(v, d1, d2, sq):
    """(c, c', c'') of a driven row from its function's f, f', f'' (floats or arrays); a
    squared target is f^2: (f^2)' = 2 f f', (f^2)'' = 2 (f'^2 + f f'')."""
    if sq:
        return v * v, 2.0 * v * d1, 2.0 * (d1 * d1 + v * d2)
    return v, d1, d2


class _TableCache(dict):
    """key -> table, kept on the Model it was built from (it lives and dies with it);
    pickled and copied empty, as mbsim.core's Data cache."""

    def __reduce__(self):
        return (_TableCache, ())


def model_table(model, key, build, *args):
    """``build(*args)`` for ``model``, built at the first call with this key and shared by
    every later one (compile once: a Model is frozen, so its tables never change).  The
    arrays of the result are made read-only (the C code takes them as ``const``); ``key``
    must name everything the result depends on besides the model (e.g. the row set)."""
    tables = model.__dict__.get("_fast_tables")
    if tables is None:  # Model is frozen: a cache, not a field (as mbsim.core.make_data)
        tables = _TableCache()
        object.__setattr__(model, "_fast_tables", tables)
    if key not in tables:
        value = build(*args)
        for a in value if isinstance(value, tuple) else (value,):
            if isinstance(a, np.ndarray):
                a.setflags(write=False)
        tables[key] = value
    return tables[key]


def _csr(data, indices, indptr, shape):
    """A csr_matrix on given arrays without the O(nnz) format check (they are canonical)."""
    import scipy.sparse as sp

    J = sp.csr_matrix(shape)
    J.data, J.indices, J.indptr = data, indices, indptr
    J.has_sorted_indices = True
    J.has_canonical_format = True
    return J


def flatten(model):
    """The model's kernel Blocks as tables (module doc).

    Returns ci (nc, NI) int64, cf (nc, NF) float64, rb (m, 2) int64 bodies of each row and
    funcs: [(TimeFunction, squared)] indexed by ci[:, I_FUNC]."""
    ci_rows, cf_rows, funcs = [], [], []
    rb = np.full((model.m, 2), -1, dtype=np.int64)
    for blk in model.blocks:
        code = KERNEL_CODE[blk.kernel]
        fn_of = {}
        for n, f, sq in blk.funcs:
            fn_of[n] = len(funcs)
            funcs.append((f, bool(sq)))
        for n in range(len(blk.bi)):
            ci = np.zeros(NI, dtype=np.int64)
            cf = np.zeros(NF)
            bi, bj = int(blk.bi[n]), int(blk.bj[n])
            if blk.kernel == "dot2":
                flag = int(bool(blk.vecs["on_j"][n]))
            elif blk.kernel == "absolute":
                flag = int(blk.vecs["axis"][n])
            else:
                flag = 0
            ci[: I_SLOT] = (code, bi, bj, blk.rows[n, 0], flag, fn_of.get(n, -1))
            ci[I_SLOT :] = -1
            for v, slot in enumerate(VECTORS[blk.kernel]):
                if slot is not None:
                    key, side = slot
                    on_j = side == "j" or (blk.kernel == "dot2" and key == "a" and flag)
                    ci[I_SLOT + v] = bj if on_j else bi
                    cf[3 * v : 3 * v + 3] = blk.vecs[key][n]
            cf[F_CONST : F_CONST + blk.ne] = blk.c_const[n]
            ci_rows.append(ci)
            cf_rows.append(cf)
            rb[blk.rows[n], 0] = bi
            rb[blk.rows[n], 1] = bj
    ci = np.array(ci_rows, dtype=np.int64).reshape(-1, NI)
    cf = np.array(cf_rows, dtype=np.float64).reshape(-1, NF)
    return ci, cf, rb, funcs
