"""Animations (mbsim/animate.py, ``mbsim animate``): the 3D frames (mbsim.view.render), the
sketch taken from the deck, the projections, the frames' geometry, GIF and MP4."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from mbsim.animate import animate_result, frames, projection, sketch_from_result, sketch_of
from mbsim.api import load_model, run_model
from mbsim.cli import main
from mbsim.deck import load_deck
from mbsim.errors import UsageError
from mbsim.output import write_result

MODELS = Path(__file__).resolve().parents[1] / "models"
SLIDER = MODELS / "slider_crank.yaml"


@pytest.fixture(scope="module")
def slider_result():
    """Kinematics of the slider-crank over 0.2 s (11 outputs), as `mbsim run` stores it."""
    spec, model = load_model(SLIDER)
    result = run_model(model, "kinematic", {"t_end": 0.2, "step": 0.02}, deck=spec)
    result.settings.setdefault("overrides", {})
    return result


def test_sketch_of_the_slider_crank():
    sk = sketch_of(load_deck(SLIDER))
    assert sk.bodies == ["crank", "rod", "slider"]
    crank = {tuple(p) for p in sk.points["crank"]}
    assert crank == {(0.0, 0.0, 0.0), (0.0, 0.08, 0.0)}  # pivot A and pin B
    assert {tuple(p) for p in sk.points["rod"]} == {(0.0, 0.15, 0.0), (0.0, -0.15, 0.0)}
    assert np.allclose(sk.points["slider"], 0.0)  # drawn as a block
    assert {tuple(P) for _, P in sk.ground} == {(0.0, 0.1, 0.12), (0.0, 0.0, 0.0)}
    assert len(sk.rails) == 1 and np.allclose(sk.rails[0][2], [1, 0, 0])  # the slider's guide
    assert sk.links == [] and np.allclose(sk.up, [0, 0, 1])  # gravity -z


def test_sketch_of_the_three_body_model_and_the_governor():
    sk = sketch_of(load_deck(SLIDER, scene="three_body"))
    assert sk.bodies == ["crank", "slider"] and len(sk.links) == 1  # the massless rod B-C
    gov = sketch_of(load_deck(MODELS / "governor.yaml"))
    assert len(gov.links) == 2 and len(gov.springs) == 1  # couplers DIST1/2, the TSDA
    assert np.allclose(gov.up, [0, 1, 0])  # gravity -y


@pytest.mark.parametrize("view", ["iso", "xy", "xz", "yz"])
def test_projections_are_orthonormal(view):
    P = projection(view, np.array([0.0, 0.0, 1.0]))
    assert np.allclose(P @ P.T, np.eye(2))
    if view == "iso":  # "up" stays up, and the screen is not mirrored
        assert P[1, 2] > 0.5
        assert np.cross(P[0], P[1]) @ np.ones(3) > 0
    with pytest.raises(ValueError, match="unknown view"):
        projection("top", np.array([0.0, 0.0, 1.0]))


def test_frames_put_joint_points_together(slider_result):
    """The spherical joint B: the crank's pin and the rod's end coincide in every frame."""
    sk = sketch_of(load_deck(SLIDER))
    fr = frames(slider_result, sk, "xz", every=2)
    assert [f["t"] for f in fr] == pytest.approx(slider_result.t[::2])
    for f in fr:
        crank, rod = f["bodies"]["crank"][1], f["bodies"]["rod"][1]
        gap = np.min(np.linalg.norm(crank[:, None, :] - rod[None, :, :], axis=2))
        assert gap < 1e-9
        assert f["ground"].shape == (2, 2)


@pytest.mark.parametrize("style", ["3d", "sketch"])
def test_gif_has_one_frame_per_drawn_output(slider_result, tmp_path, style):
    path, n = animate_result(slider_result, tmp_path / "m.gif", every=3, dpi=40, size=3,
                             style=style)  # fmt: skip
    assert n == 4  # outputs 0, 3, 6, 9 of 11
    with Image.open(path) as im:
        assert im.n_frames == 4 and im.size == (120, 120)
    with pytest.raises(ValueError, match=r"name it \*\.gif"):
        animate_result(slider_result, tmp_path / "m.mp4", style="sketch")
    with pytest.raises(UsageError, match=r"name it \*\.gif or \*\.mp4"):
        animate_result(slider_result, tmp_path / "m.avi")


def test_3d_frames_show_the_shapes_moving(slider_result, tmp_path):
    """The crank turns: frames differ; every frame has shaded body pixels (many colours)."""
    from mbsim.view.geometry import read_scene
    from mbsim.view.render import render_frames

    write_result(slider_result, tmp_path / "r.h5")
    from mbsim.output import read_result

    scene = read_scene(read_result(tmp_path / "r.h5"))
    a, b = (np.asarray(im, int) for im in render_frames(scene, [0, 5], pixels=160))
    assert (np.abs(a - b).sum(axis=2) > 60).mean() > 0.005
    for img in (a, b):
        assert len(np.unique(img.reshape(-1, 3), axis=0)) > 30


def test_mp4_where_an_encoder_is_found(slider_result, tmp_path):
    from mbsim.view.render import mp4_encoder

    if mp4_encoder() is None:
        with pytest.raises(UsageError, match="no MP4 encoder"):
            animate_result(slider_result, tmp_path / "m.mp4")
        assert not (tmp_path / "m.mp4").exists()
        return
    path, n = animate_result(slider_result, tmp_path / "m.mp4", every=5, dpi=40, size=3)
    assert n == 3 and path.stat().st_size > 0


def test_animate_checks_the_output_before_drawing(slider_result, tmp_path, monkeypatch):
    """A bad -o fails at once (exit 2, one line), before a frame is drawn."""
    import mbsim.view.render as render

    write_result(slider_result, tmp_path / "r.h5")
    drawn = []
    monkeypatch.setattr(render, "render_frames", lambda *a, **k: drawn.append(1) or iter(()))
    res = CliRunner().invoke(main, ["animate", str(tmp_path / "r.h5"), "-o",
                                    str(tmp_path / "nofolder" / "a.gif")])  # fmt: skip
    assert res.exit_code == 2 and not drawn
    assert res.output.strip().splitlines() == [
        f"error: -o: output {tmp_path / 'nofolder' / 'a.gif'}: the folder "
        f"{tmp_path / 'nofolder'} does not exist"]


def test_sketch_comes_from_the_stored_deck_with_its_scene(tmp_path):
    spec, model = load_model(SLIDER, scene="three_body")
    result = run_model(model, "kinematic", {"t_end": 0.02, "step": 0.01}, deck=spec)
    result.settings.update(scene="three_body", overrides={"parameters.ell": "0.3"})
    write_result(result, tmp_path / "r.h5")
    from mbsim.output import read_result

    sk = sketch_from_result(read_result(tmp_path / "r.h5"))
    assert "rod" not in sk.bodies and len(sk.links) == 1


def test_cli_animate(slider_result, tmp_path):
    write_result(slider_result, tmp_path / "r.h5")
    runner = CliRunner()
    res = runner.invoke(
        main,
        [
            "animate",
            str(tmp_path / "r.h5"),
            "--every",
            "5",
            "--dpi",
            "30",
            "--view",
            "xy",
            "--fps",
            "10",
        ],
    )
    assert res.exit_code == 0, res.output
    assert "animation: 3 frames at 10 fps" in res.output
    assert (tmp_path / "r.gif").exists()
    bare = dataclasses.replace(slider_result, deck_text="", arrays={})
    write_result(bare, tmp_path / "nodeck.h5")
    res = runner.invoke(main, ["animate", str(tmp_path / "nodeck.h5")])
    assert res.exit_code == 2 and "holds no shapes" in res.output
    res = runner.invoke(main, ["animate", str(tmp_path / "nodeck.h5"), "--style", "sketch"])
    assert res.exit_code == 2 and "holds no deck text" in res.output
    res = runner.invoke(main, ["animate", str(tmp_path / "r.h5"), "--every", "0"])
    assert res.exit_code == 2


# -- issue 14: bodies through all their points, axes, mode shapes ----------------------------

PENDULUM2 = """
title: double pendulum
gravity: [0, -9.81, 0]
bodies:
  ground: {ground: true}
  link1: {mass: 1.0, inertia: [0.0833, 0.001, 0.0833], r: [0, -0.5, 0]}
  link2: {mass: 1.0, inertia: [0.0833, 0.001, 0.0833], r: [0, -1.5, 0]}
joints:
  top: {type: revolute, bodies: [ground, link1],
        points: {ground: [0, 0, 0, 0, 0, 1, 1, 0, 0], link1: [0, 0.5, 0, 0, 0.5, 1]}}
  mid: {type: revolute, bodies: [link1, link2],
        points: {link1: [0, -0.5, 0, 0, -0.5, 1, 1, -0.5, 0], link2: [0, 0.5, 0, 0, 0.5, 1]}}
"""


def test_a_link_hanging_from_one_joint_is_drawn_to_its_free_end(tmp_path):
    """Issue 14: the second link of a pendulum looked half as long (drawn from its centroid
    to its one joint).  Its free end, mirrored through the centroid, is drawn too; output
    points are points of their body."""
    path = tmp_path / "p.yaml"
    path.write_text(PENDULUM2 + "outputs:\n  points:\n"
                    "    tip1: {body: link1, point: [0, -0.4, 0]}\n")
    sk = sketch_of(load_deck(path))
    assert {tuple(p) for p in sk.points["link2"]} == {(0.0, 0.5, 0.0), (0.0, -0.5, 0.0)}
    assert (0.0, -0.4, 0.0) in {tuple(p) for p in sk.points["link1"]}


def test_hull_outline():
    from mbsim.animate import hull

    sq = hull(np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0.5]]))
    assert len(sq) == 5 and np.allclose(sq[0], sq[-1])  # closed, the inner point dropped
    seg = hull(np.array([[0, 0], [0.5, 0.5], [1, 1]]))
    assert {tuple(p) for p in seg} == {(0.0, 0.0), (1.0, 1.0)}


def test_mode_shape_animation(tmp_path):
    """`mbsim animate LINEAR.h5 --mode-shape K`: mode K of the double pendulum oscillating
    with its period 2 pi / Im(lambda); the joints stay together (each frame projected on the
    constraints); the second (out-of-phase) mode moves the links in opposite senses."""
    from mbsim.animate import mode_shape_result
    from mbsim.output import read_result

    path = tmp_path / "p.yaml"
    path.write_text(PENDULUM2)
    spec, model = load_model(path)
    res = run_model(model, "linear", {}, deck=spec)
    write_result(res, tmp_path / "lin.h5")
    back = read_result(tmp_path / "lin.h5")
    lam = back.arrays["linear/eigenvalues"][0]
    shaped, title = mode_shape_result(back, 3)
    assert shaped.t[-1] == pytest.approx(2 * np.pi / lam[2].imag)
    assert "mode 3" in title and "Hz" in title
    r1 = shaped.channel("bodies/link1/r").data[0]
    r2 = shaped.channel("bodies/link2/r").data[0]
    assert np.sign(r1[0]) != np.sign(r2[0]) and abs(r1[0]) > 0.01  # out of phase
    # the joint 'mid': link1's bottom and link2's top coincide
    from mbsim.rotations import A

    p1 = shaped.channel("bodies/link1/p").data[0]
    p2 = shaped.channel("bodies/link2/p").data[0]
    gap = (r1 + A(p1) @ [0, -0.5, 0]) - (r2 + A(p2) @ [0, 0.5, 0])
    assert np.linalg.norm(gap) < 1e-8
    runner = CliRunner()
    out = runner.invoke(main, ["animate", str(tmp_path / "lin.h5"), "--mode-shape", "1",
                               "--dpi", "30", "--every", "10", "--labels", "--view", "xy"])
    assert out.exit_code == 0, out.output
    out = runner.invoke(main, ["animate", str(tmp_path / "lin.h5"), "--mode-shape", "9"])
    assert out.exit_code == 2 and "modes 1 to 4" in out.output


def test_animation_reports_progress_per_frame(slider_result, tmp_path):
    """Issue 26: a progress line while frames are drawn: progress(done, total) once a frame,
    and the terminal line counts frames."""
    import io

    from mbsim.cli_study import FrameProgress

    calls = []
    animate_result(slider_result, tmp_path / "m.gif", every=2, dpi=30, size=2,
                   progress=lambda done, total: calls.append((done, total)))  # fmt: skip
    assert calls == [(float(k), 6.0) for k in range(1, 7)]  # outputs 0, 2, ..., 10
    clock = iter(range(100)).__next__
    stream = io.StringIO()
    bar = FrameProgress(stream, tty=False, clock=lambda: float(clock()))
    bar.min_interval = 0.0
    for k in range(1, 4):
        bar(float(k), 6.0)
    assert stream.getvalue().splitlines()[-1].startswith("animate  frame 3/6   50%  1 frames/s")
