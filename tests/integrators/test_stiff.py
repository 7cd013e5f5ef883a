"""Stiffness and disparate masses: a stiff TSDA (k = 1e7) run by the implicit methods at steps
far above the explicit stability limit 2/omega, and a 1e4 mass ratio."""

import numpy as np
import pytest

from mbsim.analyses.dynamic import dynamic
from mbsim.model import compile_model
from tests.helpers import body, joint, pts, spec
from tests.integrators import models as M

K_SOFT, K_STIFF = 10.0, 1e7
SLIDE = {"ground": pts((0, 0, 0), (1, 0, 0), (0, 1, 0))}


def two_sliders():
    """Two 1 kg sliders on the x axis: a soft spring (10 N/m) from the ground to slider a, a
    stiff TSDA (1e7 N/m) between a and b.  Fast mode sqrt(2 k / 1 kg) = 4472 rad/s, explicit
    limit 2/omega = 4.5e-4 s; slow mode: the pair on the soft spring, sqrt(10 / 2) rad/s."""
    bodies = [
        body("ground", ground=True),
        body("a", 1.0, (0.1, 0.1, 0.1), (0, 0, 0)),
        body("b", 1.0, (0.1, 0.1, 0.1), (0.5, 0, 0)),
    ]
    tr = {"a": pts((0, 0, 0), (1, 0, 0), (0, 1, 0)), "b": pts((0, 0, 0), (1, 0, 0), (0, 1, 0))}
    joints = [
        joint("Ta", "translational", "ground", "a", {"ground": SLIDE["ground"], "a": tr["a"]}),
        joint("Tb", "translational", "ground", "b", {"ground": SLIDE["ground"], "b": tr["b"]}),
    ]
    forces = [
        M.tsda("soft", "ground", "a", (-1.0, 0, 0), (0, 0, 0), k=K_SOFT, L0=1.0),
        M.tsda("stiff", "a", "b", k=K_STIFF, L0=0.5),
    ]
    return compile_model(spec(bodies, joints, forces=forces))


def _start(model, v=0.5):
    q = model.q0.copy()
    qd = np.zeros(model.nq)
    qd[7] = qd[14] = v  # both sliders at 0.5 m/s: the fast mode is not excited
    return q, qd


@pytest.mark.parametrize("name", ["genalpha", "hht"])
def test_stiff_tsda_at_steps_far_above_the_explicit_limit(name):
    """h = 0.01 s = 22 x (2/omega): the slow motion x = (v0/w) sin(w t), w = sqrt(5), is
    followed to 1e-3 of its amplitude (second-order error (w h)^2/12 ~ 4e-5 relative, plus
    the stiff spring's compliance ~1e-6)."""
    model = two_sliders()
    q, qd = _start(model)
    res = dynamic(
        model, {"t_end": 2.0, "step": 0.05, "integrator": name, "h": 0.01, "q0": q, "qd0": qd}
    )
    assert res.complete, res.message
    w = np.sqrt(K_SOFT / 2)
    x = res.channel("bodies/a/r").data[:, 0]
    amp = 0.5 / w
    assert np.abs(x - amp * np.sin(w * res.t)).max() < 1e-3 * amp
    assert 0.01 > 20 * 2 / np.sqrt(2 * K_STIFF)


def test_stiff_tsda_adaptive_steps_are_large():
    """With error control the implicit method's mean step stays far above 2/omega."""
    model = two_sliders()
    q, qd = _start(model)
    res = dynamic(
        model,
        {
            "t_end": 2.0,
            "step": 0.1,
            "integrator": "genalpha",
            "rtol": 1e-4,
            "atol": 1e-6,
            "q0": q,
            "qd0": qd,
        },
    )
    assert res.complete, res.message
    assert 2.0 / res.counters["steps"] > 10 * 2 / np.sqrt(2 * K_STIFF)


def test_explicit_fixed_step_is_unstable_there():
    """The same step in RK4 (stability limit ~2.8/omega = 6.3e-4 s) diverges: the run stops
    as incomplete, or its energy explodes."""
    model = two_sliders()
    q, qd = _start(model, 0.5)
    qd[14] += 1e-3  # a seed for the fast mode
    res = dynamic(
        model, {"t_end": 0.5, "step": 0.05, "integrator": "rk4", "h": 0.01, "q0": q, "qd0": qd}
    )
    E = res.channel("monitors/energy").data
    assert (not res.complete) or not np.isfinite(E).all() or E.max() > 1e3 * E[0]


def chassis_and_rack():
    """Table 12.5.1 masses: chassis 1247.5 kg swinging on a revolute about z, rack 0.1 kg on a
    translational joint along the chassis x', held by a TSDA (1e4 N/m): mass ratio 1.2e4."""
    bodies = [
        body("ground", ground=True),
        body("chassis", 1247.5, (1240.1, 209.6, 139.9), (1.0, 0, 0)),
        body("rack", 0.1, (0.01, 0.01, 0.01), (1.0, 0.5, 0)),
    ]
    joints = [
        joint(
            "R",
            "revolute",
            "ground",
            "chassis",
            {
                "ground": pts((0, 0, 0), (0, 0, 1), (1, 0, 0)),
                "chassis": pts((-1, 0, 0), (-1, 0, 1), (0, 0, 0)),
            },
        ),
        joint(
            "D",
            "translational",
            "chassis",
            "rack",
            {
                "chassis": pts((0, 0.5, 0), (1, 0.5, 0), (0, 1.5, 0)),
                "rack": pts((0, 0, 0), (1, 0, 0), (0, 1, 0)),
            },
        ),
    ]
    forces = [
        M.tsda("rack_spring", "chassis", "rack", (-0.2, 0.5, 0), (0, 0, 0), k=1e4, c=1.0, L0=0.2)
    ]
    return compile_model(spec(bodies, joints, forces=forces, gravity=(0, -9.81, 0)))


@pytest.mark.parametrize("name", ["gcp-dop853", "projection", "genalpha"])
def test_mass_ratio_1e4(name):
    """The pair swings; the run completes and energy minus the damper's work is conserved:
    relative to the energy exchanged (the chassis' drop times its weight, ~1e3 J) 1e-6 at
    rtol 1e-7 for the explicit pairs, 1e-3 for the implicit method's numerical damping."""
    model = chassis_and_rack()
    q = model.q0.copy()
    res = dynamic(
        model,
        {
            "t_end": 1.0,
            "step": 0.05,
            "integrator": name,
            "rtol": 1e-7,
            "atol": 1e-9,
            "q0": q,
            "qd0": np.zeros(model.nq),
        },
    )
    assert res.complete, res.message
    E = res.channel("monitors/energy").data - res.channel("monitors/work_nonconservative").data
    y = res.channel("bodies/chassis/r").data[:, 1]
    assert y[-1] < -0.1  # it fell
    exchanged = 1247.5 * 9.81 * np.abs(y).max()
    tol = 1e-3 if name == "genalpha" else 1e-6
    assert np.abs(E - E[0]).max() < tol * exchanged
