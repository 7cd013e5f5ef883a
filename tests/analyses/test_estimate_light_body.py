"""The coarse error estimate on a mechanism with a light body (issue 23's hunt: mass ratio
1e-3 ... 1e-4).  Known fault, written down as a strict xfail so that its fix shows."""

from pathlib import Path

import pytest

from mbsim.api import load_model, run_model
from tests.helpers import position_error

DECK = Path(__file__).resolve().parents[2] / "models" / "slider_crank.yaml"


@pytest.mark.xfail(strict=True, reason=(
    "the coarse companion (the run's mesh coarsened by 2, difference / (2^8 - 1)) is not in "
    "its asymptotic regime here: about 30 % of the run's steps are rejected and the rod "
    "spins about its own axis at 36 rad/s; the estimate is 16x below the true error (the "
    "tighter companion at rtol/5 is right to 1.3x). Cause not found yet (estimate.py)"))
def test_coarse_estimate_within_factor_10_with_a_light_connecting_rod():
    """The free slider-crank with its rod 1000x lighter (5e-4 kg, inertia / 1000) at rtol
    1e-5: the default estimate (projection-dop853, coarse companion) should be within 10x of
    the true error against gcp-dop853 at rtol 1e-11 (a different method; its own error is
    below 1e-9 m, four decades under the run's 1e-4 m).  Measured: true 1.02e-4 m, estimate
    6.1e-6 m (16.6x under); at rtol 1e-6 3.7e-5 against 2.2e-6 (16.3x)."""
    sets = {"bodies.rod.mass": "5e-4", "bodies.rod.inertia": "[4e-6, 4e-7, 4e-6]"}
    spec, model = load_model(DECK, overrides=sets, scene="free")
    ref = run_model(model, "dynamic", {"integrator": "gcp-dop853", "rtol": 1e-11,
                                       "atol": 1e-13, "error_estimate": False}, deck=spec)
    res = run_model(model, "dynamic", {"rtol": 1e-5, "atol": 1e-7}, deck=spec)
    assert ref.complete and res.complete
    true = position_error(res, ref)
    est = res.summary["error_estimate"]["position"]
    assert 0.1 <= est / true <= 10, (est, true)
