"""Independent reference solutions for the accuracy tests of issue 11 (no mbsim dynamics).

Every reference is derived here from first principles and integrated with scipy's DOP853 at
rtol 1e-13 (or written in closed form), so that it can judge mbsim's own error estimate:

- :func:`free_body`: torque-free rigid body, Euler's equations J w' + w x (J w) = 0 in the
  body frame plus the Euler-parameter kinematics p' = 1/2 p (x) (0, w') (Haug eq. 6.3.19 in
  quaternion form); the centroid moves uniformly.
- :func:`heavy_top`: rigid body about a fixed point under gravity, Euler's equations about
  the pivot with the gravity torque s' x A^T m g in the body frame.
- :func:`pendulum`: planar compound pendulum released from rest, exact solution
  theta = 2 asin(k sn(w0 t + K(k), k)), k = sin(theta0 / 2) (Jacobi elliptic functions).
- :func:`slider_crank`: the free spatial slider-crank of tests/helpers.py reduced to its one
  degree of freedom (crank angle) with sympy: Lagrange's equation
  m(phi) phi'' + m'(phi) phi'^2 / 2 + V'(phi) = 0.
- :func:`parallel_fourbar`: N parallel cranks joined by a translating coupler (the multi-loop
  mechanism of issue 11), T = 1/2 (N I_pivot + M L^2) theta'^2.

Each returns ``{body name: (r (nt, 3), A (nt, 3, 3))}`` at the requested times; the helpers
:func:`position_error` and :func:`orientation_error` compare them with an mbsim Result.
The rotation algebra is written out again here on purpose (not imported from mbsim).
"""

from __future__ import annotations

import functools

import numpy as np
from scipy.integrate import solve_ivp
from scipy.special import ellipj, ellipk

RTOL, ATOL = 1e-13, 1e-15  # the references' own tolerances (error ~1e-12 relative)


# ----------------------------------------------------------------- rotation algebra


def rot(p):
    """Rotation matrix body -> global of unit Euler parameters p (..., 4) (Haug eq. 6.3.20):
    A = (e0^2 - e.e) I + 2 e e^T + 2 e0 e~; p is normalised first."""
    p = np.asarray(p, float)
    p = p / np.linalg.norm(p, axis=-1, keepdims=True)
    e0, e = p[..., 0], p[..., 1:]
    I = np.broadcast_to(np.eye(3), p.shape[:-1] + (3, 3))
    out = (e0 * e0 - (e * e).sum(-1))[..., None, None] * I
    out = out + 2 * e[..., :, None] * e[..., None, :]
    ex = np.zeros(p.shape[:-1] + (3, 3))
    ex[..., 0, 1], ex[..., 0, 2], ex[..., 1, 2] = -e[..., 2], e[..., 1], -e[..., 0]
    ex = ex - np.swapaxes(ex, -1, -2)
    return out + 2 * e0[..., None, None] * ex


def quat_mul(a, b):
    """Hamilton product a (x) b of quaternions (scalar first)."""
    a0, av, b0, bv = a[0], a[1:], b[0], b[1:]
    return np.concatenate([[a0 * b0 - av @ bv], a0 * bv + b0 * av + np.cross(av, bv)])


def omega_local(p, pd):
    """Body-frame angular velocity from Euler parameters and their rates:
    (0, w') = 2 conj(p) (x) p' (the inverse of p' = 1/2 p (x) (0, w'))."""
    conj = np.array([p[0], -p[1], -p[2], -p[3]])
    return 2 * quat_mul(conj, pd)[1:]


def rot_z(theta):
    """(nt, 3, 3) rotations about global z by theta (nt,)."""
    c, s = np.cos(theta), np.sin(theta)
    out = np.zeros(np.shape(theta) + (3, 3))
    out[..., 0, 0], out[..., 0, 1], out[..., 1, 0], out[..., 1, 1] = c, -s, s, c
    out[..., 2, 2] = 1.0
    return out


def rotation_angle(A_ref, A):
    """Angle (rad) of the rotation A_ref^T A, from ||A - A_ref||_F = 2 sqrt(2) sin(angle/2)
    (accurate for small angles, unlike arccos of the trace)."""
    d = np.linalg.norm(np.asarray(A) - A_ref, axis=(-2, -1)) / (2 * np.sqrt(2))
    return 2 * np.arcsin(np.clip(d, 0.0, 1.0))


def _rigid_body(J, w0, p0, t, torque=None):
    """Integrate Euler's equations J w' + w x (J w) = tau'(p) with p' = 1/2 p (x) (0, w').
    Returns (p (nt, 4) normalised, w' (nt, 3))."""
    J = np.asarray(J, float)

    def f(_, y):
        p, w = y[:4], y[4:]
        tau = np.zeros(3) if torque is None else torque(p)
        dw = (tau - np.cross(w, J * w)) / J
        dp = 0.5 * quat_mul(p, np.concatenate([[0.0], w]))
        return np.concatenate([dp, dw])

    y0 = np.concatenate([np.asarray(p0, float) / np.linalg.norm(p0), w0])
    sol = solve_ivp(f, (t[0], t[-1]), y0, t_eval=t, method="DOP853", rtol=RTOL, atol=ATOL)
    assert sol.success, sol.message
    p = sol.y[:4].T
    return p / np.linalg.norm(p, axis=1, keepdims=True), sol.y[4:].T


# ----------------------------------------------------------------- the references


def free_body(t, J, p0, pd0, r0, v0):
    """Torque-free body with principal moments J (3,) at its centroid: {"b": (r, A)}, plus
    the body-frame angular velocity under key "omega_local"."""
    t = np.asarray(t, float)
    p, w = _rigid_body(J, omega_local(np.asarray(p0, float), np.asarray(pd0, float)), p0, t)
    r = np.asarray(r0, float) + (t - t[0])[:, None] * np.asarray(v0, float)
    return {"b": (r, rot(p)), "omega_local": w}


def heavy_top(t, m, l, I1c, I3, g, p0, pd0, name="top"):
    """Symmetric top (centroidal moments I1c, I1c, I3, symmetry axis z') on a ball joint at
    the fixed pivot; the centroid is at s' = (0, 0, l) from the pivot; gravity -z.
    Euler's equations about the pivot: J_o = diag(I1c + m l^2, I1c + m l^2, I3),
    tau' = s' x (A^T (0, 0, -m g)).  Returns {name: (r, A)}; r = A s' (pivot at the origin)."""
    s = np.array([0.0, 0.0, l])
    J = np.array([I1c + m * l * l, I1c + m * l * l, I3])
    F = np.array([0.0, 0.0, -m * g])

    def torque(p):
        return np.cross(s, rot(p).T @ F)

    p0 = np.asarray(p0, float)
    p, w = _rigid_body(J, omega_local(p0, np.asarray(pd0, float)), p0, np.asarray(t, float),
                       torque)
    A = rot(p)
    return {name: (A @ s, A), "omega_local": w}


def pendulum_theta(t, theta0, omega0):
    """Exact libration from rest at theta0 (rad) of theta'' = -omega0^2 sin(theta):
    theta = 2 asin(k sn(omega0 t + K, k)), k = sin(theta0 / 2) (scipy's ellipj takes m = k^2)."""
    k = np.sin(theta0 / 2)
    K = ellipk(k * k)
    sn = ellipj(omega0 * np.asarray(t, float) + K, k * k)[0]
    return 2 * np.arcsin(k * sn)


def pendulum(t, theta0, L, m, Ic, g, name="bob"):
    """Compound pendulum: revolute about global z at the origin, centroid at distance L,
    gravity -y, theta from the downward vertical; omega0^2 = m g L / (Ic + m L^2).
    Returns {name: (r, A)} with r = L (sin theta, -cos theta, 0), A = Rz(theta)."""
    theta = pendulum_theta(t, theta0, np.sqrt(m * g * L / (Ic + m * L * L)))
    r = L * np.stack([np.sin(theta), -np.cos(theta), np.zeros_like(theta)], axis=1)
    return {name: (r, rot_z(theta)), "theta": theta}


def parallel_fourbar(t, theta0, thetad0, N, L, m_crank, I_crank, M, g, xs):
    """N parallel cranks (length L, pivots (x_i, 0, 0), rotation about z by theta, centroid
    at mid-length, centroidal moment I_crank about z) carrying a coupler of mass M that
    translates on a circle of radius L (centroid (mean x_i + L cos, L sin, 0)); gravity -y.

    T = 1/2 (N I_pivot + M L^2) theta'^2, I_pivot = I_crank + m_crank L^2 / 4;
    V = g sin(theta) (N m_crank L / 2 + M L), so
    theta'' = -g cos(theta) (N m_crank L / 2 + M L) / (N I_pivot + M L^2).
    Returns {"crank<i>": (r, A), "coupler": (r, A), "theta": theta, "thetad": theta'}."""
    t = np.asarray(t, float)
    mass = N * (I_crank + m_crank * L * L / 4) + M * L * L
    grav = g * (N * m_crank * L / 2 + M * L)

    sol = solve_ivp(lambda _, y: [y[1], -grav * np.cos(y[0]) / mass], (t[0], t[-1]),
                    [theta0, thetad0], t_eval=t, method="DOP853", rtol=RTOL, atol=ATOL)
    assert sol.success, sol.message
    th, thd = sol.y
    c, s, z = np.cos(th), np.sin(th), np.zeros_like(th)
    A = rot_z(th)
    out = {f"crank{i}": (np.stack([x + L / 2 * c, L / 2 * s, z], axis=1), A)
           for i, x in enumerate(xs)}
    out["coupler"] = (np.stack([np.mean(xs) + L * c, L * s, z], axis=1),
                      np.broadcast_to(np.eye(3), (len(t), 3, 3)))
    out["theta"], out["thetad"] = th, thd
    out["energy"] = 0.5 * mass * thd**2 + grav * np.sin(th)
    return out


# ---------------------------------------------------------------- slider-crank reduction


@functools.lru_cache(maxsize=4)
def _slider_crank_functions(ell, m_rod, J_rod, m_slider, J_crank_x, g, sign):
    """Lambdified m(phi), m'(phi), V(phi), V'(phi) and body poses of the free slider-crank
    (geometry of tests/helpers.py:slider_crank_spec, reference geometry §1), derived with
    sympy.  phi: the crank's rotation about +x (A_crank = Rx(phi)); crank pin
    B = (0, 0.1, 0.12) + Rx(phi) (0, 0.08, 0); slider C = (x, 0, 0) with |B - C| = ell,
    x > 0; rod y' = (B - C) / ell; the universal at C keeps rod x' perpendicular to global
    x: x' = sign (X x y') / |X x y'|, z' = x' x y'; gravity -z."""
    import sympy as sp

    phi = sp.symbols("phi", real=True)
    B = sp.Matrix([0, sp.Rational(1, 10) + sp.Rational(8, 100) * sp.cos(phi),
                   sp.Rational(12, 100) + sp.Rational(8, 100) * sp.sin(phi)])
    x = sp.sqrt(sp.nsimplify(ell) ** 2 - B[1] ** 2 - B[2] ** 2)
    C = sp.Matrix([x, 0, 0])
    y = (B - C) / sp.nsimplify(ell)
    X = sp.Matrix([1, 0, 0])
    xa = X.cross(y)
    xa = sign * xa / sp.sqrt(xa.dot(xa))
    za = xa.cross(y)
    A = sp.Matrix.hstack(xa, y, za)
    r_rod = (B + C) / 2
    dr = r_rod.diff(phi)
    W = A.diff(phi) * A.T  # skew(omega) / phi'  (A' = omega~ A)
    w = sp.Matrix([W[2, 1], W[0, 2], W[1, 0]])
    Jg = A * sp.diag(*J_rod) * A.T
    mass = (J_crank_x + m_rod * dr.dot(dr) + (w.T * Jg * w)[0, 0]
            + m_slider * x.diff(phi) ** 2)
    V = m_rod * g * r_rod[2]
    # one lambdified function for the right-hand side (common subexpressions shared), the
    # poses only at the output times
    rhs = sp.lambdify(phi, [mass, mass.diff(phi), V, V.diff(phi)], "math", cse=True)
    pose = sp.lambdify(phi, [r_rod, A, x], "numpy", cse=True)
    return rhs, pose


def slider_crank(t, phi0, phid0, ell=0.3, m_rod=0.5, J_rod=(0.004, 0.0004, 0.004),
                 m_slider=2.0, J_crank_x=1e-4, g=9.81, A_rod0=None):
    """The free spatial slider-crank by its exact one-DOF reduction.  phi0, phid0: crank
    rotation about +x and its rate; A_rod0: the rod's initial orientation, which picks the
    branch of x' (+-); returns {"crank", "rod", "slider": (r, A)} and "energy" (T + V)."""
    sign = 1
    if A_rod0 is not None:
        _, pose = _slider_crank_functions(ell, m_rod, tuple(J_rod), m_slider, J_crank_x, g, 1)
        A_try = np.array(pose(phi0)[1], float)
        sign = 1 if np.sum(A_try[:, 0] * np.asarray(A_rod0)[:, 0]) > 0 else -1
    rhs_f, pose = _slider_crank_functions(ell, m_rod, tuple(J_rod), m_slider, J_crank_x, g,
                                          sign)

    def rhs(_, y):
        ph, phd = y
        m, dm, _, dV = rhs_f(ph)
        return [phd, -(0.5 * dm * phd * phd + dV) / m]

    t = np.asarray(t, float)
    sol = solve_ivp(rhs, (t[0], t[-1]), [phi0, phid0], t_eval=t, method="DOP853", rtol=RTOL,
                    atol=ATOL)
    assert sol.success, sol.message
    ph, phd = sol.y
    nt = len(t)
    A_c = np.zeros((nt, 3, 3))
    A_c[:, 0, 0] = 1.0
    A_c[:, 1, 1], A_c[:, 1, 2], A_c[:, 2, 1], A_c[:, 2, 2] = (np.cos(ph), -np.sin(ph),
                                                              np.sin(ph), np.cos(ph))
    r_c = np.broadcast_to([0.0, 0.1, 0.12], (nt, 3))
    poses = [pose(a) for a in ph]
    r_rod = np.array([np.ravel(np.array(r, float)) for r, _, _ in poses])
    A_rod = np.array([np.array(A, float) for _, A, _ in poses])
    x = np.array([float(x) for _, _, x in poses])
    r_s = np.stack([x, np.zeros(nt), np.zeros(nt)], axis=1)
    energy = np.array([0.5 * m * ad * ad + V for (m, _, V, _), ad in
                       zip(map(rhs_f, ph), phd)])
    return {"crank": (r_c, A_c), "rod": (r_rod, A_rod),
            "slider": (r_s, np.broadcast_to(np.eye(3), (nt, 3, 3))),
            "phi": ph, "phid": phd, "energy": energy}


# ----------------------------------------------------------------- comparing with mbsim


def bodies_of(ref):
    """The body entries (name -> (r, A)) of a reference dict."""
    return {k: v for k, v in ref.items() if isinstance(v, tuple)}


def position_error(res, ref):
    """(nt,) max over the reference's bodies of |r_mbsim - r_ref| (m) at each output time."""
    err = [np.linalg.norm(res.channel(f"bodies/{b}/r").data - r, axis=1)
           for b, (r, _) in bodies_of(ref).items()]
    return np.max(err, axis=0)


def orientation_error(res, ref):
    """(nt,) max over the reference's bodies of the angle (rad) between the computed and the
    reference orientation."""
    err = [rotation_angle(A, rot(res.channel(f"bodies/{b}/p").data))
           for b, (_, A) in bodies_of(ref).items()]
    return np.max(err, axis=0)
