"""Built-in force elements (registered in FORCES on import).

Sign conventions (docs/deck.md, forces):

- ``tsda``: tension f > 0 pulls P_i and P_j together; f = k (l - L0) + c ldot - actuator,
  so a positive actuator pushes the points apart (Haug Sec. 11.3).
- ``rsda``: torque n > 0 opposes theta growing; n = k (theta - theta0) + c thetadot -
  actuator, so a positive actuator turns body j forward about the joint axis f_i.  The
  torque axis is the exact gradient of theta(q) (= f_i where the joint holds), so the spring
  stays conservative even when the constraints drift.
- ``force``/``torque``: the vector acts on the (last listed) body; a torque pair puts
  the opposite torque on the first body.

Each element compiles its body-fixed vectors once (``from_spec``); ``apply`` only adds to the
accumulators.  Laws may use ``t``, the element's own variables (tsda: l, ldot; rsda: theta,
thetadot) and the measures the element declares (:mod:`mbsim.forces.measures`).
"""

from __future__ import annotations

import numpy as np

from mbsim.errors import DeckError
from mbsim.forces import register
from mbsim.forces.base import ForceElement
from mbsim.forces.laws import compile_law, compile_optional
from mbsim.forces.measures import Angle, compile_measures
from mbsim.model import joint_frame
from mbsim.rotations import skew as rot_skew


def _body_indices(spec, body_index, n: int) -> tuple[int, ...]:
    if len(spec.bodies) != n:
        raise DeckError(
            f"a {spec.type} force needs {n} bod{'y' if n == 1 else 'ies'}, got {list(spec.bodies)}",
            spec.where.child("bodies"),
        )
    out = []
    for name in spec.bodies:
        if name not in body_index:
            raise DeckError(f"unknown body {name!r}", spec.where.child("bodies"))
        out.append(body_index[name])
    return tuple(out)


def _local_point(spec, body: str) -> np.ndarray:
    ps = spec.points.get(body)
    s = np.zeros(3) if ps is None else np.array(ps.P, dtype=float)
    s.setflags(write=False)
    return s


def _skew(s: np.ndarray) -> np.ndarray:
    S = rot_skew(s)
    S.setflags(write=False)
    return S


def _measures(spec, body_index, own: tuple[str, ...]) -> dict:
    measures = compile_measures(spec.data.get("measures"), body_index, spec.where)
    for name in measures:
        if name in own or name == "t":
            raise DeckError(
                f"measure name {name!r} is taken by the {spec.type} element "
                f"(its own variables: t, {', '.join(own) or 'none'})",
                spec.where.child("measures").child(name),
            )
    return measures


def _vector_law(spec, measures: dict, unit: str):
    """(constant vector or None, list of 3 laws or None, (law, unit direction) or None)."""
    d, where = spec.data, spec.where
    single = d.get("law") is not None and not isinstance(d["law"], (list, tuple))
    if d.get("direction") is not None and not single:
        raise DeckError(
            "direction goes with a single law (law: '...'), not with a vector or 3 laws",
            where.child("direction"),
        )
    if d.get("vector") is not None:
        if d.get("law") is not None:
            raise DeckError("give exactly one of vector, law", where.child("law"))
        v = np.array(d["vector"], dtype=float).reshape(3)
        v.setflags(write=False)
        return v, None, None
    law = d.get("law")
    if law is None:
        raise DeckError(f"a {spec.type} needs a vector ({unit}) or a law", where)
    if isinstance(law, (list, tuple)):
        if len(law) != 3:
            raise DeckError(f"expected 3 laws, got {len(law)}", where.child("law"))
        laws = [compile_law(x, where.child(f"law[{k}]"), measures) for k, x in enumerate(law)]
        if all(x.is_constant for x in laws):  # a constant vector after all
            v = np.array([x.value for x in laws])
            v.setflags(write=False)
            return v, None, None
        return None, laws, None
    if d.get("direction") is None:
        raise DeckError(
            "a single law needs a direction: [x, y, z] (or give a list of 3 laws)",
            where.child("law"),
        )
    u = np.array(d["direction"], dtype=float).reshape(3)
    if not np.linalg.norm(u) > 0:
        raise DeckError("the direction must not be the zero vector", where.child("direction"))
    u = u / np.linalg.norm(u)
    u.setflags(write=False)
    return None, None, (compile_law(law, where.child("law"), measures), u)


def switching_or_plain(el, spec):
    """The element, or its hybrid form when its law switches on the sign of a velocity
    measure (:mod:`mbsim.forces.switching`)."""
    from mbsim.forces.switching import make_switching

    return make_switching(el, spec.where.child("law"))


class _Element(ForceElement):
    def __repr__(self) -> str:
        return f"<{self.type} {self.name}>"


class _VectorLoad(_Element):
    """Shared by force and torque: a vector from a constant, 3 laws or a law times a
    direction, given in the global frame or a body frame."""

    vec = laws = scaled = None
    local = False

    def _setup_vector(self, spec, body_index, unit):
        measures = _measures(spec, body_index, ())
        self.vec, self.laws, self.scaled = _vector_law(spec, measures, unit)
        frame = spec.data.get("frame", "global")
        if frame not in ("global", "local"):
            raise DeckError(
                f"expected frame global | local, got {frame!r}", spec.where.child("frame")
            )
        self.local = frame == "local"

    def vector(self, st, t) -> np.ndarray:
        """(3,) the vector in the frame it is given in."""
        if self.vec is not None:
            return self.vec
        if self.laws is not None:
            return np.array([law(st, t) for law in self.laws])
        law, u = self.scaled
        return law(st, t) * u


@register
class PointForce(_VectorLoad):
    type = "force"
    description = "force at a body point: constant vector or laws; global or follower (local)"

    @classmethod
    def from_spec(cls, spec, body_index):
        el = cls()
        (el.b,) = _body_indices(spec, body_index, 1)
        el.s = _local_point(spec, spec.bodies[0])
        el.S = _skew(el.s)  # s' x (np.cross costs ~40 us on 3-vectors, a matvec ~1 us)
        el._setup_vector(spec, body_index, "N")
        return switching_or_plain(el, spec)

    def apply(self, st, t, F, n_local):
        self.add_vector(st, self.vector(st, t), F, n_local)

    def add_vector(self, st, v, F, n_local):
        """Add the force ``v`` (in the frame it is given in) at the body point."""
        A = st.A[self.b]
        if self.local:  # follower force: body-fixed direction
            F[self.b] += A @ v
            n_local[self.b] += self.S @ v
        else:
            F[self.b] += v
            n_local[self.b] += self.S @ (A.T @ v)

    def potential(self, st):
        """V = -F . (r + A s') for a constant global force; 0 otherwise (not conservative
        in general)."""
        if self.vec is None or self.local:
            return 0.0
        b = self.b
        return -float(self.vec @ (st.r[b] + st.A[b] @ self.s))

    def channels(self, st, t):
        v = self.vector(st, t)
        return {"force": (st.A[self.b] @ v if self.local else np.array(v), "N")}


@register
class Torque(_VectorLoad):
    type = "torque"
    description = (
        "torque on a body, or equal and opposite on a pair [i, j] (+ on j); "
        "constant or laws; global or body frame (of the first body)"
    )

    @classmethod
    def from_spec(cls, spec, body_index):
        el = cls()
        n = len(spec.bodies)
        if n not in (1, 2):
            raise DeckError(
                f"a torque acts on one body or a pair, got {list(spec.bodies)}",
                spec.where.child("bodies"),
            )
        idx = _body_indices(spec, body_index, n)
        el.bi, el.bj = (idx[0], idx[1]) if n == 2 else (-1, idx[0])
        el._setup_vector(spec, body_index, "N m")
        return switching_or_plain(el, spec)

    def torque_global(self, st, t, v=None) -> np.ndarray:
        """(3,) torque on body j (the body, for one body), global frame; ``v``: the vector
        in the frame it is given in (default: the law's at (st, t))."""
        v = self.vector(st, t) if v is None else v
        if not self.local:
            return v
        return st.A[self.bi if self.bi >= 0 else self.bj] @ v

    def apply(self, st, t, F, n_local):
        self.add_vector(st, self.vector(st, t), F, n_local)

    def add_vector(self, st, v, F, n_local):
        """Add the torque ``v`` (in the frame it is given in)."""
        T = self.torque_global(st, None, v)
        n_local[self.bj] += st.A[self.bj].T @ T
        if self.bi >= 0:
            n_local[self.bi] -= st.A[self.bi].T @ T

    def channels(self, st, t):
        return {"torque": (np.array(self.torque_global(st, t)), "N m")}


@register
class TSDA(_Element):
    type = "tsda"
    description = (
        "translational spring-damper-actuator between two body points, "
        "f = k (l - L0) + c ldot - actuator (Haug Sec. 11.3)"
    )
    own = ("l", "ldot")

    @classmethod
    def from_spec(cls, spec, body_index):
        el = cls()
        d, where = spec.data, spec.where
        el.bi, el.bj = _body_indices(spec, body_index, 2)
        el.si, el.sj = (_local_point(spec, b) for b in spec.bodies)
        el.Si, el.Sj = _skew(el.si), _skew(el.sj)
        el.k, el.c = float(d.get("k", 0.0)), float(d.get("c", 0.0))
        el.L0 = float(d.get("L0", 0.0))
        measures = _measures(spec, body_index, cls.own)
        el.law = compile_optional(d, "law", where, measures, cls.own)
        el.actuator = compile_optional(d, "actuator", where, measures, cls.own)
        if el.law is not None and (el.k or el.c):
            raise DeckError(
                "give either a law (the whole tension) or k and c, not both", where.child("law")
            )
        return el

    def state(self, st, t):
        """(l, ldot, f, u): length, its rate, tension and unit vector P_i -> P_j."""
        bi, bj = self.bi, self.bj
        Ai, Aj = st.A[bi], st.A[bj]
        d = (st.r[bj] + Aj @ self.sj) - (st.r[bi] + Ai @ self.si)
        l = float(np.sqrt(d @ d))
        u = d / l if l > 0 else np.zeros(3)  # coincident points: no direction, no force
        wi, wj = st.omega_local[bi], st.omega_local[bj]
        v = (st.rd[bj] - Aj @ (self.Sj @ wj)) - (
            st.rd[bi] - Ai @ (self.Si @ wi)
        )  # w' x s' = -s'~ w'
        ldot = float(u @ v)
        own = {"l": l, "ldot": ldot}
        if self.law is not None:
            f = self.law(st, t, own)
        else:
            f = self.k * (l - self.L0) + self.c * ldot
        if self.actuator is not None:
            f -= self.actuator(st, t, own)
        return l, ldot, f, u

    def apply(self, st, t, F, n_local):
        _, _, f, u = self.state(st, t)
        fu = f * u  # on P_i towards P_j (tension), the opposite on P_j
        bi, bj = self.bi, self.bj
        F[bi] += fu
        F[bj] -= fu
        n_local[bi] += self.Si @ (st.A[bi].T @ fu)
        n_local[bj] -= self.Sj @ (st.A[bj].T @ fu)

    def potential(self, st):
        """k (l - L0)^2 / 2 (the law and the actuator are not counted)."""
        if self.law is not None or not self.k:
            return 0.0
        d = (st.r[self.bj] + st.A[self.bj] @ self.sj) - (st.r[self.bi] + st.A[self.bi] @ self.si)
        return 0.5 * self.k * (float(np.sqrt(d @ d)) - self.L0) ** 2

    def channels(self, st, t):
        l, ldot, f, _ = self.state(st, t)
        return {"length": (l, "m"), "velocity": (ldot, "m/s"), "force": (f, "N")}

    def _lengths(self, states):
        """(d (nt, 3) P_i -> P_j, l (nt,)) at every output of ``states`` (core.States)."""
        bi, bj = self.bi, self.bj
        d = (states.r[:, bj] + states.A[:, bj] @ self.sj) - (
            states.r[:, bi] + states.A[:, bi] @ self.si)
        return d, np.sqrt(np.einsum("ti,ti->t", d, d))

    def channels_many(self, states, t):
        """:meth:`state` over all outputs in array code; with a law or an actuator (scalar
        code) output by output."""
        if self.law is not None or self.actuator is not None:
            return super().channels_many(states, t)
        bi, bj = self.bi, self.bj
        d, l = self._lengths(states)
        pos = l > 0  # coincident points: no direction, no force
        u = np.zeros_like(d)
        u[pos] = d[pos] / l[pos, None]
        Ai, Aj = states.A[:, bi], states.A[:, bj]
        wi, wj = states.omega_local[:, bi], states.omega_local[:, bj]
        v = (states.rd[:, bj] - np.einsum("tij,tj->ti", Aj, wj @ self.Sj.T)) - (
            states.rd[:, bi] - np.einsum("tij,tj->ti", Ai, wi @ self.Si.T))
        ldot = np.einsum("ti,ti->t", u, v)
        f = self.k * (l - self.L0) + self.c * ldot
        return {"length": (l, "m"), "velocity": (ldot, "m/s"), "force": (f, "N")}

    def potential_many(self, states):
        if self.law is not None or not self.k:
            return np.zeros(len(states))
        return 0.5 * self.k * (self._lengths(states)[1] - self.L0) ** 2


@register
class RSDA(_Element):
    type = "rsda"
    description = (
        "rotational spring-damper-actuator about a revolute joint's axis, "
        "n = k (theta - theta0) + c thetadot - actuator (Haug Sec. 11.3)"
    )
    own = ("theta", "thetadot")

    @classmethod
    def from_spec(cls, spec, body_index):
        el = cls()
        d, where = spec.data, spec.where
        bi, bj = _body_indices(spec, body_index, 2)
        names = spec.bodies
        if names[0] not in spec.points or names[1] not in spec.points:
            raise DeckError(
                f"the rsda needs the frames of joint {d.get('joint')!r} on both bodies",
                where.child("joint"),
            )
        el.k, el.c = float(d.get("k", 0.0)), float(d.get("c", 0.0))
        el.theta0 = float(d.get("theta0", 0.0))
        el.angle = Angle(
            bi,
            bj,
            joint_frame(spec.points[names[0]]),
            joint_frame(spec.points[names[1]]),
            el.theta0,
        )
        el.bi, el.bj = bi, bj
        measures = _measures(spec, body_index, cls.own)
        el.law = compile_optional(d, "law", where, measures, cls.own)
        el.actuator = compile_optional(d, "actuator", where, measures, cls.own)
        if el.law is not None and (el.k or el.c):
            raise DeckError(
                "give either a law (the whole torque) or k and c, not both", where.child("law")
            )
        return el

    def state(self, st, t):
        """(theta, thetadot, n, a): angle (within pi of theta0), rate, torque, axis (global)."""
        theta, a = self.angle.terms(st)
        thd = self.angle.rate(st, a)
        own = {"theta": theta, "thetadot": thd}
        if self.law is not None:
            n = self.law(st, t, own)
        else:
            n = self.k * (theta - self.theta0) + self.c * thd
        if self.actuator is not None:
            n -= self.actuator(st, t, own)
        return theta, thd, n, a

    def apply(self, st, t, F, n_local):
        _, _, n, a = self.state(st, t)
        na = n * a  # -n a on body j, +n a on body i: exact gradient of k (theta - theta0)^2/2
        n_local[self.bj] -= st.A[self.bj].T @ na
        n_local[self.bi] += st.A[self.bi].T @ na

    def potential(self, st):
        """k (theta - theta0)^2 / 2, theta within pi of theta0 (see the measures module)."""
        if self.law is not None or not self.k:
            return 0.0
        theta, _ = self.angle.terms(st)
        return 0.5 * self.k * (theta - self.theta0) ** 2

    def channels(self, st, t):
        theta, thd, n, _ = self.state(st, t)
        return {"angle": (theta, "rad"), "rate": (thd, "rad/s"), "torque": (n, "N m")}
