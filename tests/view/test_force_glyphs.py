"""The force elements drawn (mbsim.view.glyphs): a deck with a bushing, a contact and end
stops gets their primitives in the result file's layout, with the geometry the deck gives
(sphere radius and centre, plane through P_i normal to n, the bushing frames, the stop limits);
the viewer page, the 3D frames and the 2D sketch draw them."""

import json
import re

import numpy as np
import pytest

from mbsim.deck import load_deck_text
from mbsim.deck.schema import FORCE_TYPES
from mbsim.view import geometry, glyphs

R = 0.05  # the ball's radius, m
DECK = f"""\
title: a ball on a plane, a block on a bushing, a slider and a disc with end stops
units: SI
gravity: [0, 0, -9.81]
bodies:
  ground: {{ground: true}}
  ball: {{mass: 1.0, inertia: [0.001, 0.001, 0.001], r: [0, 0, 0.1]}}
  block: {{mass: 1.0, inertia: [0.01, 0.01, 0.01], r: [0.5, 0, 0.3]}}
  slider: {{mass: 1.0, inertia: [0.001, 0.001, 0.001], r: [0, 0.5, 0], rdot: [0.5, 0, 0]}}
  disc: {{mass: 1.0, inertia: [0.01, 0.01, 0.01], r: [0, -0.5, 0.2], omega: [0, 0, 2]}}
joints:
  T:
    type: translational
    bodies: [ground, slider]
    points:
      ground: {{P: [0, 0.5, 0], Q: [1, 0.5, 0], R: [0, 1.5, 0]}}
      slider: {{P: [0, 0, 0], Q: [1, 0, 0], R: [0, 1, 0]}}
  REV:
    type: revolute
    bodies: [ground, disc]
    points:
      ground: {{P: [0, -0.5, 0.2], Q: [0, -0.5, 1.2], R: [1, -0.5, 0.2]}}
      disc: {{P: [0, 0, 0], Q: [0, 0, 1], R: [1, 0, 0]}}
forces:
  impact:
    type: contact
    geometry: sphere-plane
    bodies: [ground, ball]
    points: {{ground: [0, 0, 0], ball: [0, 0, 0]}}
    normal: [0, 0, 2]
    radius: {R}
    k: 1.0e6
  mount:
    type: bushing
    bodies: [ground, block]
    points:
      ground: {{P: [0.5, 0, 0.3], Q: [0.5, 1, 0.3], R: [0.5, 0, 1.3]}}
      block: {{P: [0, 0, 0], Q: [0, 1, 0], R: [0, 0, 1]}}
    k: [1000, 1000, 1000]
    kr: [10, 10, 10]
  end:
    type: stop
    joint: T
    lower: -0.2
    upper: 0.2
    k: 1.0e6
  limit:
    type: stop
    joint: REV
    lower: -1.0
    upper: 0.5
    k: 1.0e3
  spring:
    type: tsda
    bodies: [ground, block]
    points: {{ground: [0.5, 0, 1.0], block: [0, 0, 0]}}
    k: 10
"""


@pytest.fixture(scope="module")
def result_file(tmp_path_factory):
    """The deck run for 0.1 s (the ball falls onto the plane at t = 0.1 s, the slider moves
    5 cm, the disc turns 0.2 rad), written as `mbsim run` writes it."""
    from mbsim.api import load_model, run_model
    from mbsim.output import write_result

    folder = tmp_path_factory.mktemp("glyphs")
    deck = folder / "elements.yaml"
    deck.write_text(DECK)
    spec, model = load_model(deck)
    result = run_model(model, "dynamic", {"t_end": 0.1, "step": 0.01, "error_estimate": False},
                       deck=spec)
    assert result.complete, result.message
    return write_result(result, folder / "elements.h5")


@pytest.fixture(scope="module")
def scene(result_file):
    from mbsim.output import read_result

    return geometry.read_scene(read_result(result_file))


def drawn(scene, name):
    (force,) = [f for f in scene.layout["forces"] if f["name"] == name]
    return force.get("glyphs")


def test_contact_is_drawn_as_its_plane_and_its_sphere(scene):
    square, sphere = drawn(scene, "impact")
    assert sphere["shape"] == "sphere" and sphere["body"] == "ball"
    assert sphere["radius"] == R and sphere["center"] == [0.0, 0.0, 0.0]
    assert square["shape"] == "square" and square["body"] == "ground"
    assert square["normal"] == [0.0, 0.0, 1.0]  # the deck's [0, 0, 2], normalised
    # a square of edge a about P_i = 0 in the plane z = 0: corners at a/sqrt(2) from P_i,
    # neighbours a apart; a at least PLANE_RADII sphere radii
    a = square["size"]
    assert a >= glyphs.PLANE_RADII * R
    c = np.array(square["corners"])
    np.testing.assert_allclose(c[:, 2], 0.0, atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(c, axis=1), a / np.sqrt(2), rtol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(c - np.roll(c, 1, axis=0), axis=1), a, rtol=1e-15)


def test_bushing_is_drawn_as_a_box_on_each_frame(scene):
    boxes = drawn(scene, "mount")
    assert [(b["shape"], b["body"]) for b in boxes] == [("box", "ground"), ("box", "block")]
    # frame: x = P->Q = global y, y towards R = global z, z = x cross y = global x
    axes = np.array([[0.0, 1, 0], [0, 0, 1], [1, 0, 0]])
    for box, P in zip(boxes, ([0.5, 0, 0.3], [0.0, 0, 0])):
        a = box["size"]
        np.testing.assert_allclose(box["axes"], axes, atol=1e-15)
        local = (np.array(box["corners"]) - P) @ axes.T  # corner i + 2 j + 4 k: bits on x, y, z
        bits = np.array([[i, j, k] for k in (0, 1) for j in (0, 1) for i in (0, 1)]) - 0.5
        np.testing.assert_allclose(local, a * bits, atol=1e-15)
        assert sorted(map(sorted, box["faces"])) == sorted(map(sorted, glyphs.BOX_FACES))


def test_stops_are_drawn_at_their_limits(scene):
    # translational: P_i + s f_i at s = lower, upper (P_i = (0, 0.5, 0), f_i = x)
    lower, upper = drawn(scene, "end")
    assert (lower["shape"], lower["body"]) == ("marker", "ground")
    np.testing.assert_allclose(lower["point"], [-0.2, 0.5, 0.0], atol=1e-15)
    np.testing.assert_allclose(upper["point"], [0.2, 0.5, 0.0], atol=1e-15)
    # revolute: rays from P_i at the limit angles from g_i = x about f_i = z (h_i = y)
    P = np.array([0.0, -0.5, 0.2])
    for ray, angle in zip(drawn(scene, "limit"), (-1.0, 0.5)):
        assert (ray["shape"], ray["body"]) == ("segment", "ground")
        np.testing.assert_allclose(ray["a"], P, atol=1e-15)
        d = np.array(ray["b"]) - P
        np.testing.assert_allclose(d / np.linalg.norm(d), [np.cos(angle), np.sin(angle), 0],
                                   atol=1e-15)  # fmt: skip


def test_a_force_without_a_drawing_keeps_its_spring_line(scene):
    assert drawn(scene, "spring") is None


def test_glyphs_on_a_body_without_recorded_pose_are_not_drawn(result_file):
    """`outputs: only:` may leave a body's pose out of the file: its glyphs are dropped, not
    drawn at the origin; those on the ground stay."""
    from mbsim.output import read_result

    result = read_result(result_file)
    del result.channels["bodies/ball/p"]
    scene = geometry.read_scene(result)
    assert [g["shape"] for g in drawn(scene, "impact")] == ["square"]  # on the ground
    assert len(drawn(scene, "mount")) == 2


def test_sphere_sphere_contact_draws_both_spheres():
    text = DECK.replace("geometry: sphere-plane", "geometry: sphere-sphere\n    radius_i: 0.02")
    text = text.replace("    normal: [0, 0, 2]\n", "")
    spec = load_deck_text(text)
    sphere_i, sphere_j = glyphs.force_glyphs(spec.forces["impact"], spec, 1.0)
    assert (sphere_i["body"], sphere_i["radius"]) == ("ground", 0.02)
    assert (sphere_j["body"], sphere_j["radius"]) == ("ball", R)


def test_every_drawing_is_a_force_type_and_a_new_one_is_one_entry(monkeypatch):
    """The hook for a new element (friction): one entry in DRAWINGS."""
    assert set(glyphs.DRAWINGS) <= set(FORCE_TYPES)
    spec = load_deck_text(DECK)
    mark = {"shape": "marker", "body": "block", "point": [0.0, 0, 0], "color": "#000000",
            "opacity": 1.0}  # fmt: skip
    monkeypatch.setitem(glyphs.DRAWINGS, "tsda", lambda force, spec, size: [mark])
    (spring,) = [f for f in geometry.layout(spec)["forces"] if f["name"] == "spring"]
    assert spring["glyphs"] == [mark]
    # an element in a joint (the stop here, friction to come): markers at the joint's points
    monkeypatch.setitem(glyphs.DRAWINGS, "stop", glyphs.joint_marker)
    (limit,) = [f for f in geometry.layout(spec)["forces"] if f["name"] == "limit"]
    assert [(g["shape"], g["body"], g["point"]) for g in limit["glyphs"]] == [
        ("marker", "ground", [0.0, -0.5, 0.2]), ("marker", "disc", [0.0, 0.0, 0.0])]


def test_viewer_page_carries_the_glyphs(result_file, tmp_path):
    from mbsim.view.page import build_page

    html = build_page([result_file])
    data = json.loads(re.search(r'id="mbsim-data"[^>]*>(.*?)</script>', html, re.S).group(1)
                      .replace("<\\/", "</"))  # fmt: skip
    shapes = [g["shape"] for f in data["cases"][0]["layout"]["forces"] for g in f.get("glyphs", ())]
    assert sorted(shapes) == ["box", "box", "marker", "marker", "segment", "segment", "sphere",
                              "square"]  # fmt: skip


def _near(img, color, tol=40):
    rgb = np.array([int(color[i : i + 2], 16) for i in (1, 3, 5)])
    return int((np.abs(np.asarray(img, int) - rgb).max(axis=2) < tol).sum())


def test_frames_draw_the_glyphs(scene):
    """The colours of the stops, the contact sphere and the bushing: 20 pixels or more of each
    (a 400 px frame: a dot of radius 3 px covers ~30, the sphere outline of ~12 px radius ~35,
    anti-aliasing blurs the rest) are added."""
    pytest.importorskip("PIL")
    from mbsim.view.render import render_frames

    bare = dict(scene.layout, forces=[{k: v for k, v in f.items() if k != "glyphs"}
                                      for f in scene.layout["forces"]])  # fmt: skip
    plain = geometry.Scene(scene.names, scene.t, scene.r, scene.p, scene.meshes, bare)
    (with_glyphs,) = render_frames(scene, [5], gravity=scene.layout["gravity"])
    (without,) = render_frames(plain, [5], gravity=scene.layout["gravity"])
    for color in (glyphs.STOP_COLOR, glyphs.CONTACT_COLOR, glyphs.BUSHING_COLOR):
        assert _near(with_glyphs, color) > _near(without, color) + 20, color


def test_sketch_draws_the_sphere_outline_at_its_radius(result_file):
    from mbsim.animate import frames, sketch_from_result
    from mbsim.output import read_result

    result = read_result(result_file)
    sketch = sketch_from_result(result)
    k = [g["shape"] for g in sketch.glyphs].index("sphere")
    for frame in frames(result, sketch, "xy", every=5):
        ring = frame["glyphs"][k]
        centre = frame["bodies"]["ball"][0]  # the ball's centroid, projected
        np.testing.assert_allclose(np.linalg.norm(ring - centre, axis=1), R, rtol=1e-12)


def test_viewer_builds_the_glyphs_in_a_browser(result_file, tmp_path):
    from mbsim.view.browser import dump_dom, find_chromium
    from mbsim.view.page import write_page

    if find_chromium() is None:
        pytest.skip("no Chromium on PATH (install it with .ci/browser.sh)")
    page = write_page([result_file], tmp_path / "elements.html")
    dom = dump_dom(page, "t=0.05")
    assert 'data-first-frame-ms="' in dom, "the page did not finish its first frame"
    assert 'data-glyphs="8"' in dom
