"""Animations (mbsim/animate.py, ``mbsim animate``): the sketch taken from the deck, the
projections, the frames' geometry and the GIF."""

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
from mbsim.output import write_result

MODELS = Path(__file__).resolve().parents[1] / "models"
SLIDER = MODELS / "slider_crank.yaml"


@pytest.fixture(scope="module")
def slider_result():
    """Kinematics of the slider-crank over 0.2 s (11 outputs), as `mbsim run` stores it."""
    _, model = load_model(SLIDER)
    result = run_model(model, "kinematic", {"t_end": 0.2, "step": 0.02})
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


def test_gif_has_one_frame_per_drawn_output(slider_result, tmp_path):
    path, n = animate_result(slider_result, tmp_path / "m.gif", every=3, dpi=40, size=3)
    assert n == 4  # outputs 0, 3, 6, 9 of 11
    with Image.open(path) as im:
        assert im.n_frames == 4 and im.size == (120, 120)
    with pytest.raises(ValueError, match=r"name it \*\.gif"):
        animate_result(slider_result, tmp_path / "m.mp4")


def test_sketch_comes_from_the_stored_deck_with_its_scene(tmp_path):
    _, model = load_model(SLIDER, scene="three_body")
    result = run_model(model, "kinematic", {"t_end": 0.02, "step": 0.01})
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
    write_result(dataclasses.replace(slider_result, deck_text=""), tmp_path / "nodeck.h5")
    res = runner.invoke(main, ["animate", str(tmp_path / "nodeck.h5")])
    assert res.exit_code == 2 and "holds no deck text" in res.output
    res = runner.invoke(main, ["animate", str(tmp_path / "r.h5"), "--every", "0"])
    assert res.exit_code == 2
