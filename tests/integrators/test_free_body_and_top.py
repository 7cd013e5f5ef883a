"""Rigid-body checks with known answers: a torque-free asymmetric body (Euler's equations,
conservation of angular momentum and energy) and a heavy symmetric top in steady precession
(closed form, Goldstein Sec. 5.7)."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from mbsim.analyses.dynamic import dynamic
from mbsim.rotations import A as rot_A
from mbsim.rotations import omega_local_to_pd
from tests.integrators import models as M

J = np.array([1.0, 2.0, 3.0])
W0 = np.array([0.4, 0.2, 1.0])  # rad/s, body frame: far from the unstable middle axis


def euler_equations(t, w):
    """Torque-free Euler equations J w' + w x (J w) = 0 in the body frame."""
    return -np.cross(w, J * w) / J


@pytest.mark.parametrize(
    "name,rtol,factor",
    [
        ("gcp-dop853", 1e-10, 1e3),
        ("projection-dop853", 1e-10, 1e3),
        ("gcp-rk45", 1e-9, 1e3),
        ("genalpha", 1e-7, 1e3),
    ],
)
def test_torque_free_body(name, rtol, factor):
    """omega'(t) agrees with Euler's equations integrated alone by solve_ivp (rtol 1e-12);
    H = A J omega' and T are constant.  Bounds: `factor` x rtol (global error of a 10 s run
    of ~5 rotations, scipy's test_ivp uses the same kind of scaled bound)."""
    model = M.free_body(J=tuple(J))
    q = model.q0.copy()
    qd = np.zeros(7)
    qd[3:] = omega_local_to_pd(q[3:], W0)
    res = dynamic(
        model,
        {
            "t_end": 10.0,
            "step": 0.5,
            "integrator": name,
            "rtol": rtol,
            "atol": rtol * 1e-2,
            "q0": q,
            "qd0": qd,
        },
    )
    assert res.complete, res.message
    ref = solve_ivp(
        euler_equations, (0, 10), W0, t_eval=res.t, rtol=1e-12, atol=1e-14, method="DOP853"
    )
    w = res.channel("bodies/b/omega_local").data
    assert np.abs(w - ref.y.T).max() < factor * rtol * np.abs(W0).max()
    p = res.channel("bodies/b/p").data
    H = np.array([rot_A(pk) @ (J * wk) for pk, wk in zip(p, w)])
    H0 = J * W0
    assert np.abs(H - H0).max() < factor * rtol * np.linalg.norm(H0)
    E = res.channel("monitors/energy").data
    assert np.abs(E - E[0]).max() < factor * rtol * E[0]


@pytest.mark.parametrize(
    "name",
    [
        "projection-dop853",
        pytest.param("gcp-dop853", marks=pytest.mark.slow),  # ~40 s: a re-partition per 1/4 spin
    ],
)
def test_heavy_top_steady_precession(name):
    """Spin omega3 = 100 rad/s at nutation 30 deg with the slow precession rate of the
    closed form m g l = Omega (I3 omega3 - I1 Omega cos theta): the nutation stays at 30 deg
    and the symmetry axis turns at Omega (rtol 1e-10: bounds 1e-7 leave 3 decades)."""
    l, theta = 0.1, np.radians(30.0)
    model = M.top(l=l)
    q, qd, Om = M.top_state(model, theta, 100.0, l=l)
    res = dynamic(
        model,
        {
            "t_end": 1.0,
            "step": 0.01,
            "integrator": name,
            "rtol": 1e-10,
            "atol": 1e-12,
            "q0": q,
            "qd0": qd,
        },
    )
    assert res.complete, res.message
    e3 = np.array([rot_A(p)[:, 2] for p in res.channel("bodies/top/p").data])
    nut = np.arccos(np.clip(e3[:, 2], -1, 1))
    assert np.abs(nut - theta).max() < 1e-7
    az = np.unwrap(np.arctan2(e3[:, 1], e3[:, 0]))
    rate = np.polyfit(res.t, az, 1)[0]
    assert rate == pytest.approx(Om, rel=1e-7)
    assert Om == pytest.approx(2.6325, rel=1e-4)  # the slow root for these numbers
    # the tip stays at the ground origin: position constraints held
    assert res.channel("monitors/position_violation").data.max() < 1e-9
