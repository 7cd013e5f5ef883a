"""Phi, Phi_q, nu and gamma of all constraint rows in one pass, for the integrators' inner loop.

Same equations and results as :func:`mbsim.equations.constraints` (tests compare them to
round-off), organised for few numpy calls per evaluation:

1. every body-fixed vector a' of every kernel row sits in one table (K vectors); with
   B(p, a') = T(a') p (B is linear in p) and A(p) a' = B(p, a') p / 2 (A is a homogeneous
   quadratic form), one batched product gives all a = A a' and all a_p = B, one more
   all ad = B pd and bdot = B(pd, a') pd (Haug eq. 9.3.x);
2. each kernel (dot-1, dot-2, spherical, distance, absolute, ground, normalisation) is a
   handful of array operations on slices of that table;
3. the Jacobian values land in a preallocated dense array (or the data array of a CSR
   matrix with a fixed pattern) through one precomputed index.

Kernels outside this set (the rotational driver's ``angle``) make :func:`fused_constraints`
return None; the caller then uses :mod:`mbsim.equations`.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from mbsim.rotations import A as rot_A
from mbsim.rotations import B as rot_B

SUPPORTED = {"dot1", "dot2", "spherical", "distance", "absolute", "ground", "normalization"}
VECTORS = {"dot1": ("ai", "aj"), "dot2": ("a", "si", "sj"), "spherical": ("si", "sj"),
           "distance": ("si", "sj"), "absolute": ("s",)}


def _tensor(a):
    """(k, 3, 4, 4) T(a') with B(p, a') = T(a') p, from B at the unit vectors (B is linear)."""
    k = a.shape[0]
    T = np.empty((k, 3, 4, 4))
    for m in range(4):
        e = np.zeros((k, 4))
        e[:, m] = 1.0
        T[..., m] = rot_B(e, a)
    return T


class FusedConstraints:
    """Compiled evaluation of all rows of a model (see module doc).  Call it as
    ``fc(q, t, qd=None, jac=True, gamma=False, nu=False)`` -> (phi, J, gamma, nu) on all
    rows; J dense (m, nq) or CSR when ``sparse``."""

    def __init__(self, model, sparse=False):
        self.model, self.sparse = model, sparse
        self.nb, self.m, self.nq = model.nb, model.m, model.nq
        vb, vt, self.kern = [], [], []
        K = 0
        for blk in model.blocks:
            entry = {"blk": blk, "k": len(blk.bi)}
            if blk.kernel == "dot2":
                entry["on_j"] = np.asarray(blk.vecs["on_j"], float)[:, None]
            for key in VECTORS.get(blk.kernel, ()):
                loc = np.asarray(blk.vecs[key], dtype=float)
                if blk.kernel == "dot2" and key == "a":
                    bodies = np.where(blk.vecs["on_j"], blk.bj, blk.bi)
                else:
                    bodies = blk.bj if key in ("aj", "sj") else blk.bi
                vb.append(bodies)
                vt.append(_tensor(loc))
                entry[key] = slice(K, K + loc.shape[0])
                K += loc.shape[0]
            self.kern.append(entry)
        self.vb = np.concatenate(vb) if vb else np.zeros(0, int)
        self.T = np.concatenate(vt).reshape(K, 12, 4) if vt else np.zeros((0, 12, 4))
        # row order: the blocks' rows concatenated -> global rows
        self.row_perm = np.concatenate([b.rows.reshape(-1) for b in model.blocks])
        # Jacobian value layout: per block ji (k, ne, 7) then jj (k, ne, 7)
        ri, ci = [], []
        for blk in model.blocks:
            ri.append(blk.scatter["ri"])
            ci.append(blk.scatter["ci"])
            if blk.bj[0] >= 0:
                ri.append(blk.scatter["rj"])
                ci.append(blk.scatter["cj"])
        ri, ci = np.concatenate(ri), np.concatenate(ci)
        self.nval = ri.size
        off = 0
        for e in self.kern:  # views of one value buffer: ji (k, ne, 7), then jj
            blk = e["blk"]
            size = blk.rows.size * 7
            e["ji"] = slice(off, off + size)
            off += size
            if blk.bj[0] >= 0:
                e["jj"] = slice(off, off + size)
                off += size
        self._vals = np.zeros(self.nval)
        self._init_constant_parts()
        if sparse:
            order = np.lexsort((ci, ri))
            self.csr_order = order
            self.csr_indices = ci[order].astype(np.int32)
            self.csr_indptr = np.searchsorted(ri[order], np.arange(self.m + 1)).astype(np.int32)
        else:
            self.flat = ri * self.nq + ci
        self.ok = all(b.kernel in SUPPORTED for b in model.blocks) and self._homogeneous()

    def _init_constant_parts(self):
        """Jacobian entries that do not depend on q (ground rows, +-I of spherical rows)
        are written once; the kernels overwrite only the rest."""
        v = self._vals
        for e in self.kern:
            blk, k = e["blk"], e["k"]
            ji = v[e["ji"]].reshape(k, blk.ne, 7)
            if blk.kernel == "ground":
                ji[:, :3, :3] = np.eye(3)
                ji[:, 3:, 4:] = np.eye(3)
            elif blk.kernel == "spherical":
                ji[:, :, :3] = -np.eye(3)
                v[e["jj"]].reshape(k, 3, 7)[:, :, :3] = np.eye(3)
            elif blk.kernel == "absolute":
                ji[np.arange(k), 0, blk.vecs["axis"]] = 1.0

    def _homogeneous(self):
        """A(p) a' = B(p, a') p / 2 also off |p| = 1 (checked once, at random p)."""
        p = np.random.default_rng(0).normal(size=(1, 4))
        a = np.array([[0.3, -0.2, 0.7]])
        return bool(np.allclose(rot_A(p)[0] @ a[0], 0.5 * rot_B(p, a)[0] @ p[0]))

    def __call__(self, q, t, qd=None, jac=True, gamma=False, nu=False):
        nb = self.nb
        Q = q.reshape(nb, 7)
        r, p = Q[:, :3], Q[:, 3:]
        K = self.vb.size
        Pk = p[self.vb]
        Bk = np.matmul(self.T, Pk[:, :, None]).reshape(K, 3, 4)  # a_p = B(p, a')
        Vk = 0.5 * np.matmul(Bk, Pk[:, :, None])[:, :, 0]  # a = A a'
        if gamma:
            V = qd.reshape(nb, 7)
            rd, pd = V[:, :3], V[:, 3:]
            PDk = pd[self.vb]
            Dk = np.matmul(Bk, PDk[:, :, None])[:, :, 0]  # ad = B pd
            Ek = np.matmul(np.matmul(self.T, PDk[:, :, None]).reshape(K, 3, 4),
                           PDk[:, :, None])[:, :, 0]  # bdot = B(pd, a') pd
        phis, gams, vals = [], [], self._vals
        for e in self.kern:
            blk, k = e["blk"], e["k"]
            kern = blk.kernel
            if kern == "normalization":
                pb = p[blk.bi]
                phis.append((pb * pb).sum(1))
                if jac:
                    vals[e["ji"]].reshape(k, 7)[:, 3:] = 2 * pb
                if gamma:
                    pdb = pd[blk.bi]
                    gams.append(-2 * np.einsum("ij,ij->i", pdb, pdb))
                continue
            if kern == "ground":
                b = blk.bi
                phis.append(Q[b][:, [0, 1, 2, 4, 5, 6]].reshape(-1))
                if gamma:
                    gams.append(np.zeros(6 * k))
                continue
            if kern == "dot1":
                si_, sj_ = e["ai"], e["aj"]
                ai, aj, Bi, Bj = Vk[si_], Vk[sj_], Bk[si_], Bk[sj_]
                phis.append((ai * aj).sum(1))
                if jac:
                    vals[e["ji"]].reshape(k, 7)[:, 3:] = np.matmul(aj[:, None, :], Bi)[:, 0]
                    vals[e["jj"]].reshape(k, 7)[:, 3:] = np.matmul(ai[:, None, :], Bj)[:, 0]
                if gamma:
                    gams.append(-(np.einsum("ij,ij->i", ai, Ek[sj_])
                                  + np.einsum("ij,ij->i", aj, Ek[si_])
                                  + 2 * np.einsum("ij,ij->i", Dk[si_], Dk[sj_])))
                continue
            if kern == "absolute":
                s_ = e["s"]
                ax, kk = blk.vecs["axis"], np.arange(k)
                phis.append((r[blk.bi] + Vk[s_])[kk, ax])
                if jac:
                    vals[e["ji"]].reshape(k, 7)[:, 3:] = Bk[s_][kk, ax, :]
                if gamma:
                    gams.append(-Ek[s_][kk, ax])
                continue
            # point-difference kernels: d = r_j + A_j s_j - r_i - A_i s_i
            si_, sj_ = e["si"], e["sj"]
            d = r[blk.bj] + Vk[sj_] - r[blk.bi] - Vk[si_]
            Bsi, Bsj = Bk[si_], Bk[sj_]
            if gamma:
                dd = rd[blk.bj] + Dk[sj_] - rd[blk.bi] - Dk[si_]
                de = Ek[sj_] - Ek[si_]
            if kern == "spherical":
                phis.append(d.reshape(-1))
                if jac:
                    vals[e["ji"]].reshape(k, 3, 7)[:, :, 3:] = -Bsi
                    vals[e["jj"]].reshape(k, 3, 7)[:, :, 3:] = Bsj
                if gamma:
                    gams.append(-de.reshape(-1))
            elif kern == "distance":
                phis.append((d * d).sum(1))
                if jac:
                    ji = vals[e["ji"]].reshape(k, 7)
                    jj = vals[e["jj"]].reshape(k, 7)
                    jj[:, :3] = 2 * d
                    ji[:, :3] = -jj[:, :3]
                    ji[:, 3:] = -2 * np.matmul(d[:, None, :], Bsi)[:, 0]
                    jj[:, 3:] = 2 * np.matmul(d[:, None, :], Bsj)[:, 0]
                if gamma:
                    gams.append(-2 * (np.einsum("ij,ij->i", d, de) + np.einsum("ij,ij->i", dd, dd)))
            else:  # dot2: a . d with a on body i or j
                a_ = e["a"]
                a, Ba = Vk[a_], Bk[a_]
                phis.append((a * d).sum(1))
                if jac:
                    on_j = e["on_j"]
                    da = np.matmul(d[:, None, :], Ba)[:, 0]
                    ji = vals[e["ji"]].reshape(k, 7)
                    jj = vals[e["jj"]].reshape(k, 7)
                    ji[:, :3] = -a
                    jj[:, :3] = a
                    ji[:, 3:] = (1.0 - on_j) * da - np.matmul(a[:, None, :], Bsi)[:, 0]
                    jj[:, 3:] = on_j * da + np.matmul(a[:, None, :], Bsj)[:, 0]
                if gamma:
                    gams.append(-(np.einsum("ij,ij->i", a, de) + np.einsum("ij,ij->i", d, Ek[a_])
                                  + 2 * np.einsum("ij,ij->i", Dk[a_], dd)))
        perm = self.row_perm
        phi = np.empty(self.m)
        phi[perm] = np.concatenate(phis)
        g = None
        if gamma:
            g = np.empty(self.m)
            g[perm] = np.concatenate(gams)
        nu_ = np.zeros(self.m) if nu else None
        # targets: constants, then time functions (as in equations.constraints)
        phi -= self._c_const
        for blk in self.model.blocks:
            for n, f, sq in blk.funcs:
                row = blk.rows[n, 0]
                v = f(t)
                phi[row] -= v * v if sq else v
                if nu or gamma:
                    d1, d2 = f.d1(t), f.d2(t)
                    if sq:
                        d1, d2 = 2 * v * d1, 2 * (d1 * d1 + v * d2)
                    if nu:
                        nu_[row] = d1
                    if gamma:
                        g[row] += d2
        J = None
        if jac == "values":  # the raw (row, body) pieces, see pieces()
            J = vals.copy()
        elif jac:
            v = vals
            if self.sparse:
                J = sp.csr_matrix((v[self.csr_order], self.csr_indices, self.csr_indptr),
                                  shape=(self.m, self.nq))
            else:
                J = np.zeros(self.m * self.nq)
                J[self.flat] = v
                J = J.reshape(self.m, self.nq)
        return phi, J, g, nu_

    def pieces(self):
        """(rows, bodies) (P,) of the Jacobian pieces: the value buffer that ``jac="values"``
        returns is (P, 7), piece p holding d Phi_row / d [r_b, p_b]."""
        rows, bodies = [], []
        for e in self.kern:
            blk = e["blk"]
            rows.append(blk.rows.reshape(-1))
            bodies.append(np.repeat(blk.bi, blk.ne))
            if "jj" in e:
                rows.append(blk.rows.reshape(-1))
                bodies.append(np.repeat(blk.bj, blk.ne))
        return np.concatenate(rows), np.concatenate(bodies)

    @property
    def _c_const(self):
        c = getattr(self, "_cc", None)
        if c is None:
            c = np.zeros(self.m)
            for blk in self.model.blocks:
                c[blk.rows.reshape(-1)] = np.asarray(blk.c_const, float).reshape(-1)
            self._cc = c
        return c
