"""The tire law one tire at a time on 3-vectors: the reference the C law (mbsim/fast/
kernels.c ``tire_law``, read by mbsim/forces/tire.py) is checked against.

This is the scalar implementation mbsim ran before the tires were evaluated together (then
compiled), kept here only for the tests (one implementation of the law in production)."""

from __future__ import annotations

import math

import numpy as np

from mbsim.rotations import skew

Z = np.array([0.0, 0.0, 1.0])


def smoothstep(x: float, x1: float) -> float:
    """0 at x <= 0, 1 at x >= x1, 3 s^2 - 2 s^3 between (C1)."""
    if x <= 0.0:
        return 0.0
    if x >= x1:
        return 1.0
    s = x / x1
    return s * s * (3.0 - 2.0 * s)


def slip_angle(v_fwd: float, v_lat: float) -> float:
    """alpha = atan2(v_lat, |v_fwd|) (rad): Haug eq. 12.5.1 in the tire's heading frame."""
    return math.atan2(v_lat, abs(v_fwd))


def tire_state(el, st) -> dict:
    """Everything tire ``el`` computes at state ``st`` (symbols: mbsim/forces/tire.py)."""
    b = el.b
    A, r = st.A[b], st.r[b]
    P = r + A @ el.s
    h = float(P[2])
    sc = A.T @ (P - h * Z - r)  # contact point, body frame
    v = st.rd[b] - A @ (skew(sc) @ st.omega_local[b])  # w x s = -s~ w (body frame)
    u = A @ el.fwd
    un = math.hypot(u[0], u[1])
    u = np.array([u[0] / un, u[1] / un, 0.0]) if un > 1e-12 else np.array([0.0, 1.0, 0.0])
    lat = np.array([u[1], -u[0], 0.0])  # u x z
    v_fwd, v_lat = float(u @ v), float(lat @ v)
    alpha = slip_angle(v_fwd, v_lat)
    defl = el.radius - h
    f_ver = max(0.0, el.kt * defl - el.c * float(v[2])) if defl > 0 else 0.0
    limit = el.mu * f_ver
    f_lin = el.c_alpha * alpha
    saturated = defl > 0 and f_lin != 0.0 and abs(f_lin) >= limit
    w = smoothstep(math.hypot(v_fwd, v_lat), el.v_min)
    f_lat = w * min(max(f_lin, -limit), limit)
    f_roll = el.rolling * f_ver * min(max(v_fwd / el.v_min, -1.0), 1.0)
    F = f_ver * Z - f_lat * lat - f_roll * u
    n_local = skew(sc) @ (A.T @ F)
    return dict(F=F, n_local=n_local, sc=sc, F_ver=f_ver, F_lat=f_lat, F_roll=f_roll,
                alpha=alpha, saturated=float(saturated), deflection=defl, v=v, u=u,
                speed=math.hypot(v_fwd, v_lat))  # fmt: skip


VECTORS = ("F", "n_local", "sc", "v", "u")
SCALARS = ("F_ver", "F_lat", "F_roll", "alpha", "saturated", "deflection", "speed")
REL = 1e-12  # of each quantity's scale: forces |F|, moments |F| x max(1, |sc|), the rest 1


def assert_matches(got, ref, label="got"):
    """Every quantity of :func:`tire_state` in ``got`` against ``ref`` (the same keys, arrays
    of any equal shapes) within REL of its scale."""
    scale = np.abs(ref["F"]).max()
    lever = max(1.0, np.abs(ref["sc"]).max())
    bounds = {"F": scale, "F_ver": scale, "F_lat": scale, "F_roll": scale,
              "n_local": scale * lever}  # fmt: skip
    for key in VECTORS + SCALARS:
        bound = REL * bounds.get(key, 1.0)
        err = np.abs(np.asarray(got[key]) - ref[key]).max()
        assert err <= bound, f"{key}: {label} - reference = {err:.3g} > {bound:.3g}"
