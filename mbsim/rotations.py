"""Euler-parameter algebra (Haug 1989, Sec. 6.3 and 9.3), batched over leading axes.

Every function accepts a single Euler-parameter vector p = (e0, e1, e2, e3) of shape (4,)
or a stack of shape (k, 4), and returns the matching (3, 3) / (k, 3, 3) etc.
"""

from __future__ import annotations

import numpy as np


def skew(a: np.ndarray) -> np.ndarray:
    """Skew-symmetric cross-product matrix: skew(a) @ b = a x b. (…, 3) -> (…, 3, 3)."""
    a = np.asarray(a, dtype=float)
    out = np.zeros(a.shape[:-1] + (3, 3))
    out[..., 0, 1] = -a[..., 2]
    out[..., 0, 2] = a[..., 1]
    out[..., 1, 0] = a[..., 2]
    out[..., 1, 2] = -a[..., 0]
    out[..., 2, 0] = -a[..., 1]
    out[..., 2, 1] = a[..., 0]
    return out


def A(p: np.ndarray) -> np.ndarray:
    """Rotation matrix body -> global (Haug eq. 6.3.20), written in the homogeneous form
    A = (e0^2 - e^T e) I + 2 e e^T + 2 e0 e~, which equals Haug's (2 e0^2 - 1) I + 2 (e e^T + e0 e~)
    on |p| = 1.  Homogeneous, A(p) a' is a quadratic form in p, so its derivative B(p, a') is
    bilinear in (p, a') and A(p) a' = B(p, a') p / 2: one precomputed tensor contraction gives
    both (see :func:`B_tensor`).  The normalisation constraint keeps |p| = 1 at every solution.
    """
    p = np.asarray(p, dtype=float)
    e0, e1, e2, e3 = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    out = np.empty(p.shape[:-1] + (3, 3))
    d = e0 * e0 - e1 * e1 - e2 * e2 - e3 * e3
    out[..., 0, 0] = d + 2 * e1 * e1
    out[..., 1, 1] = d + 2 * e2 * e2
    out[..., 2, 2] = d + 2 * e3 * e3
    out[..., 0, 1] = 2 * (e1 * e2 - e0 * e3)
    out[..., 1, 0] = 2 * (e1 * e2 + e0 * e3)
    out[..., 0, 2] = 2 * (e1 * e3 + e0 * e2)
    out[..., 2, 0] = 2 * (e1 * e3 - e0 * e2)
    out[..., 1, 2] = 2 * (e2 * e3 - e0 * e1)
    out[..., 2, 1] = 2 * (e2 * e3 + e0 * e1)
    return out


def _quadratic_tensor() -> np.ndarray:
    """S (3, 4, 4, 3), symmetric in its middle axes, with (A(p) a')_i = S_ikml p_k p_m a_l."""
    S = np.zeros((3, 4, 4, 3))
    eye4 = np.eye(4)
    for k in range(4):
        for m in range(4):
            for l_ in range(3):
                # polarisation of the quadratic form: S_km = (Q(u+v) - Q(u-v)) / 4
                S[:, k, m, l_] = (A(eye4[k] + eye4[m]) - A(eye4[k] - eye4[m]))[:, l_] / 4.0
    return S


_S2 = 2.0 * _quadratic_tensor()  # B(p, a')_ik = _S2_ikml p_m a'_l


def B_tensor(a_local: np.ndarray) -> np.ndarray:
    """(…, 3, 4, 4) tensor T(a') with B(p, a') = T(a') p, precomputed once per body-fixed vector."""
    return np.einsum("ikml,...l->...ikm", _S2, np.asarray(a_local, dtype=float))


def G(p: np.ndarray) -> np.ndarray:
    """G(p) = [-e, -e~ + e0 I], (…, 3, 4): omega_local = 2 G(p) pd (Haug eq. 6.3.18)."""
    return np.asarray(p, dtype=float)[..., _G_INDEX] * _G_SIGN


# G(p) entry by entry: G[i, k] = _G_SIGN[i, k] * p[_G_INDEX[i, k]] (a gather and a product:
# the per-call cost of building G row by row was most of a small model's omega_local)
_G_INDEX = np.array([[1, 0, 3, 2], [2, 3, 0, 1], [3, 2, 1, 0]])
_G_SIGN = np.array([[-1.0, 1.0, 1.0, -1.0], [-1.0, -1.0, 1.0, 1.0], [-1.0, 1.0, -1.0, 1.0]])


def E(p: np.ndarray) -> np.ndarray:
    """E(p) = [-e, e~ + e0 I], (…, 3, 4): omega (global) = 2 E(p) pd (Haug eq. 6.3.17)."""
    p = np.asarray(p, dtype=float)
    e0, e1, e2, e3 = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    out = np.empty(p.shape[:-1] + (3, 4))
    out[..., 0, :] = np.stack([-e1, e0, -e3, e2], axis=-1)
    out[..., 1, :] = np.stack([-e2, e3, e0, -e1], axis=-1)
    out[..., 2, :] = np.stack([-e3, -e2, e1, e0], axis=-1)
    return out


def B(p: np.ndarray, a_local: np.ndarray) -> np.ndarray:
    """Exact partial derivative d(A(p) a')/dp, (…, 3, 4) (Haug eq. 9.3.14 on |p| = 1).

    Column e0 is 2 (e0 a' + e~ a'), the e block 2 ((e^T a') I + e a'^T - a' e^T - e0 a'~).
    B is linear in p, so d/dt(B(p, a')) = B(pd, a'), and A(p) a' = B(p, a') p / 2.
    """
    return np.einsum("...ikm,...m->...ik", B_tensor(a_local), np.asarray(p, dtype=float))


def normalize(p: np.ndarray) -> np.ndarray:
    p = np.asarray(p, dtype=float)
    return p / np.linalg.norm(p, axis=-1, keepdims=True)


def from_matrix(R: np.ndarray) -> np.ndarray:
    """Euler parameters of a rotation matrix (Shepperd's method, robust for any angle); e0 >= 0."""
    R = np.asarray(R, dtype=float)
    tr = np.trace(R)
    cands = np.array([tr, R[0, 0], R[1, 1], R[2, 2]])
    k = int(np.argmax(cands))
    if k == 0:
        e0 = 0.5 * np.sqrt(1 + tr)
        p = [e0, (R[2, 1] - R[1, 2]) / (4 * e0), (R[0, 2] - R[2, 0]) / (4 * e0),
             (R[1, 0] - R[0, 1]) / (4 * e0)]
    else:
        i = k - 1
        j, m = (i + 1) % 3, (i + 2) % 3
        ei = 0.5 * np.sqrt(1 + 2 * R[i, i] - tr)
        e = [0.0, 0.0, 0.0]
        e[i] = ei
        e[j] = (R[j, i] + R[i, j]) / (4 * ei)
        e[m] = (R[m, i] + R[i, m]) / (4 * ei)
        e0 = (R[m, j] - R[j, m]) / (4 * ei)
        p = [e0] + e
    p = np.array(p)
    return p if p[0] >= 0 else -p


def from_axis_angle(axis, angle: float) -> np.ndarray:
    """p = (cos(angle/2), sin(angle/2) u) for a rotation by `angle` about unit axis u (Haug
    eq. 6.3.5)."""
    u = np.asarray(axis, dtype=float)
    u = u / np.linalg.norm(u)
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * u])


def from_euler313(phi: float, theta: float, psi: float) -> np.ndarray:
    """Euler parameters of 3-1-3 Euler angles (radians): Rz(phi) Rx(theta) Rz(psi)."""
    c, s = np.cos, np.sin
    Rz1 = np.array([[c(phi), -s(phi), 0], [s(phi), c(phi), 0], [0, 0, 1]])
    Rx = np.array([[1, 0, 0], [0, c(theta), -s(theta)], [0, s(theta), c(theta)]])
    Rz2 = np.array([[c(psi), -s(psi), 0], [s(psi), c(psi), 0], [0, 0, 1]])
    return from_matrix(Rz1 @ Rx @ Rz2)


def omega_to_pd(p: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """pd from global angular velocity: pd = 1/2 E(p)^T omega (Haug eq. 6.3.27, |p| = 1)."""
    return 0.5 * np.einsum("...ji,...j->...i", E(p), omega)


def omega_local_to_pd(p: np.ndarray, omega_local: np.ndarray) -> np.ndarray:
    """pd from body-frame angular velocity: pd = 1/2 G(p)^T omega' (|p| = 1)."""
    return 0.5 * np.einsum("...ji,...j->...i", G(p), omega_local)


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(3,) a x b for two 3-vectors (np.cross costs ~20 us on 3-vectors, this ~2 us)."""
    return np.array(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )
