"""Every seed deck under every adaptive integrator starts and runs: the deck's own settings
but the integrator, over its first 0.3 s (or its whole span where shorter), no error
estimate.  Each run must end complete.  Two runs failed here before: the compressor under
generalized-alpha and HHT (the velocity noise of an index-3 method crossing the switching
surface of pistons at rest: events piling up at t_end, then h_min, and a traceback from the
diagnosis of a run in a mode with hold rows)."""

from pathlib import Path

import pytest

from mbsim.api import load_model, run_model

MODELS = Path(__file__).resolve().parents[2] / "models"
DECKS = [("governor", None), ("slider_crank", None), ("slider_crank", "free"),
         ("four_bar", None), ("parallel_fourbar", None), ("compressor", None),
         ("vehicle", None), ("vehicle", "circle"), ("andrews", None)]
INTEGRATORS = ["projection-dop853", "projection", "gcp-dop853", "gcp-rk45", "baumgarte",
               "genalpha", "hht"]
SPAN = 0.3  # s


@pytest.mark.parametrize("integrator", INTEGRATORS)
@pytest.mark.parametrize("deck, scene", DECKS, ids=[f"{d}-{s}" if s else d for d, s in DECKS])
def test_every_seed_deck_runs_under_every_adaptive_integrator(deck, scene, integrator):
    spec, model = load_model(MODELS / f"{deck}.yaml", scene=scene)
    opts = dict(spec.analysis.get("dynamic", {}))
    t0 = float(opts.get("t_start", 0.0))
    t_end = min(float(opts.get("t_end", 1.0)), t0 + SPAN)
    opts.update(integrator=integrator, error_estimate=False, t_end=t_end)
    res = run_model(model, "dynamic", opts)
    assert res.status == "complete", res.message
    assert res.t[-1] == pytest.approx(t_end, abs=1e-12)
