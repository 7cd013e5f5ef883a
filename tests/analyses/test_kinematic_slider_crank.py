"""Spatial slider-crank (reference geometry §1) driven at -2 pi rad/s: slider x, xd, xdd
against the closed form x = sqrt(l^2 - B_y^2 - B_z^2) of the crank pin B(t)."""

from pathlib import Path

import numpy as np
import pytest

from mbsim.analyses.kinematic import kinematic
from mbsim.api import load_model
from mbsim.model import compile_model
from tests.helpers import slider_crank_spec


def slider_crank_model(ell, source):
    """The model built here in Python ("spec") or the shipped models/slider_crank.yaml
    ("deck"), whose header documents the same geometry (reference §1)."""
    if source == "deck":
        deck = Path(__file__).resolve().parents[2] / "models" / "slider_crank.yaml"
        return load_model(deck, overrides={"parameters.ell": ell})[1]
    return compile_model(slider_crank_spec(ell))


def closed_form(t, ell):
    w = -2 * np.pi
    th = np.pi / 2 + w * t
    By, Bz = 0.1 + 0.08 * np.cos(th), 0.12 + 0.08 * np.sin(th)
    dBy, dBz = -0.08 * np.sin(th) * w, 0.08 * np.cos(th) * w
    ddBy, ddBz = -0.08 * np.cos(th) * w * w, -0.08 * np.sin(th) * w * w
    S = By**2 + Bz**2
    dS = 2 * (By * dBy + Bz * dBz)
    ddS = 2 * (dBy**2 + dBz**2 + By * ddBy + Bz * ddBz)
    x = np.sqrt(ell**2 - S)
    xd = -dS / (2 * x)
    xdd = -ddS / (2 * x) - xd**2 / x
    return x, xd, xdd


@pytest.mark.parametrize("source", ["spec", "deck"])
@pytest.mark.parametrize("ell", [0.3, 0.27, 0.24])
def test_slider_matches_closed_form(ell, source):
    model = slider_crank_model(ell, source)
    res = kinematic(model, {"t_end": 1.0, "step": 0.01})
    assert res.complete, res.message
    x, xd, xdd = closed_form(res.t, ell)
    # Newton tolerance 1e-10 on Phi; velocity/acceleration solves are exact to round-off
    # times cond(Phi_q) (< 1e3 here), so 1e-8 is a justified bound.
    assert np.abs(res.channel("bodies/slider/r").data[:, 0] - x).max() < 1e-8
    assert np.abs(res.channel("bodies/slider/rd").data[:, 0] - xd).max() < 1e-8
    rdd = res.channel("bodies/slider/rdd").data[:, 0]
    assert np.abs(rdd - xdd).max() < 1e-8 * max(1, np.abs(xdd).max())
    # the slider first reverses at t ~ 0.11 s (reference §1.1)
    t_rev = res.t[np.argmax(np.diff(np.sign(res.channel("bodies/slider/rd").data[:, 0])) != 0)]
    assert 0.10 <= t_rev <= 0.12


def test_ctrl_c_keeps_the_finished_output_times(monkeypatch):
    """A KeyboardInterrupt in the solve of the 7th output time (t = 0.06 s) ends the run as
    incomplete with the six output times before it, every channel the same length."""
    from mbsim import core

    solve, calls = core.kinematic_state, {"n": 0}

    def interrupted(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 7:
            raise KeyboardInterrupt
        return solve(*args, **kwargs)

    monkeypatch.setattr(core, "kinematic_state", interrupted)
    res = kinematic(slider_crank_model(0.3, "deck"), {"t_end": 1.0, "step": 0.01})
    assert res.status == "incomplete" and "interrupted (Ctrl-C)" in res.message
    assert len(res.t) == 6 and res.t[-1] == pytest.approx(0.05)
    assert all(c.data.shape[0] == 6 for c in res.channels.values())
