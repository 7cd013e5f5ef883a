"""Bad parameters of the bushing, contact and stop elements through the command line: each
ends in exactly one ``error:`` line that names the deck file, the line and the key path, with
exit code 2 (deck error), no traceback.  The decks are tests/forces/data/*.yaml with one value
changed; the API-level checks of the messages are in test_bushing.py and test_contact.py."""

import re
from pathlib import Path

import pytest
from click.testing import CliRunner

from mbsim.cli import main

DATA = Path(__file__).parent / "data"

# (deck, text replaced, replacement (or tuples of them), key path in the error, words of the
# message)
CASES = [
    # negative stiffness
    ("bushing_block.yaml", "k: [8000,", "k: [-8000,", "forces.mount.k", "must not be negative"),
    ("bushing_block.yaml", "kr: [300,", "kr: [-300,", "forces.mount.kr", "must not be negative"),
    ("ball_drop.yaml", "E: 2.0e11", "k: -1.0e9", "forces.impact.k", "must be positive"),
    ("ball_drop.yaml", "E: 2.0e11", "E: -2.0e11", "forces.impact.E", "must be positive"),
    ("stops.yaml", "k: 1.0e7", "k: -1.0e7", "forces.end.k", "must be positive"),
    # negative damping
    ("bushing_block.yaml", "c: [4,", "c: [-4,", "forces.mount.c", "must not be negative"),
    ("bushing_block.yaml", "cr: [0.2,", "cr: [-0.2,", "forces.mount.cr", "must not be negative"),
    (
        "ball_drop.yaml",
        "nu: 0.3",
        "nu: 0.3\n    c_max: -10\n    depth: 1.0e-4",
        "forces.impact.c_max",
        "must be >= 0",
    ),
    (
        "stops.yaml",
        "k: 1.0e4",
        "k: 1.0e4\n    c_max: -3\n    depth: 1.0e-3",
        "forces.limit.c_max",
        "must be >= 0",
    ),
    (
        "ball_drop.yaml",
        "nu: 0.3",
        "nu: 0.3\n    c_max: 10\n    depth: -1.0e-4",
        "forces.impact.depth",
        "must be positive",
    ),
    # radius, exponent, Poisson's ratio, speeds
    ("ball_drop.yaml", "radius: R", "radius: -R", "forces.impact.radius", "must be positive"),
    ("ball_drop.yaml", "radius: R", "radius: 0", "forces.impact.radius", "must be positive"),
    (
        "ball_drop.yaml",
        "normal: [0, 0, 1]",
        "radius_i: -0.01",
        "forces.impact.radius_i",
        "radius_i goes with sphere-sphere",
    ),
    (
        "ball_drop.yaml",
        "geometry: sphere-plane",
        "geometry: sphere-sphere",
        "forces.impact.normal",
        "normal goes with sphere-plane",
    ),
    (
        "ball_drop.yaml",
        ("geometry: sphere-plane", "normal: [0, 0, 1]"),
        ("geometry: sphere-sphere", "radius_i: -0.01"),
        "forces.impact.radius_i",
        "radius_i must be positive",
    ),
    (
        "stops.yaml",
        "k: 1.0e4",
        "k: 1.0e4\n    exponent: -1",
        "forces.limit.exponent",
        "must be positive",
    ),
    ("ball_drop.yaml", "nu: 0.3", "nu: 0.7", "forces.impact.nu", "must lie in (-1, 0.5)"),
    (
        "ball_drop.yaml",
        "nu: 0.3",
        "nu: 0.3\n    v_slip: -1",
        "forces.impact.v_slip",
        "must be positive",
    ),
    (
        "ball_drop.yaml",
        "nu: 0.3",
        "nu: 0.3\n    restitution: 0.5\n    v_impact: -1",
        "forces.impact.v_impact",
        "must be positive",
    ),
    (
        "ball_drop.yaml",
        "nu: 0.3",
        "nu: 0.3\n    restitution: 1.5\n    v_impact: 1",
        "forces.impact.restitution",
        "must lie in (0, 1]",
    ),
    # mu < 0
    ("ball_drop.yaml", "nu: 0.3", "nu: 0.3\n    mu: -0.2", "forces.impact.mu", "must be >= 0"),
    # unknown law or geometry
    (
        "ball_drop.yaml",
        "nu: 0.3",
        "nu: 0.3\n    restitution: 0.5\n    v_impact: 1\n    restitution_law: newton",
        "forces.impact.restitution_law",
        "hunt-crossley | lankarani-nikravesh | flores",
    ),
    (
        "stops.yaml",
        "k: 1.0e4",
        "k: 1.0e4\n    restitution: 0.5\n    v_impact: 1\n    restitution_law: newton",
        "forces.limit.restitution_law",
        "hunt-crossley | lankarani-nikravesh | flores",
    ),
    (
        "ball_drop.yaml",
        "geometry: sphere-plane",
        "geometry: sphere-box",
        "forces.impact.geometry",
        "sphere-plane | sphere-sphere",
    ),
    # a stop on a joint type it does not support, or a motion its joint does not allow
    (
        "stops.yaml",
        "type: revolute",
        "type: spherical",
        "forces.limit.joint",
        "needs a translational or revolute or cylindrical joint; REV is spherical",
    ),
    (
        "stops.yaml",
        "joint: T",
        "joint: T\n    motion: rotation",
        "forces.end.motion",
        "allows only motion: translation",
    ),
    ("stops.yaml", "lower: -0.1", "lower: 0.1", "forces.end.lower", "lower must be below upper"),
]


@pytest.mark.parametrize("deck, old, new, path, words", CASES,
                         ids=[f"{c[3]}:{c[4][:24]}" for c in CASES])  # fmt: skip
def test_bad_parameter_is_one_error_line_naming_file_and_key(tmp_path, deck, old, new, path,
                                                               words):  # fmt: skip
    text = (DATA / deck).read_text()
    pairs = zip(old, new) if isinstance(old, tuple) else [(old, new)]
    for a, b in pairs:
        assert text.count(a) == 1, f"{deck}: {a!r} must occur once"
        text = text.replace(a, b)
    bad = tmp_path / deck
    bad.write_text(text)
    r = CliRunner().invoke(main, ["info", str(bad)])
    assert r.exit_code == 2, r.output
    assert "Traceback" not in r.output
    errors = [line for line in r.output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1, r.output
    assert re.match(rf"error: {re.escape(str(bad))}:\d+: {re.escape(path)}: ", errors[0]), errors[0]
    assert words in errors[0]


def test_bad_parameter_stops_a_run_before_it_starts(tmp_path):
    """`mbsim run` reports the same line and writes no result file."""
    bad = tmp_path / "ball_drop.yaml"
    bad.write_text((DATA / "ball_drop.yaml").read_text().replace("radius: R", "radius: -R"))
    out = tmp_path / "ball.h5"
    r = CliRunner().invoke(main, ["run", str(bad), "--mode", "dynamic", "--t-end", "0.01",
                                  "-o", str(out)])  # fmt: skip
    assert r.exit_code == 2, r.output
    assert f"error: {bad}:" in r.output
    assert "forces.impact.radius: radius must be positive" in r.output
    assert not out.exists()


DOC = Path(__file__).resolve().parents[2] / "docs" / "deck.md"
HOST = """\
title: host of the documented force blocks
gravity: [0, 0, -9.81]
bodies:
  ground: {ground: true}
  ball: {mass: 0.03, inertia: [1.0e-6, 1.0e-6, 1.0e-6], r: [0, 0, 0.05]}
  block: {mass: 2.0, inertia: [0.3, 0.5, 0.7], r: [0.5, 0, 0.3]}
  slider: {mass: 1.0, inertia: [0.01, 0.01, 0.01], r: [-0.05, 0.5, 0]}
  shaft: {mass: 1.0, inertia: [0.01, 0.01, 0.01], r: [0, -0.5, 0]}
joints:
  T:
    type: translational
    bodies: [ground, slider]
    points:
      ground: {P: [0, 0.5, 0], Q: [1, 0.5, 0], R: [0, 1.5, 0]}
      slider: {P: [0, 0, 0], Q: [1, 0, 0], R: [0, 1, 0]}
  CYL:
    type: cylindrical
    bodies: [ground, shaft]
    points:
      ground: {P: [0, -0.5, 0], Q: [0, -0.5, 1], R: [1, -0.5, 0]}
      shaft: {P: [0, 0, 0], Q: [0, 0, 1], R: [1, 0, 0]}
"""
# each commented alternative of the block swapped in: (lines commented out, lines uncommented)
ALTERNATIVES = {
    "curves": (
        ["k: [8000", "kr: [300"],
        ["force_curves:", "torque_curves:", "{polynomial: [0, 20000]}]"],
    ),
    "hertz": (["k: 1.0e9"], ["E: 2.0e11", "nu: 0.3"]),
    "restitution": (
        ["c_max: 20", "depth: 1.0e-4"],
        ["restitution: 0.8", "v_impact: 1.0", "restitution_law: lankarani"],
    ),
    "sphere-sphere": (["normal: [0, 0, 1]"], ["radius_i: 0.02"]),
    "stop-damping": (
        ["restitution: 0.6", "v_impact: 0.5", "restitution_law: flores"],
        ["c_max: 50", "depth: 1.0e-4"],
    ),
    "stop-bodies": ([], ["bodies: [ground, slider]"]),
}


def documented_block() -> str:
    text = DOC.read_text()
    section = text[text.index("#### Every key of `bushing`, `contact` and `stop`") :]
    return section[section.index("```yaml\n") + 8 : section.index("```\n")]


def _swap(block: str, off: list[str], on: list[str]) -> str:
    out = []
    for line in block.splitlines():
        body = line.lstrip()
        pad = line[: len(line) - len(body)]
        if any(body.startswith(key) for key in off):
            line = pad + "# " + body
        elif body.startswith("# ") and any(body[2:].lstrip().startswith(k) for k in on):
            line = pad + body[2:]
        out.append(line)
    return "\n".join(out) + "\n"


@pytest.mark.parametrize("variant", [None, *ALTERNATIVES])
def test_documented_block_with_every_key_loads(variant):
    from mbsim.deck import load_deck_text
    from mbsim.model import compile_model

    block = documented_block()
    if variant == "sphere-sphere":
        block = block.replace("geometry: sphere-plane", "geometry: sphere-sphere")
    if variant is not None:
        off, on = ALTERNATIVES[variant]
        block = _swap(block, off, on)
        lines = [line.lstrip() for line in block.splitlines()]
        for key in on:  # the alternative is in use, the key it replaces commented out
            assert any(line.startswith(key) for line in lines), key
        for key in off:
            assert not any(line.startswith(key) for line in lines), key
    spec = load_deck_text(HOST + block)
    assert set(spec.forces) == {"mount", "impact", "end", "spin_stop"}
    model = compile_model(spec)
    assert len(model.forces) == 4


def test_list_forces_and_info_show_the_new_elements():
    """`mbsim list forces` has a line for each type; `mbsim info` a line for each element with
    its own figures (the stiffnesses; a stop's range and its step limit, the contact's is in
    test_contact.py)."""
    runner = CliRunner()
    listed = runner.invoke(main, ["list", "forces"])
    assert listed.exit_code == 0, listed.output
    types = {line.split()[0] for line in listed.output.splitlines() if line.strip()}
    assert {"bushing", "contact", "stop"} <= types
    info = runner.invoke(main, ["info", str(DATA / "bushing_block.yaml")])
    assert info.exit_code == 0, info.output
    assert re.search(r"bushing force: mount +ground, block; k = \[8000, 1\.2e\+04, 2e\+04\] N/m, "
                     r"kr = \[300, 450, 900\] N m/rad", info.output), info.output  # fmt: skip
    info = runner.invoke(main, ["info", str(DATA / "stops.yaml")])
    assert info.exit_code == 0, info.output
    assert re.search(r"stop force: end +ground, slider; -0\.1 \.\. 0 m, k = 1e\+07; .*keep h_max "
                     r"below", info.output), info.output  # fmt: skip
    assert re.search(r"stop force: limit +ground, disc; -1 \.\. 0 rad, k = 1e\+04; .*keep h_max "
                     r"below", info.output), info.output  # fmt: skip
