"""Four-bar deck: Table 12.3.1's Izz = 0 inertias warn but the deck runs (both models)."""

from pathlib import Path

import numpy as np
import pytest

from mbsim.analyses.kinematic import kinematic
from mbsim.api import load_model

DECK = Path(__file__).resolve().parents[2] / "models" / "four_bar.yaml"


def test_izz_zero_is_a_warning_not_an_error():
    spec, _ = load_model(DECK)
    assert any("triangle" in w or "zero" in w for w in spec.warnings), spec.warnings


@pytest.mark.parametrize("scene", ["inverse1", "inverse2"])
def test_driven_four_bar_runs(scene):
    _, model = load_model(DECK, scene=scene)
    res = kinematic(model, {"t_end": 2.0, "step": 0.02})
    assert res.complete, res.message
    # link 1 turns at omega = pi rad/s about x: after 2 s it is back where it started
    w = res.channel("bodies/link1/omega").data
    assert np.allclose(w[:, 0], np.pi, atol=1e-9) and np.allclose(w[:, 1:], 0, atol=1e-9)
    c = res.channel("points/centroid_CD/position").data
    assert np.abs(c[-1] - c[0]).max() < 1e-8
    # CD's centroid moves on a circle of radius 3.7 about D's axis (global y through D)
    d = c - np.array([-4.0, -8.5, 0.0])
    assert np.allclose(np.hypot(d[:, 0], d[:, 2]), 3.7, atol=1e-8)
    assert np.allclose(c[:, 1], -8.5, atol=1e-8)
