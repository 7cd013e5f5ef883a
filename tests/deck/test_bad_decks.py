"""One test per bad input: each error is ONE line naming the file, the key path, the line
(where there is one) and what was expected/received."""

from __future__ import annotations

from pathlib import Path

import pytest

from mbsim.deck import load_deck
from mbsim.errors import DeckError

DECK = """\
title: bad decks start from this one
parameters:
  k: 1000
  L: 0.16
bodies:
  ground: {ground: true}
  spindle:
    mass: 200
    inertia: [25, 25, 0.5]
  ball1:
    mass: 1
    inertia: [1.0e-4, 1.0e-4, 1.0e-4]
    r: [-0.16, 0, 0]
    p: [1, 0, 0, 0]
joints:
  REV2:
    type: revolute
    bodies: [spindle, ball1]
    points:
      spindle: {P: [0, 0, 0], Q: [0, 1, 0], R: [1, 0, 0]}
      ball1: {P: [L, 0, 0], Q: [L, 1, 0]}
forces:
  spring:
    type: tsda
    bodies: [spindle, ball1]
    points: {spindle: [0, 0, 0], ball1: [0, 0, 0]}
    k: k
    L0: 0.15
"""


def fails(tmp_path: Path, old: str, new: str, path: str, *parts: str, at: str | None = None,
          **kw) -> str:  # fmt: skip
    """Load DECK with ``old`` replaced by ``new``; the error must be one line with the file,
    ``path``, the line of the (first) line containing ``at`` (default: ``new``'s first line)
    and all ``parts``."""
    assert old in DECK
    text = DECK.replace(old, new, 1)
    deck = tmp_path / "bad.yaml"
    deck.write_text(text)
    with pytest.raises(DeckError) as err:
        load_deck(deck, **kw)
    msg = str(err.value)
    assert "\n" not in msg
    snippet = (at if at is not None else new).splitlines()[0].strip()
    line = next(i for i, ln in enumerate(text.splitlines(), 1) if snippet in ln)
    assert msg.startswith(f"{deck}:{line}: {path}: "), msg
    for part in parts:
        assert part in msg, msg
    assert err.value.where.path == path and err.value.where.line == line
    return msg


def test_the_base_deck_is_good(tmp_path):
    deck = tmp_path / "good.yaml"
    deck.write_text(DECK)
    assert set(load_deck(deck).bodies) == {"ground", "spindle", "ball1"}


# -- references, keys, shapes -------------------------------------------------------------------
def test_unknown_body(tmp_path):
    fails(tmp_path, "bodies: [spindle, ball1]", "bodies: [spindle, ball2]",
          "joints.REV2.bodies[1]", "unknown body 'ball2'", "did you mean 'ball1'?")  # fmt: skip


def test_unknown_key_with_suggestion(tmp_path):
    fails(tmp_path, "    mass: 200", "    mas: 200", "bodies.spindle.mas",
          "unknown key 'mas'", "did you mean 'mass'?")  # fmt: skip


def test_unknown_top_level_key(tmp_path):
    fails(tmp_path, "joints:", "joint:", "joint", "unknown key 'joint'", "did you mean 'joints'?")


def test_missing_field(tmp_path):
    fails(tmp_path, "    mass: 200\n", "", "bodies.spindle", "missing required key 'mass'",
          at="  spindle:")  # fmt: skip


def test_missing_distance(tmp_path):
    fails(tmp_path, "type: revolute", "type: revolute-spherical", "joints.REV2",
          "missing required key 'distance'", at="  REV2:")  # fmt: skip


def test_wrong_vector_length(tmp_path):
    fails(tmp_path, "Q: [L, 1, 0]", "Q: [0, 1]", "joints.REV2.points.ball1.Q",
          "expected 3 numbers, got [0.0, 1.0]", at="ball1: {P")  # fmt: skip


def test_non_numeric_entry(tmp_path):
    fails(tmp_path, "r: [-0.16, 0, 0]", "r: [-0.16, zero, 0]", "bodies.ball1.r[1]",
          "unknown parameter 'zero'")  # fmt: skip


def test_flat_point_row_of_wrong_length(tmp_path):
    fails(tmp_path, "ball1: {P: [L, 0, 0], Q: [L, 1, 0]}", "ball1: [0, 0, 0, 0, 1]",
          "joints.REV2.points.ball1", "expected 3, 6 or 9 numbers")  # fmt: skip


def test_missing_point_q(tmp_path):
    fails(tmp_path, "ball1: {P: [L, 0, 0], Q: [L, 1, 0]}", "ball1: {P: [L, 0, 0]}",
          "joints.REV2.points.ball1", "needs points P, Q; Q missing")  # fmt: skip


def test_unknown_joint_type(tmp_path):
    fails(tmp_path, "type: revolute", "type: revolut", "joints.REV2.type",
          "did you mean 'revolute'?")  # fmt: skip


# -- joint geometry ----------------------------------------------------------------------------
def test_r_parallel_to_axis(tmp_path):
    fails(tmp_path, "R: [1, 0, 0]", "R: [0, 3, 0]", "joints.REV2.points.spindle.R",
          "P→R is parallel to P→Q", at="spindle: {P")  # fmt: skip


def test_r_nearly_parallel_to_axis(tmp_path):
    fails(tmp_path, "R: [1, 0, 0]", "R: [0.005, 1, 0]", "joints.REV2.points.spindle.R",
          "P→R is nearly parallel to P→Q", at="spindle: {P")  # fmt: skip


def test_zero_length_axis(tmp_path):
    fails(tmp_path, "Q: [L, 1, 0]", "Q: [L, 0, 0]", "joints.REV2.points.ball1.Q",
          "zero-length axis P→Q", at="ball1: {P")  # fmt: skip


# -- bodies ------------------------------------------------------------------------------------
def test_zero_mass(tmp_path):
    fails(tmp_path, "mass: 200", "mass: 0", "bodies.spindle.mass", "mass must be > 0, got 0")


def test_negative_mass(tmp_path):
    fails(tmp_path, "mass: 200", "mass: -2", "bodies.spindle.mass", "mass must be > 0, got -2")


def test_negative_principal_moment(tmp_path):
    fails(tmp_path, "inertia: [25, 25, 0.5]", "inertia: [1, 1, 1, 2, 0, 0]",
          "bodies.spindle.inertia", "negative principal moment (-1 kg m²)")  # fmt: skip


def test_euler_parameters_far_from_unit_length(tmp_path):
    fails(tmp_path, "p: [1, 0, 0, 0]", "p: [1.1, 0, 0, 0]", "bodies.ball1.p",
          "Euler parameters have length 1.1; expected unit length")  # fmt: skip


def test_omega_and_omega_local(tmp_path):
    fails(tmp_path, "p: [1, 0, 0, 0]", "omega: [0, 0, 1]\n    omega_local: [0, 0, 1]",
          "bodies.ball1.omega_local", "not both", at="omega_local")  # fmt: skip


# -- files that are not decks --------------------------------------------------------------------
def test_not_yaml(tmp_path):
    deck = tmp_path / "bad.yaml"
    deck.write_text("title: x\nkey: [unclosed\n")
    with pytest.raises(DeckError) as err:
        load_deck(deck)
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith(f"{deck}:3: not valid YAML")
    assert "line 3, column 1" in msg


def test_binary_file(tmp_path):
    deck = tmp_path / "bad.yaml"
    deck.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\xff\xfe")
    with pytest.raises(DeckError) as err:
        load_deck(deck)
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith(f"{deck}:1: not a text file")


def test_text_with_control_characters(tmp_path):
    deck = tmp_path / "bad.yaml"
    deck.write_bytes(b"title: x\nbodies: \x00\x01\n")
    with pytest.raises(DeckError) as err:
        load_deck(deck)
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith(f"{deck}:2: not a YAML text file")


def test_missing_file(tmp_path):
    deck = tmp_path / "nowhere.yaml"
    with pytest.raises(DeckError) as err:
        load_deck(deck)
    assert str(err.value) == f"{deck}: no such deck file"


def test_top_level_not_a_mapping(tmp_path):
    deck = tmp_path / "bad.yaml"
    deck.write_text("- bodies\n- joints\n")
    with pytest.raises(DeckError, match="expected a mapping of top-level keys"):
        load_deck(deck)


def test_duplicate_key(tmp_path):
    fails(tmp_path, "  L: 0.16\n", "  L: 0.16\n  k: 2000\n", "parameters.k",
          "duplicate key 'k' (first given on line 3)", at="k: 2000")  # fmt: skip


# -- numbers, formulas, units ------------------------------------------------------------------
def test_bad_formula_is_never_run(tmp_path):
    fails(tmp_path, "mass: 200", "mass: \"__import__('os')\"", "bodies.spindle.mass",
          "bad formula", "__import__")  # fmt: skip


def test_unknown_parameter_name(tmp_path):
    fails(tmp_path, "    k: k", "    k: kk", "forces.spring.k", "unknown parameter 'kk'",
          "did you mean 'k'?")  # fmt: skip


def test_unknown_name_in_formula(tmp_path):
    fails(tmp_path, "    k: k", "    k: 2*kx", "forces.spring.k", "unknown name 'kx'",
          "did you mean 'k'?")  # fmt: skip


def test_parameter_using_a_later_one(tmp_path):
    fails(tmp_path, "  k: 1000", "  k: 2*L", "parameters.k", "uses 'L', which comes later")


def test_bad_unit(tmp_path):
    fails(tmp_path, "mass: 200", "mass: '200 kgg'", "bodies.spindle.mass", "'200 kgg'")


def test_unit_of_the_wrong_dimension(tmp_path):
    fails(tmp_path, "mass: 200", "mass: '200 m'", "bodies.spindle.mass",
          "expected a mass (SI unit kg), got '200 m'")  # fmt: skip


# -- functions, scenes, overrides -----------------------------------------------------------------
def test_table_times_not_increasing(tmp_path):
    fails(tmp_path, "forces:", "drivers:\n  d:\n    type: rotation\n    joint: REV2\n"
          "    function: {table: {t: [0, 2, 1], value: [0, 1, 2]}}\nforces:",
          "drivers.d.function.table.t", "strictly increasing", at="function:")  # fmt: skip


def test_driver_on_a_joint_of_the_wrong_type(tmp_path):
    fails(tmp_path, "forces:", "drivers:\n  d: {type: translation, joint: REV2, function: 0}\n"
          "forces:", "drivers.d.joint", "needs a translational or cylindrical joint",
          at="d: {type")  # fmt: skip


def test_unknown_scene(tmp_path):
    msg = fails(
        tmp_path,
        "forces:",
        "scenes:\n  light: {set: {parameters.k: 10}}\nforces:",
        "scenes",
        "unknown scene 'lihgt'",
        "(scenes: light)",
        scene="lihgt",
    )
    assert "did you mean 'light'?" in msg


def test_scene_path_that_does_not_exist(tmp_path):
    fails(tmp_path, "forces:", "scenes:\n  light:\n    set: {parameters.kk: 10}\nforces:",
          "scenes.light.set.parameters.kk", "no such key; did you mean parameters.k?",
          at="set: {")  # fmt: skip


def test_set_value_that_is_not_yaml(tmp_path):
    deck = tmp_path / "bad.yaml"
    deck.write_text(DECK)
    with pytest.raises(DeckError) as err:
        load_deck(deck, overrides={"parameters.k": "[1, 2"})
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith(f"{deck}: parameters.k: --set parameters.k=[1, 2")
