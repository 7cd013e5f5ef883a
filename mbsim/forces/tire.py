"""The ``tire`` force element: a vertical tire on a flat road z = 0 (Haug Sec. 12.5.1).

Haug's model (Eqs. 12.5.1-12.5.3 and the text around them):

- vertical force F_ver = k_t d, d = tire deflection from the spindle height above the road;
- lateral force F_lat = C_alpha alpha, at most mu F_ver in magnitude;
- slip angle alpha = psi - psi_v (12.5.1), tire heading psi = 2 acos(e0) (12.5.2), velocity
  angle psi_v = -atan(v_x / v_y) (12.5.3).

Written here so that it holds at any heading and at standstill (12.5.2 presumes the spindle
turns about z only and 12.5.3 loses the quadrant):

- heading u: the body-fixed ``forward`` axis (default y', the book's driving direction)
  projected on the road and normalised; lateral axis l = u x z (to the right of u);
- v: velocity of the body point at the contact point C (below the spindle on the road);
  v_fwd = u . v, v_lat = l . v;
- alpha = atan2(v_lat, |v_fwd|): equal to psi - psi_v (mod 2 pi) in forward motion, at every
  heading; in reverse the slip is measured from the backward direction, so the lateral force
  still opposes sideways sliding (Haug's angle would be near pi there);
- below the speed ``v_min`` the lateral force fades to zero (cubic smoothstep in the road
  speed |v_h|), so that it vanishes at standstill where alpha has no meaning;
- F_ver = max(0, k_t d + c d_dot) for d > 0, else 0 (no tension off the ground); ``c`` is an
  optional tire damping (the book has none);
- F_lat = w(|v_h|) clip(C_alpha alpha, -mu F_ver, mu F_ver); optional rolling resistance
  F_roll = f_r F_ver clip(v_fwd / v_min, -1, 1) against the forward motion.

The force F = F_ver z - F_lat l - F_roll u acts at C = P - h z (P the spindle point, h its
height): the lateral force at the road gives the roll moment a real tire gives.  Because the
slip uses the velocity of the point where the force acts, the lateral force never does
positive work (its power is -F_lat v_lat with F_lat of the sign of v_lat).

Channels: ``F_ver`` (N), ``F_lat`` (N, along -l), ``alpha`` (rad), ``saturated`` (1 where
|C_alpha alpha| >= mu F_ver on the ground, else 0), ``deflection`` (m), ``heading`` (psi of
eq. 12.5.2 in (-pi, pi], from global y about z, rad), ``speed`` (|v_h|, the road speed of the
contact point, m/s), ``force`` (global).
"""

from __future__ import annotations

import math

import numpy as np

from mbsim.errors import DeckError
from mbsim.forces import register
from mbsim.forces.elements import _body_indices, _Element, _local_point, _skew

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


@register
class Tire(_Element):
    type = "tire"
    description = (
        "vertical tire on the road z = 0: F_ver = k_t d, F_lat = C_alpha alpha <= mu F_ver "
        "(Haug Sec. 12.5.1)"
    )

    @classmethod
    def from_spec(cls, spec, body_index):
        el = cls()
        d, where = spec.data, spec.where
        (el.b,) = _body_indices(spec, body_index, 1)
        el.s = _local_point(spec, spec.bodies[0])  # spindle, body frame
        el.kt = float(d["kt"])
        el.radius = float(d["radius"])
        el.c = float(d.get("c", 0.0))
        el.c_alpha = float(d["c_alpha"])
        el.mu = float(d.get("mu", 0.8))
        el.rolling = float(d.get("rolling", 0.0))
        el.v_min = float(d.get("v_min", 0.5))
        fwd = np.array(d.get("forward", (0.0, 1.0, 0.0)), dtype=float)
        for key, value in (("kt", el.kt), ("radius", el.radius), ("v_min", el.v_min)):
            if not value > 0:
                raise DeckError(f"expected a positive {key}, got {value:g}", where.child(key))
        for key, value in (("c", el.c), ("c_alpha", el.c_alpha), ("mu", el.mu),
                           ("rolling", el.rolling)):  # fmt: skip
            if value < 0:
                raise DeckError(f"expected {key} >= 0, got {value:g}", where.child(key))
        if not np.linalg.norm(fwd) > 0:
            raise DeckError("the forward axis must not be the zero vector", where.child("forward"))
        el.fwd = fwd / np.linalg.norm(fwd)
        el.fwd.setflags(write=False)
        return el

    def state(self, st, t) -> dict:
        """Everything the tire computes at one state (see the module doc for the symbols)."""
        b = self.b
        A, r = st.A[b], st.r[b]
        P = r + A @ self.s
        h = float(P[2])
        sc = A.T @ (P - h * Z - r)  # contact point, body frame
        v = st.rd[b] - A @ (_skew(sc) @ st.omega_local[b])  # w x s = -s~ w (body frame)
        u = A @ self.fwd
        un = math.hypot(u[0], u[1])
        u = np.array([u[0] / un, u[1] / un, 0.0]) if un > 1e-12 else np.array([0.0, 1.0, 0.0])
        lat = np.array([u[1], -u[0], 0.0])  # u x z
        v_fwd, v_lat = float(u @ v), float(lat @ v)
        alpha = slip_angle(v_fwd, v_lat)
        defl = self.radius - h
        f_ver = max(0.0, self.kt * defl - self.c * float(v[2])) if defl > 0 else 0.0
        limit = self.mu * f_ver
        f_lin = self.c_alpha * alpha
        saturated = defl > 0 and f_lin != 0.0 and abs(f_lin) >= limit
        w = smoothstep(math.hypot(v_fwd, v_lat), self.v_min)
        f_lat = w * min(max(f_lin, -limit), limit)
        f_roll = self.rolling * f_ver * min(max(v_fwd / self.v_min, -1.0), 1.0)
        F = f_ver * Z - f_lat * lat - f_roll * u
        return dict(F=F, sc=sc, F_ver=f_ver, F_lat=f_lat, F_roll=f_roll, alpha=alpha,
                    saturated=float(saturated), deflection=defl, v=v, u=u,
                    speed=math.hypot(v_fwd, v_lat))  # fmt: skip

    def apply(self, st, t, F, n_local):
        s = self.state(st, t)
        b = self.b
        F[b] += s["F"]
        n_local[b] += _skew(s["sc"]) @ (st.A[b].T @ s["F"])

    def potential(self, st):
        """k_t d^2 / 2 on the ground (the damping, lateral and rolling forces are not counted)."""
        d = self.radius - float(st.r[self.b][2] + st.A[self.b][2] @ self.s)
        return 0.5 * self.kt * d * d if d > 0 else 0.0

    def state_many(self, states, t) -> dict:
        """:meth:`state` at every output of ``states`` (:class:`mbsim.core.States`) in array
        code: the same quantities with a leading time axis (F, sc, v, u (nt, 3); the rest
        (nt,))."""
        b = self.b
        A, r = states.A[:, b], states.r[:, b]
        P = r + A @ self.s
        h = P[:, 2]
        sc = np.einsum("tji,tj->ti", A, P - h[:, None] * Z - r)  # contact point, body frame
        v = states.rd[:, b] - np.einsum("tij,tj->ti", A, np.cross(sc, states.omega_local[:, b]))
        u = A @ self.fwd
        un = np.hypot(u[:, 0], u[:, 1])
        ok = un > 1e-12
        u = np.where(ok[:, None], np.stack([u[:, 0] / np.where(ok, un, 1.0),
                                            u[:, 1] / np.where(ok, un, 1.0),
                                            np.zeros_like(un)], axis=1), [0.0, 1.0, 0.0])
        lat = np.stack([u[:, 1], -u[:, 0], np.zeros_like(un)], axis=1)  # u x z
        v_fwd, v_lat = np.einsum("ti,ti->t", u, v), np.einsum("ti,ti->t", lat, v)
        alpha = np.arctan2(v_lat, np.abs(v_fwd))
        defl = self.radius - h
        ground = defl > 0
        f_ver = np.where(ground, np.maximum(0.0, self.kt * defl - self.c * v[:, 2]), 0.0)
        limit = self.mu * f_ver
        f_lin = self.c_alpha * alpha
        saturated = ground & (f_lin != 0.0) & (np.abs(f_lin) >= limit)
        speed = np.hypot(v_fwd, v_lat)
        x = np.clip(speed / self.v_min, 0.0, 1.0)
        w = x * x * (3.0 - 2.0 * x)  # smoothstep
        f_lat = w * np.minimum(np.maximum(f_lin, -limit), limit)
        f_roll = self.rolling * f_ver * np.clip(v_fwd / self.v_min, -1.0, 1.0)
        F = f_ver[:, None] * Z - f_lat[:, None] * lat - f_roll[:, None] * u
        return dict(F=F, sc=sc, F_ver=f_ver, F_lat=f_lat, F_roll=f_roll, alpha=alpha,
                    saturated=saturated.astype(float), deflection=defl, v=v, u=u,
                    speed=speed)  # fmt: skip

    def loads_many(self, states, t, F, n_local):
        """:meth:`apply` at every output: adds to F, n_local (nt, nb, 3)."""
        s = self.state_many(states, t)
        b = self.b
        F[:, b] += s["F"]
        n_local[:, b] += np.cross(s["sc"], np.einsum("tji,tj->ti", states.A[:, b], s["F"]))

    def potential_many(self, states):
        d = self.radius - (states.r[:, self.b, 2] + states.A[:, self.b, 2] @ self.s)
        return np.where(d > 0, 0.5 * self.kt * d * d, 0.0)

    def channels_many(self, states, t):
        s = self.state_many(states, t)
        return {
            "F_ver": (s["F_ver"], "N"),
            "F_lat": (s["F_lat"], "N"),
            "alpha": (s["alpha"], "rad"),
            "saturated": (s["saturated"], ""),
            "deflection": (s["deflection"], "m"),
            "heading": (np.arctan2(-s["u"][:, 0], s["u"][:, 1]), "rad"),
            "speed": (s["speed"], "m/s"),
            "force": (s["F"], "N"),
        }

    def channels(self, st, t):
        s = self.state(st, t)
        return {
            "F_ver": (s["F_ver"], "N"),
            "F_lat": (s["F_lat"], "N"),
            "alpha": (s["alpha"], "rad"),
            "saturated": (s["saturated"], ""),
            "deflection": (s["deflection"], "m"),
            "heading": (math.atan2(-s["u"][0], s["u"][1]), "rad"),
            "speed": (s["speed"], "m/s"),
            "force": (s["F"], "N"),
        }
