"""Body shapes: the deck's ``shape:`` key (mbsim.deck.shapes), their triangles and the
default shapes (mbsim.view.geometry), and their way into the result file."""

import struct
import textwrap

import numpy as np
import pytest

from mbsim.deck import load_deck, load_deck_text
from mbsim.errors import DeckError
from mbsim.view import geometry

DECK = """\
title: one body on a revolute
bodies:
  ground: {ground: true}
  arm:
    mass: 2.0
    inertia: [0.02, 0.5, 0.5]
    r: [0.5, 0, 0]
    {shape}
joints:
  pin:
    type: revolute
    bodies: [ground, arm]
    points:
      ground: [0, 0, 0,   0, 0, 1,   1, 0, 0]
      arm:    [-0.5, 0, 0,   -0.5, 0, 1,   0.5, 0, 0]
"""


def deck(shape: str, tmp_path=None, name="deck.yaml"):
    text = DECK.replace("{shape}", shape)
    if tmp_path is None:
        return load_deck_text(text)
    path = tmp_path / name
    path.write_text(text)
    return load_deck(path)


def volume(v, f):
    """Enclosed volume by the divergence theorem: sum of det[a, b, c] / 6 over triangles
    wound counter-clockwise seen from outside (positive for an outward winding)."""
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6)


def polygon_factor(n):
    """Area of a regular n-gon inscribed in the unit circle / pi."""
    return n * np.sin(2 * np.pi / n) / (2 * np.pi)


@pytest.mark.parametrize("shape, exact, rel", [
    ("{type: box, size: [0.2, 0.3, 0.4]}", 0.2 * 0.3 * 0.4, 1e-12),
    # the 32-gon prism: pi r^2 l times the polygon's area ratio, exactly
    ("{type: cylinder, radius: 0.1, length: 0.5, axis: x}",
     np.pi * 0.01 * 0.5 * polygon_factor(32), 1e-12),
    # a 32 x 16 UV sphere falls short of 4/3 pi r^3 by under 2 %
    ("{type: sphere, radius: '50 mm'}", 4 / 3 * np.pi * 0.05**3, 0.02),
    ("{type: capsule, radius: 0.05, length: 0.3, axis: y}",
     np.pi * 0.05**2 * 0.3 + 4 / 3 * np.pi * 0.05**3, 0.02),
])  # fmt: skip
def test_primitive_shapes_enclose_their_volume_with_outward_faces(shape, exact, rel):
    spec = deck(f"shape: {shape}")
    (piece,) = spec.bodies["arm"].shapes
    v, f = geometry.triangulate(piece)
    assert volume(v, f) == pytest.approx(exact, rel=rel)


def test_cylinder_and_capsule_lie_along_their_axis():
    for axis, k in (("x", 0), ("y", 1), ("z", 2)):
        (piece,) = deck(f"shape: {{type: cylinder, radius: 0.1, length: 0.6, axis: {axis}}}") \
            .bodies["arm"].shapes
        v, _ = geometry.triangulate(piece)
        extent = np.ptp(v, axis=0)
        assert extent[k] == pytest.approx(0.6) and np.delete(extent, k) == pytest.approx(0.2)


def test_offset_colour_and_several_pieces():
    spec = deck("shape: [{type: sphere, radius: 0.1, offset: [0.5, 0, 0], color: '#ff0000'},\n"
                "           {type: box, size: [1, 0.1, 0.1]}]")
    v, f, c = geometry.body_mesh(spec.bodies["arm"].shapes, "#0000ff")
    assert v[:, 0].max() == pytest.approx(0.6)  # sphere centre 0.5 + radius
    assert {tuple(x) for x in c} == {(1.0, 0.0, 0.0), (0.0, 0.0, 1.0)}
    assert f.max() == len(v) - 1


def test_shape_none_draws_nothing():
    assert deck("shape: none").bodies["arm"].shapes == []


@pytest.mark.parametrize("shape, words", [
    ("shape: {type: cube, size: [1, 1, 1]}", "bodies.arm.shape.type: expected shape type"),
    ("shape: {type: box}", "missing required key 'size'"),
    ("shape: {type: sphere, radius: -1}", "sphere dimensions must be > 0"),
    ("shape: {type: box, size: [1, 1, 1], colour: red}", "unknown key 'colour'"),
    ("shape: {type: box, size: [1, 1, 1], color: red}", "expected a colour '#rrggbb'"),
    ("shape: {type: cylinder, radius: 1, length: 1, axis: w}", "expected axis x | y | z"),
    ("shape: 3", "expected a shape mapping"),
])  # fmt: skip
def test_bad_shapes_are_deck_errors_naming_the_key(shape, words):
    with pytest.raises(DeckError) as err:
        deck(shape)
    assert words in str(err.value)
    assert "bodies.arm.shape" in str(err.value)


def stl_binary(triangles):
    raw = b"\0" * 80 + struct.pack("<I", len(triangles))
    for tri in triangles:
        raw += struct.pack("<12fH", 0, 0, 0, *np.ravel(tri), 0)
    return raw


TETRA = np.array([[[0, 0, 0], [0, 1, 0], [1, 0, 0]], [[0, 0, 0], [1, 0, 0], [0, 0, 1]],
                  [[0, 0, 0], [0, 0, 1], [0, 1, 0]], [[1, 0, 0], [0, 1, 0], [0, 0, 1]]],
                 float)  # fmt: skip  # outward winding, volume 1/6


def test_mesh_files_stl_binary_ascii_and_obj_read_relative_to_the_deck(tmp_path):
    (tmp_path / "parts").mkdir()
    (tmp_path / "parts" / "t.stl").write_bytes(stl_binary(TETRA))
    ascii_stl = "solid t\n" + "".join(
        "facet normal 0 0 0\nouter loop\n" + "".join(f"vertex {x} {y} {z}\n" for x, y, z in tri)
        + "endloop\nendfacet\n" for tri in TETRA) + "endsolid t\n"  # fmt: skip
    (tmp_path / "parts" / "a.stl").write_text(ascii_stl)
    (tmp_path / "parts" / "t.obj").write_text(textwrap.dedent("""\
        # a tetrahedron, one quad-free face list; f with v/vt/vn forms
        v 0 0 0
        v 1 0 0
        v 0 1 0
        v 0 0 1
        f 1 3 2
        f 1/1 2/1 4/1
        f 1//1 4//1 3//1
        f -3 -2 -1
        """))
    for name in ("t.stl", "a.stl", "t.obj"):
        spec = deck(f"shape: {{type: mesh, file: parts/{name}, scale: 2}}", tmp_path)
        v, f = geometry.triangulate(spec.bodies["arm"].shapes[0])
        assert volume(v, f) == pytest.approx(8 / 6, rel=1e-6), name  # scale 2: volume x 8


def test_mesh_paths_leaving_the_deck_folder_and_big_meshes_are_refused(tmp_path, monkeypatch):
    sub = tmp_path / "decks"
    sub.mkdir()
    (tmp_path / "outside.stl").write_bytes(stl_binary(TETRA))
    (sub / "big.stl").write_bytes(stl_binary(np.repeat(TETRA, 5, axis=0)))
    with pytest.raises(DeckError, match="leaves the deck's folder"):
        deck("shape: {type: mesh, file: ../outside.stl}", sub)
    with pytest.raises(DeckError, match="leaves the deck's folder"):
        deck(f"shape: {{type: mesh, file: {tmp_path / 'outside.stl'}}}", sub)
    monkeypatch.setenv("MBSIM_MAX_MESH_TRIANGLES", "10")
    with pytest.raises(DeckError, match="MBSIM_MAX_MESH_TRIANGLES"):
        deck("shape: {type: mesh, file: big.stl}", sub)
    monkeypatch.setenv("MBSIM_MAX_MESH_BYTES", "100")
    with pytest.raises(DeckError, match="MBSIM_MAX_MESH_BYTES"):
        deck("shape: {type: mesh, file: big.stl}", sub)
    (sub / "bad.stl").write_text("not a mesh")
    with pytest.raises(DeckError, match="not an STL file"):
        deck("shape: {type: mesh, file: bad.stl}", sub)
    with pytest.raises(DeckError, match="no such file"):
        deck("shape: {type: mesh, file: gone.obj}", sub)


def test_inertia_box_has_the_body_inertia():
    m, edges = 3.0, np.array([0.4, 0.2, 0.1])
    a, b, c = edges
    J = m / 12 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])
    got, axes = geometry.inertia_box(m, J)
    assert sorted(got) == pytest.approx(sorted(edges), rel=1e-12)


def test_default_shape_is_the_inertia_box_with_rods_to_the_joints():
    spec = deck("")
    assert spec.bodies["arm"].shapes is None
    pts = geometry.attachment_points(spec)["arm"]
    pieces = geometry.default_shapes(spec, "arm", pts)
    v, f, _ = geometry.body_mesh(pieces, "#888888")
    # box edges sqrt(6 (I_y + I_z - I_x) / m) = 1.22 m clipped to the reach 0.5 m along x';
    # the rod reaches the pin at x' = -0.5
    assert v[:, 0].min() == pytest.approx(-0.5, abs=0.02)
    assert np.ptp(v[:, 1]) == pytest.approx(np.sqrt(6 * 0.02 / 2), rel=1e-9)
    assert geometry.default_shapes(spec, "ground", []) == []


def test_shapes_and_layout_reach_the_result_file(tmp_path):
    from mbsim.api import load_model, run_model
    from mbsim.output import read_result, write_result

    (tmp_path / "deck.yaml").write_text(DECK.replace("{shape}", "shape: {type: box, size: "
                                                     "[1, 0.1, 0.1]}"))  # fmt: skip
    spec, model = load_model(tmp_path / "deck.yaml")
    res = run_model(model, "dynamic", {"t_end": 0.1, "step": 0.05, "error_estimate": False},
                    deck=spec)
    write_result(res, tmp_path / "r.h5")
    scene = geometry.read_scene(read_result(tmp_path / "r.h5"))
    v, f, c = scene.meshes["arm"]
    assert np.ptp(v, axis=0) == pytest.approx([1, 0.1, 0.1])
    assert "ground" not in scene.meshes
    assert scene.layout["bodies"]["arm"]["shape"] == "deck"
    assert [j["name"] for j in scene.layout["joints"]] == ["pin"]
    assert scene.r.shape == (3, 2, 3)


def test_a_body_without_recorded_pose_is_not_drawn(tmp_path):
    """`outputs: only:` may leave a body's r or p out of the file: no mesh, not one at the
    origin."""
    from mbsim.api import load_model, run_model

    (tmp_path / "deck.yaml").write_text(DECK.replace("{shape}", "shape: {type: box, size: "
                                                     "[1, 0.1, 0.1]}"))  # fmt: skip
    spec, model = load_model(tmp_path / "deck.yaml")
    res = run_model(model, "dynamic", {"t_end": 0.1, "step": 0.05, "error_estimate": False},
                    deck=spec)
    del res.channels["bodies/arm/p"]
    assert "arm" not in geometry.read_scene(res).meshes
