"""The dynamic analysis as an API: options, channels, monitors, counters, failures."""

from pathlib import Path

import numpy as np
import pytest

from mbsim.analyses.dynamic import dynamic
from mbsim.errors import DeckError
from mbsim.integrators import DEFAULT
from tests.integrators import models as M
from tests.reference import equations as eq

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def crank():
    model = M.slider_crank()
    q, qd = M.slider_crank_state(model, 2 * np.pi)
    return model, q, qd


def test_channels_monitors_and_counters(crank):
    model, q, qd = crank
    res = dynamic(model, {"t_end": 0.2, "step": 0.02, "q0": q, "qd0": qd})
    assert res.complete and res.mode == "dynamic"
    assert np.allclose(res.t, np.linspace(0, 0.2, 11))
    for name in (
        "position_violation",
        "velocity_violation",
        "energy",
        "work_nonconservative",
        "step_size",
    ):
        assert res.channel(f"monitors/{name}").data.shape == (11,)
    lam = res.channel("constraints/lam")
    assert lam.data.shape == (11, model.m) and lam.components == model.row_label
    # multipliers at t0 are those of the KKT solve (Haug Ch. 11)
    assert np.allclose(lam.data[0], eq.accelerations(model, q, qd)[1], atol=1e-8)
    for key in (
        "steps",
        "rejected_steps",
        "function_evaluations",
        "factorizations",
        "newton_iterations",
    ):
        assert key in res.counters
    assert res.settings["integrator"] == DEFAULT and res.summary["dof"] == 1
    assert res.channel("monitors/position_violation").data.max() < 1e-9


def test_output_sampling_is_independent_of_the_step(crank):
    """Dense output: the outputs at 0.1 s and at 0.01 s agree at common times to the
    integration accuracy, and the steps taken are the same (output does not cut steps)."""
    model, q, qd = crank
    base = {
        "t_end": 0.3,
        "q0": q,
        "qd0": qd,
        "rtol": 1e-8,
        "atol": 1e-10,
        "integrator": "projection-dop853",
    }
    a = dynamic(model, dict(base, step=0.1))
    b = dynamic(model, dict(base, step=0.01))
    xa = a.channel("bodies/slider/r").data[:, 0]
    xb = b.channel("bodies/slider/r").data[::10, 0]
    assert np.abs(xa - xb).max() < 1e-8
    assert a.counters["steps"] == b.counters["steps"]


def test_energy_minus_work_is_conserved_with_a_damper():
    """Governor (damper c = 30): W_nc <= 0 and E - W_nc stays at E(0) (1e-7 relative)."""
    model = M.governor(g=9.81)
    q, qd = M.governor_state(model)
    res = dynamic(
        model, {"t_end": 0.5, "step": 0.05, "q0": q, "qd0": qd, "rtol": 1e-9, "atol": 1e-11}
    )
    W = res.channel("monitors/work_nonconservative").data
    E = res.channel("monitors/energy").data
    assert W[-1] < 0
    assert np.abs((E - W) - E[0]).max() < 1e-7 * E[0]


def test_failure_keeps_data_and_names_time_and_joints(crank):
    model, q, qd = crank
    res = dynamic(
        model,
        {
            "t_end": 1.0,
            "step": 0.01,
            "q0": q,
            "qd0": qd,
            "integrator": "projection",
            "rtol": 1e-10,
            "h_min": 0.05,
        },
    )
    assert res.status == "incomplete"
    assert res.message.startswith("t = ") and "h_min" in res.message
    assert any(j in res.message for j in ("A", "B", "C", "T"))
    assert len(res.t) >= 1 and res.t[-1] < 1.0
    res = dynamic(model, {"t_end": 1.0, "step": 0.01, "q0": q, "qd0": qd, "max_steps": 3})
    assert res.status == "incomplete" and "max_steps" in res.message
    assert 0 < res.t[-1] < 1.0


def test_ctrl_c_keeps_the_finished_outputs(crank, monkeypatch):
    """A KeyboardInterrupt in the 40th call of the integrator (Integrator.advance: the steps
    up to the next output) ends the run as incomplete with every output reached so far,
    each with its monitors (all channels the same length)."""
    from mbsim.analyses import trajectory as dyn

    model, q, qd = crank
    cls = dyn.integrator_class("projection-dop853")
    advance, calls = cls.advance, {"n": 0}

    def interrupted_advance(self, *args):
        calls["n"] += 1
        if calls["n"] == 40:
            raise KeyboardInterrupt
        return advance(self, *args)

    monkeypatch.setattr(cls, "advance", interrupted_advance)
    monkeypatch.setattr(dyn, "OUTPUT_LOOP", False)  # (the loop's Ctrl-C: test_output_loop.py)
    res = dynamic(model, {"t_end": 1.0, "step": 0.005, "q0": q, "qd0": qd,
                          "integrator": "projection-dop853", "rtol": 1e-8})
    assert res.status == "incomplete" and "interrupted (Ctrl-C)" in res.message
    assert 0.0 < res.t[-1] < 1.0
    assert all(c.data.shape[0] == len(res.t) for c in res.channels.values())


def test_unknown_integrator_is_a_usage_error(crank):
    model, q, qd = crank
    with pytest.raises(DeckError, match="did you mean gcp-dop853"):
        dynamic(model, {"integrator": "gcp-dop85", "q0": q, "qd0": qd})


def test_deck_run_with_initial_conditions_and_alias():
    """models/governor.yaml: the initial-condition analysis spins every body with the spindle
    (11.0174 rad/s), the deck's alias ``dop853`` selects gcp-dop853."""
    pytest.importorskip("yaml")
    from mbsim.api import load_model
    from mbsim.options import run_options

    path = ROOT / "models" / "governor.yaml"
    if not path.exists():
        pytest.skip("models/governor.yaml not present")
    spec, model = load_model(path)
    res = dynamic(model, run_options("dynamic", spec, {"t_end": 0.1, "step": 0.05,
                                                       "integrator": "dop853"}))
    assert res.complete, res.message
    assert res.settings["integrator"] == "gcp-dop853"
    w = res.channel("bodies/spindle/omega").data[:, 1]
    assert w[0] == pytest.approx(11.0174, rel=1e-9)
    assert res.channel("monitors/velocity_violation").data.max() < 1e-8


def test_fixed_step_method_steps_at_the_output_step(crank):
    model, q, qd = crank
    res = dynamic(model, {"t_end": 0.1, "step": 0.01, "integrator": "rk4", "q0": q, "qd0": qd})
    assert res.complete and res.counters["steps"] == 10
    assert np.allclose(res.channel("monitors/step_size").data[1:], 0.01)
