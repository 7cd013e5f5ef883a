"""The 'settle' method's own logic (artificial damping, settling detection, the report),
run against a small stand-in for the dynamic analysis so that it is checked whether or not
mbsim.analyses.dynamic is present.  The cross-check with the real dynamic analysis is
test_equilibrium.py::test_fourbar_settles_where_the_minimum_is."""

import sys
import types

import numpy as np
import pytest
import scipy.linalg as la
from scipy.integrate import solve_ivp

from mbsim.analyses.assembly import assemble
from mbsim.analyses.common import Recorder
from mbsim.analyses.equilibrium import equilibrium
from mbsim.analyses.kinematic import output_times
from mbsim.model import compile_model
from tests.forces.builders import force
from tests.helpers import body, joint, pts, spec
from tests.reference import equations as eq

M, K, L0 = 2.0, 500.0, 0.3


def stand_in_dynamic(model, options):
    """Forward dynamics for the test only: KKT accelerations with Baumgarte terms
    (alpha = beta = 10), scipy DOP853 at rtol 1e-8, output through the Recorder."""
    times = output_times(0.0, float(options["t_end"]), float(options["step"]))
    q0 = assemble(model).q if options.get("q0") is None else options["q0"]
    n = model.nq

    def acc(t, q, qd):
        T = eq.constraints(model, q, t, qd=qd, gamma=True)
        J = T.jac
        rhs_c = T.gamma - 2 * 10.0 * (J @ qd) - 100.0 * T.phi
        Kk = np.block([[eq.mass_matrix(model, q), J.T], [J, np.zeros((model.m, model.m))]])
        return la.solve(Kk, np.concatenate([eq.applied_forces(model, q, qd, t)[0], rhs_c]))[:n]

    sol = solve_ivp(lambda t, y: np.concatenate([y[n:], acc(t, y[:n], y[n:])]),
                    (times[0], times[-1]), np.concatenate([q0, np.zeros(n)]), t_eval=times,
                    method="DOP853", rtol=1e-8, atol=1e-11)
    rec = Recorder(model)
    for k, t in enumerate(sol.t):
        q, qd = sol.y[:n, k], sol.y[n:, k]
        rec.add(t, q, qd, acc(t, q, qd))
    return rec.result("dynamic")


@pytest.fixture
def fake_dynamic(monkeypatch):
    mod = types.ModuleType("mbsim.analyses.dynamic")
    mod.dynamic = stand_in_dynamic
    monkeypatch.setitem(sys.modules, "mbsim.analyses.dynamic", mod)


def spring_model():
    """A 2 kg slider on a vertical translational joint, hung from a TSDA (k 500, L0 0.3),
    released 0.1 m above its equilibrium z* = -(L0 + m g / k) = -0.33924."""
    bodies = [body("mass", M, (0.1, 0.1, 0.1), (0, 0, -0.24)), body("ground", ground=True)]
    joints = [joint("slide", "translational", "ground", "mass",
                    {"ground": pts((0, 0, 0), (0, 0, 1), (1, 0, 0)),
                     "mass": pts((0, 0, 0), (0, 0, 1), (1, 0, 0))})]
    forces = [force("spring", "tsda", ("ground", "mass"), {"ground": (0, 0, 0), "mass": (0, 0, 0)},
                    k=K, c=0.0, L0=L0)]
    return compile_model(spec(bodies, joints, forces=forces, gravity=(0, 0, -9.81)))


def test_settle_with_artificial_damping_reaches_the_minimum(fake_dynamic):
    """Mass-proportional damping c = 20 1/s (F = -c m zdot, damping ratio c / (2 omega_n) =
    0.63): the amplitude 0.1 m decays as exp(-10 t); velocity and acceleration (omega_n = 15.8
    rad/s: acc ~ 250 x displacement) fall below 1e-6 after ln(0.1 * 250 / 1e-6) / 10 ~ 1.7 s.
    The settled position equals the minimum to the velocity tolerance over omega_n."""
    model = spring_model()
    mini = equilibrium(model, {})
    res = equilibrium(model, {"method": "settle", "damping": 20.0, "t_end": 3.0, "step": 0.01})
    assert res.complete, res.message
    s = res.summary
    assert s["settled"] and s["method"] == "settle" and s["stable"]
    assert 1.2 < s["settling_time"] < 2.5
    z_min = mini.summary["configuration"]["mass"]["r"][2]
    assert z_min == pytest.approx(-(L0 + M * 9.81 / K), abs=1e-12)
    assert s["configuration"]["mass"]["r"][2] == pytest.approx(z_min, abs=1e-7)
    assert s["reduced_force"] < 1e-4  # K x 1e-7 m
    assert res.mode == "equilibrium" and len(res.t) == 301  # the whole history is kept


def test_settle_without_damping_reports_that_it_did_not_settle(fake_dynamic):
    model = spring_model()
    res = equilibrium(model, {"method": "settle", "t_end": 0.3, "step": 0.01})
    assert res.status == "incomplete" and not res.summary["settled"]
    assert "did not settle" in res.message and "damping" in res.message
    assert "\n" not in res.message
