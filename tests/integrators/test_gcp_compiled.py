"""The stage and the trial step of coordinate partitioning in C (mbsim/fast/partition.c)
against the Python stage and trial of the same equations (option ``compiled_step: false``):
at every stage (the dense output's), every trial and every step's outputs of runs on the
seed decks, over whole runs, and on the failure paths (Newton, the Python force elements'
exceptions and Ctrl-C inside the C call)."""

from pathlib import Path

import numpy as np
import pytest
import scipy.linalg as la

from mbsim.api import load_model, run_model
from mbsim.integrators.base import Integrator
from mbsim.integrators.gcp import GeneralizedCoordinatePartitioning as Gcp
from tests.helpers import python_loads_raise

MODELS = Path(__file__).resolve().parents[2] / "models"
DECKS = [("governor", None), ("slider_crank", None), ("slider_crank", "free"),
         ("four_bar", None), ("compressor", None), ("vehicle", None), ("andrews", None)]
SPAN = 0.05  # s
EPS = np.finfo(float).eps


def run_span(deck, scene):
    """The deck's dynamic run (scene) under gcp-dop853 over its first SPAN seconds, no
    estimate: complete."""
    spec, model = load_model(MODELS / f"{deck}.yaml", scene=scene)
    opts = dict(spec.analysis.get("dynamic", {}))
    t0 = float(opts.get("t_start", 0.0))
    opts.update(integrator="gcp-dop853", error_estimate=False, t_end=t0 + SPAN)
    res = run_model(model, "dynamic", opts)
    assert res.status == "complete", res.message


def python_stage(gcp, t, v, vd, q, part):
    """The Python stage (``_complete``, then System.accelerations) from the same predicted q."""
    compiled, gcp._compiled = gcp._compiled, None
    try:
        gcp._pred = q.copy()
        qp, qdp, _ = gcp._complete(t, v, vd, part)
        qddp, _, powerp = gcp.system.accelerations(qp, qdp, t, jac=gcp._jac)
    finally:
        gcp._compiled, gcp._pred = compiled, None
    return qp, qdp, qddp, powerp


def compare_stages(monkeypatch):
    """Patch Gcp._compiled_call (the stages outside the compiled trial: the dense output's
    extra stages and samples) to evaluate every compiled stage with accelerations in Python
    too, from the same prediction; returns the list of comparisons it fills."""
    seen = []
    compiled = Gcp._compiled_call

    def both(self, t, v, vd, q, part, accelerations):
        q_in = np.array(q, dtype=float)
        got = compiled(self, t, v, vd, q_in.copy(), part, accelerations)
        if got is None or not accelerations:
            return got
        fac, J = self._compiled.factor(), self._compiled.jacobian()
        try:
            want = python_stage(self, t, v, vd, q_in, part)
        except ArithmeticError:
            want = None
        seen.append((self, t, np.array(vd), part, fac, J, got, want))
        return got

    monkeypatch.setattr(Gcp, "_compiled_call", both)
    return seen


def assert_same_stages(seen):
    """Both sides take the same Newton iteration (the same kernels and LAPACK calls), so each
    q is within newton_tol of the iteration's limit: they differ by at most 2 newton_tol.
    The velocities are compared with the Python formula on the compiled stage's own factor and
    Phi_q, where only the order of the sums in Phi_v vd differs: each entry of that product
    is within k eps sum_c |Phi_v||vd| (the dot product's bound), and the solve carries it by
    at most ||Phi_u^-1||_inf.  The accelerations and the power are the same kernel call on
    the same inputs: within 64 eps of their scale."""
    both = [s for s in seen if s[-1] is not None]
    assert both and len(both) >= 0.9 * len(seen), (len(both), len(seen))
    for gcp, t, vd, part, fac, J, got, want in both:
        q, qd, qdd, power = got
        qp, _, _, _ = want
        assert np.abs(q - qp).max() <= 2 * gcp.newton_tol, (t, np.abs(q - qp).max())
        iv, iu, k = part.iv, part.iu, part.k
        nu = gcp.system.nu(q, t) if gcp.system.rheonomic else np.zeros(iu.size)
        # nu at the last iterate; for a driven row nu = c'(t) does not depend on q
        ud = la.lu_solve(fac, nu - J[:, iv] @ vd)
        inv_norm = np.abs(la.lu_solve(fac, np.eye(iu.size))).sum(axis=1).max()
        bound = 2 * k * EPS * inv_norm * (np.abs(J[:, iv]) @ np.abs(vd)).max() + 4 * EPS * (
            np.abs(ud).max())
        assert np.abs(qd[iu] - ud).max() <= bound, (t, np.abs(qd[iu] - ud).max(), bound)
        assert np.array_equal(qd[iv], vd)
        qddr, _, powerr = gcp.system.accelerations(q, qd, t, jac=J)
        scale = np.abs(qddr).max()
        assert np.abs(qdd - qddr).max() <= 64 * EPS * scale, (t, np.abs(qdd - qddr).max())
        assert abs(power - powerr) <= 64 * EPS * max(abs(powerr), 1e-300)


@pytest.mark.parametrize("deck, scene", DECKS, ids=[f"{d}-{s}" if s else d for d, s in DECKS])
def test_compiled_stage_takes_the_python_stage(deck, scene, monkeypatch):
    seen = compare_stages(monkeypatch)
    run_span(deck, scene)
    assert_same_stages(seen)


def compare_trials(monkeypatch):
    """Patch Gcp._attempt to take every trial in coordinates in Python too (``_trial`` and
    the error norms with the compiled stage off), from the same state, before the compiled
    trial; returns the list of (gcp, h, Python result or exception, compiled result or
    exception) it fills."""
    seen = []
    compiled = Gcp._attempt

    def both(self, h):
        if self._compiled is None or self.part.C is not None:
            return compiled(self, h)
        stage, self._compiled = self._compiled, None
        try:
            y_new, _ = self._trial(h)
            want = (max(self._error_norm(h, y_new), self._extra_error(h)), y_new.copy())
        except ArithmeticError as exc:
            want = exc
        finally:
            self._compiled, self._pred = stage, None
        try:
            got = compiled(self, h)
        except ArithmeticError as exc:
            seen.append((self, h, want, exc))
            raise
        seen.append((self, h, want, got))
        return got

    monkeypatch.setattr(Gcp, "_attempt", both)
    return seen


@pytest.mark.parametrize("deck, scene", DECKS, ids=[f"{d}-{s}" if s else d for d, s in DECKS])
def test_compiled_trial_takes_the_python_trial(deck, scene, monkeypatch):
    """The trial step in C (mb_gcp_trial) against ``_trial`` and the error norms in Python:
    both succeed or both fail on at least 90 % of the trials; where both succeed, every
    stage's q is within newton_tol of the same Newton limit on each side (the predictors
    differ by the round-off of their sums, so the iterations may stop at different
    iterates), which moves y_new and the error norm by a small multiple of newton_tol in the
    scale atol + rtol |y| of the error test: both are compared within 2 newton_tol / atol
    tolerance units."""
    seen = compare_trials(monkeypatch)
    run_span(deck, scene)
    same = [isinstance(w, Exception) == isinstance(g, Exception) for _, _, w, g in seen]
    assert seen and sum(same) >= 0.9 * len(seen), (sum(same), len(seen))
    for gcp, h, want, got in seen:
        if isinstance(want, Exception) or isinstance(got, Exception):
            continue
        bound = 2 * gcp.newton_tol / gcp.atol
        err_p, y_p = want
        err_c, y_c = got[0], got[1]
        scale = gcp.atol + gcp.rtol * np.abs(y_p)
        worst = np.abs((y_c - y_p) / scale).max()
        assert worst <= bound, (h, worst)
        assert abs(err_c - err_p) <= bound, (h, err_c, err_p)


@pytest.mark.parametrize("deck", ["governor", "andrews", "four_bar"])
def test_compiled_trial_end_measures_equal_the_python_formulas(deck, monkeypatch):
    """The sensitivity max |Phi_u^-1 Phi_v| and the measure (smallest / largest |U_ii|) that
    an accepted compiled trial hands to ``_accept`` equal ``_sensitivity`` and
    ``_pivot_ratio`` on the same factor and Phi_q (copied out of the stage's buffers) to
    the round-off of the solve: 64 eps relative (k right-hand sides through the same LU,
    their sums in another order)."""
    seen = []
    accept = Gcp._accept

    def checked(self, t, y, f):
        if self._c_end is not None:
            fac, J = self._compiled.factor(), self._compiled.jacobian()
            seen.append((self._c_end, self._sensitivity(fac, J, self.part.iv),
                         self._pivot_ratio(fac)))
        return accept(self, t, y, f)

    monkeypatch.setattr(Gcp, "_accept", checked)
    spec, model = load_model(MODELS / f"{deck}.yaml")
    opts = dict(spec.analysis.get("dynamic", {}), integrator="gcp-dop853", error_estimate=False)
    assert run_model(model, "dynamic", opts).status == "complete"
    assert seen
    for (sens, ratio), sens_p, ratio_p in seen:
        assert abs(sens - sens_p) <= 64 * EPS * sens_p, (sens, sens_p)
        assert ratio == ratio_p


DENSE = [("governor", "gcp-dop853"), ("governor", "gcp-rk45"), ("slider_crank", "gcp-dop853"),
         ("four_bar", "gcp-dop853"), ("four_bar", "gcp-rk4"), ("andrews", "gcp-dop853")]


@pytest.mark.parametrize("deck, integrator", DENSE, ids=[f"{d}-{i}" for d, i in DENSE])
def test_compiled_dense_output_takes_the_python_dense_output(deck, integrator, monkeypatch):
    """Every step's outputs in C (mb_gcp_dense) against the Python dense output of the same
    step: the interpolants are the same arithmetic up to the order of sums, and each output's
    q is completed by Newton from the same start, so the positions agree within 2 newton_tol
    (each within newton_tol of the same limit); the velocities and the work integral, which
    follow q (and, through DOP853's extra stages, their own Newton iterates), within
    2 newton_tol / atol units of the error test's scale atol + rtol |x| (as the trial's)."""
    seen = []
    compiled = Gcp.dense_output_many

    def both(self, times):
        got = compiled(self, times)
        seen.append((self, self._c_last, got, Integrator.dense_output_many(self, times)))
        return got

    monkeypatch.setattr(Gcp, "dense_output_many", both)
    spec, model = load_model(MODELS / f"{deck}.yaml")
    opts = dict(spec.analysis.get("dynamic", {}), integrator=integrator, error_estimate=False)
    if integrator == "gcp-rk4":
        opts["step"] = 1e-3
    res = run_model(model, "dynamic", opts)
    assert res.status == "complete", res.message
    assert sum(c for _, c, _, _ in seen) >= 0.9 * len(seen) > 0  # the steps taken in C
    for gcp, _, (Q, QD, W), (Qp, QDp, Wp) in seen:
        units = 2 * gcp.newton_tol / gcp.atol
        assert np.abs(Q - Qp).max() <= 2 * gcp.newton_tol
        for got, want in ((QD, QDp), (W, Wp)):
            worst = (np.abs(got - want) / (gcp.atol + gcp.rtol * np.abs(want))).max()
            assert worst <= units, worst


def run(deck, integrator, compiled, **extra):
    spec, model = load_model(MODELS / f"{deck}.yaml")
    opts = dict(spec.analysis.get("dynamic", {}), integrator=integrator, error_estimate=False,
                compiled_step=compiled, **extra)
    return run_model(model, "dynamic", opts)


@pytest.mark.parametrize("integrator", ["gcp-dop853", "gcp-rk45"])
def test_compiled_and_python_runs_agree_within_the_tolerance(integrator):
    """A whole governor run both ways: each stage agrees to round-off (above), so the
    trajectories differ by far less than one unit of the run's tolerance."""
    rtol, atol = 1e-8, 1e-10
    a = run("governor", integrator, True, rtol=rtol, atol=atol)
    b = run("governor", integrator, False, rtol=rtol, atol=atol)
    assert a.status == b.status == "complete"
    for name in ("r", "p"):  # every body's position and Euler parameters
        for body in a.names["bodies"]:
            qa = a.channel(f"bodies/{body}/{name}").data
            qb = b.channel(f"bodies/{body}/{name}").data
            scale = atol + rtol * np.abs(qb).max()
            assert np.abs(qa - qb).max() <= scale, (body, np.abs(qa - qb).max() / scale)


def test_newton_failure_reads_the_same_both_ways():
    """A Newton iteration that cannot stop (newton_tol below round-off) fails the stage with
    the Python stage's message (the constraints of the largest residuals), both ways."""
    msgs = [run("governor", "gcp-dop853", c, newton_tol=1e-30).message for c in (True, False)]
    assert "Newton iteration for the dependent coordinates did not converge" in msgs[0]
    assert msgs[0] == msgs[1]


def test_a_python_load_that_raises_inside_the_stage_is_raised(monkeypatch):
    """A Python force element that raises during the C stage (the load callback returns 1):
    the stage is taken again in Python, where the same exception fails the stage (a
    ZeroDivisionError is numerical: the step shrinks to h_min and the run ends incomplete
    naming it), with the Python stage's message; a KeyboardInterrupt there (Ctrl-C)
    leaves the C call, is raised after it and ends the run as an interruption."""
    python_loads_raise(monkeypatch, ZeroDivisionError("the element's law divided by zero"))
    res, py = (run("compressor", "gcp-rk45", c, t_end=0.05) for c in (True, False))
    assert res.status == "incomplete"
    assert "the element's law divided by zero" in res.message
    assert res.message == py.message
    assert 0.0 < res.t[-1] <= 0.01 + 1e-12

    python_loads_raise(monkeypatch, KeyboardInterrupt)
    res = run("compressor", "gcp-rk45", True, t_end=0.05)
    assert res.status == "incomplete" and "interrupted (Ctrl-C)" in res.message
