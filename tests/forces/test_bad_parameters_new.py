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
    ("ball_drop.yaml", "nu: 0.3", "nu: 0.3\n    c_max: -10\n    depth: 1.0e-4",
     "forces.impact.c_max", "must be >= 0"),
    ("stops.yaml", "k: 1.0e4", "k: 1.0e4\n    c_max: -3\n    depth: 1.0e-3",
     "forces.limit.c_max", "must be >= 0"),
    ("ball_drop.yaml", "nu: 0.3", "nu: 0.3\n    c_max: 10\n    depth: -1.0e-4",
     "forces.impact.depth", "must be positive"),
    # radius, exponent, Poisson's ratio, speeds
    ("ball_drop.yaml", "radius: R", "radius: -R", "forces.impact.radius", "must be positive"),
    ("ball_drop.yaml", "radius: R", "radius: 0", "forces.impact.radius", "must be positive"),
    ("ball_drop.yaml", "normal: [0, 0, 1]", "radius_i: -0.01", "forces.impact.radius_i",
     "radius_i goes with sphere-sphere"),
    ("ball_drop.yaml", "geometry: sphere-plane", "geometry: sphere-sphere",
     "forces.impact.normal", "normal goes with sphere-plane"),
    ("ball_drop.yaml", ("geometry: sphere-plane", "normal: [0, 0, 1]"),
     ("geometry: sphere-sphere", "radius_i: -0.01"), "forces.impact.radius_i",
     "radius_i must be positive"),
    ("stops.yaml", "k: 1.0e4", "k: 1.0e4\n    exponent: -1", "forces.limit.exponent",
     "must be positive"),
    ("ball_drop.yaml", "nu: 0.3", "nu: 0.7", "forces.impact.nu", "must lie in (-1, 0.5)"),
    ("ball_drop.yaml", "nu: 0.3", "nu: 0.3\n    v_slip: -1", "forces.impact.v_slip",
     "must be positive"),
    ("ball_drop.yaml", "nu: 0.3", "nu: 0.3\n    restitution: 0.5\n    v_impact: -1",
     "forces.impact.v_impact", "must be positive"),
    ("ball_drop.yaml", "nu: 0.3", "nu: 0.3\n    restitution: 1.5\n    v_impact: 1",
     "forces.impact.restitution", "must lie in (0, 1]"),
    # mu < 0
    ("ball_drop.yaml", "nu: 0.3", "nu: 0.3\n    mu: -0.2", "forces.impact.mu", "must be >= 0"),
    # unknown law or geometry
    ("ball_drop.yaml", "nu: 0.3",
     "nu: 0.3\n    restitution: 0.5\n    v_impact: 1\n    restitution_law: newton",
     "forces.impact.restitution_law", "hunt-crossley | lankarani-nikravesh | flores"),
    ("stops.yaml", "k: 1.0e4",
     "k: 1.0e4\n    restitution: 0.5\n    v_impact: 1\n    restitution_law: newton",
     "forces.limit.restitution_law", "hunt-crossley | lankarani-nikravesh | flores"),
    ("ball_drop.yaml", "geometry: sphere-plane", "geometry: sphere-box",
     "forces.impact.geometry", "sphere-plane | sphere-sphere"),
    # a stop on a joint type it does not support, or a motion its joint does not allow
    ("stops.yaml", "type: revolute", "type: spherical", "forces.limit.joint",
     "needs a translational or revolute or cylindrical joint; REV is spherical"),
    ("stops.yaml", "joint: T", "joint: T\n    motion: rotation", "forces.end.motion",
     "allows only motion: translation"),
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
