"""Joint friction under the implicit integrators: the Newton iteration's friction loads take
their normal load from the iterate's own multipliers (mbsim/fast/implicit.c leaves them in
the model, mbsim/fast/stepper.py's load_callback hands them to the friction elements)."""

from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest

from mbsim.api import load_model, run_model
from tests.helpers import position_error

DECK = Path(__file__).resolve().parents[2] / "models" / "slider_crank.yaml"


@lru_cache(maxsize=1)
def friction_scene():
    """(spec, model, reference run over 0.1 s at rtol 1e-10), shared by the two cases."""
    spec, model = load_model(DECK, scene="friction")
    ref = run_model(model, "dynamic", {"t_end": 0.1, "rtol": 1e-10, "atol": 1e-12,
                                       "error_estimate": False}, deck=spec)
    return spec, model, ref


@pytest.mark.parametrize("integrator", ["genalpha", "hht"])
def test_friction_normal_load_follows_the_newton_iterate(integrator):
    """The slider-crank's `friction` scene (Coulomb friction in the guide with the guide's
    reaction as normal load, end stops) over 0.1 s (before the first event) at rtol 1e-6:
    the implicit integrators agree with Dormand-Prince 8 at rtol 1e-10 within 10x their own
    error estimate and the friction's normal load within 1e-3 of its size (527 N; gcp-rk45
    at rtol 1e-6: 9e-3 N, 7e-8 m).  Measured: genalpha 3.1e-6 m against an estimate of
    2.4e-6 m, normal load 0.18 N off (with the last reaction loop's multipliers instead of
    the iterate's: 6.6e-4 m, 11 N)."""
    spec, model, ref = friction_scene()
    res = run_model(model, "dynamic", {"t_end": 0.1, "rtol": 1e-6, "atol": 1e-8,
                                       "integrator": integrator}, deck=spec)
    assert ref.complete and res.complete
    N, N_ref = (r.channel("forces/slider_friction/normal_load").data for r in (res, ref))
    assert np.abs(N - N_ref).max() < 1e-3 * np.abs(N_ref).max()
    assert position_error(res, ref) < 10 * res.summary["error_estimate"]["position"]
