"""Named measures: scalar quantities of the motion that force laws may use by name.

A force element may declare ``measures: {name: {type: ..., ...}}``; its expression laws then
use those names besides ``t`` (see :mod:`mbsim.forces.laws`).  Each type is one small class:

==================  =============================================================  =======
type                value                                                          unit
==================  =============================================================  =======
distance            |P_j - P_i|, points on bodies i and j                          m
displacement        u_i . (P_j - P_i), u_i = A_i axis' fixed in body i             m
velocity            u . v_P, v_P = rd + A (w' x s'); u = axis (global) or A axis'   m/s
angle               rotation from g_i to g_j about f_i of a revolute/cylindrical  rad
                    joint, in [theta0 - pi, theta0 + pi)
angular_velocity    u . w, u = axis (global) or A axis' (frame local)             rad/s
coordinate          u . P (global), axis x|y|z or a global direction               m
time                t                                                              s
==================  =============================================================  =======

Measures are evaluated from the state alone (no history): an integrator may reject steps.
The ``angle`` measure is therefore only continuous for |theta - theta0| < pi (one turn
around the reference angle); multi-turn angles need a driver or a state variable.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mbsim.deck.spec import PointSet
from mbsim.errors import DeckError, Where
from mbsim.model import joint_frame  # the same f, g, h as the joints and drivers
from mbsim.rotations import cross, skew

TWO_PI = 2.0 * np.pi


def axis_travel(st, bi, bj, si, sj, f):
    """(s, sd, f (3,) global, P_j (3,) global) of a joint axis: s = f_i . (P_j - P_i), f = A_i
    f' fixed in body i, P_i = r_i + A_i s_i', P_j = r_j + A_j s_j' (the translation driver's
    measure), and its rate sd = (w_i x f_i) . (P_j - P_i) + f_i . (v_Pj - v_Pi) (None
    without velocities)."""
    Ai, Aj = st.A[bi], st.A[bj]
    Pi, Pj = st.r[bi] + Ai @ si, st.r[bj] + Aj @ sj
    fg = Ai @ f
    s = float(fg @ (Pj - Pi))
    if st.rd is None:
        return s, None, fg, Pj
    wi, wj = Ai @ st.omega_local[bi], Aj @ st.omega_local[bj]
    vi = st.rd[bi] + cross(wi, Pi - st.r[bi])
    vj = st.rd[bj] + cross(wj, Pj - st.r[bj])
    return s, float(cross(wi, fg) @ (Pj - Pi) + fg @ (vj - vi)), fg, Pj


@dataclass
class MeasureSpec:
    """A measure as the deck gives it (plain data, checked by :func:`read_measures`).

    bodies: (i, j) for two-body types, (b,) for one-body types, () for time.
    points: body -> PointSet; for ``angle`` the PointSets of the joint (P, Q, R).
    data: 'axis' (3,) direction, 'frame' 'global'|'local', 'joint' name, 'theta0' rad.
    """

    name: str
    type: str
    bodies: tuple[str, ...] = ()
    points: dict[str, PointSet] = field(default_factory=dict)
    data: dict[str, Any] = field(default_factory=dict)
    where: Where = field(default_factory=Where)


def _unit(v, where: Where) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    n = np.linalg.norm(v)
    if not n > 0:
        raise DeckError("the axis must not be the zero vector", where.child("axis"))
    return v / n


def _index(name: str, body_index: dict, where: Where) -> int:
    try:
        return body_index[name]
    except KeyError:
        raise DeckError(f"unknown body {name!r}", where.child("bodies")) from None


def _point(ms: MeasureSpec, body: str) -> np.ndarray:
    ps = ms.points.get(body)
    return np.zeros(3) if ps is None else np.asarray(ps.P, dtype=float)


class Measure(ABC):
    """A compiled measure: ``value(st, t) -> float``.  Class data: type, unit, keys (the deck
    keys it takes), required (those it must have), description."""

    type = ""
    unit = ""
    keys: tuple[str, ...] = ()
    required: tuple[str, ...] = ()
    description = ""

    @classmethod
    @abstractmethod
    def from_spec(cls, ms: MeasureSpec, body_index: dict) -> Measure:
        """Compile a measure of the deck (names -> indices)."""

    @abstractmethod
    def value(self, st, t: float) -> float:
        """The measure at state ``st`` (:class:`mbsim.core.State`) and time t."""


class _Pair(Measure):
    """Two body points P_i, P_j (local s_i, s_j)."""

    keys = required = ("bodies", "points")

    def __init__(self, ms: MeasureSpec, body_index: dict):
        bi, bj = ms.bodies
        self.bi, self.bj = _index(bi, body_index, ms.where), _index(bj, body_index, ms.where)
        self.si, self.sj = _point(ms, bi), _point(ms, bj)

    @classmethod
    def from_spec(cls, ms, body_index):
        return cls(ms, body_index)

    def d(self, st) -> np.ndarray:
        """(3,) P_j - P_i, global."""
        return (st.r[self.bj] + st.A[self.bj] @ self.sj) - (st.r[self.bi] + st.A[self.bi] @ self.si)


class Distance(_Pair):
    type, unit = "distance", "m"
    description = "|P_j - P_i| between points of two bodies"

    def value(self, st, t):
        return float(np.linalg.norm(self.d(st)))


class Displacement(_Pair):
    type, unit = "displacement", "m"
    keys = ("bodies", "points", "axis")
    required = keys
    description = "u_i . (P_j - P_i), u_i = axis fixed in body i (body frame)"

    def __init__(self, ms, body_index):
        super().__init__(ms, body_index)
        self.u = _unit(ms.data["axis"], ms.where)

    def value(self, st, t):
        return float((st.A[self.bi] @ self.u) @ self.d(st))


class _One(Measure):
    """One body b, an optional point s' and an optional axis in the global or body frame."""

    def __init__(self, ms: MeasureSpec, body_index: dict):
        (name,) = ms.bodies
        self.b = _index(name, body_index, ms.where)
        self.s = _point(ms, name)
        self.S = skew(self.s)  # s'~: a matvec is ~40 times faster than np.cross on 3-vectors
        self.u = _unit(ms.data.get("axis", (0.0, 0.0, 1.0)), ms.where)
        self.local = ms.data.get("frame", "global") == "local"

    @classmethod
    def from_spec(cls, ms, body_index):
        return cls(ms, body_index)

    def axis(self, st) -> np.ndarray:
        return st.A[self.b] @ self.u if self.local else self.u


class Velocity(_One):
    type, unit = "velocity", "m/s"
    keys, required = ("body", "point", "axis", "frame"), ("body", "axis")
    description = "u . (rd + A (w' x s')) of a body point; axis global or body-fixed (frame)"

    def value(self, st, t):
        b = self.b
        v = st.rd[b] - st.A[b] @ (self.S @ st.omega_local[b])  # w' x s' = -s'~ w'
        return float(self.axis(st) @ v)


class AngularVelocity(_One):
    type, unit = "angular_velocity", "rad/s"
    keys, required = ("body", "axis", "frame"), ("body", "axis")
    description = "u . w of a body; axis global or body-fixed (frame)"

    def value(self, st, t):
        w_local = st.omega_local[self.b]
        if self.local:
            return float(self.u @ w_local)
        return float(self.u @ (st.A[self.b] @ w_local))


class Coordinate(_One):
    type, unit = "coordinate", "m"
    keys, required = ("body", "point", "axis"), ("body", "axis")
    description = "global coordinate u . (r + A s') of a body point (axis x|y|z or a direction)"

    def value(self, st, t):
        return float(self.u @ (st.r[self.b] + st.A[self.b] @ self.s))


class Angle(Measure):
    """theta from g_i to g_j about f_i (the rotation driver's angle): c = g_i.g_j,
    s = h_i.g_j, theta = theta0 + wrap(atan2(s, c) - theta0) into (-pi, pi]."""

    type, unit = "angle", "rad"
    keys, required = ("joint", "theta0"), ("joint",)
    description = "relative rotation about a revolute/cylindrical joint's axis f_i"

    def __init__(self, bi: int, bj: int, frames_i: dict, frames_j: dict, theta0: float):
        self.bi, self.bj = bi, bj
        self.gi, self.hi, self.gj = frames_i["g"], frames_i["h"], frames_j["g"]
        self.Sgj = skew(self.gj)
        self.theta0 = float(theta0)

    @classmethod
    def from_spec(cls, ms, body_index):
        bi, bj = ms.bodies
        return cls(
            _index(bi, body_index, ms.where),
            _index(bj, body_index, ms.where),
            joint_frame(ms.points.get(bi)),
            joint_frame(ms.points.get(bj)),
            ms.data.get("theta0", 0.0),
        )

    def terms(self, st):
        """(theta, a): the angle and its gradient axis a (global, (3,)): d theta = a . (dphi_j -
        dphi_i) for small rotations dphi; a = f_i when f_j is parallel to f_i."""
        Ai, Aj = st.A[self.bi], st.A[self.bj]
        gi, hi, gj = Ai @ self.gi, Ai @ self.hi, Aj @ self.gj
        c, s = gi @ gj, hi @ gj
        rho = c * c + s * s
        theta = self.theta0 + (np.arctan2(s, c) - self.theta0 + np.pi) % TWO_PI - np.pi
        # a = g_j x (c h_i - s g_i) / rho, the cross product taken in body j's frame
        a = Aj @ (self.Sgj @ (Aj.T @ (c * hi - s * gi))) / rho if rho > 0 else np.zeros(3)
        return float(theta), a

    def rate(self, st, a) -> float:
        """theta dot = a . (w_j - w_i) (global angular velocities)."""
        wi = st.A[self.bi] @ st.omega_local[self.bi]
        wj = st.A[self.bj] @ st.omega_local[self.bj]
        return float(a @ (wj - wi))

    def value(self, st, t):
        return self.terms(st)[0]


class Time(Measure):
    type, unit = "time", "s"
    description = "the time t (also available as 't' without declaring it)"

    @classmethod
    def from_spec(cls, ms, body_index):
        return cls()

    def value(self, st, t):
        return float(t)


MEASURES: dict[str, type[Measure]] = {
    c.type: c for c in (Distance, Displacement, Velocity, Angle, AngularVelocity, Coordinate, Time)
}


def compile_measures(specs: dict | None, body_index: dict, where: Where) -> dict[str, Measure]:
    """{name: Measure} from a force's ``data['measures']`` ({name: MeasureSpec})."""
    out = {}
    for name, ms in (specs or {}).items():
        cls = MEASURES.get(ms.type)
        if cls is None:
            raise DeckError(
                f"unknown measure type {ms.type!r}; known: {', '.join(MEASURES)}",
                where.child("measures").child(name).child("type"),
            )
        out[name] = cls.from_spec(ms, body_index)
    return out


# -- reading from the deck (called by the loader for fields of kind 'measures') ------------------
AXIS_NAMES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}
MEASURE_DIMS = {"angle": "angle", "time": "time"}


def read_measures(rd, node, where: Where, bodies: dict, joints: dict) -> dict[str, MeasureSpec]:
    """Read ``measures: {name: {type: ..., ...}}`` with the loader's Reader ``rd``."""
    out = {}
    for name, child, w in rd.items(node, where):
        if not name.isidentifier() or name in ("t", "pi", "e"):
            raise rd.error(
                w, f"a measure name must be a plain name other than t, pi, e; got {name!r}"
            )
        got = rd.fields(child, w, ("type",) + _all_keys(), ("type",), "a measure")
        mtype = rd.choice(*got["type"], MEASURES, "measure type")
        cls = MEASURES[mtype]
        got = rd.fields(
            child, w, ("type",) + cls.keys, ("type",) + cls.required, f"a {mtype} measure"
        )
        ms = MeasureSpec(name, mtype, where=w)
        if "bodies" in got:
            ms.bodies = rd.body_names(*got["bodies"], bodies, 2)
            ms.points = rd.points(*got["points"], dict.fromkeys(ms.bodies, "P"))
        if "body" in got:
            ms.bodies = (rd.name(*got["body"], bodies, "body"),)
            if "point" in got:
                ms.points = {ms.bodies[0]: PointSet(rd.vector(*got["point"], 3, "length"))}
        if "axis" in got:
            ax, aw = got["axis"]
            if ax.kind == "scalar":
                ms.data["axis"] = np.array(AXIS_NAMES[rd.choice(ax, aw, tuple(AXIS_NAMES), "axis")])
            else:
                ms.data["axis"] = rd.vector(ax, aw, 3)
                if not np.linalg.norm(ms.data["axis"]) > 0:
                    raise rd.error(aw, "the axis must not be the zero vector")
        if "frame" in got:
            ms.data["frame"] = rd.choice(*got["frame"], ("global", "local"), "frame")
        if "theta0" in got:
            ms.data["theta0"] = rd.number(*got["theta0"], "angle")
        if "joint" in got:
            jname = rd.name(*got["joint"], joints, "joint")
            joint = joints[jname]
            if joint.type not in ("revolute", "cylindrical"):
                raise rd.error(
                    got["joint"][1],
                    f"an angle measure needs a revolute or "
                    f"cylindrical joint; {jname} is {joint.type}",
                )
            ms.data["joint"] = jname
            ms.bodies, ms.points = tuple(joint.bodies), dict(joint.points)
        out[name] = ms
    return out


def _all_keys() -> tuple[str, ...]:
    return tuple(dict.fromkeys(k for c in MEASURES.values() for k in c.keys))
