"""Tight tolerances at regular points: Andrews' squeezing mechanism (models/andrews.yaml, seven
bodies, one DOF, nine redundant rows in 3-D, Phi_q condition ~360, nowhere near a change
point) with every adaptive integrator at rtol 1e-10, 1e-11 and rtol = atol = 3e-11 (the
RK families also at 1e-12), against the test set's own equations in minimal coordinates
(tests/integrators/andrews.py, which meets the test set's published solution at t = 0.03 s
to 4.7e-12 m).

gcp-dop853 and gcp-rk45 stopped here at t = 0 with "step size fell below h_min (6.7e-18
s)": at these tolerances their tangent-coordinate threshold put the start into tangent
coordinates, whose value C q is ~5e-14 there, and the starting-step formula of Hairer,
Norsett & Wanner (0.01 |y| / |y'| in the tolerances' scale) took that round-off for the
size of y; the first step now starts at least FIRST_STEP_ROOM x h_min (rk._initial_step).

Bound: the issue's 10 rtol + 1e-12 m on the centroids of the seven bodies at t = 0.03 s.
The second-order implicit methods (genalpha, hht) hold their local error to
(rtol / 1e-6)^(1/2) x the tolerances below rtol 1e-6 (GeneralizedAlpha.tolerance_factor), so
that their global error is proportional to rtol; with the error per step held to the
tolerances (before) their error grew as rtol^(2/3) and genalpha at rtol = atol = 3e-11
(9.0e-10 m), hht there (1.1e-9 m) and at 1e-11 (1.95e-10 m) exceeded the bound.  Now
3.7e-11 and 4.5e-11 m at 3e-11; hht at 1e-11 ended 2.3e-10 m off until the acceleration-like
variable's offset was rescaled at each change of step size (GeneralizedAlpha._shifted_a):
1.7e-11 m.  Each takes 30-70 s CPU (1e5-2.5e5 steps), so they are slow but for one default
case.
"""

from pathlib import Path

import numpy as np
import pytest

from mbsim.analyses.dynamic import dynamic
from mbsim.api import load_model
from mbsim.integrators import INTEGRATORS
from mbsim.options import run_options
from tests.integrators import andrews as A

DECK = "models/andrews.yaml"
SETTINGS = {"1e-10": (1e-10, None), "1e-11": (1e-11, None), "3e-11/3e-11": (3e-11, 3e-11),
            "1e-12": (1e-12, None)}
ORDER2 = {"genalpha", "hht"}
DEFAULT_ORDER2 = ("genalpha", "3e-11/3e-11")  # the index-3 family's default case
KNOWN = {}  # (setting, method) measured over the bound: strict xfails (none now)


def cases():
    out = []
    for name, cls in INTEGRATORS.items():
        if not cls.adaptive:
            continue
        for key in SETTINGS:
            if name in ORDER2 and key == "1e-12":
                continue  # some 1e6 steps of an order-2 method
            marks = []
            if name in ORDER2 and (name, key) != DEFAULT_ORDER2:
                marks.append(pytest.mark.slow)
            if (name, key) in KNOWN:
                marks.append(pytest.mark.xfail(reason=KNOWN[name, key], strict=True))
            out.append(pytest.param(name, key, id=f"{name}-{key}", marks=marks))
    return out


@pytest.fixture(scope="module")
def andrews_deck():
    """(spec, model) of the deck; its runs take the deck's settings (run_options)."""
    return load_model(DECK)


@pytest.fixture(scope="module")
def model(andrews_deck):
    return andrews_deck[1]


@pytest.fixture(scope="module")
def reference():
    return A.solve(np.array([0.0, A.T_REF]))[-1]


def test_andrews_reference_meets_the_test_set(reference):
    """The independent reference (DOP853 at rtol 1e-13 on the test set's equations) against
    the test set's published angles at t = 0.03 s: the centroids within 1e-11 m (measured
    4.7e-12 m; the angles differ by 1.1e-9 rad in beta and theta, whose sum, which moves the
    bodies, agrees to 3e-10 rad), and the constraints hold to 1e-14 m."""
    ref, pub = A.centroids(reference), A.centroids(A.Y_REF)
    assert max(np.linalg.norm(ref[b] - pub[b]) for b in A.BODIES) <= 1e-11
    assert np.abs(A.constraints(reference)).max() <= 1e-14


def test_deck_is_the_test_set_mechanism(model, andrews_deck):
    """The deck at its start: one degree of freedom with nine redundant rows (three planar
    loops), its centroids those of the test set's initial angles to round-off."""
    res = dynamic(model, run_options("dynamic", andrews_deck[0], {
        "t_end": 1e-4, "step": 1e-4, "error_estimate": False}))
    assert res.complete, res.message
    assert res.summary["dof"] == 1 and res.summary["rank"] == 55
    start = A.centroids(A.Y0)
    for b in A.BODIES:
        assert np.linalg.norm(res.channel(f"bodies/{b}/r").data[0] - start[b]) <= 1e-14


@pytest.mark.parametrize("name,key", cases())
def test_tight_tolerance_at_a_regular_point(model, andrews_deck, reference, name, key):
    rtol, atol = SETTINGS[key]
    opt = {"integrator": name, "rtol": rtol, "t_end": A.T_REF, "error_estimate": False}
    if atol is not None:
        opt["atol"] = atol
    res = dynamic(model, run_options("dynamic", andrews_deck[0], opt))
    assert res.complete, f"{name} {key}: {res.message}"
    assert res.t[-1] == pytest.approx(A.T_REF)
    err = A.position_error(res, reference)
    bound = 10 * rtol + 1e-12
    assert err <= bound, f"{name} {key}: {err:.3g} m > {bound:.3g} m"


@pytest.mark.parametrize("name", ["projection-dop853", "projection"])
@pytest.mark.xfail(strict=True, raises=AssertionError, reason=(
    "index-1 change-point measure not mass-invariant: with the connecting rod 1000x lighter the "
    "Schur measure of the regular states falls 10x (median 0.032 -> 0.0032, min 0.0024) below "
    "the switch at rtol 1e-12 (0.0037), the stages go into tangent coordinates, and their "
    "Newton iteration stops at max |Phi| = 5.9e-12, above newton_tol 1e-12 (not verified: "
    "[Phi_q; C] carrying the mass ratio through the M-orthogonal C): h_min at t = 0.066 s; "
    "gcp, whose measure is Phi_u's, completes; mbsim/integrators/changepoints.py"))
def test_tight_tolerance_with_a_light_body(name):
    """The free slider-crank with its connecting rod 1000x lighter (5e-4 kg, inertia / 1000;
    Phi_q condition 24, no change point on the way) at rtol 1e-12 completes its 2 s (issue
    23: no h_min at a regular point at any rtol >= 1e-12; the brief: mass ratios of 1e4).
    Measured: both index-1 methods stop at t = 0.066 s; complete at rtol 1e-11 and with the
    rod 100x lighter at 1e-12; gcp-dop853 complete at 1e-12."""
    sets = {"bodies.rod.mass": "5e-4", "bodies.rod.inertia": "[4e-6, 4e-7, 4e-6]"}
    deck = Path(__file__).resolve().parents[2] / "models" / "slider_crank.yaml"
    spec, model = load_model(deck, overrides=sets, scene="free")
    res = dynamic(model, {"integrator": name, "rtol": 1e-12, "atol": 1e-14, "t_end": 2.0,
                          "error_estimate": False})
    assert res.complete, res.message
