"""FastConstraints(model): Phi, Phi_q, gamma and nu of a Model in one compiled call.

Built once per Model (and row selection): the kernel Blocks are flattened into the tables
of :mod:`mbsim.fast._compiled`, the output buffers and the CSR pattern are allocated, and
every evaluation is then one call of :func:`~mbsim.fast._compiled.eval_constraints` plus one
fill of the dense or CSR Jacobian.  Time targets (driver functions) stay Python callables:
f, f', f'' of the few time-dependent rows are evaluated here and passed in as an array.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from mbsim.equations import Terms
from mbsim.fast import _compiled as K

SPARSE_NQ = 700  # the same switch as mbsim.integrators.system: CSR Jacobian from here on


class FastConstraints:
    """Compiled constraint evaluation of one model on a fixed set of rows.

    model: compiled :class:`mbsim.model.Model`; rows: (m_a,) the rows to return (e.g. an
    assembly's active rows), default all m, in the model's order; sparse: the Jacobian as
    CSR (fixed pattern) instead of dense; None chooses by size (nq >= ``SPARSE_NQ``).

    Two ways to evaluate:

    - :meth:`evaluate`: results in buffers owned by this object (no allocation; valid until
      the next call; copy what you keep);
    - :meth:`constraints`: fresh arrays, the contract of :func:`mbsim.equations.constraints`
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
        self.ci, self.cf, self.rb, self.funcs = flatten(model)
        self.tv = np.zeros((len(self.funcs), 3))  # (nf, 3) c(t), c'(t), c''(t)
        m, ma = self.m, self.rows.size
        self.phi_all, self.gamma_all, self.nu_all = np.zeros(m), np.zeros(m), np.zeros(m)
        self.Jc = np.zeros((m, 14))  # compact Phi_q: d/d[r_i, p_i], d/d[r_j, p_j] per row
        self._phi, self._gamma, self._nu = np.zeros(ma), np.zeros(ma), np.zeros(ma)
        self._J = None  # dense (m_a, nq), allocated on first use (pattern-only writes)
        self._csr = None  # (indptr, indices, dpos, data), built on first use
        self._no_J = np.zeros((0, 0))  # placeholders of the compiled call's fixed types
        self._no_csr = (None, None, np.zeros((0, 14), dtype=np.int64), np.zeros(0))

    # -- time targets ----------------------------------------------------------------------
    def targets(self, t: float, derivatives: bool = True) -> np.ndarray:
        """tv (nf, 3): c(t) (f^2 for squared targets), c'(t), c''(t) of the driven rows."""
        tv = self.tv
        for n, (f, sq) in enumerate(self.funcs):
            v = float(f(t))
            if derivatives:
                d1, d2 = float(f.d1(t)), float(f.d2(t))
                if sq:  # (f^2)' = 2 f f', (f^2)'' = 2 (f'^2 + f f'')
                    d1, d2 = 2.0 * v * d1, 2.0 * (d1 * d1 + v * d2)
                tv[n, 1], tv[n, 2] = d1, d2
            tv[n, 0] = v * v if sq else v
        return tv

    # -- evaluation ------------------------------------------------------------------------
    def compact(self, q, t=0.0, qd=None, jac=True, gamma=False):
        """All m rows into the buffers phi_all, Jc (m, 14), gamma_all, nu_all (module
        :mod:`mbsim.fast._compiled`); returns nothing."""
        q = self.vector(q, "q")
        if gamma and qd is None:
            raise ValueError("gamma needs the velocities qd")
        qd = q if qd is None else self.vector(qd, "qd")  # not read unless gamma
        tv = self.targets(t) if self.funcs else self.tv
        out = (self.phi_all, self.Jc, self.gamma_all, self.nu_all)
        K.eval_constraints(q, qd, tv, self.ci, self.cf, bool(jac), bool(gamma), *out)

    def vector(self, x, name="q") -> np.ndarray:
        """x as the C-contiguous float64 (nq,) array the compiled code reads (it does not
        check bounds: a wrong shape is an error here, not a wrong read there)."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        if not x.flags.writeable:  # a read-only array is another numba type: another compile
            x = x.copy()
        if x.shape != (self.nq,):
            raise ValueError(f"{name}: expected shape ({self.nq},), got {x.shape}")
        return x

    def evaluate(self, q, t=0.0, qd=None, jac=True, gamma=False, sparse=None) -> Terms:
        """Phi, Phi_q, gamma (when asked; needs qd) and nu on ``rows`` at (q, qd, t), in this
        object's buffers: Terms(phi (m_a,), jac (m_a, nq) dense or csr, gamma, nu)."""
        self.compact(q, t, qd, jac, gamma)
        sparse = self.sparse if sparse is None else sparse
        mode = 0 if not jac else (2 if sparse else 1)
        if mode == 1 and self._J is None:
            self._J = np.zeros((self.rows.size, self.nq))  # pattern-only writes from here on
        J = self._J if mode == 1 else self._no_J
        indptr, indices, dpos, data = self.csr_pattern() if mode == 2 else self._no_csr
        out = (self._phi, self._nu, self._gamma, J, dpos, data)
        all_ = (self.phi_all, self.nu_all, self.gamma_all, self.Jc)
        K.gather(self.rows, self.rb, *all_, bool(gamma), mode, *out)
        T = Terms()
        T.phi, T.nu = self._phi, self._nu
        T.gamma = self._gamma if gamma else None
        T.jac = None
        if mode == 1:
            T.jac = J
        elif mode == 2:
            T.jac = _csr(data, indices, indptr, (self.rows.size, self.nq))
        return T

    def constraints(
        self, q, t=0.0, qd=None, phi=True, jac=True, gamma=False, nu=False, sparse=None
    ) -> Terms:
        """Like :func:`mbsim.equations.constraints` on ``rows``: fresh arrays, None for the
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
            self._csr = (indptr.astype(np.int32), indices, dpos, np.zeros(indices.size))
        return self._csr


def _csr(data, indices, indptr, shape):
    """A csr_matrix on given arrays without the O(nnz) format check (they are canonical)."""
    J = sp.csr_matrix(shape)
    J.data, J.indices, J.indptr = data, indices, indptr
    J.has_sorted_indices = True
    J.has_canonical_format = True
    return J


def flatten(model):
    """The model's kernel Blocks as tables (module doc of :mod:`mbsim.fast._compiled`).

    Returns ci (nc, NI) int64, cf (nc, NF) float64, rb (m, 2) int64 bodies of each row and
    funcs: [(TimeFunction, squared)] indexed by ci[:, I_FUNC]."""
    ci_rows, cf_rows, funcs = [], [], []
    rb = np.full((model.m, 2), -1, dtype=np.int64)
    for blk in model.blocks:
        code = K.KERNEL_CODE[blk.kernel]
        fn_of = {}
        for n, f, sq in blk.funcs:
            fn_of[n] = len(funcs)
            funcs.append((f, bool(sq)))
        for n in range(len(blk.bi)):
            ci = np.zeros(K.NI, dtype=np.int64)
            cf = np.zeros(K.NF)
            bi, bj = int(blk.bi[n]), int(blk.bj[n])
            if blk.kernel == "dot2":
                flag = int(bool(blk.vecs["on_j"][n]))
            elif blk.kernel == "absolute":
                flag = int(blk.vecs["axis"][n])
            else:
                flag = 0
            ci[: K.I_SLOT] = (code, bi, bj, blk.rows[n, 0], flag, fn_of.get(n, -1))
            ci[K.I_SLOT :] = -1
            for v, slot in enumerate(K.VECTORS[blk.kernel]):
                if slot is not None:
                    key, side = slot
                    on_j = side == "j" or (blk.kernel == "dot2" and key == "a" and flag)
                    ci[K.I_SLOT + v] = bj if on_j else bi
                    cf[3 * v : 3 * v + 3] = blk.vecs[key][n]
            cf[K.F_CONST : K.F_CONST + blk.ne] = blk.c_const[n]
            ci_rows.append(ci)
            cf_rows.append(cf)
            rb[blk.rows[n], 0] = bi
            rb[blk.rows[n], 1] = bj
    ci = np.array(ci_rows, dtype=np.int64).reshape(-1, K.NI)
    cf = np.array(cf_rows, dtype=np.float64).reshape(-1, K.NF)
    return ci, cf, rb, funcs
