"""The numpy reference of the basic constraints of Haug Ch. 9, evaluated in batches.

Tests only: production evaluates the same equations in C (mbsim/fast/kernels.c through
:mod:`mbsim.core`); tests/test_kernels.py compares the two to round-off.

Every joint and driver is compiled into rows of a few *kernels* (dot-1, dot-2, spherical,
distance, angle, absolute coordinate, ground, normalisation).  All rows of one kernel,
whatever joint they come from, are stacked in one :class:`Block` and evaluated together
with numpy, so the cost of an evaluation grows with the number of kernels, not of joints.

A kernel returns, for its k constraints of ne equations each:

- ``phi``   (k, ne)      Phi(q) without the time target
- ``ji``    (k, ne, 7)   d Phi / d [r_i, p_i]
- ``jj``    (k, ne, 7)   d Phi / d [r_j, p_j]   (None for one-body kernels)
- ``gamma`` (k, ne)      -(d/dt Phi_q) qd  (Haug Ch. 9), without the target's f''

Notation: for a body-fixed vector a' on body b, a = A_b a', a_p = B(p_b, a') and
ad = B(p_b, a') pd_b; ``bdot`` = B(pd_b, a') pd_b is the term that enters gamma.
Time targets c(t) are handled generically by :mod:`tests.reference.equations`:
Phi = phi(q) - c(t), nu = c'(t), gamma += c''(t)  (the angle kernel wraps its own target).
"""

from __future__ import annotations

import numpy as np


class Vec:
    """A body-fixed vector a' on the bodies `b` of a batch, evaluated at the current state.

    Uses the tensor T(a') precomputed at compile time (``vecs[key + "~T"]``), so that
    B(p, a') = T p, a = A(p) a' = B p / 2, ad = B pd and bdot = B(pd, a') pd are four
    contractions (see :func:`mbsim.rotations.B_tensor`)."""

    __slots__ = ("bdot", "jac", "val", "vel")

    def __init__(self, st, b: np.ndarray, T: np.ndarray, vel: bool):
        p = st.p[b]
        self.jac = np.einsum("nikm,nm->nik", T, p)  # (k, 3, 4)
        self.val = 0.5 * np.einsum("kij,kj->ki", self.jac, p)
        if vel:
            pd = st.pd[b]
            self.vel = np.einsum("kij,kj->ki", self.jac, pd)
            self.bdot = np.einsum("kij,kj->ki", np.einsum("nikm,nm->nik", T, pd), pd)


def _point_diff(st, blk, vel):
    """d = r_j + A_j s_j - r_i - A_i s_i, with its parts (Haug Ch. 9)."""
    si = Vec(st, blk.bi, blk.vecs["si~T"], vel)
    sj = Vec(st, blk.bj, blk.vecs["sj~T"], vel)
    d = st.r[blk.bj] + sj.val - st.r[blk.bi] - si.val
    dd = None
    if vel:
        dd = st.rd[blk.bj] + sj.vel - st.rd[blk.bi] - si.vel
    return d, dd, si, sj


def dot1(st, blk, jac=True, gamma=False):
    """Phi = a_i . a_j  (Haug eq. 9.2.3)."""
    ai = Vec(st, blk.bi, blk.vecs["ai~T"], gamma)
    aj = Vec(st, blk.bj, blk.vecs["aj~T"], gamma)
    out = {"phi": np.sum(ai.val * aj.val, axis=1)[:, None]}
    if jac:
        k = len(blk.bi)
        ji = np.zeros((k, 1, 7))
        jj = np.zeros((k, 1, 7))
        ji[:, 0, 3:] = np.einsum("ki,kij->kj", aj.val, ai.jac)
        jj[:, 0, 3:] = np.einsum("ki,kij->kj", ai.val, aj.jac)
        out["ji"], out["jj"] = ji, jj
    if gamma:
        g = -(np.sum(ai.val * aj.bdot, 1) + np.sum(aj.val * ai.bdot, 1)
              + 2 * np.sum(ai.vel * aj.vel, 1))
        out["gamma"] = g[:, None]
    return out


def dot2(st, blk, jac=True, gamma=False):
    """Phi = a . d_ij with a on body i or j (flag ``on_j``)  (Haug eq. 9.2.6)."""
    d, dd, si, sj = _point_diff(st, blk, gamma)
    on_j = blk.vecs["on_j"]
    bc = np.where(on_j, blk.bj, blk.bi)
    a = Vec(st, bc, blk.vecs["a~T"], gamma)
    out = {"phi": np.sum(a.val * d, axis=1)[:, None]}
    if jac:
        k = len(blk.bi)
        ji = np.zeros((k, 1, 7))
        jj = np.zeros((k, 1, 7))
        ji[:, 0, :3] = -a.val
        jj[:, 0, :3] = a.val
        ji[:, 0, 3:] = -np.einsum("ki,kij->kj", a.val, si.jac)
        jj[:, 0, 3:] = np.einsum("ki,kij->kj", a.val, sj.jac)
        da = np.einsum("ki,kij->kj", d, a.jac)
        ji[:, 0, 3:] += np.where(on_j[:, None], 0.0, da)
        jj[:, 0, 3:] += np.where(on_j[:, None], da, 0.0)
        out["ji"], out["jj"] = ji, jj
    if gamma:
        g = -(np.sum(a.val * (sj.bdot - si.bdot), 1) + np.sum(d * a.bdot, 1)
              + 2 * np.sum(a.vel * dd, 1))
        out["gamma"] = g[:, None]
    return out


def spherical(st, blk, jac=True, gamma=False):
    """Phi = d_ij (3 equations, Haug eq. 9.4.1)."""
    d, dd, si, sj = _point_diff(st, blk, gamma)
    out = {"phi": d}
    if jac:
        k = len(blk.bi)
        ji = np.zeros((k, 3, 7))
        jj = np.zeros((k, 3, 7))
        ji[:, :, :3] = -np.eye(3)
        jj[:, :, :3] = np.eye(3)
        ji[:, :, 3:] = -si.jac
        jj[:, :, 3:] = sj.jac
        out["ji"], out["jj"] = ji, jj
    if gamma:
        out["gamma"] = si.bdot - sj.bdot
    return out


def distance(st, blk, jac=True, gamma=False):
    """Phi = d . d (target C^2; Haug eq. 9.2.9, spherical-spherical)."""
    d, dd, si, sj = _point_diff(st, blk, gamma)
    out = {"phi": np.sum(d * d, axis=1)[:, None]}
    if jac:
        k = len(blk.bi)
        ji = np.zeros((k, 1, 7))
        jj = np.zeros((k, 1, 7))
        ji[:, 0, :3] = -2 * d
        jj[:, 0, :3] = 2 * d
        ji[:, 0, 3:] = -2 * np.einsum("ki,kij->kj", d, si.jac)
        jj[:, 0, 3:] = 2 * np.einsum("ki,kij->kj", d, sj.jac)
        out["ji"], out["jj"] = ji, jj
    if gamma:
        g = -2 * (np.sum(d * (sj.bdot - si.bdot), 1) + np.sum(dd * dd, 1))
        out["gamma"] = g[:, None]
    return out


def angle(st, blk, jac=True, gamma=False, t=0.0):
    """Relative rotation theta from g_i to g_j about f_i, minus its target f(t), wrapped to
    (-pi, pi] (Haug Sec. 9.5: rotational driver).  c = g_i.g_j, s = h_i.g_j are dot-1 terms;
    theta = atan2(s, c) without any history, since the target unwraps it."""
    gi = Vec(st, blk.bi, blk.vecs["gi~T"], gamma)
    hi = Vec(st, blk.bi, blk.vecs["hi~T"], gamma)
    gj = Vec(st, blk.bj, blk.vecs["gj~T"], gamma)
    c = np.sum(gi.val * gj.val, 1)
    s = np.sum(hi.val * gj.val, 1)
    f = np.array([fn(t) for _, fn, _ in blk.funcs]) if blk.funcs else blk.c_const[:, 0]
    cf, sf = np.cos(f), np.sin(f)
    out = {"phi": np.arctan2(s * cf - c * sf, c * cf + s * sf)[:, None]}
    rho = c * c + s * s
    if jac:
        k = len(blk.bi)
        ji = np.zeros((k, 1, 7))
        jj = np.zeros((k, 1, 7))
        ci = np.einsum("ki,kij->kj", gj.val, gi.jac)
        si_ = np.einsum("ki,kij->kj", gj.val, hi.jac)
        cj = np.einsum("ki,kij->kj", gi.val, gj.jac)
        sj_ = np.einsum("ki,kij->kj", hi.val, gj.jac)
        ji[:, 0, 3:] = (c[:, None] * si_ - s[:, None] * ci) / rho[:, None]
        jj[:, 0, 3:] = (c[:, None] * sj_ - s[:, None] * cj) / rho[:, None]
        out["ji"], out["jj"] = ji, jj
    if gamma:
        gc = -(np.sum(gi.val * gj.bdot, 1) + np.sum(gj.val * gi.bdot, 1)
               + 2 * np.sum(gi.vel * gj.vel, 1))
        gs = -(np.sum(hi.val * gj.bdot, 1) + np.sum(gj.val * hi.bdot, 1)
               + 2 * np.sum(hi.vel * gj.vel, 1))
        cd = np.sum(gi.vel * gj.val + gi.val * gj.vel, 1)
        sd = np.sum(hi.vel * gj.val + hi.val * gj.vel, 1)
        thd = (c * sd - s * cd) / rho
        rhod = 2 * (c * cd + s * sd)
        out["gamma"] = ((c * gs - s * gc) / rho + thd * rhod / rho)[:, None]
    return out


def absolute(st, blk, jac=True, gamma=False):
    """Phi = (r + A s')[axis] - c(t): a global coordinate of a body point (Haug Sec. 9.5)."""
    s = Vec(st, blk.bi, blk.vecs["s~T"], gamma)
    ax = blk.vecs["axis"]
    k = len(blk.bi)
    kk = np.arange(k)
    out = {"phi": (st.r[blk.bi] + s.val)[kk, ax][:, None]}
    if jac:
        ji = np.zeros((k, 1, 7))
        ji[kk, 0, ax] = 1.0
        ji[:, 0, 3:] = s.jac[kk, ax, :]
        out["ji"], out["jj"] = ji, None
    if gamma:
        out["gamma"] = -s.bdot[kk, ax][:, None]
    return out


def ground(st, blk, jac=True, gamma=False):
    """The book's ground constraint: r = r0 and (e1, e2, e3) = e0' (6 equations)."""
    b = blk.bi
    k = len(b)
    out = {"phi": np.concatenate([st.r[b], st.p[b][:, 1:]], axis=1)}
    if jac:
        ji = np.zeros((k, 6, 7))
        ji[:, :3, :3] = np.eye(3)
        ji[:, 3:, 4:] = np.eye(3)
        out["ji"], out["jj"] = ji, None
    if gamma:
        out["gamma"] = np.zeros((k, 6))
    return out


def normalization(st, blk, jac=True, gamma=False):
    """Euler-parameter normalisation p^T p - 1 = 0 (Haug eq. 6.3.2), one row per body."""
    p = st.p[blk.bi]
    k = len(blk.bi)
    out = {"phi": np.sum(p * p, 1)[:, None]}
    if jac:
        ji = np.zeros((k, 1, 7))
        ji[:, 0, 3:] = 2 * p
        out["ji"], out["jj"] = ji, None
    if gamma:
        pd = st.pd[blk.bi]
        out["gamma"] = (-2 * np.sum(pd * pd, 1))[:, None]
    return out


KERNELS = {
    "dot1": (dot1, 1),
    "dot2": (dot2, 1),
    "spherical": (spherical, 3),
    "distance": (distance, 1),
    "angle": (angle, 1),
    "absolute": (absolute, 1),
    "ground": (ground, 6),
    "normalization": (normalization, 1),
}
"""kernel name -> (function, equations per constraint)."""
