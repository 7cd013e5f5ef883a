"""The `tire` force element (Haug Sec. 12.5.1, Eqs. 12.5.1-12.5.3; mbsim/forces/tire.py).

One free body (the wheel assembly) with a tire at its origin; states are set by hand.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from mbsim.errors import DeckError
from mbsim.model import compile_model
from mbsim.rotations import from_axis_angle, omega_local_to_pd
from tests.forces.builders import force
from tests.forces.tire_reference import slip_angle
from tests.helpers import body, spec
from tests.reference import equations as eq

KT, R0, CA, MU, VMIN = 2.0e5, 0.30, 5.0e4, 0.8, 0.5


def wheel_model(**data):
    params = dict(kt=KT, radius=R0, c_alpha=CA, mu=MU, v_min=VMIN) | data
    tire = force("tire", "tire", ["w"], {"w": [0.0, 0.0, 0.0]}, **params)
    return compile_model(spec([body("w", 40.0, (1.0, 0.5, 1.0))], forces=[tire]))


def state(model, height=0.28, heading=0.0, v=(0.0, 0.0, 0.0), omega_local=(0.0, 0.0, 0.0)):
    """State of the wheel at `height`, turned by `heading` (rad) about z, centroid velocity
    v (global) and body angular velocity omega_local."""
    p = from_axis_angle([0.0, 0.0, 1.0], heading)
    q = np.r_[0.0, 0.0, height, p]
    qd = np.r_[v, omega_local_to_pd(p, np.asarray(omega_local, float))]
    return eq.State(model, q, qd)


def velocity(speed, direction):
    """Velocity of magnitude `speed` along the road direction at angle `direction` (rad,
    from global y about z, the book's psi_v)."""
    return (-speed * math.sin(direction), speed * math.cos(direction), 0.0)


def loads(model, st):
    F, n = np.zeros((1, 3)), np.zeros((1, 3))
    model.forces[0].apply(st, 0.0, F, n)
    return F[0], n[0]


@pytest.mark.parametrize("height", [0.25, 0.28, 0.2999, 0.30, 0.35])
def test_vertical_force_is_kt_times_deflection_without_tension(height):
    model = wheel_model()
    tire = model.forces[0]
    s = tire.state(state(model, height), 0.0)
    expected = KT * max(0.0, R0 - height)  # Haug: F_ver = k_t d, no tension off the ground
    assert s["F_ver"] == pytest.approx(expected, rel=1e-12, abs=1e-9)
    F, _ = loads(model, state(model, height))
    assert F[2] == pytest.approx(expected, rel=1e-12, abs=1e-9)
    # the potential k_t d^2 / 2 is the vertical force's: -dV/dz = F_ver
    h = 1e-7
    dV = tire.potential(state(model, height + h)) - tire.potential(state(model, height - h))
    assert -dV / (2 * h) == pytest.approx(expected, rel=1e-6, abs=KT * h)  # kink at d = 0


def test_tire_damping_adds_and_never_pulls():
    model = wheel_model(c=2000.0)
    tire = model.forces[0]
    down = tire.state(state(model, 0.29, v=(0, 0, -0.5)), 0.0)["F_ver"]
    assert down == pytest.approx(KT * 0.01 + 2000.0 * 0.5)
    up = tire.state(state(model, 0.299, v=(0, 0, 5.0)), 0.0)["F_ver"]
    assert up == 0.0  # k_t d + c d_dot < 0: clamped, a tire cannot pull the wheel down


@pytest.mark.parametrize("heading_deg", [0.0, 90.0, 180.0, 270.0, 33.0])
@pytest.mark.parametrize("beta_deg", [0.0, 2.0, -3.0])
def test_slip_angle_at_any_heading(heading_deg, beta_deg):
    """Velocity beta CCW of the heading: alpha = psi - psi_v = -beta (Eq. 12.5.1), at every
    heading; the lateral force pushes against the sideways velocity."""
    model = wheel_model()
    psi, beta = math.radians(heading_deg), math.radians(beta_deg)
    st = state(model, 0.28, psi, velocity(20.0, psi + beta))
    s = model.forces[0].state(st, 0.0)
    assert s["alpha"] == pytest.approx(-beta, abs=1e-12)
    F, _ = loads(model, st)
    v_h = np.array(velocity(20.0, psi + beta))
    lateral_velocity = v_h - (v_h @ s["u"]) * s["u"]
    assert F @ lateral_velocity <= 1e-9  # opposes sliding
    assert abs(s["F_lat"]) == pytest.approx(CA * abs(beta), rel=1e-12, abs=1e-9)
    assert math.atan2(-s["u"][0], s["u"][1]) == pytest.approx(
        math.atan2(math.sin(psi), math.cos(psi)), abs=1e-12)  # fmt: skip


def test_matches_haug_formula_in_forward_motion():
    """alpha = psi - psi_v with psi = 2 acos(e0) (12.5.2), psi_v = -atan(v_x/v_y) (12.5.3)."""
    model = wheel_model()
    for psi, beta in [(0.1, 0.02), (0.4, -0.05), (1.2, 0.03)]:
        st = state(model, 0.28, psi, velocity(15.0, psi + beta))
        e0 = st.p[0, 0]
        vx, vy = st.rd[0, 0], st.rd[0, 1]
        haug = 2 * math.acos(e0) - (-math.atan(vx / vy))
        assert model.forces[0].state(st, 0.0)["alpha"] == pytest.approx(haug, abs=1e-12)


def test_standstill_and_low_speed():
    model = wheel_model()
    tire = model.forces[0]
    s = tire.state(state(model, 0.28), 0.0)
    assert s["alpha"] == 0.0 and s["F_lat"] == 0.0  # no velocity, no slip, no force
    # sliding straight sideways at half the fade speed: alpha = 90 deg, force faded to half
    s = tire.state(state(model, 0.28, 0.0, (VMIN / 2, 0.0, 0.0)), 0.0)
    assert s["alpha"] == pytest.approx(math.pi / 2)
    assert abs(s["F_lat"]) == pytest.approx(0.5 * MU * s["F_ver"])  # smoothstep(1/2) = 1/2
    # continuous at zero speed: the force goes to 0 with the speed
    s = tire.state(state(model, 0.28, 0.0, (1e-6, 0.0, 0.0)), 0.0)
    assert abs(s["F_lat"]) < 1e-6 * s["F_ver"]
    assert slip_angle(-10.0, 0.5) == pytest.approx(math.atan(0.5 / 10.0))  # reverse


def test_saturation_at_mu_times_vertical_force():
    model = wheel_model()
    tire = model.forces[0]
    small = tire.state(state(model, 0.28, 0.0, velocity(20.0, 0.01)), 0.0)
    assert small["saturated"] == 0.0 and small["F_lat"] == pytest.approx(CA * small["alpha"])
    big = tire.state(state(model, 0.28, 0.0, velocity(20.0, 0.3)), 0.0)
    assert big["saturated"] == 1.0
    assert abs(big["F_lat"]) == pytest.approx(MU * KT * 0.02, rel=1e-12)  # F_lat = mu F_ver
    off = tire.state(state(model, 0.35, 0.0, velocity(20.0, 0.3)), 0.0)
    assert off["F_ver"] == 0.0 and off["F_lat"] == 0.0 and off["saturated"] == 0.0


def test_rolling_resistance_opposes_forward_motion():
    model = wheel_model(rolling=0.015)
    F, _ = loads(model, state(model, 0.28, 0.0, (0.0, 20.0, 0.0)))
    assert F[1] == pytest.approx(-0.015 * KT * 0.02)
    F, _ = loads(model, state(model, 0.28, 0.0, (0.0, -20.0, 0.0)))
    assert F[1] == pytest.approx(0.015 * KT * 0.02)


@pytest.mark.parametrize("seed", range(20))
def test_virtual_power_of_the_horizontal_force_is_never_positive(seed):
    """The generalized forces' power Q.qd = F.rd + n'.w' equals F.v_C (the force acts at the
    contact point C), and its horizontal part (lateral + rolling) dissipates."""
    rng = np.random.default_rng(seed)
    model = wheel_model(rolling=0.01)
    st = state(model, rng.uniform(0.26, 0.30), rng.uniform(-np.pi, np.pi),
               rng.normal(scale=5.0, size=3), rng.normal(scale=2.0, size=3))  # fmt: skip
    s = model.forces[0].state(st, 0.0)
    F, n = loads(model, st)
    power = F @ st.rd[0] + n @ st.omega_local[0]
    assert power == pytest.approx(F @ s["v"], rel=1e-10, abs=1e-9)
    horizontal = F.copy()
    horizontal[2] = 0.0
    assert horizontal @ s["v"] <= 1e-9


def test_tire_acts_at_the_road_below_the_spindle():
    """A lateral force at the contact patch, h below the spindle: moment h F_lat about the
    heading axis (the roll moment a real tire gives)."""
    model = wheel_model()
    st = state(model, 0.28, 0.0, velocity(20.0, 0.02))
    F, n = loads(model, st)
    assert n == pytest.approx(np.cross([0.0, 0.0, -0.28], F), abs=1e-9)


def test_bad_values_are_deck_errors():
    with pytest.raises(DeckError, match="kt"):
        wheel_model(kt=0.0)
    with pytest.raises(DeckError, match="mu"):
        wheel_model(mu=-0.1)
