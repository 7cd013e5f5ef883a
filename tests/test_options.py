"""mbsim.options: a run's settings and its deck context, resolved once where the run is
requested; the compiled model does not carry its deck (issue 24, item 6)."""

import dataclasses
from pathlib import Path

import h5py
import pytest

from mbsim.api import load_model, run_model
from mbsim.deck import load_deck_text
from mbsim.deck.spec import DeckSpec
from mbsim.errors import DeckError
from mbsim.model import Model, compile_model
from mbsim.options import NO_DECK, deck_context, run_options
from mbsim.output import write_result

MODELS = Path(__file__).resolve().parents[1] / "models"
GOVERNOR = MODELS / "governor.yaml"

MEASURED = """
title: pendulum with a measure and outputs only
gravity: [0, -9.81, 0]
bodies:
  ground: {ground: true}
  bob: {mass: 1, inertia: [0.01, 0.01, 0.01], r: [1, 0, 0]}
joints:
  pin:
    type: revolute
    bodies: [ground, bob]
    points:
      ground: {P: [0, 0, 0], Q: [0, 0, 1], R: [1, 0, 0]}
      bob: {P: [-1, 0, 0], Q: [-1, 0, 1], R: [0, 0, 0]}
outputs:
  measures:
    v_bob: {type: point_velocity, body: bob}
  only: [measures, bodies.bob.r]
analysis:
  dynamic: {t_end: 0.05, step: 0.01}
"""


def test_the_compiled_model_does_not_carry_the_deck():
    spec, model = load_model(GOVERNOR)
    assert not hasattr(compile_model(spec), "spec")
    assert "spec" not in {f.name for f in dataclasses.fields(Model)}
    assert not any(isinstance(getattr(model, f.name), DeckSpec)
                   for f in dataclasses.fields(Model))


def test_output_measures_are_compiled_into_the_model():
    spec = load_deck_text(MEASURED)
    model = compile_model(spec)
    assert list(model.measures) == ["v_bob"] == list(spec.output_measures)
    with pytest.raises(TypeError):  # read-only, as the rest of the model
        model.measures["other"] = None


def test_deck_context_holds_what_a_run_takes_from_the_deck():
    spec, _ = load_model(GOVERNOR)
    ctx = deck_context(spec)
    assert ctx.hold == ("spindle.e2", "collar.y")  # analysis.assembly.hold
    assert dict(ctx.analysis["equilibrium"]) == {"method": "steady", "body": "spindle"}
    assert ctx.only is None and ctx.text == spec.text
    assert "shapes/layout" in ctx.shapes
    assert deck_context(spec, shapes=False).shapes == {}


def test_run_options_merge_defaults_deck_and_caller_once():
    """defaults < the deck's analysis: dynamic: < the caller's; the context rides along."""
    spec, _ = load_model(GOVERNOR)
    opt = run_options("dynamic", spec, {"step": 0.02})
    assert opt["t_end"] == 2.0 and opt["step"] == 0.02 and opt["rtol"] == 1e-6
    assert opt.given == {"step"} and opt.deck == {"t_end", "step"}
    assert opt.context.hold == ("spindle.e2", "collar.y")
    assert opt.replace(progress=None).context is opt.context
    inner = opt.within("equilibrium", {"t": 0.5})  # an analysis that runs another
    assert inner["method"] == "steady" and inner["t"] == 0.5
    assert inner.context is opt.context
    plain = run_options("dynamic", None, {"step": 0.02})
    assert plain["t_end"] == 1.0 and plain.context is NO_DECK


def test_run_model_with_and_without_the_deck(tmp_path):
    """deck=: the deck's settings, outputs: only:, measures and text; without it a run of
    the model alone (defaults, every channel, no deck text)."""
    path = tmp_path / "pendulum.yaml"
    path.write_text(MEASURED)
    spec, model = load_model(path)
    res = run_model(model, "dynamic", {"error_estimate": False}, deck=spec)
    assert res.t[-1] == pytest.approx(0.05)  # the deck's t_end
    assert set(res.channels) >= {"measures/v_bob", "bodies/bob/r"}
    assert not any(c.startswith("points/") or c.startswith("bodies/bob/p")
                   for c in res.channels)
    assert res.deck_text == spec.text
    write_result(res, tmp_path / "r.h5")
    with h5py.File(tmp_path / "r.h5") as f:  # the results file stores the deck text
        assert f["deck"].asstr()[()] == path.read_text()
    bare = run_model(model, "dynamic", {"t_end": 0.02, "error_estimate": False})
    assert "bodies/bob/p" in bare.channels and "measures/v_bob" in bare.channels
    assert bare.deck_text == ""


def test_cli_run_stores_the_deck_text(tmp_path):
    from click.testing import CliRunner

    from mbsim.cli import main

    out = tmp_path / "gov.h5"
    r = CliRunner().invoke(main, ["run", str(GOVERNOR), "-m", "dynamic", "--t-end", "0.02",
                                  "-q", "-o", str(out)])
    assert r.exit_code == 0, r.output
    with h5py.File(out) as f:
        assert f["deck"].asstr()[()] == GOVERNOR.read_text()


@pytest.mark.parametrize("hold, why", [
    ("[spindle.e2, shaft.y]", "'shaft.y' is not BODY.COORD"),
    ("[collar.q]", "'collar.q' is not BODY.COORD"),
    ("collar.y", "expected a list of BODY.COORD"),
])
def test_a_bad_hold_is_a_deck_error_at_its_line(hold, why):
    text = GOVERNOR.read_text().replace("hold: [spindle.e2, collar.y]", f"hold: {hold}")
    line = text[:text.index(f"hold: {hold}")].count("\n") + 1
    with pytest.raises(DeckError, match=why) as err:
        load_deck_text(text, "governor.yaml")
    assert err.value.where.path.startswith("analysis.assembly.hold")
    assert err.value.where.line == line
