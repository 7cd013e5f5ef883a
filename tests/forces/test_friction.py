"""Joint friction with true stick-slip (mbsim/forces/friction.py) against closed forms derived
here, run through the public API (``run_model(..., "dynamic")``) or the CLI.

Event times: an event is the root of its function g on the run's own dense output, found to
EVENT_TIME_TOL max(1, t); the solution's error e adds |dt| ~ |e_g| / |dg/dt|.  At rtol
1e-11 the position and velocity errors of these runs are below 1e-10 (m, m/s) and the rates
|dg/dt| are O(1) (k v_b = 10 N/s at a breakaway, |vdot| = k |x| / m >= 1 m/s^2 at a turning
point), so the analytic times are met to 1e-8 s with a margin of 100 or more.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from mbsim.api import load_model, run_model
from tests.helpers import INTEGRATOR_FAMILIES

G = 9.81


def run(path, **options):
    spec, model = load_model(str(path))
    return model, run_model(model, "dynamic", options, deck=spec)


def events_of(res, element):
    """[(t, event name, q)] of one element's events, in time order."""
    names, times = res.names["events"], res.arrays["events/time"][0]
    q = res.arrays["events/q"][0]
    return [(float(t), n.split(": ", 1)[1], q[k]) for k, (t, n) in enumerate(zip(times, names))
            if n.startswith(element + ": ")]


# -- a block on an incline ------------------------------------------------------------------
INCLINE = """\
title: block on an incline
gravity: [0, -{g}, 0]
bodies:
  ground: {{ground: true}}
  block: {{mass: {m}, inertia: [1, 1, 1], r: [0, 0, 0]}}
joints:
  slide:
    type: translational
    bodies: [ground, block]
    points:
      ground: {{P: [0, 0, 0], Q: [{c}, {ms}, 0], R: [{s}, {c}, 0]}}
      block: {{P: [0, 0, 0], Q: [{c}, {ms}, 0], R: [{s}, {c}, 0]}}
forces:
  fr:
    type: friction
    joint: slide
    mu_s: {mu_s}
    mu_k: {mu_k}
analysis:
  dynamic: {{t_end: 10.0, step: 0.1}}
"""


def incline(tmp_path, theta, mu_s, mu_k, m=2.0):
    """The joint axis f points down the slope (angle theta below x); the normal load is the
    joint's reaction m g cos(theta)."""
    c, s = math.cos(theta), math.sin(theta)
    path = tmp_path / "incline.yaml"
    path.write_text(INCLINE.format(g=G, m=m, c=c, s=s, ms=-s, mu_s=mu_s, mu_k=mu_k))
    return path


def test_incline_sticks_when_tan_theta_below_mu_s(tmp_path):
    """tan(30 deg) = 0.577 < mu_s = 0.7: the block never moves; the stick carries
    m g sin(theta) with the normal load m g cos(theta)."""
    theta, m = math.radians(30.0), 2.0
    model, res = run(incline(tmp_path, theta, 0.7, 0.5, m), rtol=1e-10, atol=1e-12)
    assert res.complete, res.message
    r = res.channel("bodies/block/r").data
    rd = res.channel("bodies/block/rd").data
    assert np.abs(r - r[0]).max() <= 1e-12  # position drift over 10 s
    assert np.abs(rd).max() <= 1e-14  # at rest to round-off (accelerations ~1e-16 x 10 s)
    assert np.all(res.channel("forces/fr/mode").data == 0.0)
    np.testing.assert_allclose(res.channel("forces/fr/friction").data, -m * G * math.sin(theta),
                               rtol=1e-12)
    np.testing.assert_allclose(res.channel("forces/fr/normal_load").data,
                               m * G * math.cos(theta), rtol=1e-12)
    assert "events" not in res.summary or res.summary["events"] == []


def test_incline_slides_at_g_sin_minus_mu_k_cos(tmp_path):
    """tan(30 deg) > mu_s = 0.5: the block slides from rest with a = g (sin - mu_k cos)."""
    theta, m, mu_k = math.radians(30.0), 2.0, 0.4
    model, res = run(incline(tmp_path, theta, 0.5, mu_k, m), rtol=1e-10, atol=1e-12)
    assert res.complete, res.message
    a = G * (math.sin(theta) - mu_k * math.cos(theta))
    t = res.t
    f = np.array([math.cos(theta), -math.sin(theta), 0.0])
    s = (res.channel("bodies/block/r").data - res.channel("bodies/block/r").data[0]) @ f
    np.testing.assert_allclose(s, 0.5 * a * t**2, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(res.channel("forces/fr/slip_velocity").data, a * t, rtol=1e-9,
                               atol=1e-12)
    N = m * G * math.cos(theta)
    np.testing.assert_allclose(res.channel("forces/fr/normal_load").data, N, rtol=1e-12)
    np.testing.assert_allclose(res.channel("forces/fr/friction").data, -mu_k * N, rtol=1e-12)
    assert np.all(res.channel("forces/fr/mode").data == 1.0)


# -- a mass-spring on a moving belt --------------------------------------------------------
BELT = "tests/forces/data/stick_slip_belt.yaml"
# the deck's values: m, k, v_b, normal load, mu_s, mu_k
M, K, VB, NLOAD, MU_S, MU_K = 1.0, 100.0, 0.1, 10.0, 0.4, 0.3


def belt_cycle():
    """The limit cycle of m x'' + k x = friction, the belt at v_b (x = 0: spring relaxed).
    Stick (x' = v_b) ends when k x reaches F_s; the slip then (relative velocity < 0,
    friction +F_k) is u = x - F_k / k = R cos(w tau - phi), u(0) = D = (F_s - F_k) / k,
    u'(0) = v_b, so R = sqrt(D^2 + (v_b / w)^2), tan(phi) = v_b / (w D); the relative
    velocity is 0 again when sin(w tau - phi) = -sin(phi): tau = (pi + 2 phi) / w, where
    u = -D, i.e. x = (2 F_k - F_s) / k, and the stick holds (|2 F_k - F_s| <= F_s).  The
    stick that follows lasts 2 D / v_b.  Returns (t_first_breakaway, t_slip, t_stick, R,
    centre F_k / k)."""
    fs, fk = MU_S * NLOAD, MU_K * NLOAD
    w = math.sqrt(K / M)
    D = (fs - fk) / K
    phi = math.atan2(VB / w, D)
    return fs / (K * VB), (math.pi + 2 * phi) / w, 2 * D / VB, math.hypot(D, VB / w), fk / K


def belt_x(t):
    """The block's x(t) of the cycle above, from x = 0 stuck at t = 0."""
    t1, ts, tk, R, xc = belt_cycle()
    w = math.sqrt(K / M)
    D = (MU_S - MU_K) * NLOAD / K
    phi = math.atan2(VB / w, D)
    out = np.empty_like(t)
    for k, tt in enumerate(t):
        if tt <= t1:
            out[k] = VB * tt
            continue
        tau = (tt - t1) % (ts + tk)
        if tau <= ts:
            out[k] = xc + R * math.cos(w * tau - phi)
        else:
            out[k] = (2 * MU_K - MU_S) * NLOAD / K + VB * (tau - ts)
    return out


def belt_v(t):
    """The block's velocity dx/dt of :func:`belt_x`."""
    t1, ts, tk, R, xc = belt_cycle()
    w = math.sqrt(K / M)
    phi = math.atan2(VB / w, (MU_S - MU_K) * NLOAD / K)
    out = np.full_like(t, VB)
    for k, tt in enumerate(t):
        tau = (tt - t1) % (ts + tk)
        if tt > t1 and tau <= ts:
            out[k] = -R * w * math.sin(w * tau - phi)
    return out


FAMILIES = INTEGRATOR_FAMILIES


@pytest.mark.parametrize("integrator, tols", FAMILIES, ids=[f[0] for f in FAMILIES])
def test_belt_events_on_every_integrator_family(integrator, tols):
    """The first four stick-slip events of the belt on every integrator family, each within
    10 x (the run's true error of the switching function / its rate) of the closed form:
    a breakaway's g = F_s - k x moves at k v_b (dt ~ e_x / v_b), a re-stick's v at
    |vdot| = |F_k - k x| / m = 1 m/s^2 there (dt ~ e_v / 1 m/s^2)."""
    from mbsim.events import EVENT_TIME_TOL

    model, res = run(BELT, integrator=integrator, t_end=1.7, **tols)
    assert res.complete, res.message
    t1, ts, tk, _, _ = belt_cycle()
    want = [t1, t1 + ts, t1 + ts + tk, t1 + 2 * ts + tk]
    evs = events_of(res, "belt_friction")
    assert len(evs) == len(want)
    e_x = float(np.abs(res.channel("bodies/block/r").data[:, 0] - belt_x(res.t)).max())
    e_v = float(np.abs(res.channel("bodies/block/rd").data[:, 0] - belt_v(res.t)).max())
    for (te, name, _), tw in zip(evs, want):
        bound = 10 * (e_x / VB if name == "breakaway" else e_v / 1.0)
        assert abs(te - tw) <= bound + EVENT_TIME_TOL, (name, te, tw, bound)


def test_belt_limit_cycle_stick_and_slip_at_the_analytic_times(tmp_path):
    """Breakaway and re-stick events at the closed form's times (1e-8 s), the block's x
    there (F_s / k and (2 F_k - F_s) / k), the cycle's amplitude R and period to 1e-6."""
    deck = tmp_path / "belt.yaml"
    text = open(BELT).read()
    deck.write_text(text.replace(
        "analysis:", "events:\n  top:\n    when: 'block.vx < 0'\n  bottom:\n"
        "    when: 'block.vx > 0'\nanalysis:"))
    model, res = run(deck, rtol=1e-11, atol=1e-13)
    assert res.complete, res.message
    t1, ts, tk, R, xc = belt_cycle()
    evs = events_of(res, "belt_friction")
    b = model.body_index("block")
    want = []
    t = t1
    while t < 3.0:
        want.append((t, "breakaway", MU_S * NLOAD / K))
        if t + ts < 3.0:
            want.append((t + ts, "rest", (2 * MU_K - MU_S) * NLOAD / K))
        t += ts + tk
    assert [e[1] for e in evs] == [w[1] for w in want]
    for (te, _, q), (tw, _, xw) in zip(evs, want):
        assert abs(te - tw) <= 1e-8, (te, tw)
        assert abs(q[7 * b] - xw) <= 1e-9
    modes = [e["mode"] for e in res.summary["events"] if e.get("element") == "belt_friction"]
    assert modes[:2] == ["stick -> -", "- -> stick"]
    # amplitude: the block's turning points (deck events on its velocity) at xc +- R
    tops = [q[7 * b] for t, n, q in events_of_all(res, "top")]
    bottoms = [q[7 * b] for t, n, q in events_of_all(res, "bottom")]
    assert tops and bottoms
    amp = 0.5 * (np.array(tops[:len(bottoms)]) - np.array(bottoms[:len(tops)]))
    np.testing.assert_allclose(amp, R, rtol=1e-6)
    period = np.diff([e[0] for e in evs if e[1] == "breakaway"])
    np.testing.assert_allclose(period, ts + tk, rtol=1e-6)


def events_of_all(res, name):
    names, times = res.names["events"], res.arrays["events/time"][0]
    q = res.arrays["events/q"][0]
    return [(float(t), n, q[k]) for k, (t, n) in enumerate(zip(times, names)) if n == name]


def test_belt_error_estimate_honest_across_events(tmp_path):
    """The run's error estimate against the closed form x(t): est / err within [0.1, 10]."""
    model, res = run(BELT, rtol=1e-8, atol=1e-10)
    assert res.complete, res.message
    x = res.channel("bodies/block/r").data[:, 0]
    err = float(np.abs(x - belt_x(res.t)).max())
    est = res.summary["error_estimate"]["position"]
    assert 0.1 <= est / err <= 10, (est, err)


# -- a linear oscillator with Coulomb friction (preload only) --------------------------------
COULOMB = """\
title: oscillator with Coulomb friction
gravity: [0, 0, 0]
bodies:
  ground: {{ground: true}}
  block: {{mass: {m}, inertia: [1, 1, 1], r: [{x0}, 0, 0]}}
joints:
  slide:
    type: translational
    bodies: [ground, block]
    points:
      ground: {{P: [0, 0, 0], Q: [1, 0, 0], R: [0, 1, 0]}}
      block: {{P: [0, 0, 0], Q: [1, 0, 0], R: [0, 1, 0]}}
forces:
  spring:
    type: tsda
    bodies: [ground, block]
    points: {{ground: [-1, 0, 0], block: [0, 0, 0]}}
    k: {k}
    L0: 1.0
  fr:
    type: friction
    joint: slide
    mu_s: {mu}
    mu_k: {mu}
    preload: {N}
    reaction: false
analysis:
  dynamic: {{t_end: 2.0, step: 0.01}}
"""
CM, CK, CX0, CMU, CN = 1.0, 100.0, 0.17, 0.2, 10.0


def coulomb_turns():
    """Released at rest from x0 (k x0 > F = mu N): each half cycle is a harmonic half swing
    about +-F/k (the friction opposes the motion), so the turning points are
    x_n = (-1)^n (x0 - 2 n F / k) at t_n = n pi / w: the amplitude falls by 4 F / k per
    cycle; the motion stops at the first x_n with k |x_n| <= mu_s N."""
    F, w = CMU * CN, math.sqrt(CK / CM)
    out, n = [], 0
    while True:
        n += 1
        x = (-1) ** n * (CX0 - 2 * n * F / CK)
        out.append((n * math.pi / w, x))
        if CK * abs(x) <= CMU * CN:
            return out


def coulomb_x(t):
    F, w = CMU * CN, math.sqrt(CK / CM)
    turns = coulomb_turns()
    out = np.empty_like(t)
    for k, tt in enumerate(t):
        n = min(int(tt * w / math.pi), len(turns))
        if n >= len(turns):
            out[k] = turns[-1][1]
            continue
        x_start = CX0 if n == 0 else turns[n - 1][1]
        centre = math.copysign(F / CK, x_start)  # moving towards -sign(x_start)
        out[k] = centre + (x_start - centre) * math.cos(w * tt - n * math.pi)
    return out


def coulomb_deck(tmp_path):
    path = tmp_path / "coulomb.yaml"
    path.write_text(COULOMB.format(m=CM, k=CK, x0=CX0, mu=CMU, N=CN))
    return path


def test_coulomb_oscillator_amplitude_falls_4F_over_k_and_stops_at_the_predicted_state(
        tmp_path):
    model, res = run(coulomb_deck(tmp_path), rtol=1e-11, atol=1e-13)
    assert res.complete, res.message
    turns = coulomb_turns()
    evs = events_of(res, "fr")
    b = model.body_index("block")
    assert len(evs) == len(turns)
    assert all(name == "rest" for _, name, _ in evs)
    for (te, _, q), (tw, xw) in zip(evs, turns):
        assert abs(te - tw) <= 1e-8, (te, tw)
        assert abs(q[7 * b] - xw) <= 1e-8
    x_turn = np.array([q[7 * b] for _, _, q in evs])
    F = CMU * CN
    np.testing.assert_allclose(np.abs(x_turn[2:]) - np.abs(x_turn[:-2]), -4 * F / CK,
                               atol=1e-9)
    modes = [e["mode"] for e in res.summary["events"]]
    assert modes[-1].endswith("-> stick") and all("stick" not in m for m in modes[:-1])
    # after the stop: at rest at the predicted position
    t_stop, x_stop = turns[-1]
    after = res.t > t_stop
    r = res.channel("bodies/block/r").data[:, 0]
    np.testing.assert_allclose(r[after], x_stop, atol=1e-8)
    assert np.abs(res.channel("bodies/block/rd").data[after, 0]).max() <= 1e-14
    assert np.all(res.channel("forces/fr/mode").data[after] == 0.0)


def test_coulomb_error_estimate_honest_across_events(tmp_path):
    model, res = run(coulomb_deck(tmp_path), rtol=1e-8, atol=1e-10)
    assert res.complete, res.message
    x = res.channel("bodies/block/r").data[:, 0]
    err = float(np.abs(x - coulomb_x(res.t)).max())
    est = res.summary["error_estimate"]["position"]
    assert 0.1 <= est / err <= 10, (est, err)


# -- bad parameters ------------------------------------------------------------------------
@pytest.mark.parametrize("edit, key, message", [
    (("mu_k: 0.2", "mu_k: 0.3"), "forces.fr.mu_k", "must not exceed mu_s"),
    (("mu_s: 0.2", "mu_s: -0.2"), "forces.fr.mu_s", ">= 0"),
    (("preload: 10.0", "preload: 10.0\n    viscous: -1"), "forces.fr.viscous", ">= 0"),
    (("joint: slide", "joint: sliide"), "forces.fr.joint", "sliide"),
    (("reaction: false", "reaction: maybe"), "forces.fr.reaction", "true or false"),
    (("preload: 10.0", "preload: 10.0\n    pin_radius: 0.01"), "forces.fr.pin_radius",
     "goes with a revolute or cylindrical joint"),
    (("preload: 10.0", "preload: -10.0"), "forces.fr.preload", ">= 0"),
])
def test_bad_parameters_one_error_line_exit_2(tmp_path, edit, key, message):
    from click.testing import CliRunner

    from mbsim.cli import main

    path = coulomb_deck(tmp_path)
    text = path.read_text()
    assert edit[0] in text
    path.write_text(text.replace(edit[0], edit[1], 1))
    out = CliRunner().invoke(main, ["run", str(path), "--mode", "dynamic"])
    assert out.exit_code == 2, out.output
    lines = [ln for ln in out.output.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1 and "Traceback" not in out.output, out.output
    assert str(path) in lines[0] and key in lines[0] and message in lines[0], lines[0]


def test_friction_on_an_unsupported_joint_type_is_a_deck_error(tmp_path):
    from click.testing import CliRunner

    from mbsim.cli import main

    path = coulomb_deck(tmp_path)
    text = path.read_text().replace("type: translational", "type: fixed", 1)
    path.write_text(text)
    out = CliRunner().invoke(main, ["run", str(path), "--mode", "dynamic"])
    assert out.exit_code == 2, out.output
    lines = [ln for ln in out.output.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1, out.output
    assert str(path) in lines[0] and "forces.fr.joint" in lines[0] and "fixed" in lines[0]


# -- a pendulum with pivot friction, the normal load its joint's reaction ----------------------
PENDULUM = """\
title: pendulum with pivot friction
gravity: [0, -{g}, 0]
bodies:
  ground: {{ground: true}}
  rod: {{mass: {m}, inertia: [{J}, {J}, {J}], r: [{x}, {y}, 0]}}
joints:
  pivot:
    type: revolute
    bodies: [ground, rod]
    points:
      ground: {{P: [0, 0, 0], Q: [0, 0, 1], R: [1, 0, 0]}}
      rod: {{P: [{px}, {py}, 0], Q: [{px}, {py}, 1], R: [{qx}, {py}, 0]}}
forces:
  fr:
    type: friction
    joint: pivot
    mu_s: {mu_s}
    mu_k: {mu_k}
    pin_radius: {r}
analysis:
  dynamic: {{t_end: {t_end}, step: 0.01}}
"""
PM, PJ, PL, PR, P_MU_S, P_MU_K = 1.0, 0.02, 0.5, 0.05, 0.4, 0.3


def pendulum_deck(tmp_path, theta0, t_end):
    x, y = PL * math.sin(theta0), -PL * math.cos(theta0)
    path = tmp_path / "pendulum.yaml"
    path.write_text(PENDULUM.format(g=G, m=PM, J=PJ, x=x, y=y, px=-x, py=-y, qx=1 - x,
                                    mu_s=P_MU_S, mu_k=P_MU_K, r=PR, t_end=t_end))
    return path


def pendulum_reference(theta0, t_end):
    """The pendulum's turning points [(t, theta)] up to its stop, by its own equations (not
    mbsim): about the pivot, I theta'' = -m g L sin(theta) - s mu_k r |R| (I = J + m L^2,
    s the sign of theta'), R = m (a_c - g) the pivot's reaction, whose magnitude with
    a = theta'' and w = theta' is m sqrt(L^2 a^2 + 2 g L sin(theta) a + L^2 w^4
    + 2 g L w^2 cos(theta) + g^2) (a_c = L a e_t - L w^2 e_r); the implicit a is found by
    fixed-point iteration (it contracts with mu_k r m L / I < 1).  At a turning point (w = 0)
    the stuck pendulum needs the torque m g L |sin(theta)| and its pivot carries m g: it
    stops there when L |sin(theta)| <= mu_s r, else swings back."""
    from scipy.integrate import solve_ivp

    Ip = PJ + PM * PL**2

    def acc(th, w, s):
        a = 0.0
        for _ in range(200):
            R = PM * math.sqrt(max(PL**2 * a * a + 2 * G * PL * math.sin(th) * a
                                   + PL**2 * w**4 + 2 * G * PL * w * w * math.cos(th)
                                   + G * G, 0.0))
            a_new = (-PM * G * PL * math.sin(th) - s * P_MU_K * PR * R) / Ip
            if abs(a_new - a) <= 1e-16 * max(1.0, abs(a)):
                return a_new
            a = a_new
        return a

    t, th, turns = 0.0, theta0, []
    while PL * abs(math.sin(th)) > P_MU_S * PR and t < t_end:
        s = -math.copysign(1.0, math.sin(th))  # the swing starts towards the bottom

        def rhs(_, y, s=s):
            return [y[1], acc(y[0], y[1], s)]

        def turn(_, y, s=s):
            return y[1]

        turn.terminal, turn.direction = True, -s
        sol = solve_ivp(rhs, (t, t_end), [th, 0.0], method="DOP853", rtol=1e-13,
                        atol=1e-15, events=turn, first_step=1e-6)
        t, th = float(sol.t_events[0][0]), float(sol.y_events[0][0][0])
        turns.append((t, th))
    return turns


def pendulum_angle(res):
    r = res.channel("bodies/rod/r").data
    return np.arctan2(r[:, 0], -r[:, 1])


def test_pendulum_sticks_at_once_inside_the_friction_cone(tmp_path):
    """L |sin(theta0)| = 0.015 <= mu_s r = 0.02: the pendulum released at rest never moves;
    the stick holds the gravity torque m g L sin(theta0) with the pivot load m g."""
    theta0 = 0.03
    model, res = run(pendulum_deck(tmp_path, theta0, 2.0), rtol=1e-10, atol=1e-12)
    assert res.complete, res.message
    th = pendulum_angle(res)
    assert np.abs(th - theta0).max() <= 1e-12
    assert np.abs(res.channel("bodies/rod/rd").data).max() <= 1e-14
    np.testing.assert_allclose(res.channel("forces/fr/normal_load").data, PM * G, rtol=1e-12)
    np.testing.assert_allclose(np.abs(res.channel("forces/fr/friction").data),
                               PM * G * PL * math.sin(theta0), rtol=1e-12)
    assert np.all(res.channel("forces/fr/mode").data == 0.0)


def test_pendulum_swings_then_stops_where_the_friction_cone_says(tmp_path):
    """From theta0 = 0.3 (L sin = 0.148 > mu_s r): swings, loses energy to the pivot
    friction (normal load: the reaction, centripetal and tangential parts included), and
    stops at the first turning point with L |sin(theta)| <= mu_s r; every turning point
    and the stop against the reference above to 1e-8 (s, rad)."""
    theta0, t_end = 0.3, 4.5
    turns = pendulum_reference(theta0, t_end)
    assert len(turns) >= 3 and turns[-1][0] < t_end - 0.5
    model, res = run(pendulum_deck(tmp_path, theta0, t_end), rtol=1e-11, atol=1e-13)
    assert res.complete, res.message
    evs = events_of(res, "fr")
    assert len(evs) == len(turns)
    b = model.body_index("rod")
    for (te, name, q), (tw, thw) in zip(evs, turns):
        assert name == "rest"
        assert abs(te - tw) <= 1e-8, (te, tw)
        assert abs(math.atan2(q[7 * b], -q[7 * b + 1]) - thw) <= 1e-8
    # the analytic condition: it swings on where L |sin| > mu_s r, stops where it is not
    assert all(PL * abs(math.sin(th)) > P_MU_S * PR for _, th in turns[:-1])
    assert PL * abs(math.sin(turns[-1][1])) <= P_MU_S * PR
    after = res.t > turns[-1][0]
    np.testing.assert_allclose(pendulum_angle(res)[after], turns[-1][1], atol=1e-8)
    assert np.all(res.channel("forces/fr/mode").data[after] == 0.0)


# -- the hold rows of the stick: zero at the stick state, Jacobian against differences ------
def _friction_model(joint_type, rng, **data):
    from mbsim.model import compile_model
    from tests.forces.builders import force
    from tests.helpers import body, joint, pts, spec

    P = rng.normal(size=3)
    points = {"a": pts(P, P + rng.normal(size=3), P + rng.normal(size=3)),
              "b": pts(rng.normal(size=3), rng.normal(size=3), rng.normal(size=3))}
    if joint_type == "spherical":
        points = {"a": pts(P), "b": pts(rng.normal(size=3))}
    bodies = [body("a", 2.0, (1, 2, 3), rng.normal(size=3), rng.normal(size=4)),
              body("b", 3.0, (2, 2, 1), rng.normal(size=3), rng.normal(size=4))]
    fields = dict(joint="J", joint_type=joint_type, mu_s=0.3, mu_k=0.2, viscous=0.0,
                  preload=0.0, reaction=True)
    fields.update(data)
    fr = force("fr", "friction", ("a", "b"), points, **fields)
    return compile_model(spec(bodies, [joint("J", joint_type, "a", "b", points)], forces=[fr]))


HOLD_CASES = [("translational", {}), ("revolute", {"pin_radius": 0.01}),
              ("cylindrical", {"pin_radius": 0.01}), ("spherical", {"ball_radius": 0.01})]


@pytest.mark.parametrize("joint_type, extra", HOLD_CASES, ids=[c[0] for c in HOLD_CASES])
def test_hold_rows_vanish_at_the_stick_state_and_match_finite_differences(joint_type, extra):
    """Each row the stick holds: Phi = 0 at the state where the stick begins (its target is
    the joint's coordinate there) and Phi_q against central differences along random tangent
    directions (error O(h^2) ~ 1e-10 at h = 1e-5, plus round-off 1e-16 / h)."""
    from types import SimpleNamespace

    from mbsim import core
    from mbsim.events import extend_model
    from tests.forces.builders import tangent

    rng = np.random.default_rng(7)
    model = _friction_model(joint_type, rng, **extra)
    el = model.forces[0]
    q = model.q0.copy()
    stick = ("stick", "stick") if joint_type == "cylindrical" else "stick"
    holds = el.holds(stick, SimpleNamespace(state=core.State(model, q)))
    assert len(holds) == el.hold_count(stick) == {"cylindrical": 2, "spherical": 3}.get(
        joint_type, 1)
    ext = extend_model(model, holds)
    rows = np.arange(model.m, ext.m)
    np.testing.assert_allclose(core.phi(ext, None, q)[rows], 0.0, atol=1e-14)
    J = core.phi_q(ext, None, q)[rows]
    h = 1e-5
    for _ in range(4):
        dq = tangent(ext, q, rng)
        fd = (core.phi(ext, None, q + h * dq)[rows]
              - core.phi(ext, None, q - h * dq)[rows]) / (2 * h)
        np.testing.assert_allclose(J @ dq, fd, atol=1e-8 * max(1.0, np.abs(fd).max()))
    # independent rows: the held rows add their full rank to the joint's
    rank = np.linalg.matrix_rank
    J_all = core.phi_q(ext, None, q)
    assert rank(J_all) == rank(J_all[:model.m]) + len(rows)


def test_spherical_pendulum_stops_where_the_ball_friction_cone_says(tmp_path):
    """The pendulum above on a ball joint (ball_radius = the pin's radius), swinging in its
    plane: the ball's normal load is the whole reaction force, here in the plane of the
    swing as the pin's radial one, so the turning points and the stop are the revolute's
    (same reference, 1e-8)."""
    theta0, t_end = 0.3, 4.5
    turns = pendulum_reference(theta0, t_end)
    path = pendulum_deck(tmp_path, theta0, t_end)
    text = path.read_text().replace("type: revolute", "type: spherical")
    text = text.replace("pin_radius:", "ball_radius:")
    path.write_text(text)
    model, res = run(path, rtol=1e-11, atol=1e-13)
    assert res.complete, res.message
    evs = events_of(res, "fr")
    assert [e[1] for e in evs] == ["rest"] * len(turns)
    b = model.body_index("rod")
    for (te, _, q), (tw, thw) in zip(evs, turns):
        assert abs(te - tw) <= 1e-8, (te, tw)
        assert abs(math.atan2(q[7 * b], -q[7 * b + 1]) - thw) <= 1e-8
    after = res.t > turns[-1][0]
    np.testing.assert_allclose(pendulum_angle(res)[after], turns[-1][1], atol=1e-8)
    assert np.all(res.channel("forces/fr/mode").data[after] == 0.0)


CYLINDER = """\
title: a sleeve sliding and spinning on a horizontal shaft
gravity: [0, -{g}, 0]
bodies:
  ground: {{ground: true}}
  sleeve: {{mass: {m}, inertia: [{J}, 1, 1], r: [0, 0, 0], rdot: [{v0}, 0, 0],
           omega: [{w0}, 0, 0]}}
joints:
  shaft:
    type: cylindrical
    bodies: [ground, sleeve]
    points:
      ground: {{P: [0, 0, 0], Q: [1, 0, 0], R: [0, 1, 0]}}
      sleeve: {{P: [0, 0, 0], Q: [1, 0, 0], R: [0, 1, 0]}}
forces:
  fr:
    type: friction
    joint: shaft
    mu_s: {mu_s}
    mu_k: {mu_k}
    pin_radius: {r}
analysis:
  dynamic: {{t_end: 2.0, step: 0.01}}
"""


def test_cylindrical_slide_and_spin_stop_independently(tmp_path):
    """A sleeve (m, J about the shaft) pushed along a horizontal shaft at v0 and spun at w0:
    the shaft carries m g, so the slide decelerates at mu_k g and stops at v0 / (mu_k g)
    after v0^2 / (2 mu_k g); the spin decelerates at mu_k m g r / J and stops at
    w0 J / (mu_k m g r) after w0^2 J / (2 mu_k m g r).  Both then stick (nothing drives
    them): the two events at those times (1e-8 s), the positions (1e-8)."""
    m, J, v0, w0, mu_s, mu_k, r = 2.0, 0.01, 0.5, 3.0, 0.3, 0.2, 0.02
    path = tmp_path / "cylinder.yaml"
    path.write_text(CYLINDER.format(g=G, m=m, J=J, v0=v0, w0=w0, mu_s=mu_s, mu_k=mu_k, r=r))
    model, res = run(path, rtol=1e-11, atol=1e-13)
    assert res.complete, res.message
    t_slide, t_spin = v0 / (mu_k * G), w0 * J / (mu_k * m * G * r)
    evs = events_of(res, "fr")
    want = sorted([(t_slide, "rest (translation)"), (t_spin, "rest (rotation)")])
    assert [e[1] for e in evs] == [w[1] for w in want]
    for (te, _, _), (tw, _) in zip(evs, want):
        assert abs(te - tw) <= 1e-8, (te, tw)
    after = res.t > max(t_slide, t_spin)
    x = res.channel("bodies/sleeve/r").data[:, 0]
    np.testing.assert_allclose(x[after], v0**2 / (2 * mu_k * G), atol=1e-8)
    theta = res.channel("forces/fr/slip_rate").data
    assert np.all(theta[after] == 0.0) or np.abs(theta[after]).max() <= 1e-14
    np.testing.assert_allclose(res.channel("forces/fr/normal_load").data, m * G, rtol=1e-10)
    assert np.all(res.channel("forces/fr/mode").data[after] == 0.0)
    assert np.all(res.channel("forces/fr/mode_rotation").data[after] == 0.0)


BEARING = """\
title: a slider whose weight acts off its bearing
gravity: [0, -{g}, 0]
bodies:
  ground: {{ground: true}}
  slider: {{mass: {m}, inertia: [1, 1, 1], r: [0, 0, 0], rdot: [{v0}, 0, 0]}}
joints:
  guide:
    type: translational
    bodies: [ground, slider]
    points:
      ground: {{P: [{d}, 0, 0], Q: [{d1}, 0, 0], R: [{d}, 1, 0]}}
      slider: {{P: [{d}, 0, 0], Q: [{d1}, 0, 0], R: [{d}, 1, 0]}}
forces:
  fr:
    type: friction
    joint: guide
    mu_s: {mu_s}
    mu_k: {mu_k}
    bearing_length: {L}
analysis:
  dynamic: {{t_end: 1.0, step: 0.01}}
"""


def test_bearing_length_turns_the_reaction_moment_into_normal_load(tmp_path):
    """A slider on a horizontal guide whose bearing centre P lies d ahead of its centroid:
    the guide carries the weight m g and its moment m g d about P; the friction at P and the
    slider's inertia m a (at the centroid, on the line through P along the guide) add no
    moment.  N = m g (1 + 2 d / L) (two end forces m g d / L), so the slider decelerates
    at mu_k N / m and stops at v0 m / (mu_k N) (the loop friction <-> reaction here settles
    in one iteration)."""
    m, v0, d, L, mu_s, mu_k = 3.0, 0.4, 0.05, 0.2, 0.3, 0.2
    path = tmp_path / "bearing.yaml"
    path.write_text(BEARING.format(g=G, m=m, v0=v0, d=d, d1=d + 1, L=L, mu_s=mu_s, mu_k=mu_k))
    model, res = run(path, rtol=1e-11, atol=1e-13)
    assert res.complete, res.message
    N = m * G * (1 + 2 * d / L)
    slipping = res.channel("forces/fr/mode").data == 1.0
    assert slipping.sum() > 3
    np.testing.assert_allclose(res.channel("forces/fr/normal_load").data[slipping], N,
                               rtol=1e-10)
    t_stop = v0 * m / (mu_k * N)
    evs = events_of(res, "fr")
    assert [e[1] for e in evs] == ["rest"]
    assert abs(evs[0][0] - t_stop) <= 1e-8
    x = res.channel("bodies/slider/r").data[:, 0]
    np.testing.assert_allclose(x[res.t > t_stop], v0 * t_stop / 2, atol=1e-8)


def test_stribeck_and_viscous_slip_law_on_the_incline(tmp_path):
    """The block on a 30 deg incline (tan > mu_s: it breaks away at once) with a Stribeck
    transition and a viscous term: m s'' = m g sin - mu(s') m g cos - c s', mu(v) = mu_k +
    (mu_s - mu_k) exp(-(v / v_s)^2), against scipy's solution of that one equation
    (rtol 1e-12: 1e-9 m); the friction channel equals the law at every output."""
    from scipy.integrate import solve_ivp

    theta, m, mu_s, mu_k, vs, c = math.radians(30.0), 2.0, 0.55, 0.3, 0.2, 0.5
    path = incline(tmp_path, theta, mu_s, mu_k, m)
    path.write_text(path.read_text().replace(
        f"mu_k: {mu_k}", f"mu_k: {mu_k}\n    stribeck_velocity: {vs}\n    viscous: {c}"))
    model, res = run(path, rtol=1e-11, atol=1e-13, t_end=2.0)
    assert res.complete, res.message
    N = m * G * math.cos(theta)

    def mu(v):
        return mu_k + (mu_s - mu_k) * np.exp(-((v / vs) ** 2))

    sol = solve_ivp(lambda _, y: [y[1], G * math.sin(theta) - mu(y[1]) * N / m - c * y[1] / m],
                    (0.0, 2.0), [0.0, 0.0], t_eval=res.t, rtol=1e-12, atol=1e-14,
                    method="DOP853")
    f = np.array([math.cos(theta), -math.sin(theta), 0.0])
    r = res.channel("bodies/block/r").data
    np.testing.assert_allclose((r - r[0]) @ f, sol.y[0], atol=1e-9)
    v = res.channel("forces/fr/slip_velocity").data
    np.testing.assert_allclose(v, sol.y[1], atol=1e-9)
    np.testing.assert_allclose(res.channel("forces/fr/friction").data, -mu(v) * N - c * v,
                               rtol=1e-12, atol=1e-12)
    power = res.channel("forces/fr/power").data
    assert np.all(power <= 0.0)
