"""Body shapes as triangle meshes, and the drawing of a mechanism stored with its results.

Every shape (mbsim.deck.shapes: box, cylinder, sphere, capsule, mesh) becomes triangles in
its body's frame here, once, when a run's result is made (:func:`scene_arrays`, called by
mbsim.api.run_model); the HDF5 file then holds everything the viewer, the animation and the
VTK export draw (docs/hdf5.md, "Shapes"), so they need only the ``.h5``:

    shapes/<body>/vertices  (nv, 3) float64  body frame, m
    shapes/<body>/faces     (nf, 3) int32    vertex indices, counter-clockwise seen from outside
    shapes/<body>/colors    (nv, 3) float64  RGB in [0, 1]
    shapes/layout           (1,) string      JSON: bodies, joints, forces, points (below)

Force elements with a drawing of their own (bushing, contact, stop) carry it in the layout as
primitives in body frames (mbsim.view.glyphs: the registry from force type to drawing).

A body without ``shape:`` gets one derived from its inertia and its joints
(:func:`default_shapes`): the box of uniform density with the body's mass and principal
moments, in its principal axes, plus a rod from the centroid to every joint or force point
that lies outside that box.
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass, field

import numpy as np

from mbsim.deck.spec import DeckSpec, ShapeSpec

SEGMENTS = 32  # around a cylinder, capsule or sphere
RINGS = 16  # pole to pole of a sphere
PALETTE = ("#4e79a7", "#f28e2b", "#59a14f", "#e15759", "#76b7b2", "#edc948", "#b07aa1",
           "#ff9da7", "#9c755f", "#bab0ac")  # fmt: skip  (Tableau 10)
ROD_RADIUS = 0.025  # rods of a default shape: radius / the body's size
MIN_EDGE = 0.05  # edges of an inertia box: at least this fraction of the body's size
_AXIS = {"z": np.eye(3), "x": np.array([[0.0, 1, 0], [0, 0, 1], [1, 0, 0]]),
         "y": np.array([[0.0, 0, 1], [1, 0, 0], [0, 1, 0]])}  # fmt: skip  # v @ M: z -> axis


def triangulate(shape: ShapeSpec) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (nv, 3) in the body frame, faces (nf, 3)) of one shape piece."""
    d = shape.data
    if shape.kind == "box":
        v, f = box(np.asarray(d["size"], float))
    elif shape.kind == "sphere":
        v, f = capsule(d["radius"], 0.0)
    elif shape.kind == "cylinder":
        v, f = cylinder(d["radius"], d["length"])
        v = v @ _AXIS[d.get("axis", "z")]
    elif shape.kind == "capsule":
        v, f = capsule(d["radius"], d["length"])
        v = v @ _AXIS[d.get("axis", "z")]
    else:  # mesh
        v, f = np.asarray(d["vertices"], float) * d.get("scale", 1.0), np.asarray(d["faces"])
    return v + np.asarray(shape.offset, float), f.astype(np.int32)


def box(size: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A box centred at the origin, edges ``size`` along x y z; 4 vertices a face (flat)."""
    signs, faces = _box_layout()
    return signs * (np.asarray(size, float) / 2), faces.copy()


@functools.lru_cache(maxsize=1)
def _box_layout():
    """(signs (24, 3) of +-1 per vertex and axis, faces (12, 3)) of :func:`box`: per face
    (axis, sign) four corners (a, b) in the plane of the two other axes u, w, the winding
    outward."""
    signs, faces = [], []
    for axis in range(3):
        for sign in (1.0, -1.0):
            u, w = (axis + 1) % 3, (axis + 2) % 3
            if sign < 0:
                u, w = w, u  # keep the winding outward
            n = len(signs)
            for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                p = np.zeros(3)
                p[axis], p[u], p[w] = sign, a, b
                signs.append(p)
            faces += [[n, n + 1, n + 2], [n, n + 2, n + 3]]
    out = (np.array(signs), np.array(faces))
    for x in out:
        x.flags.writeable = False
    return out


def cylinder(radius: float, length: float, n: int = SEGMENTS) -> tuple[np.ndarray, np.ndarray]:
    """A closed cylinder along z centred at the origin: vertices the bottom ring, the top
    ring, then for the caps the bottom centre, the bottom ring, the top centre, the top ring;
    the faces depend on n only (:func:`_cylinder_layout`)."""
    cos_a, sin_a, faces = _cylinder_layout(n)
    v = np.empty((4 * n + 2, 3))
    half = length / 2
    below = 0.0 - half  # (as the rings were: z = 0 - length / 2, +0.0 at length 0)
    for rows, z in ((slice(0, n), below), (slice(n, 2 * n), half),
                    (slice(2 * n + 1, 3 * n + 1), below), (slice(3 * n + 2, 4 * n + 2), half)):
        v[rows, 0], v[rows, 1], v[rows, 2] = radius * cos_a, radius * sin_a, z
    v[2 * n] = (0.0, 0.0, -half)
    v[3 * n + 1] = (0.0, 0.0, half)
    return v, faces.copy()


@functools.lru_cache(maxsize=8)
def _cylinder_layout(n: int):
    """cos, sin of the segments' azimuths and the faces of :func:`cylinder` (the sides: two
    triangles per segment; the caps: a fan around each centre)."""
    a = 2 * np.pi * np.arange(n) / n
    k = np.arange(n)
    k1 = (k + 1) % n
    side = np.r_[np.c_[k, k1, n + k1], np.c_[k, n + k1, n + k]]  # bot 0..n-1, top n..2n-1
    c0, c1 = 2 * n, 3 * n + 1  # centres of the bottom and the top cap
    caps = np.r_[np.c_[np.full(n, c0), c0 + 1 + k1, c0 + 1 + k],
                 np.c_[np.full(n, c1), c1 + 1 + k, c1 + 1 + k1]]  # fmt: skip
    out = (np.cos(a), np.sin(a), np.r_[side, caps])
    for x in out:
        x.flags.writeable = False
    return out


def capsule(radius: float, length: float, n: int = SEGMENTS, rings: int = RINGS):
    """A capsule along z (cap centres at z = +-length/2); a sphere when ``length`` is 0.
    Rows of vertices from the north pole, the equator ring doubled (it splits the two caps);
    the mesh's layout and faces depend on (n, rings) only (:func:`_capsule_layout`)."""
    sin_th, cos_th, cos_a, sin_a, ti, ai, north, faces = _capsule_layout(n, rings)
    rs = radius * sin_th[ti]
    row = np.stack((rs * cos_a[ai], rs * sin_a[ai], radius * cos_th[ti]), axis=1)
    half = np.array([0.0, 0.0, length / 2])
    v = np.where(north[:, None], row + half, row - half)
    return v, faces.copy()


@functools.lru_cache(maxsize=8)
def _capsule_layout(n: int, rings: int):
    """What :func:`capsule` needs besides its size: sin, cos of the rings' polar angles and
    of the segments' azimuths, each vertex's ring and segment, whether it is on the north
    cap, and the faces (two triangles per quad between neighbouring rows)."""
    rings += rings % 2  # an equator ring, doubled below, splits the two caps
    theta = np.pi * np.arange(rings + 1) / rings  # from the north pole
    a = 2 * np.pi * np.arange(n) / n
    ring = [i for i in range(rings + 1) for _ in range((2 * i <= rings) + (2 * i >= rings))]
    north = [2 * i <= rings and (j == 0 or 2 * i != rings)
             for i in range(rings + 1) for j in range((2 * i <= rings) + (2 * i >= rings))]
    nrows = len(ring)
    ti = np.repeat(ring, n)
    ai = np.tile(np.arange(n), nrows)
    k = np.arange(n)
    k1 = (k + 1) % n
    faces = []
    for r in range(nrows - 1):
        top, bot = r * n, (r + 1) * n
        faces.append(np.c_[top + k, bot + k, bot + k1])
        faces.append(np.c_[top + k, bot + k1, top + k1])
    out = (np.sin(theta), np.cos(theta), np.cos(a), np.sin(a), ti, ai,
           np.repeat(north, n), np.concatenate(faces))
    for x in out:
        x.flags.writeable = False
    return out


def inertia_box(mass: float, inertia: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(edges (3,), axes (3, 3) columns) of the uniform box with this mass and inertia:
    I_x = m (b^2 + c^2) / 12, ..., so a^2 = 6 (I_y + I_z - I_x) / m.  Edges the moments
    cannot give (a thin rod's) come out 0."""
    moments, axes = np.linalg.eigh(np.asarray(inertia, float))
    s = moments.sum()
    edges = np.sqrt(np.clip(6 * (s - 2 * moments) / mass, 0, None))
    return edges, axes


def attachment_points(spec: DeckSpec) -> dict[str, list[np.ndarray]]:
    """Body name -> the points (body frame) where its joints, drivers and forces act."""
    pts: dict[str, list[np.ndarray]] = {b: [] for b in spec.bodies}
    for item in (*spec.joints.values(), *spec.drivers.values(), *spec.forces.values()):
        for body, ps in item.points.items():
            if body in pts:
                pts[body].append(np.asarray(ps.P, float))
    for out in spec.outputs.values():
        pts[out.body].append(np.asarray(out.point, float))
    return pts


def default_shapes(spec: DeckSpec, name: str, points: list[np.ndarray]) -> list[ShapeSpec]:
    """A body's shape when the deck gives none: its inertia box (principal axes), edges kept
    between MIN_EDGE and 1 times the body's size (the distance to its farthest joint or force
    point; the box's largest edge when it has none), and rods from the centroid to the points
    outside it."""
    body = spec.bodies[name]
    if body.ground:
        return []
    edges, axes = inertia_box(body.mass, body.inertia)
    reach = max((float(np.linalg.norm(p)) for p in points), default=0.0)
    size = reach if reach > 0 else float(edges.max()) or 0.1
    edges = np.clip(edges, MIN_EDGE * size, size)
    v, f = box(edges)
    pieces = [ShapeSpec("mesh", {"vertices": v @ axes.T, "faces": f}, np.zeros(3))]
    radius = ROD_RADIUS * size
    local = np.abs(np.array(points).reshape(-1, 3) @ axes) if points else np.zeros((0, 3))
    for p, lp in zip(points, local):
        length = float(np.linalg.norm(p))
        if np.all(lp <= edges / 2) or length < radius:
            continue
        rv, rf = capsule(radius, length, n=12, rings=6)
        pieces.append(ShapeSpec("mesh", {"vertices": rv @ _rotation_z_to(p / length).T,
                                         "faces": rf}, p / 2))  # fmt: skip
    return pieces


def _rotation_z_to(u: np.ndarray) -> np.ndarray:
    """A rotation matrix taking the z axis onto the unit vector u."""
    z = np.array([0.0, 0, 1])
    c = float(z @ u)
    if c < -1 + 1e-12:
        return np.diag([1.0, -1, -1])
    k = np.cross(z, u)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + K + K @ K / (1 + c)


def _rgb(color: str) -> np.ndarray:
    return np.array([int(color[i : i + 2], 16) / 255 for i in (1, 3, 5)])


def body_mesh(pieces: list[ShapeSpec], color: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All pieces of a body in one mesh: (vertices (nv, 3), faces (nf, 3), colors (nv, 3))."""
    vs, fs, cs, n = [], [], [], 0
    for piece in pieces:
        v, f = triangulate(piece)
        vs.append(v)
        fs.append(f + n)
        cs.append(np.broadcast_to(_rgb(piece.color or color), (len(v), 3)))
        n += len(v)
    if not vs:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int32), np.zeros((0, 3))
    return np.concatenate(vs), np.concatenate(fs).astype(np.int32), np.concatenate(cs)


def mechanism_size(spec: DeckSpec) -> float:
    """The mechanism's size (m) at its initial estimates: the largest spread, along any global
    axis, of the bodies' centroids and their joint and force points; when those all coincide
    (a body on a bushing at its centroid), the largest edge of a body's inertia box."""
    from mbsim.rotations import A

    pts = [np.asarray(b.r, float) for b in spec.bodies.values()]
    for name, local in attachment_points(spec).items():
        body = spec.bodies[name]
        A_body = A(body.p)
        pts += [body.r + A_body @ P for P in local]
    spread = float(np.ptp(np.array(pts), axis=0).max()) if pts else 0.0
    if spread > 0:
        return spread
    edges = [inertia_box(b.mass, b.inertia)[0].max() for b in spec.bodies.values() if not b.ground]
    return float(max(edges, default=0.0)) or 1.0


def layout(spec: DeckSpec) -> dict:
    """What the viewer draws besides the shapes: joints (their points P on each body and the
    axis P -> Q where the joint has one), force elements (with ``glyphs``, mbsim.view.glyphs,
    where their type has a drawing) and output points, all in body frames."""
    from mbsim.view.glyphs import force_glyphs

    def pointset(ps):
        d = {"P": np.asarray(ps.P, float).tolist()}
        if ps.Q is not None:
            d["Q"] = np.asarray(ps.Q, float).tolist()
        return d

    def items(group):
        return [{"name": it.name, "type": it.type, "bodies": [b for b in it.points],
                 "points": [pointset(ps) for ps in it.points.values()]}
                for it in group.values()]  # fmt: skip

    forces = items(spec.forces)
    size = mechanism_size(spec) if spec.forces else 1.0
    for entry, force in zip(forces, spec.forces.values()):
        glyphs = force_glyphs(force, spec, size)
        if glyphs is not None:
            entry["glyphs"] = glyphs
    return {
        "gravity": np.asarray(spec.gravity, float).tolist(),  # m/s^2: the views' 'up' opposes it
        "bodies": {b.name: {"ground": bool(b.ground), "mass": float(b.mass)}
                   for b in spec.bodies.values()},
        "joints": items(spec.joints),
        "drivers": items(spec.drivers),
        "forces": forces,
        "points": [{"name": o.name, "body": o.body, "point": np.asarray(o.point).tolist()}
                   for o in spec.outputs.values()],  # fmt: skip
    }


def scene_arrays(spec: DeckSpec | None) -> dict[str, tuple[np.ndarray, dict]]:
    """The ``shapes/...`` arrays of a result (module docstring) for ``Result.arrays``."""
    if spec is None:
        return {}
    out: dict[str, tuple[np.ndarray, dict]] = {}
    points = attachment_points(spec)
    lay = layout(spec)
    for i, (name, body) in enumerate(spec.bodies.items()):
        derived = body.shapes is None
        pieces = default_shapes(spec, name, points[name]) if derived else body.shapes
        v, f, c = body_mesh(pieces, PALETTE[i % len(PALETTE)])
        lay["bodies"][name]["shape"] = "derived" if derived else "deck"
        if len(f):
            out[f"shapes/{name}/vertices"] = (v, {"unit": "m", "frame": "body"})
            out[f"shapes/{name}/faces"] = (f, {})
            out[f"shapes/{name}/colors"] = (c, {})
    out["shapes/layout"] = (np.array([json.dumps(lay)]), {"format": "JSON, docs/hdf5.md"})
    return out


@dataclass
class Scene:
    """A result file's mechanism over time, as the viewer, the animation and the VTK export
    read it (:func:`read_scene`).

    names: body names (model order); t: (nt,) s; r: (nt, nb, 3) centroids, global;
    p: (nt, nb, 4) Euler parameters; meshes: body name -> (vertices, faces, colors);
    layout: :func:`layout`'s dict.
    """

    names: list[str]
    t: np.ndarray
    r: np.ndarray
    p: np.ndarray
    meshes: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]
    layout: dict = field(default_factory=dict)


def read_scene(result) -> Scene:
    """The :class:`Scene` of a :class:`~mbsim.result.Result` read from a file.  A file written
    before shapes were stored (no ``shapes/layout``) gets the default shapes of the deck text it
    holds.  A body whose ``r`` or ``p`` channel the file lacks (``outputs: only:``) has no mesh:
    it is not drawn rather than drawn at the origin."""
    names = list(result.names.get("bodies", []))
    arrays = result.arrays
    if "shapes/layout" not in arrays and result.deck_text:
        arrays = {**arrays, **_arrays_from_deck(result.deck_text)}
    lay = json.loads(str(arrays["shapes/layout"][0][0])) if "shapes/layout" in arrays else {}
    if not names:
        names = list(lay.get("bodies", {}))
    nt = len(result.t)
    r = np.zeros((nt, len(names), 3))
    p = np.zeros((nt, len(names), 4))
    p[..., 0] = 1.0
    for k, b in enumerate(names):
        if f"bodies/{b}/r" in result.channels:
            r[:, k] = result.channels[f"bodies/{b}/r"].data
        if f"bodies/{b}/p" in result.channels:
            p[:, k] = result.channels[f"bodies/{b}/p"].data
    meshes, unseen = {}, set()
    for b in names:
        key = f"shapes/{b}/"
        recorded = f"bodies/{b}/r" in result.channels and f"bodies/{b}/p" in result.channels
        if key + "faces" in arrays and recorded:  # a body `outputs: only:` left out: not drawn
            meshes[b] = tuple(np.asarray(arrays[key + q][0]) for q in ("vertices", "faces",
                                                                        "colors"))  # fmt: skip
        if not recorded and not lay.get("bodies", {}).get(b, {}).get("ground"):
            unseen.add(b)
    for f in lay.get("forces", []) if unseen else ():  # nor are the glyphs on such a body
        if "glyphs" in f:
            f["glyphs"] = [g for g in f["glyphs"] if g["body"] not in unseen]
    return Scene(names, np.asarray(result.t, float), r, p, meshes, lay)


def _arrays_from_deck(text: str) -> dict:
    from mbsim.deck import load_deck_text
    from mbsim.errors import MbsimError

    try:
        return scene_arrays(load_deck_text(text))
    except MbsimError:  # a deck that needs its mesh files or its --set values: no shapes
        return {}
