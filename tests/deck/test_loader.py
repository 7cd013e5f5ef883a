"""Decks that load: the complete fixture, numbers/units/formulas, points, orientation, inertia,
scenes and --set overrides, and the warnings that do not stop loading."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from mbsim.deck import load_deck, load_deck_text
from mbsim.deck.spec import DeckSpec, FunctionSpec
from mbsim.errors import DeckError
from mbsim.expr import Expression

DATA = Path(__file__).parent / "data"
GOVERNOR = DATA / "governor.yaml"

BASE = """\
parameters: {k: 1000}
bodies:
  ground: {ground: true}
  crank:
    mass: 0.12
    inertia: [1.0e-4, 1.0e-5, 1.0e-4]
    r: [0, 0.1, 0.12]
joints:
  A:
    type: revolute
    bodies: [ground, crank]
    points:
      ground: {P: [0, 0, 0], Q: [1, 0, 0], R: [0, 1, 0]}
      crank: {P: [0, -0.1, -0.12], Q: [1, -0.1, -0.12]}
"""


def load(text: str, **kw) -> DeckSpec:
    return load_deck_text(text, "t.yaml", **kw)


def line_of(text: str, snippet: str) -> int:
    return next(i for i, ln in enumerate(text.splitlines(), 1) if snippet in ln)


# -- the complete fixture -------------------------------------------------------------------
def test_governor_loads_completely():
    spec = load_deck(GOVERNOR)
    assert spec.file == str(GOVERNOR)
    assert spec.text == GOVERNOR.read_text()
    assert spec.title == "Flyball governor (one ball)"
    assert spec.scene is None
    np.testing.assert_allclose(spec.gravity, [0, 0, -9.81])
    assert list(spec.bodies) == ["ground", "spindle", "ball1", "collar"]
    assert list(spec.joints) == ["CYL1", "REV2", "DIST1", "CYL2", "HEIGHT"]
    assert list(spec.drivers) == ["spin", "lift", "stretch", "wobble"]
    assert list(spec.forces) == ["spring", "twist", "push", "drag"]
    assert spec.raw["forces"]["spring"]["k"] == "k"  # raw keeps what the deck says
    assert spec.warnings == []

    ground = spec.bodies["ground"]
    assert ground.ground and ground.mass == 1.0
    np.testing.assert_array_equal(ground.inertia, np.eye(3))
    np.testing.assert_array_equal(ground.p, [1, 0, 0, 0])

    spindle = spec.bodies["spindle"]
    assert spindle.mass == 200.0 and spindle.omega_local is None
    np.testing.assert_allclose(spindle.omega, [0, 0, 2 * math.pi * 600 / 60])
    ball = spec.bodies["ball1"]
    assert ball.omega is None
    np.testing.assert_allclose(ball.omega_local, [0, 0, 1])
    for body in spec.bodies.values():
        for arr in (body.r, body.p, body.inertia):
            assert isinstance(arr, np.ndarray) and arr.dtype == float
        assert body.where.file == str(GOVERNOR) and body.where.path == f"bodies.{body.name}"

    rev = spec.joints["REV2"]
    assert rev.type == "revolute" and rev.bodies == ("spindle", "ball1")
    np.testing.assert_allclose(rev.points["ball1"].P, [0.0254 * 6.3 / 2, 0, 0])
    np.testing.assert_array_equal(rev.points["ball1"].R, [0, 0, 0])
    assert spec.joints["DIST1"].data == {"distance": 0.10922}
    height = spec.joints["HEIGHT"]
    assert height.bodies == ("ground", None) and height.data["axis"] == "z"
    assert height.data["value"].kind == "constant"
    assert rev.where.line == line_of(spec.text, "REV2:")


def test_governor_functions_forces_outputs_analysis():
    spec = load_deck(GOVERNOR)
    omega0 = 2 * math.pi * 600 / 60
    spin = spec.drivers["spin"]
    assert spin.joint == "CYL1" and spin.bodies == ("ground", "spindle")
    assert spin.function.kind == "expression"
    expr = spin.function.data["expr"]
    assert isinstance(expr, Expression) and expr.names == {"t"}
    assert expr({"t": 0.5}) == pytest.approx(omega0 * 0.5)

    lift = spec.drivers["lift"].function
    assert lift.kind == "table" and lift.data["interpolation"] == "linear"
    np.testing.assert_allclose(lift.data["value"], [0, 0.01, 0])
    assert spec.drivers["stretch"].function.data == {"coefficients": [0.1, 0.01]}
    assert spec.drivers["stretch"].bodies == ("spindle", "collar")
    wobble = spec.drivers["wobble"]
    assert wobble.bodies == ("collar", None) and wobble.data == {"axis": "x"}
    np.testing.assert_allclose(wobble.points["collar"].P, [0, 0, 0.01])
    assert wobble.function.data["amplitude"] == pytest.approx(1e-3)
    assert wobble.function.data["frequency"] == pytest.approx(2 * math.pi)
    assert wobble.function.data["phase"] == 0.0

    spring = spec.forces["spring"]
    assert spring.bodies == ("spindle", "collar")
    assert spring.data == {"k": 1000.0, "c": 30.0, "L0": 0.15}
    twist = spec.forces["twist"]
    assert twist.bodies == ("spindle", "ball1") and twist.data["joint"] == "REV2"
    assert twist.points == spec.joints["REV2"].points  # the rsda works in the joint's frames
    assert twist.data["theta0"] == pytest.approx(math.radians(10))
    push = spec.forces["push"]
    assert push.data["frame"] == "global"
    assert [law.kind for law in push.data["law"]] == ["constant", "constant", "expression"]
    assert push.data["law"][2].data["expr"]({"t": 0.01}) == pytest.approx(
        -5 * math.sin(omega0 * 0.01)
    )
    np.testing.assert_allclose(spec.forces["drag"].data["vector"], [0, 0, -0.1])
    assert spec.forces["drag"].data["frame"] == "local"

    np.testing.assert_array_equal(spec.outputs["ball_centre"].point, [0, 0, 0])
    np.testing.assert_allclose(spec.outputs["collar_top"].point, [0, 0, 0.02])
    assert spec.analysis["kinematic"] == {"t_end": 1.0, "step": 0.01}
    dyn = spec.analysis["dynamic"]
    assert dyn == {"t_end": 2.0, "integrator": "dop853", "rtol": 1e-8, "max_steps": 100000}
    assert isinstance(dyn["max_steps"], int) and isinstance(dyn["t_end"], float)


# -- numbers ---------------------------------------------------------------------------------
def test_parameters_formulas_and_units():
    text = BASE.replace(
        "parameters: {k: 1000}",
        "parameters: {L: '12 in', half: L/2, n: 600, w: 2*pi*n/60, small: 1e-3}",
    ).replace("r: [0, 0.1, 0.12]", "r: [half, small, '30 mm']\n    omega: [w, '600 rpm', 0]")
    spec = load(text)
    assert spec.parameters == pytest.approx(
        {"L": 0.3048, "half": 0.1524, "n": 600.0, "w": 20 * math.pi, "small": 1e-3}
    )
    np.testing.assert_allclose(spec.bodies["crank"].r, [0.1524, 1e-3, 0.03])
    np.testing.assert_allclose(spec.bodies["crank"].omega, [20 * math.pi, 20 * math.pi, 0])


def test_string_function_without_t_is_a_constant():
    text = BASE + "drivers:\n  d: {type: rotation, joint: A, function: 'pi/2 + k*0'}\n"
    fn = load(text).drivers["d"].function
    assert fn == FunctionSpec("constant", {"value": pytest.approx(math.pi / 2)}, fn.where)


# -- points -------------------------------------------------------------------------------------
def test_nine_and_six_number_rows():
    text = BASE.replace(
        "ground: {P: [0, 0, 0], Q: [1, 0, 0], R: [0, 1, 0]}",
        "ground: [0, 0, 0,  1, 0, 0,  0, 1, 0]",
    ).replace("crank: {P: [0, -0.1, -0.12], Q: [1, -0.1, -0.12]}", "crank: [0, 0, 0, 2, 0, 0]")
    pts = load(text).joints["A"].points
    np.testing.assert_array_equal(pts["ground"].P, [0, 0, 0])
    np.testing.assert_array_equal(pts["ground"].Q, [1, 0, 0])
    np.testing.assert_array_equal(pts["ground"].R, [0, 1, 0])
    np.testing.assert_array_equal(pts["crank"].Q, [2, 0, 0])
    assert pts["crank"].R is None


def test_warning_when_r_is_more_than_1_degree_off_perpendicular():
    z = math.tan(math.radians(90 - 87.5))
    text = BASE.replace("R: [0, 1, 0]", f"R: [{z:.6f}, 1, 0]")
    spec = load(text)
    row = line_of(text, "R: [")
    assert spec.warnings == [
        f"t.yaml:{row}: joints.A.points.ground.R: P→R is 87.50° from P→Q; orthogonalised against it"
    ]
    np.testing.assert_allclose(spec.joints["A"].points["ground"].R, [z, 1, 0], atol=1e-6)


def test_89_44_degrees_is_orthogonalised_silently():
    """The vehicle's Table 12.5.2 angle (0.56 deg off perpendicular) is below the 1 deg
    warning threshold: the model orthogonalises g against f without a word."""
    z = math.tan(math.radians(90 - 89.44))
    text = BASE.replace("R: [0, 1, 0]", f"R: [{z:.6f}, 1, 0]")
    assert load(text).warnings == []


# -- bodies ---------------------------------------------------------------------------------------
def test_p_slightly_off_is_normalised_silently():
    text = BASE.replace("r: [0, 0.1, 0.12]", "r: [0, 0.1, 0.12]\n    p: [0.7071, 0.7071, 0, 0]")
    spec = load(text)
    assert spec.warnings == []
    np.testing.assert_allclose(spec.bodies["crank"].p, [2**-0.5, 2**-0.5, 0, 0])
    assert np.linalg.norm(spec.bodies["crank"].p) == pytest.approx(1.0, abs=1e-15)


def test_p_off_by_half_a_percent_is_normalised_with_a_warning():
    text = BASE.replace("r: [0, 0.1, 0.12]", "r: [0, 0.1, 0.12]\n    p: [1.005, 0, 0, 0]")
    spec = load(text)
    np.testing.assert_array_equal(spec.bodies["crank"].p, [1, 0, 0, 0])
    row = line_of(text, "p: [1.005")
    want = f"t.yaml:{row}: bodies.crank.p: Euler parameters have length 1.005; normalised"
    assert spec.warnings == [want]


def test_euler_angles_and_axis_angle():
    text = BASE.replace("r: [0, 0.1, 0.12]", "euler_deg: [90, 0, 0]")
    c = math.cos(math.pi / 4)
    np.testing.assert_allclose(load(text).bodies["crank"].p, [c, 0, 0, c], atol=1e-12)
    text = BASE.replace("r: [0, 0.1, 0.12]", "axis_angle: {axis: [2, 0, 0], angle: '90 deg'}")
    np.testing.assert_allclose(load(text).bodies["crank"].p, [c, c, 0, 0], atol=1e-12)


def test_inertia_with_products():
    text = BASE.replace("[1.0e-4, 1.0e-5, 1.0e-4]", "[4, 5, 6, 0.1, 0.2, 0.3]")
    J = load(text).bodies["crank"].inertia
    np.testing.assert_array_equal(J, [[4, 0.1, 0.3], [0.1, 5, 0.2], [0.3, 0.2, 6]])


def test_izz_zero_inertia_is_a_warning():
    # Haug's four-bar (Table 12.?) gives its links Izz = 0: the deck must still load.
    text = BASE.replace("[1.0e-4, 1.0e-5, 1.0e-4]", "[0.0016, 0.0016, 0]")
    spec = load(text)
    np.testing.assert_array_equal(np.diag(spec.bodies["crank"].inertia), [0.0016, 0.0016, 0])
    row = line_of(text, "inertia: [0.0016")
    assert len(spec.warnings) == 1
    assert spec.warnings[0].startswith(f"t.yaml:{row}: bodies.crank.inertia: ")
    assert "zero principal moment" in spec.warnings[0]


def test_triangle_inequality_is_a_warning():
    spec = load(BASE.replace("[1.0e-4, 1.0e-5, 1.0e-4]", "[1, 1, 3]"))
    assert "triangle inequality" in spec.warnings[0]


# -- scenes and --set ------------------------------------------------------------------------------
def test_scene_sets_removes_and_merges_analysis():
    spec = load_deck(GOVERNOR, scene="stiff")
    assert spec.scene == "stiff"
    assert spec.parameters["k"] == 2000.0
    assert spec.forces["spring"].data["k"] == 2000.0  # parameters are substituted after the scene
    assert spec.forces["spring"].data["c"] == 40.0
    assert "twist" not in spec.forces and "twist" not in spec.raw["forces"]
    assert spec.analysis["dynamic"]["t_end"] == 5.0
    assert spec.analysis["dynamic"]["integrator"] == "dop853"


def test_scene_that_removes_a_used_body_fails_at_the_joint():
    with pytest.raises(DeckError) as err:
        load_deck(GOVERNOR, scene="no_ball")
    row = line_of(GOVERNOR.read_text(), "bodies: [spindle, ball1]")
    assert str(err.value).startswith(
        f"{GOVERNOR}:{row}: joints.REV2.bodies[1]: unknown body 'ball1'"
    )


def test_unknown_scene_lists_the_scenes():
    with pytest.raises(DeckError, match=r"unknown scene 'stif'; did you mean 'stiff'\? "
                       r"\(scenes: stiff, no_ball\)"):  # fmt: skip
        load_deck(GOVERNOR, scene="stif")


def test_set_overrides_existing_paths():
    spec = load_deck(
        GOVERNOR,
        overrides={"parameters.k": "2000", "forces.spring.c": "40", "gravity": "[0, 0, -1.62]",
                   "bodies.spindle.r[2]": "0.5", "analysis.dynamic.t_end": "3"},
    )  # fmt: skip
    assert spec.forces["spring"].data["k"] == 2000.0
    assert spec.forces["spring"].data["c"] == 40.0
    np.testing.assert_allclose(spec.gravity, [0, 0, -1.62])
    np.testing.assert_allclose(spec.bodies["spindle"].r, [0, 0, 0.5])
    assert spec.analysis["dynamic"]["t_end"] == 3.0
    assert spec.raw["parameters"]["k"] == 2000


def test_set_after_scene_and_may_add_a_known_field():
    spec = load_deck(
        GOVERNOR,
        scene="stiff",
        overrides={"parameters.k": "3000", "bodies.collar.rdot": "[1, 0, 0]"},
    )
    assert spec.forces["spring"].data["k"] == 3000.0
    np.testing.assert_array_equal(spec.bodies["collar"].rdot, [1, 0, 0])


def test_set_nonexistent_path_is_an_error():
    with pytest.raises(DeckError) as err:
        load_deck(GOVERNOR, overrides={"parameters.kk": "1"})
    assert err.value.where.path == "parameters.kk" and err.value.where.line is None
    assert str(err.value) == (
        f"{GOVERNOR}: parameters.kk: cannot --set: no such key; did you mean parameters.k?"
    )


def test_set_bad_value_names_the_override():
    with pytest.raises(DeckError, match=r"bodies\.spindle\.mass: mass must be > 0, got -1 "
                       r"\(value from --set\)"):  # fmt: skip
        load_deck(GOVERNOR, overrides={"bodies.spindle.mass": "-1"})


# -- YAML details -----------------------------------------------------------------------------
def test_duplicate_keys_are_an_error():
    text = BASE.replace("    mass: 0.12\n", "    mass: 0.12\n    mass: 0.13\n")
    with pytest.raises(DeckError) as err:
        load(text)
    row = line_of(text, "mass: 0.13")
    assert str(err.value) == (
        f"t.yaml:{row}: bodies.crank.mass: duplicate key 'mass' (first given on line {row - 1})"
    )


def test_yaml_merge_keys_and_anchors():
    text = BASE + (
        "forces:\n"
        "  s1: &spring {type: tsda, bodies: [ground, crank], points: {ground: [0, 0, 0],"
        " crank: [0, 0, 0]}, k: k, L0: 0.1}\n"
        "  s2: {<<: *spring, k: 5}\n"
    )
    spec = load(text, overrides={"forces.s1.c": "1"})
    assert spec.forces["s1"].data == {"k": 1000.0, "c": 1.0, "L0": 0.1}
    assert spec.forces["s2"].data == {"k": 5.0, "c": 0.0, "L0": 0.1}


def test_force_laws_stay_expressions_and_measures_pass_through():
    text = BASE + (
        "forces:\n"
        "  damper: {type: tsda, bodies: [ground, crank], points: {ground: [0, 0, 0],"
        " crank: [0, 0, 0]}, law: 'k*(l - 0.1) + dv', measures: {dv: {type: time}}}\n"
        "  push: {type: force, body: crank, law: '3*t', direction: [0, 0, 1]}\n"
        "  pair: {type: torque, bodies: [ground, crank], vector: [0, 0, '2 N*m']}\n"
    )
    spec = load(text)
    law = spec.forces["damper"].data["law"]
    assert isinstance(law, Expression) and law.names == {"l", "dv"}  # k is bound
    assert law({"l": 0.2, "dv": 0.0}) == pytest.approx(100.0)
    assert spec.forces["damper"].data["measures"]["dv"].type == "time"
    push = spec.forces["push"]
    assert push.data["law"].kind == "expression" and push.data["frame"] == "global"
    np.testing.assert_array_equal(push.data["direction"], [0, 0, 1])
    assert spec.forces["pair"].bodies == ("ground", "crank")
    np.testing.assert_array_equal(spec.forces["pair"].data["vector"], [0, 0, 2])


def test_the_settings_table_lists_every_default_of_every_analysis():
    """mbsim.deck.schema.ANALYSIS_SETTINGS (what decks, --set, sweeps and run_model accept)
    holds every key of each analysis module's DEFAULTS."""
    from mbsim.api import ANALYSES, analysis_defaults
    from mbsim.deck.schema import ANALYSIS_MODES, ANALYSIS_SETTINGS

    assert set(ANALYSIS_SETTINGS) == set(ANALYSIS_MODES)
    for mode in ANALYSES:
        missing = set(analysis_defaults(mode)) - set(ANALYSIS_SETTINGS[mode])
        assert not missing, (mode, missing)


def test_a_run_leaves_the_studies_to_check(tmp_path):
    """load_deck(studies=False) (what `mbsim run` loads) does not read `studies:`; the whole
    deck (`mbsim check`, load_deck()) still refuses a study that names no scene."""
    from click.testing import CliRunner

    from mbsim.cli import main

    text = (Path(__file__).resolve().parents[2] / "models" / "governor.yaml").read_text()
    bad = text.replace("mode: dynamic, scene: governed,\n         set: {parameters.k: 2000}",
                       "mode: dynamic, scene: governd,\n         set: {parameters.k: 2000}", 1)
    assert bad != text
    deck = tmp_path / "governor.yaml"
    deck.write_text(bad)
    spec = load_deck(deck, studies=False)
    assert spec.studies == {} and "spring" in spec.forces
    with pytest.raises(DeckError, match="studies.spring_rate.cases"):
        load_deck(deck)
    res = CliRunner().invoke(main, ["check", str(deck)])
    assert res.exit_code == 2 and "governd" in res.output
    res = CliRunner().invoke(main, ["run", str(deck), "--mode", "dynamic", "--t-end", "0.02",
                                    "-o", str(tmp_path / "g.h5"), "-q"])
    assert res.exit_code == 0, res.output
