"""The step of the index-1 methods in C (mbsim/fast/step.c, mbsim/fast/stepper.py)
against the Python path (option ``compiled_step: false``), which does the same arithmetic.

- One trial step from the same state: the error norm, the stages, the end before and after
  the projection and f there agree to 1e-12 relative (the two paths sum the stages in
  another order: round-off of a dozen terms, ~1e-15, amplified at most by the projection's
  Newton iteration), and so do the dense outputs at times inside the step.
- Whole runs on the reference problems (tests/integrators/references.py): near round-off the
  two paths may take other steps, so each path's error against the independent reference
  is asserted, with the bound of the runs of the existing tests.
- Decks with time targets (a driver) and with Python force elements take the C step through
  the per-stage callback and agree the same way.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from mbsim.analyses import trajectory
from mbsim.analyses.dynamic import dynamic
from mbsim.analyses.trajectory import Stepper
from mbsim.analyses.trajectory import initial_conditions as _initial
from mbsim.deck import load_deck
from mbsim.fast import stepper
from mbsim.integrators import INTEGRATORS
from mbsim.integrators.rk import StageFailure
from mbsim.model import compile_model
from mbsim.options import deck_context
from tests.integrators import models as M
from tests.integrators import references as R

METHODS = ("projection", "projection-dop853", "rk4", "baumgarte")
EPS = np.finfo(float).eps
REL = 1e-12  # one step's round-off bound between the two paths (module doc)
ROOT = Path(__file__).resolve().parents[2]
FLOOR = 1e-12  # m: round-off of O(1) positions (tests/integrators/test_error_estimate.py)
PASSES_SINGULAR_POSITIONS = {"parallel_fourbar"}  # the reference problems with flat passages


def close(a, b):
    """|a - b| <= REL max(1, |a|), componentwise over the whole array's scale."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return np.abs(a - b).max(initial=0.0) <= REL * max(1.0, np.abs(a).max(initial=0.0))


def pair(model, q, qd, name, t_end, **opt):
    """The integrator ``name`` on (q, qd) twice: C path, Python path."""
    opt = dict({"rtol": 1e-6, "atol": 1e-8}, **opt)
    if not INTEGRATORS[name].adaptive:
        opt.setdefault("h", 1e-3)
    out = []
    for compiled in (True, False):
        o = dict(opt, compiled_step=compiled)
        st = Stepper(model, INTEGRATORS[name], o, 0.0, q.copy(), qd.copy(), t_end, None)
        out.append(st.solver)
    return out


def deck_state(name):
    spec = load_deck(ROOT / "models" / f"{name}.yaml")
    model = compile_model(spec)
    q, qd, _ = _initial(model, 0.0, {"tol": 1e-10}, deck_context(spec, shapes=False).hold)
    return model, q, qd


def problem_state(name):
    pb = M.reference_problem(name)
    return pb.model, pb.q0, pb.qd0


CASES = [("problem", n) for n in M.REFERENCE_PROBLEMS] + [
    ("deck", "governor"), ("deck", "four_bar"), ("deck", "vehicle"), ("deck", "compressor"),
    ("chain", "40")]
"""Reference problems, decks (four_bar: singular J', the KKT path; vehicle: compiled tires
and a driver; compressor: Python force elements) and a 40-link chain (nq = 280 >=
SPARSE_NQ: CSR Jacobians)."""


def state_of(kind, name):
    if kind == "chain":
        model = M.chain(int(name))
        return model, model.q0.copy(), np.zeros(model.nq)
    return problem_state(name) if kind == "problem" else deck_state(name)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("kind,name", CASES)
def test_one_trial_step_agrees_with_the_python_path(kind, name, method, monkeypatch):
    """The same trial step (accepted, then one 20 x longer, which an adaptive method
    rejects or accepts in both paths alike) and the dense outputs of the accepted one (each
    projected on fresh factors, as the Python path projects it; the outputs on factors
    already made: tests/integrators/test_output_projection.py)."""
    monkeypatch.setattr(stepper, "REUSE_FACTOR", False)
    model, q, qd = state_of(kind, name)
    c, py = pair(model, q, qd, method, 1.0)
    assert c._compiled is not None and py._compiled is None
    assert np.array_equal(c.y, py.y) and close(c.f, py.f)
    h = min(c.h_abs, 1e-3)
    while py._attempt(h)[2] is None:  # a step the error test accepts
        h *= 0.25
    # the error norm is in units of the tolerance: its terms h K^T E / (rtol |y|) carry the
    # stages' round-off, eps |y| each, over rtol |y|: ~ n_stages eps / rtol
    err_tol = 10 * c.tableau.n_stages * EPS / c.rtol
    a, b = c._attempt(h), py._attempt(h)
    assert a[0] == pytest.approx(b[0], rel=REL, abs=err_tol)
    assert close(a[1], b[1])  # the end before the projection
    assert a[2] is not None and b[2] is not None  # accepted in both
    assert close(a[2], b[2]) and close(a[3], b[3])  # projected end, f there
    assert close(a[4], b[4])  # the stages
    # a trial 20 x longer: rejected or accepted alike.  Far beyond the step the controller
    # takes, the accelerations amplify the stage sums' round-off by a factor no derivation
    # bounds (measured: up to 1.5e-11 relative in the error norm on the other cases, 2.3e-8 on
    # the vehicle with its Python tyre forces), so the norms are compared only
    # to 1e-6 and the verdict is asked where the norm is not within that of the test's 1
    a, b = c._attempt(20 * h), py._attempt(20 * h)
    assert a[0] == pytest.approx(b[0], rel=1e-6, abs=err_tol)
    if abs(b[0] - 1.0) > 1e-6 * max(1.0, b[0]):
        assert (a[2] is None) == (b[2] is None)
    # the accepted step of size h in both, then its outputs at once
    for s in (c, py):
        s.h_abs = h
        assert s.step()[0]
    assert c._c_last and close(c.y, py.y)
    times = c.t_old + np.array([0.1, 0.5, 0.9, 1.0]) * (c.t - c.t_old)
    Qc, QDc, Wc = c.dense_output_many(times)
    Qp, QDp, Wp = py.dense_output_many(times)
    assert close(Qc, Qp) and close(QDc, QDp) and close(Wc, Wp)
    dense = py.dense_output()  # the per-time dense output still works, and agrees
    q1, qd1, _ = dense(times[1])
    assert close(q1, Qc[1]) and close(qd1, QDc[1])


@pytest.mark.parametrize("kind,name", [("chain", "40"), ("deck", "governor"),
                                       ("deck", "four_bar"), ("deck", "vehicle")])
def test_the_derivative_after_the_projection_is_a_fresh_evaluation(kind, name):
    """After an accepted step step.c projects the end starting from the derivative just
    evaluated there (its Phi_q and Schur factor) and evaluates f at the projected end on
    the projection's factor: the same numbers as evaluating both afresh, so f at the end
    equals, bit for bit, the accelerations of a new System at that state (four_bar: the
    KKT path, which reuses only the constraint terms; vehicle: Python tyre forces)."""
    from mbsim.fast.dynamics import System

    model, q, qd = state_of(kind, name)
    c, _ = pair(model, q, qd, "projection-dop853", 1.0)
    h = min(c.h_abs, 1e-3)
    while (a := c._attempt(h))[2] is None:
        h *= 0.25
    y, f, n = a[2], a[3], model.nq
    qdd, _, power = System(model, c.system.rows).accelerations(y[:n], y[n:2 * n], c.t + h)
    assert np.array_equal(f[n:2 * n], qdd) and f[2 * n] == power


def test_which_models_call_python_per_stage():
    """The C step leaves C per stage only for time targets and Python force elements
    (mbsim.fast.stepper.load_callback): none on the governor and the reference problems,
    a callback on the vehicle (tires) and the compressor (pressure forces)."""
    for kind, name, calls in [("deck", "governor", False), ("problem", "slider_crank", False),
                              ("deck", "vehicle", True), ("deck", "compressor", True)]:
        model, q, qd = state_of(kind, name)
        c = pair(model, q, qd, "projection-dop853", 1.0)[0]
        assert (c._compiled._load is not None) == calls, name


@pytest.mark.parametrize("method,rtol,h", [("projection-dop853", 1e-8, None),
                                           ("projection", 1e-7, None), ("rk4", None, 2e-3),
                                           ("baumgarte", 1e-7, None)])
@pytest.mark.parametrize("name", M.REFERENCE_PROBLEMS)
def test_both_paths_meet_the_reference(name, method, rtol, h):
    """Whole runs, C and Python path, each against the independent reference.  Adaptive
    methods: positions within 1e3 x rtol (the bound of
    tests/integrators/test_free_body_and_top.py for runs of thousands of steps), and the
    two paths' errors alike (within a factor 3, or both below FLOOR: near round-off they
    may take other steps), except through singular positions, where each is held to the
    singular-passage bound 10 rtol + 1e-9 m.  The fixed-step RK4 takes the same steps in
    both paths: its two errors agree to 1e-6 relative (round-off against an error of ~h^4)."""
    pb = M.reference_problem(name)
    opts = {"t_end": pb.t_end, "step": pb.step, "q0": pb.q0, "qd0": pb.qd0,
            "integrator": method, "error_estimate": False}
    if rtol is not None:
        opts.update(rtol=rtol, atol=1e-2 * rtol)
    else:
        opts["h"] = h
    errors = []
    for compiled in (True, False):
        res = dynamic(pb.model, dict(opts, compiled_step=compiled))
        assert res.complete, res.message
        errors.append(R.position_error(res, pb.reference(res.t)).max())
    c, p = errors
    if rtol is None:
        assert c == pytest.approx(p, rel=1e-6, abs=FLOOR)
        return
    assert max(errors) <= 1e3 * rtol, errors
    if name in PASSES_SINGULAR_POSITIONS:
        # at a flat position round-off picks the steps (the first steps' error norms are
        # round-off, summed in another order by C and numpy) and what each passage leaves
        # differs between the paths (docs/benchmarks.md, "Passages over perturbed starts"): each is
        # held to the singular-passage bound instead (test_singular_loops.py)
        assert max(errors) <= 10 * rtol + 1e-9, errors
        return
    assert max(c, p) <= FLOOR or c <= 3 * max(p, FLOOR) and p <= 3 * max(c, FLOOR), errors


def test_a_stage_near_a_change_point_is_left_to_the_policy():
    """A trial with a stage whose change-point measure is below the policy's switch: C
    returns ST_ALARM and the trial is taken again by the Python path, whose policy asks for
    tangent coordinates (a StageFailure that _recover answers).  A switch above every
    measure (s <= 1) makes every trial such a trial."""
    model, q, qd = problem_state("parallel_fourbar")
    c = pair(model, q, qd, "projection-dop853", 0.1)[0]
    assert c._compiled.trial(c.t, 1e-4, c.y, c.f, 2.0) == stepper.ST_ALARM
    c.policy = dataclasses.replace(c.policy, tangent=2.0)
    with pytest.raises(StageFailure, match="tangent coordinates"):
        c._attempt(1e-4)
    assert c._tangent_wanted and not c._c_last


@pytest.mark.parametrize("method,h", [("projection-dop853", None), ("projection", None),
                                      ("baumgarte", None), ("rk4", 2e-3)])
@pytest.mark.parametrize("kind,name", [("problem", "slider_crank"), ("deck", "governor"),
                                       ("problem", "heavy_top"), ("deck", "vehicle")])
def test_a_loop_of_steps_in_c_takes_the_steps_of_one_by_one(kind, name, method, h):
    """Integrator.advance (mbsim/fast/step.c: mb_rk_steps, the controller in C) against the
    same integrator stepped one step at a time (the controller in Python, the same C
    trials): the same steps, rejections and work, and the same end state to round-off of
    the controller's arithmetic (none: both evaluate the same formulas in double); one call
    per output for the adaptive projection methods."""
    model, q, qd = state_of(kind, name)
    opt = {"rtol": 1e-7, "atol": 1e-9} if h is None else {"h": h}
    a, b = (Stepper(model, INTEGRATORS[method], opt, 0.0, q.copy(), qd.copy(), 0.5, None)
            for _ in range(2))
    for s in (a, b):
        assert s.step()[0]  # the first step of a run is always one step
    outputs, calls = (0.1, 0.35, 0.5), 0
    for t_out in outputs:
        while a.solver.t < t_out:  # (one call in C, or one step per call in Python)
            ok, msg = a.advance(t_out, 10**6)
            assert ok, msg
            calls += 1
        assert a.solver.t_old < t_out
        while b.solver.t < t_out:
            assert b.step()[0]
        assert a.solver.t == b.solver.t and a.solver.t_old == b.solver.t_old
        assert close(a.solver.y, b.solver.y)
        times = np.linspace(a.solver.t_old, a.solver.t, 5)[1:]
        assert close(a.solver.dense_output_many(times)[0], b.solver.dense_output_many(times)[0])
    ca, cb = a.all_counters(), b.all_counters()
    for key in ("steps", "rejected_steps", "function_evaluations", "factorizations"):
        assert ca[key] == cb[key], key
    if h is None and method != "baumgarte":  # (Baumgarte's drift test is Python; the
        # fixed step's change-point approach starts two steps before its switch
        # (changepoints.Approach), and leaves the steps there to Python)
        assert calls == len(outputs) < ca["steps"] - 1


def test_ctrl_c_in_a_python_force_element_reaches_the_caller(capfd):
    """Ctrl-C during a C step arrives in the per-stage callback (the only Python code
    running then): it is raised where the C call was made, not printed and dropped by
    ctypes; the integrator's state is the one before the call."""
    model, q, qd = state_of("deck", "compressor")
    c = pair(model, q, qd, "projection-dop853", 1.0)[0]
    # what the System calls per state: the compressor's air forces (hybrid: apply_in)
    el = c.system.py_forces[0]
    name = "apply_in" if getattr(el, "hybrid", False) else "apply"
    calls = {"n": 0}
    apply = getattr(el, name)

    def interrupted(*args):
        calls["n"] += 1
        if calls["n"] == 5:
            raise KeyboardInterrupt
        return apply(*args)

    setattr(el, name, interrupted)
    t, y = c.t, c.y.copy()
    with pytest.raises(KeyboardInterrupt):
        c.step()
    assert c.t == t and np.array_equal(c.y, y)
    assert "Exception ignored" not in capfd.readouterr().err


def test_an_output_the_c_path_cannot_give_ends_the_run_as_incomplete(monkeypatch):
    """A non-finite output from C (here forced after t = 0.4 s) ends the run as an
    incomplete result naming the time (the driver's IntegratorFailure), with the outputs
    before it."""
    real = stepper.CompiledStep.dense

    def dense(self, t0, h, times, k=None):
        status, Q, QD, W, flags = real(self, t0, h, times, k)
        Q[np.asarray(times) > 0.4] = np.nan
        return status, Q, QD, W, flags

    monkeypatch.setattr(stepper.CompiledStep, "dense", dense)
    monkeypatch.setattr(trajectory, "OUTPUT_LOOP", False)  # (the outputs by dense, per step)
    pb = M.reference_problem("free_body")
    res = dynamic(pb.model, {"t_end": 1.0, "step": 0.1, "q0": pb.q0, "qd0": pb.qd0,
                             "error_estimate": False})
    assert res.status == "incomplete"
    assert "not finite" in res.message and "t = 0.5" in res.message
    assert res.t[-1] == pytest.approx(0.4)
