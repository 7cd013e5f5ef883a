"""Measures as output channels (``outputs: measures:``), computed over the whole time axis.

Each measure becomes the channel ``measures/<name>`` with its SI unit.  Types (class data in
``OUTPUT_MEASURES``); points are in body coordinates, default the body origin (centroid):

=======================  ==============================================================  =====
type                     value                                                           unit
=======================  ==============================================================  =====
joint_angle              rotation from g_i to g_j about f_i of a revolute/cylindrical    rad
                         joint (as a rotation driver and an rsda), unwrapped in time
joint_rate               f_i . (omega_j - omega_i)                                       rad/s
joint_translation        f_i . (P_j - P_i) of a translational/cylindrical joint          m
joint_translation_rate   d/dt of it: (omega_i x f_i) . d + f_i . (v_Pj - v_Pi)           m/s
point_velocity           v_P = rd + omega x A s' (global x, y, z)                        m/s
point_acceleration       a_P = rdd + omegad x A s' + omega x (omega x A s')              m/s^2
body_angle               angle of a body about a global axis u: of the projection of     rad
                         A ref' (``ref``, default x', or y' if x' starts along u) on the
                         plane normal to u, from ``from`` (default the first of global
                         x, y, z not along u), positive about u, unwrapped in time
distance                 |P_j - P_i|                                                     m
expression               ``value``: a formula (safe evaluator, :mod:`mbsim.expr`) of     ``unit``
                         t, earlier measures (vector ones as name_x, name_y, name_z),
                         kinetic_energy, potential_energy (J) and the channels named in
                         ``channels: {local name: selector}`` (bodies, points, forces,
                         measures: what the recorder writes)
=======================  ==============================================================  =====

Unwrapping: consecutive outputs are assumed less than half a turn apart (np.unwrap), so an
angle counts whole turns (a crank turning 10 times ends near 20 pi).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mbsim.deck.spec import PointSet
from mbsim.errors import DeckError, Where

XYZ = ("x", "y", "z")
AXIS_NAMES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}

# type -> (keys, required keys, unit, components, what the joint must be)
OUTPUT_MEASURES: dict[str, tuple] = {
    "joint_angle": (("joint",), ("joint",), "rad", (), ("revolute", "cylindrical")),
    "joint_rate": (("joint",), ("joint",), "rad/s", (), ("revolute", "cylindrical")),
    "joint_translation": (("joint",), ("joint",), "m", (), ("translational", "cylindrical")),
    "joint_translation_rate": (("joint",), ("joint",), "m/s", (),
                               ("translational", "cylindrical")),
    "point_velocity": (("body", "point"), ("body",), "m/s", XYZ, None),
    "point_acceleration": (("body", "point"), ("body",), "m/s^2", XYZ, None),
    "body_angle": (("body", "axis", "ref", "from"), ("body", "axis"), "rad", (), None),
    "distance": (("bodies", "points"), ("bodies",), "m", (), None),
    "expression": (("value", "unit", "channels"), ("value",), None, (), None),
}
BUILTIN_NAMES = ("t", "kinetic_energy", "potential_energy")


@dataclass
class OutputMeasure:
    """A measure as the deck gives it: type and checked data (body/joint names, points)."""

    name: str
    type: str
    data: dict[str, Any] = field(default_factory=dict)
    where: Where = field(default_factory=Where)


def _axis(rd, node, where) -> np.ndarray:
    if node.kind == "scalar":
        return np.array(AXIS_NAMES[rd.choice(node, where, tuple(AXIS_NAMES), "axis")])
    v = rd.vector(node, where, 3)
    if not np.linalg.norm(v) > 0:
        raise rd.error(where, "the axis must not be the zero vector")
    return v / np.linalg.norm(v)


def read_output_measures(rd, node, where: Where, bodies: dict, joints: dict) -> dict:
    """Read ``outputs: measures: {name: {type: ..., ...}}`` with the loader's Reader."""
    from mbsim.errors import ExpressionError
    from mbsim.expr import parse_expression

    out: dict[str, OutputMeasure] = {}
    for name, child, w in rd.items(node, where):
        if not name.isidentifier() or name in BUILTIN_NAMES + ("pi", "e", "deg"):
            raise rd.error(w, f"a measure name must be a plain name other than "
                           f"{', '.join(BUILTIN_NAMES)}, pi, e, deg; got {name!r}")
        got = rd.fields(child, w, ("type",) + tuple(dict.fromkeys(
            k for spec in OUTPUT_MEASURES.values() for k in spec[0])), ("type",), "a measure")
        mtype = rd.choice(*got["type"], tuple(OUTPUT_MEASURES), "measure type")
        keys, required, _, _, joint_types = OUTPUT_MEASURES[mtype]
        got = rd.fields(child, w, ("type",) + keys, ("type",) + required, f"a {mtype} measure")
        om = OutputMeasure(name, mtype, where=w)
        d = om.data
        if "joint" in got:
            jname = rd.name(*got["joint"], joints, "joint")
            if joints[jname].type not in joint_types:
                raise rd.error(got["joint"][1], f"a {mtype} measure needs a "
                               f"{' or '.join(joint_types)} joint; {jname} is "
                               f"{joints[jname].type}")
            d["joint"] = jname
        if "body" in got:
            d["body"] = rd.name(*got["body"], bodies, "body")
            d["point"] = rd.vector(*got["point"], 3, "length") if "point" in got else np.zeros(3)
        if "bodies" in got:
            d["bodies"] = rd.body_names(*got["bodies"], bodies, 2)
            pts = {b: PointSet(np.zeros(3)) for b in d["bodies"]}  # default: the origins
            if "points" in got:
                for b, pnode, pw in rd.items(*got["points"]):
                    if b not in pts:
                        raise rd.error(pw, f"{b!r} is not a body of this measure (bodies: "
                                       f"{', '.join(d['bodies'])})")
                    pts[b] = rd.pointset(pnode, pw, "P")
            d["points"] = tuple(np.asarray(pts[b].P, float) for b in d["bodies"])
        for key in ("axis", "from"):
            if key in got:
                d[key] = _axis(rd, *got[key])
        if "ref" in got:
            d["ref"] = _axis(rd, *got["ref"])
        if mtype == "expression":
            text = to_text(got["value"][0])
            chans = {}
            if "channels" in got:
                for local, cnode, cw in rd.items(*got["channels"]):
                    if not local.isidentifier():
                        raise rd.error(cw, f"a channel's local name must be a plain name, "
                                       f"got {local!r}")
                    chans[local] = str(cnode.value)
            allowed = set(BUILTIN_NAMES) | set(chans) | set(rd.params)
            for prev, pm in out.items():
                comps = OUTPUT_MEASURES[pm.type][3]
                allowed |= {f"{prev}_{c}" for c in comps} if comps else {prev}
            try:
                expr = parse_expression(text, allowed).bind(dict(rd.params))
            except ExpressionError as exc:
                raise rd.error(got["value"][1], f"measure {name}: {exc}") from None
            d.update(value=expr, channels=chans,
                     unit=str(got["unit"][0].value) if "unit" in got else "")
        out[name] = om
    return out


def to_text(node) -> str:
    v = node.value
    if isinstance(v, bool) or v is None:
        return str(v)
    return str(v)


def selected(path: str, patterns) -> bool:
    """Is the channel ``path`` selected by the ``only`` patterns (None: all)?  A pattern is a
    channel path, a group prefix (``bodies/chassis``) or an fnmatch pattern (``points/*``)."""
    if patterns is None:
        return True
    from fnmatch import fnmatchcase

    for pat in patterns:
        if path == pat or path.startswith(pat + "/") or fnmatchcase(path, pat) or \
                fnmatchcase(path, pat + "/*"):
            return True
    return False


def _unwrap(theta):
    return np.unwrap(theta) if theta.size > 1 else theta


def _joint_frames(model, kin, name):
    """(it, fi, gi, hi, gj) (nt, 3) global joint-frame vectors and the joint item."""
    it = model.item(name)
    A = kin["A"]
    Ai, Aj = A[:, it.bi], A[:, it.bj]
    fi, gi, hi = (Ai @ it.C_i[:, k] for k in range(3))
    gj = Aj @ it.C_j[:, 1]
    return it, fi, gi, hi, gj


def _point_state(kin, b, s):
    """Global position, velocity, acceleration (nt, 3) of body point s' of body b."""
    sg = kin["A"][:, b] @ s
    w, wd = kin["omega"][:, b], kin["omegad"][:, b]
    pos = kin["r"][:, b] + sg
    vel = kin["rd"][:, b] + np.cross(w, sg)
    acc = kin["rdd"][:, b] + np.cross(wd, sg) + np.cross(w, np.cross(w, sg))
    return pos, vel, acc


def evaluate(model, om: OutputMeasure, kin, t, env) -> np.ndarray:
    """The measure's data (nt,) or (nt, 3) from the batched kinematics ``kin`` (see
    :func:`mbsim.analyses.common.body_kinematics`: arrays with time first)."""
    d, typ = om.data, om.type
    if typ in ("joint_angle", "joint_rate"):
        it, fi, gi, hi, gj = _joint_frames(model, kin, d["joint"])
        if typ == "joint_angle":
            return _unwrap(np.arctan2(np.sum(gj * hi, 1), np.sum(gj * gi, 1)))
        w = kin["omega"]
        return np.sum(fi * (w[:, it.bj] - w[:, it.bi]), 1)
    if typ in ("joint_translation", "joint_translation_rate"):
        it, fi, _, _, _ = _joint_frames(model, kin, d["joint"])
        pi_, vi, _ = _point_state(kin, it.bi, it.P_i)
        pj, vj, _ = _point_state(kin, it.bj, it.P_j)
        dd = pj - pi_
        if typ == "joint_translation":
            return np.sum(fi * dd, 1)
        fid = np.cross(kin["omega"][:, it.bi], fi)
        return np.sum(fid * dd, 1) + np.sum(fi * (vj - vi), 1)
    if typ in ("point_velocity", "point_acceleration"):
        _, vel, acc = _point_state(kin, model.body_index(d["body"]), d["point"])
        return vel if typ == "point_velocity" else acc
    if typ == "distance":
        bi, bj = (model.body_index(n) for n in d["bodies"])
        pi_ = _point_state(kin, bi, d["points"][0])[0]
        pj = _point_state(kin, bj, d["points"][1])[0]
        return np.linalg.norm(pj - pi_, axis=1)
    if typ == "body_angle":
        b = model.body_index(d["body"])
        u = d["axis"]
        A = kin["A"][:, b]
        ref = d.get("ref")
        if ref is None:
            ref = np.array([1.0, 0, 0])
            if A.shape[0] and abs((A[0] @ ref) @ u) > 1 - 1e-6:
                ref = np.array([0.0, 1, 0])
        e = d.get("from")
        if e is None:
            e = next(np.array(v) for v in AXIS_NAMES.values() if abs(np.dot(v, u)) < 1 - 1e-6)
        e = e - u * (e @ u)
        e = e / np.linalg.norm(e)
        a = A @ ref
        a = a - np.outer(a @ u, u)
        return _unwrap(np.arctan2(np.cross(e, a) @ u, a @ e))
    if typ == "expression":
        val = d["value"](env)
        return np.broadcast_to(np.asarray(val, float), t.shape).copy()
    raise DeckError(f"unknown measure type {typ!r}", om.where)  # pragma: no cover


def unit_of(om: OutputMeasure) -> str:
    unit = OUTPUT_MEASURES[om.type][2]
    return om.data.get("unit", "") if unit is None else unit


def components_of(om: OutputMeasure) -> tuple[str, ...]:
    return OUTPUT_MEASURES[om.type][3]


def describe(om: OutputMeasure) -> str:
    d = om.data
    what = d.get("joint") or d.get("body") or ", ".join(d.get("bodies", ())) or \
        getattr(d.get("value"), "text", "")
    return f"{om.type.replace('_', ' ')}: {what}"
