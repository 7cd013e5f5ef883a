"""Phi, Phi_q, nu and gamma of all constraint rows in one pass, for the integrators' inner loop.

Same equations and results as :func:`mbsim.equations.constraints` (tests compare them to
round-off), organised for a fixed, small number of numpy calls whatever the joints:

1. every body-fixed vector a' of every kernel row sits in one table (K vectors): with
   B(p, a') = T(a') p (B is linear in p) and A(p) a' = B(p, a') p / 2 (A is a homogeneous
   quadratic form), one batched product gives all a = A a' and all a_p = B; one more gives
   ad = B pd and bdot = B(pd, a') pd (Haug eq. 9.3.x);
2. the point differences d = r_j + A_j s_j - r_i - A_i s_i of all dot-2, spherical and
   distance rows are one gathered sum;
3. every row (ground and normalisation rows aside) is then a short sum of terms read from
   the tables by precomputed indices (Haug Sec. 9.2-9.4):

   ============  ==========  ======================================  =========================
   kernel        Phi         pieces i | j (r-part ; p-part)          gamma
   ============  ==========  ======================================  =========================
   dot-1         ai . aj     0 ; aj^T ai_p  |  0 ; ai^T aj_p         -(ai.Ej + aj.Ei + 2 Di.Dj)
   dot-2         a . d       -a ; -a^T si_p + [a on i] d^T a_p  |    -(a.de + d.Ea + 2 Da.dd)
                             a ; a^T sj_p + [a on j] d^T a_p
   spherical     e_k . d     -e_k ; -e_k^T si_p  |  e_k ; e_k^T sj_p  -e_k . de
   distance      d . d       -2d ; -2 d^T si_p  |  2d ; 2 d^T sj_p    -2 (d.de + dd.dd)
   absolute      e . (r + a) e ; e^T a_p                             -e . Ea
   ============  ==========  ======================================  =========================

   with a_p = B(p, a'), D = ad = B pd, E = bdot = B(pd, a') pd, dd = d', de = E_sj - E_si;
   so Phi, the (row, body) Jacobian pieces and gamma are each a few gathers, one batched
   product and one weighted sum.

Kernels outside this set (the rotational driver's ``angle``) leave ``ok`` False; the caller
then uses :mod:`mbsim.equations`.
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
    T = np.empty((a.shape[0], 3, 4, 4))
    for m in range(4):
        e = np.zeros((a.shape[0], 4))
        e[:, m] = 1.0
        T[..., m] = rot_B(e, a)
    return T


class _Terms:
    """Growing lists of (index, index, coefficient) terms, padded to a fixed count per row."""

    def __init__(self, width):
        self.width, self.rows = width, []

    def add(self, *terms):
        assert len(terms) <= self.width
        self.rows.append(list(terms) + [(0, 0, 0.0)] * (self.width - len(terms)))

    def arrays(self):
        a = np.array(self.rows, dtype=object).reshape(-1, self.width, 3)
        return (a[:, :, 0].astype(int), a[:, :, 1].astype(int), a[:, :, 2].astype(float))


class FusedConstraints:
    """Compiled evaluation of all rows of a model (module doc).  Call it as
    ``fc(q, t, qd=None, jac=True, gamma=False, nu=False)`` -> (phi, J, gamma, nu) on all
    rows; J dense (m, nq) or CSR when ``sparse``, or with ``jac="values"`` the (P * 7,)
    values of the Jacobian pieces (:meth:`pieces`)."""

    def __init__(self, model, sparse=False):
        self.model, self.sparse = model, sparse
        self.nb, self.m, self.nq = model.nb, model.m, model.nq
        self.ok = all(b.kernel in SUPPORTED for b in model.blocks) and self._homogeneous()
        if self.ok:
            self._compile(model)

    @staticmethod
    def _homogeneous():
        """A(p) a' = B(p, a') p / 2 also off |p| = 1 (checked once, at a random p)."""
        p = np.random.default_rng(0).normal(size=(1, 4))
        a = np.array([[0.3, -0.2, 0.7]])
        return bool(np.allclose(rot_A(p)[0] @ a[0], 0.5 * rot_B(p, a)[0] @ p[0]))

    def _compile(self, model):
        vb, vt, dbi, dbj, dsi, dsj = [], [], [], [], [], []
        K = 0
        vec = {}  # (block number, key) -> (k,) indices into the vector table
        for n, blk in enumerate(model.blocks):
            for key in VECTORS.get(blk.kernel, ()):
                loc = np.asarray(blk.vecs[key], dtype=float)
                if blk.kernel == "dot2" and key == "a":
                    bodies = np.where(blk.vecs["on_j"], blk.bj, blk.bi)
                else:
                    bodies = blk.bj if key in ("aj", "sj") else blk.bi
                vb.append(bodies)
                vt.append(_tensor(loc))
                vec[n, key] = np.arange(K, K + loc.shape[0])
                K += loc.shape[0]
        nD = sum(len(b.bi) for b in model.blocks if b.kernel in ("dot2", "spherical", "distance"))
        # tables: Lq = [a (K), d (nD), e_x e_y e_z, r (nb)]; Lg = [a, ad, bdot, d, dd, de, e]
        oD, oE, oR = K, K + nD, K + nD + 3
        gA, gD, gE = 0, K, 2 * K
        gd, gdd, gde, ge = 3 * K, 3 * K + nD, 3 * K + 2 * nD, 3 * K + 3 * nD
        phi_t, rpart, ppart, gam_t = _Terms(2), _Terms(1), _Terms(2), _Terms(3)
        gen_rows, piece_rows, piece_bodies = [], [], []
        ground_rows, ground_q, ground_pieces = [], [], []
        norm_rows, norm_bodies = [], []
        d_next = 0
        for n, blk in enumerate(model.blocks):
            kern, k = blk.kernel, len(blk.bi)
            if kern == "ground":
                for c in range(k):
                    b = blk.bi[c]
                    ground_rows += list(blk.rows[c])
                    ground_q += [7 * b + j for j in (0, 1, 2, 4, 5, 6)]
                    ground_pieces += [(blk.rows[c][j], b, j) for j in range(6)]
                continue
            if kern == "normalization":
                norm_rows += list(blk.rows[:, 0])
                norm_bodies += list(blk.bi)
                continue
            if kern in ("dot2", "spherical", "distance"):
                dbi.append(blk.bi)
                dbj.append(blk.bj)
                dsi.append(vec[n, "si"])
                dsj.append(vec[n, "sj"])
            for c in range(k):
                bi, bj = int(blk.bi[c]), int(blk.bj[c])
                if kern == "dot1":
                    ai, aj = vec[n, "ai"][c], vec[n, "aj"][c]
                    rows = [(blk.rows[c, 0], [(ai, aj, 1.0)],
                             [(bi, (0, 0, 0.0), [(aj, ai, 1.0)]),
                              (bj, (0, 0, 0.0), [(ai, aj, 1.0)])],
                             [(gA + ai, gE + aj, -1.0), (gA + aj, gE + ai, -1.0),
                              (gD + ai, gD + aj, -2.0)])]
                elif kern == "dot2":
                    a, si, sj = vec[n, "a"][c], vec[n, "si"][c], vec[n, "sj"][c]
                    on_j = float(blk.vecs["on_j"][c])
                    d = oD + d_next
                    rows = [(blk.rows[c, 0], [(a, d, 1.0)],
                             [(bi, (a, 0, -1.0), [(a, si, -1.0), (d, a, 1.0 - on_j)]),
                              (bj, (a, 0, 1.0), [(a, sj, 1.0), (d, a, on_j)])],
                             [(gA + a, gde + d_next, -1.0), (gd + d_next, gE + a, -1.0),
                              (gD + a, gdd + d_next, -2.0)])]
                elif kern == "spherical":
                    si, sj = vec[n, "si"][c], vec[n, "sj"][c]
                    d = oD + d_next
                    rows = [(blk.rows[c, e], [(oE + e, d, 1.0)],
                             [(bi, (oE + e, 0, -1.0), [(oE + e, si, -1.0)]),
                              (bj, (oE + e, 0, 1.0), [(oE + e, sj, 1.0)])],
                             [(ge + e, gde + d_next, -1.0)]) for e in range(3)]
                elif kern == "distance":
                    si, sj = vec[n, "si"][c], vec[n, "sj"][c]
                    d = oD + d_next
                    rows = [(blk.rows[c, 0], [(d, d, 1.0)],
                             [(bi, (d, 0, -2.0), [(d, si, -2.0)]),
                              (bj, (d, 0, 2.0), [(d, sj, 2.0)])],
                             [(gd + d_next, gde + d_next, -2.0),
                              (gdd + d_next, gdd + d_next, -2.0)])]
                else:  # absolute
                    s, ax = vec[n, "s"][c], int(blk.vecs["axis"][c])
                    rows = [(blk.rows[c, 0], [(oE + ax, oR + bi, 1.0), (oE + ax, s, 1.0)],
                             [(bi, (oE + ax, 0, 1.0), [(oE + ax, s, 1.0)])],
                             [(ge + ax, gE + s, -1.0)])]
                if kern in ("dot2", "spherical", "distance"):
                    d_next += 1
                for row, ph, pieces, gam in rows:
                    gen_rows.append(row)
                    phi_t.add(*ph)
                    gam_t.add(*gam)
                    for body, rp, pp in pieces:
                        piece_rows.append(row)
                        piece_bodies.append(body)
                        rpart.add(rp)
                        ppart.add(*pp)
        cat = (lambda x: np.concatenate(x) if x else np.zeros(0, int))  # noqa: E731
        self.vb = cat(vb).astype(int)
        self.T = np.concatenate(vt).reshape(K, 12, 4) if vt else np.zeros((0, 12, 4))
        self.K, self.nD = K, nD
        self.dbi, self.dbj, self.dsi, self.dsj = (cat(x).astype(int) for x in (dbi, dbj, dsi, dsj))
        self.phi_i, self.phi_j, self.phi_c = phi_t.arrays()
        self.r_i, _, self.r_c = rpart.arrays()
        self.p_x, self.p_v, self.p_c = ppart.arrays()
        self.g_i, self.g_j, self.g_c = gam_t.arrays()
        self.r_i, self.r_c = self.r_i[:, 0], self.r_c[:, :1]
        self.gen_rows = np.array(gen_rows, dtype=int)
        self.norm_rows = np.array(norm_rows, dtype=int)
        self.norm_b = np.array(norm_bodies, dtype=int)
        self.ground_rows = np.array(ground_rows, dtype=int)
        self.ground_q = np.array(ground_q, dtype=int)
        self.eye = np.eye(3)
        # pieces: generic, then ground, then normalisation; values (P, 7)
        ng, nn = len(piece_rows), len(norm_rows)
        self.piece_rows = np.array(piece_rows + [r for r, _, _ in ground_pieces] + norm_rows, int)
        self.piece_bodies = np.array(piece_bodies + [b for _, b, _ in ground_pieces] + norm_bodies,
                                     int)
        self.n_gen = ng
        self._vals = np.zeros((self.piece_rows.size, 7))
        for p, (_, _, j) in enumerate(ground_pieces):  # constant: r = r0, (e1, e2, e3) = e0'
            self._vals[ng + p, j if j < 3 else j + 1] = 1.0
        self.norm_pieces = np.arange(ng + len(ground_pieces), ng + len(ground_pieces) + nn)
        cols = 7 * self.piece_bodies[:, None] + np.arange(7)
        rows = np.repeat(self.piece_rows, 7)
        if self.sparse:
            order = np.lexsort((cols.reshape(-1), rows))
            self.csr_order = order
            self.csr_indices = cols.reshape(-1)[order].astype(np.int32)
            self.csr_indptr = np.searchsorted(rows[order], np.arange(self.m + 1)).astype(np.int32)
        else:
            self.flat = rows * self.nq + cols.reshape(-1)
        c = np.zeros(self.m)
        for blk in model.blocks:
            c[blk.rows.reshape(-1)] = np.asarray(blk.c_const, float).reshape(-1)
        self.c_const = c
        self.funcs = [(blk.rows[n, 0], f, sq) for blk in model.blocks for n, f, sq in blk.funcs]

    def pieces(self):
        """(rows, bodies) (P,) of the Jacobian pieces: the value buffer that ``jac="values"``
        returns is (P, 7), piece p holding d Phi_row / d [r_b, p_b]."""
        return self.piece_rows, self.piece_bodies

    def __call__(self, q, t, qd=None, jac=True, gamma=False, nu=False):
        nb, K = self.nb, self.K
        Q = q.reshape(nb, 7)
        r, p = Q[:, :3], Q[:, 3:]
        Pk = p[self.vb]
        Bk = np.matmul(self.T, Pk[:, :, None]).reshape(K, 3, 4)  # a_p = B(p, a')
        Vk = 0.5 * np.matmul(Bk, Pk[:, :, None])[:, :, 0]  # a = A a'
        d = r[self.dbj] + Vk[self.dsj] - r[self.dbi] - Vk[self.dsi]
        Lq = np.concatenate([Vk, d, self.eye, r])
        phi = np.empty(self.m)
        phi[self.gen_rows] = ((Lq[self.phi_i] * Lq[self.phi_j]).sum(2) * self.phi_c).sum(1)
        pn = p[self.norm_b]
        phi[self.norm_rows] = (pn * pn).sum(1)
        phi[self.ground_rows] = q[self.ground_q]
        phi -= self.c_const
        g = nu_ = None
        if gamma:
            V = qd.reshape(nb, 7)
            rd, pd = V[:, :3], V[:, 3:]
            PDk = pd[self.vb]
            Dk = np.matmul(Bk, PDk[:, :, None])[:, :, 0]  # ad = B pd
            Ek = np.matmul(np.matmul(self.T, PDk[:, :, None]).reshape(K, 3, 4),
                           PDk[:, :, None])[:, :, 0]  # bdot = B(pd, a') pd
            dd = rd[self.dbj] + Dk[self.dsj] - rd[self.dbi] - Dk[self.dsi]
            de = Ek[self.dsj] - Ek[self.dsi]
            Lg = np.concatenate([Vk, Dk, Ek, d, dd, de, self.eye])
            g = np.zeros(self.m)
            g[self.gen_rows] = ((Lg[self.g_i] * Lg[self.g_j]).sum(2) * self.g_c).sum(1)
            pdn = pd[self.norm_b]
            g[self.norm_rows] = -2 * (pdn * pdn).sum(1)
        if nu:
            nu_ = np.zeros(self.m)
        for row, f, sq in self.funcs:  # time targets, as in equations.constraints
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
        if jac:
            vals = self._vals
            ng = self.n_gen
            vals[:ng, :3] = Lq[self.r_i] * self.r_c
            X = Lq[self.p_x]  # (ng, 2, 3)
            prod = np.matmul(X[:, :, None, :], Bk[self.p_v])[:, :, 0, :]  # (ng, 2, 4)
            vals[:ng, 3:] = (prod * self.p_c[:, :, None]).sum(1)
            vals[self.norm_pieces, 3:] = 2 * pn
            if jac == "values":
                J = vals.reshape(-1).copy()
            elif self.sparse:
                J = sp.csr_matrix((vals.reshape(-1)[self.csr_order], self.csr_indices,
                                   self.csr_indptr), shape=(self.m, self.nq))
            else:
                J = np.zeros(self.m * self.nq)
                J[self.flat] = vals.reshape(-1)
                J = J.reshape(self.m, self.nq)
        return phi, J, g, nu_
