"""Force elements drawn: a registry from the deck's force type to its drawing, made of a few
primitives in body frames that every renderer knows (the viewer, viewer.js; the frames of
``mbsim animate``, mbsim.view.render; its 2D sketch, mbsim.animate).

A drawing is ``draw(force: ForceSpec, spec: DeckSpec, size: float) -> list[dict]``, registered
in :data:`DRAWINGS` under the force type; ``size`` (m) is the mechanism's size
(mbsim.view.geometry.mechanism_size), for the glyphs that have no size of their own.  Each
primitive is a JSON-ready dict in the body frame of ``body`` (m), stored with the layout in
the result file (``shapes/layout``, key ``glyphs`` of the force; docs/hdf5.md):

    {"shape": "sphere",  "body": b, "center": (3,), "radius": R}
    {"shape": "square",  "body": b, "center": (3,), "normal": (3,) unit, "size": edge,
                         "corners": (4, 3) in order round the square, "faces": [[0, 1, 2, 3]]}
    {"shape": "box",     "body": b, "center": (3,), "axes": (3, 3) rows x, y, z unit,
                         "size": edge, "corners": (8, 3) (:func:`box_corners`),
                         "faces": (6, 4) corner indices, BOX_FACES}
    {"shape": "marker",  "body": b, "point": (3,)}
    {"shape": "segment", "body": b, "a": (3,), "b": (3,)}

(a square's and a box's ``corners`` and ``faces``, quads of corner indices, are all a renderer
needs of them), each with ``color`` ('#rrggbb') and ``opacity`` (1 opaque; the viewer draws the rest
translucent, the frame renderer draws their outlines).  A force type without a drawing is drawn
as before: a line between its two points (a spring) or a marker at its point.  A new force
type's drawing is one line in :data:`DRAWINGS` (and, when it needs a new primitive, that
primitive in each renderer); an element that acts in a joint (joint friction) can take
:func:`joint_marker`: ``"friction": joint_marker``.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from mbsim.deck.spec import DeckSpec, ForceSpec

BUSHING_COLOR = "#9467bd"  # purple
CONTACT_COLOR = "#17becf"  # cyan: the contact spheres
PLANE_COLOR = "#8c9db5"  # grey-blue: the contact plane
STOP_COLOR = "#d62728"  # red
JOINT_ELEMENT_COLOR = "#8c564b"  # brown: an element acting in a joint (joint_marker)
TRANSLUCENT = 0.35  # opacity of the contact's plane and spheres (they overlap the body shapes)
BUSHING_EDGE = 0.08  # edge of a bushing's box / the mechanism's size
PLANE_RADII = 8.0  # edge of a contact plane's square: at least this many sphere radii ...
PLANE_SPAN = 1.0  # ... and at least this fraction of the mechanism's size
STOP_TICK = 0.1  # length of an angle stop's limit rays / the mechanism's size


BOX_FACES = ((0, 4, 6, 2), (1, 3, 7, 5), (0, 1, 5, 4), (2, 6, 7, 3), (0, 2, 3, 1), (4, 5, 7, 6))
#   the box's faces as corner quads (corner index i + 2 j + 4 k: bits along x, y, z)


def _vec(x) -> list[float]:
    return [float(v) for v in np.asarray(x, float).reshape(3)]


def box_corners(center, axes, edge: float) -> list[list[float]]:
    """(8, 3) corners of the cube of ``edge`` about ``center`` with edges along the rows of
    ``axes``: corner i + 2 j + 4 k at center + ((i, j, k) - 1/2) edge . axes."""
    bits = np.array([[i, j, k] for k in (0, 1) for j in (0, 1) for i in (0, 1)], float) - 0.5
    return (np.asarray(center, float) + edge * bits @ np.asarray(axes, float)).tolist()


def square_corners(center, normal, edge: float) -> list[list[float]]:
    """(4, 3) corners, in order round it, of the square of ``edge`` about ``center`` normal to
    the unit vector ``normal``."""
    n = np.asarray(normal, float)
    u = np.eye(3)[int(np.argmin(np.abs(n)))]  # the axis least aligned with n
    u = u - n * (n @ u)
    u /= np.linalg.norm(u)
    w = np.cross(n, u)
    half = 0.5 * edge
    return [(np.asarray(center, float) + half * (a * u + b * w)).tolist()
            for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))]  # fmt: skip


def bushing(force: ForceSpec, spec: DeckSpec, size: float) -> list[dict]:
    """A box on each body at its bushing point P, edges along its frame (x P->Q, y towards R):
    the two boxes coincide at zero deflection and part as the bushing deflects."""
    from mbsim.model import joint_frame

    out = []
    for body in force.bodies:
        fr = joint_frame(force.points.get(body))
        axes, edge = [_vec(fr[k]) for k in "fgh"], BUSHING_EDGE * size
        out.append({"shape": "box", "body": body, "center": _vec(fr["P"]), "axes": axes,
                    "size": edge, "corners": box_corners(fr["P"], axes, edge),
                    "faces": [list(f) for f in BOX_FACES],
                    "color": BUSHING_COLOR, "opacity": 1.0})  # fmt: skip
    return out


def contact(force: ForceSpec, spec: DeckSpec, size: float) -> list[dict]:
    """sphere-plane: the plane as a translucent square around P_i (edge: PLANE_RADII sphere
    radii or the mechanism's size, the larger) and the sphere of ``radius`` at P_j;
    sphere-sphere: the spheres of ``radius_i`` at P_i and ``radius`` at P_j."""
    d = force.data
    bi, bj = force.bodies
    Pi, Pj = (_vec(force.points[b].P) if b in force.points else [0.0] * 3 for b in (bi, bj))
    R = float(d["radius"])
    out = []
    if d["geometry"] == "sphere-plane":
        n = np.asarray(d.get("normal", (0.0, 0.0, 1.0)), float).reshape(3)
        n = n / np.linalg.norm(n) if np.linalg.norm(n) > 0 else np.array([0.0, 0, 1])
        edge = max(PLANE_RADII * R, PLANE_SPAN * size)
        out.append({"shape": "square", "body": bi, "center": Pi, "normal": _vec(n),
                    "size": edge, "corners": square_corners(Pi, n, edge), "faces": [[0, 1, 2, 3]],
                    "color": PLANE_COLOR, "opacity": TRANSLUCENT})  # fmt: skip
    elif d.get("radius_i") is not None:
        out.append({"shape": "sphere", "body": bi, "center": Pi, "radius": float(d["radius_i"]),
                    "color": CONTACT_COLOR, "opacity": TRANSLUCENT})  # fmt: skip
    out.append({"shape": "sphere", "body": bj, "center": Pj, "radius": R,
                "color": CONTACT_COLOR, "opacity": TRANSLUCENT})  # fmt: skip
    return out


def stop(force: ForceSpec, spec: DeckSpec, size: float) -> list[dict]:
    """The limits on body i: on a travel, a marker at P_i + lower f_i and at P_i + upper f_i
    (f_i the joint axis P->Q; the travel s = f_i . (P_j - P_i)); on an angle, a ray from P_i at
    each limit angle from g_i about f_i (the rsda's angle), STOP_TICK of the mechanism long."""
    from mbsim.model import joint_frame

    d = force.data
    bi = force.bodies[0]
    fr = joint_frame(force.points.get(bi))
    natural = {"translational": "translation", "revolute": "rotation"}.get(d.get("joint_type"))
    angular = (d.get("motion") or natural) == "rotation"
    out = []
    for limit in (d.get("lower"), d.get("upper")):
        if limit is None:
            continue
        s = float(limit)
        if angular:
            tip = fr["P"] + STOP_TICK * size * (np.cos(s) * fr["g"] + np.sin(s) * fr["h"])
            out.append({"shape": "segment", "body": bi, "a": _vec(fr["P"]), "b": _vec(tip),
                        "color": STOP_COLOR, "opacity": 1.0})  # fmt: skip
        else:
            out.append({"shape": "marker", "body": bi, "point": _vec(fr["P"] + s * fr["f"]),
                        "color": STOP_COLOR, "opacity": 1.0})  # fmt: skip
    return out


def joint_marker(force: ForceSpec, spec: DeckSpec, size: float) -> list[dict]:
    """A marker at the element's point P on each of its bodies (for an element on a joint: the
    joint's points), for elements that act in a joint and have no geometry of their own."""
    return [{"shape": "marker", "body": body, "point": _vec(ps.P), "color": JOINT_ELEMENT_COLOR,
             "opacity": 1.0} for body, ps in force.points.items() if ps is not None]  # fmt: skip


DRAWINGS: dict[str, Callable[[ForceSpec, DeckSpec, float], list[dict]]] = {
    "bushing": bushing,
    "contact": contact,
    "stop": stop,
    "friction": joint_marker,
}


def force_glyphs(force: ForceSpec, spec: DeckSpec, size: float) -> list[dict] | None:
    """The primitives of one force element (module docstring), or None when its type has no
    drawing of its own (drawn as a spring or a point force)."""
    draw = DRAWINGS.get(force.type)
    return None if draw is None else draw(force, spec, size)
