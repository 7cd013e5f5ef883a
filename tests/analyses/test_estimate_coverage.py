"""The error estimate covers the whole run or it is none; --accuracy says `met` only then.

The companion run is made to stop (Ctrl-C, or a step failure at its first step) by wrapping
Stepper.step for the runs at the companion's tolerance only: the main run is untouched, so
every figure here is compared with an undisturbed run of the same deck.
"""

from __future__ import annotations

import math
from pathlib import Path

import h5py
import pytest

from mbsim.analyses import estimate as est_mod
from mbsim.analyses import trajectory
from mbsim.analyses.inverse import states_from_result
from mbsim.api import load_model, run_model
from mbsim.integrators import DEFAULT
from mbsim.output import write_result

MODELS = Path(__file__).resolve().parents[2] / "models"
RTOL = 1e-6
OPTIONS = {"t_end": 0.2, "step": 0.01, "rtol": RTOL}


@pytest.fixture(scope="module")
def governor_deck():
    """(spec, model) of the governor deck; runs get the spec (its settings) with deck=."""
    return load_model(MODELS / "governor.yaml")


@pytest.fixture(scope="module")
def governor(governor_deck):
    return governor_deck[1]


def stop_companions(monkeypatch, how, methods=None):
    """Companion runs of ``methods`` (class names; None: all) stop at their first step:
    ``how`` 'interrupt' raises KeyboardInterrupt (Ctrl-C), 'fail' returns a step failure as
    an integrator does.  Companions are told apart by a mark on their options, the coarse
    companion (estimate.CoarseStepper) by its class."""
    options, step = est_mod.companion_options, trajectory.Stepper.step

    def marked(cls, opt):
        copt, factor, method = options(cls, opt)
        return dict(copt, test_companion=True), factor, method

    def stopping(self):
        companion = self.opt.get("test_companion") or isinstance(self, est_mod.CoarseStepper)
        if companion and (methods is None or self.cls.name in methods):
            if how == "interrupt":
                raise KeyboardInterrupt
            return False, f"t = {self.solver.t:.6g} s: step size fell below h_min (test)"
        return step(self)

    monkeypatch.setattr(est_mod, "companion_options", marked)
    monkeypatch.setattr(trajectory.Stepper, "step", stopping)


def test_interrupted_companion_gives_no_estimate(governor, governor_deck, monkeypatch, tmp_path):
    stop_companions(monkeypatch, "interrupt")
    res = run_model(governor, "dynamic", dict(OPTIONS), deck=governor_deck[0])
    assert res.complete  # the run itself reached t_end
    est = res.summary["error_estimate"]
    assert est["position"] is None and "interrupted" in est["reason"]
    assert not any(k.startswith("error/") for k in res.channels)
    out = tmp_path / "g.h5"
    write_result(res, out)
    with h5py.File(out) as f:
        assert math.isnan(f.attrs["error_estimate"])
        assert "interrupted" in str(f.attrs["error_estimate_reason"])


def test_interrupted_companion_never_says_met(governor, governor_deck, monkeypatch):
    stop_companions(monkeypatch, "interrupt")
    res = run_model(governor, "dynamic", dict(OPTIONS, accuracy=1e-6), deck=governor_deck[0])
    acc = res.summary["accuracy"]
    assert acc["met"] is False and math.isnan(acc["estimate"])
    assert "interrupted" in acc["reason"]


def test_interrupted_refinement_keeps_the_complete_run(governor, governor_deck, monkeypatch):
    """--accuracy whose first run misses (its tolerance started 1e7 x looser than the rule,
    ACCURACY_START) and whose refining run is interrupted (Ctrl-C at its first step): the
    first run, complete to t_end with its estimate, is kept (not the interrupted one), and
    the summary says interrupted and not met."""
    from mbsim.analyses import accuracy

    monkeypatch.setattr(accuracy, "ACCURACY_START", 3e4)
    runs, step = [], trajectory.Stepper.step

    def second_run_interrupted(self):
        if not isinstance(self, est_mod.CoarseStepper) and "test_companion" not in self.opt:
            if self not in runs:
                runs.append(self)
            if len(runs) == 2:
                raise KeyboardInterrupt
        return step(self)

    options = est_mod.companion_options

    def marked(cls, opt):
        copt, factor, method = options(cls, opt)
        return dict(copt, test_companion=True), factor, method

    monkeypatch.setattr(est_mod, "companion_options", marked)
    monkeypatch.setattr(trajectory.Stepper, "step", second_run_interrupted)
    res = run_model(governor, "dynamic", dict(OPTIONS, accuracy=1e-9), deck=governor_deck[0])
    acc = res.summary["accuracy"]
    assert len(runs) == 2  # the refinement was started
    assert res.complete and res.t[-1] == pytest.approx(OPTIONS["t_end"])
    assert acc["interrupted"] and acc["met"] is False
    assert acc["runs"] == 1 and math.isfinite(acc["estimate"]) and acc["estimate"] > 1e-9
    assert acc["rtol"] == pytest.approx(3e4 * 1e-9)


@pytest.fixture(scope="module")
def governor_reference(governor, governor_deck):
    """The governor over OPTIONS' span at rtol 1e-12 (the run's error is 1.1e-11 m at
    1e-6: the reference is 1e5 times closer to the truth than that)."""
    ref = run_model(governor, "dynamic", dict(OPTIONS, rtol=1e-12, atol=1e-14,
                                              error_estimate=False), deck=governor_deck[0])
    return states_from_result(governor, ref)


def true_error(model, res, ref):
    q, qd, _ = states_from_result(model, res)
    return float(est_mod.state_differences(model, q, qd, ref[0], ref[1])["position"].max())


@pytest.mark.parametrize("failing, used", [
    ({"projection-dop853"}, "gcp-dop853"),  # the run's method fails at rtol/5 and rtol/2
    ({"projection-dop853@5"}, "projection-dop853"),  # fails at rtol/5 only
])
def test_companion_failing_at_t0_is_replaced(governor, governor_deck, governor_reference,
                                              monkeypatch, failing, used):
    """The run's own companion fails at its first step; another companion reaches every
    output, and its estimate is honest: within [0.1, 10] of the true error."""
    step = trajectory.Stepper.step

    def stopping(self):  # companions run below the run's rtol; the first at exactly rtol/5
        name, rtol = self.cls.name, float(self.opt["rtol"])
        companion = isinstance(self, est_mod.CoarseStepper) or (name in failing and rtol < RTOL)
        if companion or (f"{name}@5" in failing and rtol == pytest.approx(RTOL / 5)):
            return False, f"t = {self.solver.t:.6g} s: step size fell below h_min (test)"
        return step(self)

    monkeypatch.setattr(trajectory.Stepper, "step", stopping)
    res = run_model(governor, "dynamic", dict(OPTIONS), deck=governor_deck[0])
    est = res.summary["error_estimate"]
    assert est["position"] is not None
    assert f"with {used} at rtol" in est["method"] and "stopped" in est["method"]
    err = true_error(governor, res, governor_reference)
    assert 0.1 <= est["position"] / err <= 10, (est["position"], err)
    assert any(k.startswith("error/") for k in res.channels)


def test_no_companion_reaching_the_end_gives_nan_not_a_partial_figure(governor, governor_deck,
                                                                      monkeypatch, tmp_path):
    stop_companions(monkeypatch, "fail")  # every method's companion
    res = run_model(governor, "dynamic", dict(OPTIONS), deck=governor_deck[0])
    est = res.summary["error_estimate"]
    assert est["position"] is None and "does not cover the run" in est["reason"]
    assert "orientation" not in est and not any(k.startswith("error/") for k in res.channels)
    out = tmp_path / "g.h5"
    write_result(res, out)
    with h5py.File(out) as f:
        assert math.isnan(f.attrs["error_estimate"])
    acc = run_model(governor, "dynamic", dict(OPTIONS, accuracy=1e-6),
                    deck=governor_deck[0]).summary["accuracy"]
    assert acc["met"] is False and "does not cover the run" in acc["reason"]


def test_accuracy_falls_back_from_the_decks_integrator(governor, governor_deck, monkeypatch):
    """A deck's integrator is a preference: when it cannot deliver (here every run of it
    fails at its first step, as gcp-dop853 did at rtol 3e-11 on a seven-body loop), the
    default does and the summary says so; an integrator asked for by the caller is a
    requirement: its failure is the result."""
    original = trajectory.Stepper.step

    def step(self):
        if self.cls.name == "projection":
            return False, f"t = {self.solver.t:.6g} s: step size fell below h_min (test)"
        return original(self)

    monkeypatch.setattr(trajectory.Stepper, "step", step)
    spec = governor_deck[0]
    monkeypatch.setitem(spec.analysis, "dynamic",
                        dict(spec.analysis.get("dynamic", {}), integrator="projection"))
    res = run_model(governor, "dynamic", dict(OPTIONS, accuracy=1e-6), deck=governor_deck[0])
    acc = res.summary["accuracy"]
    assert res.complete and acc["integrator"] == DEFAULT and acc["met"]
    assert acc["estimate"] <= 1e-6
    assert "the deck's integrator projection could not deliver" in acc["fallback"]
    assert any("--accuracy" in w for w in res.summary["warnings"])
    required = run_model(governor, "dynamic", dict(OPTIONS, accuracy=1e-6,
                                                   integrator="projection"), deck=governor_deck[0])
    assert not required.complete
    assert required.summary["accuracy"]["integrator"] == "projection"
    assert required.summary["accuracy"]["met"] is False
