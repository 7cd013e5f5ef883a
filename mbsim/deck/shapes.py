"""A body's ``shape:`` in the deck (docs/deck.md#shapes): what the viewer, the animation and
the VTK export draw for it.

Forms (every length may carry a unit, ``'40 mm'``)::

    shape: {type: box, size: [a, b, c]}                      # edges along x' y' z'
    shape: {type: cylinder, radius: r, length: l, axis: x}   # axis x | y | z (default z)
    shape: {type: sphere, radius: r}
    shape: {type: capsule, radius: r, length: l, axis: y}    # length between the cap centres
    shape: {type: mesh, file: parts/arm.stl, scale: 0.001}   # STL (ASCII/binary) or OBJ
    shape: [ {...}, {...} ]                                  # several pieces
    shape: none                                              # draw nothing

Each piece may add ``offset: [x, y, z]`` (its centre in the body frame, m) and
``color: '#rrggbb'``.  A mesh file is given relative to the deck's folder; paths that leave
it are refused, and its size is capped (:data:`MESH_BYTES`, :data:`MESH_TRIANGLES`), as for
every other input (mbsim.deck.limits).  The mesh is read and checked here, at the boundary;
past it the triangles travel in :class:`~mbsim.deck.spec.ShapeSpec`.
"""

from __future__ import annotations

import re
import struct
from pathlib import Path

import numpy as np

from mbsim.deck.limits import Limit
from mbsim.deck.spec import ShapeSpec
from mbsim.deck.tree import Node
from mbsim.deck.values import Reader, describe
from mbsim.errors import Where

SHAPE_TYPES = {  # type -> (required keys, optional keys)
    "box": (("size",), ()),
    "cylinder": (("radius", "length"), ("axis",)),
    "sphere": (("radius",), ()),
    "capsule": (("radius", "length"), ("axis",)),
    "mesh": (("file",), ("scale",)),
}
COMMON_KEYS = ("type", "offset", "color")
MESH_SUFFIXES = (".stl", ".obj")
MESH_BYTES = Limit("MESH_BYTES", 64 * 2**20, "mesh file size (bytes)")
MESH_TRIANGLES = Limit("MESH_TRIANGLES", 500_000, "number of triangles of a mesh")
COLOR_RE = re.compile(r"#[0-9a-fA-F]{6}")


def read_shapes(rd: Reader, node: Node, where: Where) -> list[ShapeSpec]:
    """The pieces of one body's ``shape:`` (an empty list for ``shape: none``)."""
    if node.kind == "scalar" and node.name() in ("none", "None"):
        return []
    if node.kind == "seq":
        return [_piece(rd, child, rd.item(where, i, child)) for i, child in enumerate(node.value)]
    return [_piece(rd, node, where)]


def _piece(rd: Reader, node: Node, where: Where) -> ShapeSpec:
    if node.kind != "map":
        raise rd.error(where, f"expected a shape mapping ({{type: box, size: [a, b, c]}}, ...) "
                              f"or none, got {describe(node)}", node)  # fmt: skip
    if "type" not in node.value:
        raise rd.error(where, f"missing required key 'type' for a shape; expected one of: "
                              f"{', '.join(SHAPE_TYPES)}")  # fmt: skip
    kind = rd.choice(node.value["type"], where.child("type"), tuple(SHAPE_TYPES), "shape type")
    required, optional = SHAPE_TYPES[kind]
    got = rd.fields(node, where, COMMON_KEYS + required + optional, required, f"a {kind} shape")
    data: dict = {}
    if kind == "box":
        data["size"] = rd.vector(*got["size"], 3, "length")
        bad = [x for x in data["size"] if not x > 0]
    elif kind == "mesh":
        data["scale"] = rd.number(*got["scale"]) if "scale" in got else 1.0
        bad = [data["scale"]] if not data["scale"] > 0 else []
        data["vertices"], data["faces"] = _mesh(rd, *got["file"])
    else:
        data["radius"] = rd.number(*got["radius"], "length")
        bad = [data["radius"]] if not data["radius"] > 0 else []
        if "length" in got:
            data["length"] = rd.number(*got["length"], "length")
            bad += [data["length"]] if data["length"] < 0 or kind == "cylinder" and \
                not data["length"] > 0 else []  # fmt: skip
        if "axis" in got:
            data["axis"] = rd.choice(*got["axis"], ("x", "y", "z"), "axis")
    if bad:
        raise rd.error(where, f"{kind} dimensions must be > 0, got {bad[0]:g}")
    offset = rd.vector(*got["offset"], 3, "length") if "offset" in got else np.zeros(3)
    color = ""
    if "color" in got:
        color = str(got["color"][0].value)
        if not COLOR_RE.fullmatch(color):
            raise rd.error(got["color"][1], f"expected a colour '#rrggbb', got {color!r}",
                           got["color"][0])
    return ShapeSpec(kind, data, offset, color, where)


def _mesh(rd: Reader, node: Node, where: Where) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (nv, 3) in the file's units, faces (nf, 3) int) of a mesh file given relative
    to the deck's folder; refused when it leaves that folder, is too big or is malformed."""
    name = node.value if node.kind == "scalar" and isinstance(node.value, str) else None
    if not name:
        raise rd.error(where, f"expected a file name, got {describe(node)}", node)
    if not Path(rd.file).is_file():
        raise rd.error(where, "a mesh file is found relative to the deck's folder; this deck "
                              "has no file (load it from a file)")  # fmt: skip
    folder = Path(rd.file).resolve().parent
    path = (folder / name).resolve()
    if Path(name).is_absolute() or not path.is_relative_to(folder):
        raise rd.error(where, f"mesh file {name!r} leaves the deck's folder {folder}; give a "
                              "path inside it", node)  # fmt: skip
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise rd.error(where, f"mesh file {name!r}: expected an .stl or .obj file", node)
    if not path.is_file():
        raise rd.error(where, f"mesh file {name!r}: no such file in {folder}", node)
    size = path.stat().st_size
    if size > MESH_BYTES.value:
        raise rd.error(where, f"mesh file {name!r}: {MESH_BYTES.exceeded(size)}", node)
    try:
        raw = path.read_bytes()
        vertices, faces = (read_obj(raw) if path.suffix.lower() == ".obj" else read_stl(raw))
    except (OSError, ValueError) as exc:
        raise rd.error(where, f"mesh file {name!r}: {exc}", node) from None
    return vertices, faces


def read_stl(raw: bytes) -> tuple[np.ndarray, np.ndarray]:
    """Triangles of an STL file, binary or ASCII: (vertices (3 nf, 3), faces (nf, 3))."""
    if len(raw) >= 84:
        n = struct.unpack_from("<I", raw, 80)[0]
        if len(raw) == 84 + 50 * n:  # binary: header, count, 50 bytes a triangle
            _cap(n)
            rec = np.frombuffer(raw, np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)),
                                               ("a", "<u2")]), n, 84)  # fmt: skip
            return _checked(rec["v"].reshape(-1, 3).astype(float), np.arange(3 * n).reshape(-1, 3))
    text = raw.decode("ascii", errors="replace")
    if not text.lstrip().lower().startswith("solid"):
        raise ValueError("not an STL file (neither binary nor ASCII 'solid ...')")
    nums = re.findall(r"^\s*vertex\s+(\S+)\s+(\S+)\s+(\S+)", text, re.M | re.I)
    if not nums or len(nums) % 3:
        raise ValueError(f"ASCII STL with {len(nums)} vertices (expected a multiple of 3, > 0)")
    _cap(len(nums) // 3)
    try:
        v = np.array(nums, dtype=float)
    except ValueError as exc:
        raise ValueError(f"ASCII STL: a vertex is not 3 numbers ({exc})") from None
    return _checked(v, np.arange(len(v)).reshape(-1, 3))


def read_obj(raw: bytes) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of a Wavefront OBJ file (polygons fanned into triangles;
    texture and normal indices ignored; negative indices count from the end)."""
    verts, faces = [], []
    for lineno, line in enumerate(raw.decode("utf-8", errors="replace").splitlines(), 1):
        parts = line.split()
        if not parts:
            continue
        try:
            if parts[0] == "v":
                verts.append([float(x) for x in parts[1:4]])
            elif parts[0] == "f":
                idx = [int(p.split("/")[0]) for p in parts[1:]]
                idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
                faces.extend([idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1))
                _cap(len(faces))
        except ValueError:
            raise ValueError(f"line {lineno}: cannot read {line.strip()[:60]!r}") from None
    if not faces:
        raise ValueError("no faces ('f' lines)")
    v = np.array(verts, dtype=float).reshape(-1, 3)
    f = np.array(faces, dtype=np.int64)
    if f.min() < 0 or f.max() >= len(v):
        raise ValueError(f"a face refers to a vertex that does not exist (there are {len(v)})")
    return _checked(v, f)


def _cap(n_triangles: int) -> None:
    if n_triangles > MESH_TRIANGLES.value:
        raise ValueError(MESH_TRIANGLES.exceeded(n_triangles))


def _checked(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    if not np.isfinite(v).all():
        raise ValueError("a vertex coordinate is NaN or infinite")
    return v, f.astype(np.int32)
