"""Measures as output channels (mbsim.measures) and the vectorised Recorder."""

from pathlib import Path

import numpy as np
import pytest

from mbsim.analyses.common import Recorder, body_kinematics
from mbsim.api import load_model, run_model
from mbsim.errors import DeckError

MODELS = Path(__file__).resolve().parents[1] / "models"
SLIDER = (MODELS / "slider_crank.yaml").read_text()

SLIDER_MEASURES = SLIDER.replace("""outputs:
  points:
""", """outputs:
  measures:
    crank: {type: joint_angle, joint: A}
    crank_rate: {type: joint_rate, joint: A}
    slide: {type: joint_translation, joint: T}
    slide_rate: {type: joint_translation_rate, joint: T}
    v_pin: {type: point_velocity, body: crank, point: [0, 0.08, 0]}
    a_pin: {type: point_acceleration, body: crank, point: [0, 0.08, 0]}
    rod_length: {type: distance, bodies: [crank, slider], points: {crank: [0, 0.08, 0]}}
    heading: {type: body_angle, body: crank, axis: x, ref: y}
    twice: {type: expression, value: '2*crank + 0*t', unit: rad}
    vx2: {type: expression, value: 'v_pin_y**2 + v_pin_z**2', unit: m^2/s^2}
  points:
""")


def write(tmp_path, text, name="deck.yaml"):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.fixture(scope="module")
def slider_run(tmp_path_factory):
    path = write(tmp_path_factory.mktemp("m"), SLIDER_MEASURES)
    spec, model = load_model(path)
    return model, run_model(model, "kinematic", {"t_end": 2.5, "step": 0.005}, deck=spec)


def d_dt(res, y):
    return np.gradient(y, res.t, axis=0, edge_order=2)


def test_joint_measures_closed_form_and_rates(slider_run):
    """The crank turns at -2 pi rad/s from pi/2 (the deck's driver, which measures the same
    angle as joint_angle): theta = pi/2 - 2 pi t, unwrapped over 2.5 turns.  The slider's
    travel along T (f of the slider, from the slider to ground's point) is -x_slider.  Rates
    against finite differences of the values (step 5 ms, 2nd order: error ~ (w h)^2 / 6 =
    1.6e-4 relative)."""
    _, res = slider_run
    t = res.t
    th = res.channel("measures/crank").data
    np.testing.assert_allclose(th, np.pi / 2 - 2 * np.pi * t, atol=1e-9)
    assert th[-1] < -4 * np.pi  # unwrapped
    np.testing.assert_allclose(res.channel("measures/crank_rate").data, -2 * np.pi, rtol=1e-9)
    x = res.channel("points/slider/position").data[:, 0]
    s = res.channel("measures/slide").data
    np.testing.assert_allclose(s, -x, atol=1e-12)
    sd = res.channel("measures/slide_rate").data
    inner = slice(2, -2)
    np.testing.assert_allclose(sd[inner], d_dt(res, s)[inner], atol=1e-3 * np.abs(sd).max())
    assert res.channel("measures/crank").unit == "rad"
    assert res.channel("measures/slide_rate").unit == "m/s"


def test_point_velocity_acceleration_distance_and_expressions(slider_run):
    """Pin B moves on a circle of radius 0.08 about the crank axis at 2 pi rad/s: |v| = 0.08
    * 2 pi, |a| = 0.08 (2 pi)^2 (closed form); v and a equal finite differences of the
    pin's position; the pin-slider distance is the rod length ell = 0.3 (a constraint)."""
    _, res = slider_run
    w = 2 * np.pi
    v = res.channel("measures/v_pin").data
    a = res.channel("measures/a_pin").data
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 0.08 * w, rtol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(a, axis=1), 0.08 * w**2, rtol=1e-9)
    pos = res.channel("points/pin_B/position").data
    inner = slice(2, -2)
    np.testing.assert_allclose(v[inner], d_dt(res, pos)[inner], atol=1e-3 * 0.08 * w)
    np.testing.assert_allclose(a[inner], d_dt(res, v)[inner], atol=1e-3 * 0.08 * w**2)
    np.testing.assert_allclose(res.channel("measures/rod_length").data, 0.3, atol=1e-9)
    # body_angle of the crank about global x from its y' axis: the crank angle again
    # (from the global y axis), unwrapped
    np.testing.assert_allclose(res.channel("measures/heading").data,
                               res.channel("measures/crank").data, atol=1e-9)
    np.testing.assert_allclose(res.channel("measures/twice").data,
                               2 * res.channel("measures/crank").data)
    np.testing.assert_allclose(res.channel("measures/vx2").data, (0.08 * w) ** 2, rtol=1e-9)
    assert res.channel("measures/v_pin").components == ("x", "y", "z")


def test_energy_expression_equals_the_dynamic_monitor(tmp_path):
    """kinetic_energy + potential_energy (vectorised over time from the recorded states)
    equals the dynamic analysis' own monitors/energy (its equations of motion code), and a
    sum of channels (the spring's force twice) through `channels:`."""
    gov = (MODELS / "governor.yaml").read_text().replace("""outputs:
  points:
""", """outputs:
  measures:
    E: {type: expression, value: 'kinetic_energy + potential_energy', unit: J}
    two_f: {type: expression, value: 'f + f', unit: N, channels: {f: forces.spring.force}}
  points:
""")
    spec, model = load_model(write(tmp_path, gov))
    res = run_model(model, "dynamic", {"t_end": 0.3, "step": 0.01}, deck=spec)
    np.testing.assert_allclose(res.channel("measures/E").data,
                               res.channel("monitors/energy").data, rtol=1e-10)
    np.testing.assert_allclose(res.channel("measures/two_f").data,
                               2 * res.channel("forces/spring/force").data)


def test_body_angle_of_a_free_spin_is_unwrapped(tmp_path):
    """A free body spinning at 5 rad/s about global z: its angle about z is 5 t (10 rad at
    2 s, beyond pi: unwrapped); about x, of its z' axis (which stays along global z) from
    global y: pi/2 throughout."""
    deck = """
title: spin
bodies:
  top: {mass: 1, inertia: [1, 2, 3], omega: [0, 0, 5]}
outputs:
  measures:
    yaw: {type: body_angle, body: top, axis: z}
    roll: {type: body_angle, body: top, axis: x, ref: z}
"""
    spec, model = load_model(write(tmp_path, deck))
    res = run_model(model, "dynamic", {"t_end": 2.0, "step": 0.01, "rtol": 1e-10,
                                       "atol": 1e-12}, deck=spec)
    np.testing.assert_allclose(res.channel("measures/yaw").data, 5 * res.t, atol=1e-7)
    np.testing.assert_allclose(res.channel("measures/roll").data, np.pi / 2, atol=1e-9)


def test_only_restricts_channels(tmp_path):
    text = SLIDER_MEASURES.replace("outputs:\n", "outputs:\n  only: [measures.crank, "
                                   "'points.*.position', bodies.crank]\n", 1)
    spec, model = load_model(write(tmp_path, text))
    res = run_model(model, "kinematic", {"t_end": 0.1, "step": 0.01}, deck=spec)
    names = set(res.channels)
    assert "measures/crank" in names and "measures/crank_rate" not in names
    assert {"points/slider/position", "points/pin_B/position"} <= names
    assert "points/slider/velocity" not in names
    assert {n for n in names if n.startswith("bodies/")} == {
        f"bodies/crank/{k}" for k in ("r", "p", "rd", "omega", "omega_local", "rdd", "omegad",
                                      "omegad_local")}
    assert not any(n.startswith(("constraints/", "drivers/")) for n in names)


@pytest.mark.parametrize("bad, message", [
    ("  only: [speed]\n", "outputs.only[0]: expected a channel name or pattern"),
    ("  measures:\n    a: {type: joint_angle, joint: T}\n",
     "needs a revolute or cylindrical joint; T is translational"),
    ("  measures:\n    a: {type: expression, value: 'crank + 1'}\n", "unknown name 'crank'"),
])
def test_bad_output_sections_are_deck_errors(tmp_path, bad, message):
    text = SLIDER.replace("outputs:\n", "outputs:\n" + bad, 1)
    with pytest.raises(DeckError) as exc:
        load_model(write(tmp_path, text))
    assert message in str(exc.value) and "deck.yaml" in str(exc.value)


def test_recorder_matches_the_per_instant_kinematics(slider_run):
    """The vectorised recorder gives, at every output, what body_kinematics gives for that
    instant alone (the per-output code it replaced), for every body channel and point."""
    model, res = slider_run
    rec = Recorder(model, capacity=4)  # grows several times
    rng = np.random.default_rng(1)
    qs = rng.normal(size=(20, model.nq))
    for k, q in enumerate(qs):
        rec.add(0.1 * k, q, rng.normal(size=model.nq), rng.normal(size=model.nq))
    out = rec.result("kinematic", only=("bodies", "points"))
    for k in (0, 7, 19):
        kin = body_kinematics(model, rec.q[k], rec.qd[k], rec.qdd[k])
        for b, name in enumerate(model.body_names):
            for key in ("r", "p", "rd", "omega", "omega_local", "rdd", "omegad",
                        "omegad_local"):
                np.testing.assert_allclose(out.channel(f"bodies/{name}/{key}").data[k],
                                           kin[key][b], rtol=1e-13, atol=1e-13)
        for name, b, s in model.outputs:
            sg = kin["A"][b] @ s
            np.testing.assert_allclose(out.channel(f"points/{name}/velocity").data[k],
                                       kin["rd"][b] + np.cross(kin["omega"][b], sg),
                                       rtol=1e-13, atol=1e-13)
