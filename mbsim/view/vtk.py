"""``mbsim export --vtk DIR``: a ParaView time series of a result file.

Written here, by hand, rather than through a library: VTK's XML UnstructuredGrid (``.vtu``)
is a small, stable, documented format (points, cells, point and cell data as base64 arrays,
VTK file formats, "XML File Formats") and ``.pvd`` is a list of (time, file) pairs; a writer
takes 60 lines and no dependency, while meshio (the library the tests read the files back
with) would add an install for every user of the export.  Two series, one file per output:

    DIR/<stem>_shapes.pvd -> <stem>_shapes/<k>.vtu   every body's shape triangles (global,
                                                     float32), cell data ``body`` (index into
                                                     the field data's names, model order)
    DIR/<stem>_points.pvd -> <stem>_points/<k>.vtu   one vertex per body centroid and per
                                                     output point (float64), point data
                                                     ``velocity`` (m/s) where recorded, ``kind``
                                                     (0 centroid, 1 output point)

The shapes come from the file itself (``shapes/``, mbsim.view.geometry).
"""

from __future__ import annotations

import base64
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from mbsim.errors import UsageError
from mbsim.result import Result
from mbsim.view.geometry import read_scene

VTK_VERTEX, VTK_TRIANGLE = 1, 5
_TYPES = {np.dtype("<f4"): "Float32", np.dtype("<f8"): "Float64", np.dtype("<i4"): "Int32",
          np.dtype("<i8"): "Int64", np.dtype("u1"): "UInt8"}  # fmt: skip


def _array(name: str, data: np.ndarray, ncomp: int = 1) -> str:
    """One inline binary DataArray: base64 of (UInt32 byte count, the little-endian data)."""
    data = np.ascontiguousarray(data)
    raw = data.tobytes()
    blob = base64.b64encode(np.uint32(len(raw)).tobytes() + raw).decode()
    return (f'<DataArray type="{_TYPES[data.dtype]}" Name={quoteattr(name)} '
            f'NumberOfComponents="{ncomp}" format="binary">{blob}</DataArray>')  # fmt: skip


def write_vtu(path: Path, points: np.ndarray, cells: np.ndarray, cell_type: int,
              point_data: dict | None = None, cell_data: dict | None = None) -> None:
    """One ``.vtu`` file: points (n, 3), cells (m, k) vertex indices, all of one type."""
    cells = np.asarray(cells, "<i4").reshape(len(cells), -1)
    k = cells.shape[1]
    parts = ['<?xml version="1.0"?>',
             '<VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian" '
             'header_type="UInt32">', "<UnstructuredGrid>",
             f'<Piece NumberOfPoints="{len(points)}" NumberOfCells="{len(cells)}">',
             "<Points>", _array("Points", np.asarray(points).reshape(-1, 3), 3), "</Points>",
             "<Cells>", _array("connectivity", cells.reshape(-1)),
             _array("offsets", np.arange(1, len(cells) + 1, dtype="<i4") * k),
             _array("types", np.full(len(cells), cell_type, "u1")), "</Cells>"]  # fmt: skip
    for tag, data in (("PointData", point_data), ("CellData", cell_data)):
        if data:
            parts.append(f"<{tag}>")
            parts += [_array(n, a, a.shape[1] if a.ndim > 1 else 1) for n, a in data.items()]
            parts.append(f"</{tag}>")
    parts += ["</Piece>", "</UnstructuredGrid>", "</VTKFile>"]
    path.write_text("\n".join(parts))


def write_pvd(path: Path, times: np.ndarray, files: list[str]) -> None:
    rows = "\n".join(f'<DataSet timestep="{t!r}" group="" part="0" file={quoteattr(f)}/>'
                     for t, f in zip(map(float, times), files))  # fmt: skip
    path.write_text('<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1" '
                    f'byte_order="LittleEndian">\n<Collection>\n{rows}\n</Collection>\n'
                    "</VTKFile>\n")  # fmt: skip


def export_vtk(result: Result, out_dir: str | Path, stem: str = "result") -> Path:
    """Write the two series (module docstring) into ``out_dir`` (created when missing, its
    parent must exist); returns the shapes' ``.pvd``."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--vtk {out}: is a file, not a folder")
    if not out.parent.is_dir():
        raise UsageError(f"--vtk {out}: the folder {out.parent} does not exist")
    scene = read_scene(result)
    shapes_dir, points_dir = out / f"{stem}_shapes", out / f"{stem}_points"
    for d in (shapes_dir, points_dir):
        d.mkdir(parents=True, exist_ok=True)
    drawn = [k for k, b in enumerate(scene.names) if b in scene.meshes]
    faces = np.concatenate([scene.meshes[scene.names[k]][1] + off for k, off in
                            zip(drawn, np.cumsum([0] + [len(scene.meshes[scene.names[k]][0])
                                                       for k in drawn])[:-1])]) \
        if drawn else np.zeros((0, 3), int)  # fmt: skip
    body_of_face = np.concatenate([np.full(len(scene.meshes[scene.names[k]][1]), k, "<i4")
                                   for k in drawn]) if drawn else np.zeros(0, "<i4")  # fmt: skip
    outs = [n.split("/")[1] for n in result.channels
            if n.startswith("points/") and n.endswith("/position")]  # fmt: skip
    shape_files, point_files = [], []
    for i in range(len(scene.t)):
        verts = [_to_global(scene.meshes[scene.names[k]][0], scene.r[i, k], scene.p[i, k])
                 for k in drawn]  # fmt: skip
        pts = np.concatenate(verts).astype("<f4") if verts else np.zeros((0, 3), "<f4")
        f = shapes_dir / f"{i:06d}.vtu"
        write_vtu(f, pts, faces, VTK_TRIANGLE, cell_data={"body": body_of_face})
        shape_files.append(f"{shapes_dir.name}/{f.name}")
        xyz = [scene.r[i]] + [result.channels[f"points/{o}/position"].data[i][None] for o in outs]
        vel = [_velocity(result, f"bodies/{b}/rd", i) for b in scene.names] + \
              [_velocity(result, f"points/{o}/velocity", i) for o in outs]  # fmt: skip
        kind = np.r_[np.zeros(len(scene.names)), np.ones(len(outs))].astype("u1")
        allp = np.concatenate(xyz).astype("<f8")
        f = points_dir / f"{i:06d}.vtu"
        write_vtu(f, allp, np.arange(len(allp))[:, None], VTK_VERTEX,
                  point_data={"velocity": np.array(vel, "<f8").reshape(-1, 3), "kind": kind})
        point_files.append(f"{points_dir.name}/{f.name}")
    pvd = out / f"{stem}_shapes.pvd"
    write_pvd(pvd, scene.t, shape_files)
    write_pvd(out / f"{stem}_points.pvd", scene.t, point_files)
    (out / f"{stem}_bodies.txt").write_text(
        "# body index (cell data 'body' of the shapes, first points of the points series)\n"
        + "\n".join(f"{k} {b}" for k, b in enumerate(scene.names)) + "\n")  # fmt: skip
    return pvd


def _velocity(result: Result, name: str, i: int) -> np.ndarray:
    ch = result.channels.get(name)
    return np.asarray(ch.data[i], float) if ch is not None else np.full(3, np.nan)


def _to_global(v: np.ndarray, r: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Body-frame points v (n, 3) -> global r + A(p) v (Haug eq. 6.3.20 via rotations.A)."""
    from mbsim.rotations import A

    return r + v @ A(p).T
