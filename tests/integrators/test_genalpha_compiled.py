"""The Newton iteration and tangent of generalized-alpha and HHT in C (mbsim/fast/implicit.c)
against the numpy reference of the same equations (tests/reference/genalpha_newton.py), at
every trial step of runs on the seed decks and on the sparse path; and the Python force
elements' failures and Ctrl-C inside the C call."""

from pathlib import Path

import numpy as np
import pytest

from mbsim.analyses.dynamic import dynamic
from mbsim.api import load_model, run_model
from mbsim.integrators.base import rms_norm
from mbsim.integrators.genalpha import GeneralizedAlpha
from tests.helpers import python_loads_raise
from tests.integrators import models as M
from tests.reference import genalpha_newton as ref

MODELS = Path(__file__).resolve().parents[2] / "models"
DECKS = [("governor", None), ("slider_crank", None), ("slider_crank", "free"),
         ("four_bar", None), ("compressor", None), ("vehicle", None), ("andrews", None)]
SPAN = 0.05  # s
EPS = np.finfo(float).eps


def compare_newton(monkeypatch):
    """Patch GeneralizedAlpha._newton to take every trial step both ways from the same
    state; returns the list of (solver, reference result, C result) it fills."""
    seen = []
    compiled = GeneralizedAlpha._newton

    def both(self, h, shift=True):
        a = (self._shifted_a(h) if shift else self.a).copy()
        want = ref.newton(self, h, a, self.KC)
        got = compiled(self, h, shift)
        seen.append((self, want, got))
        return got

    monkeypatch.setattr(GeneralizedAlpha, "_newton", both)
    return seen


def assert_same_steps(seen):
    """Where both converge, the steps agree to what the Newton stop leaves: each result is
    within its last scaled correction (<= newton_tol) of the iteration's limit, so the two
    differ by at most 2 newton_tol in the scaled norm of the Newton test (atol + rtol |q|);
    the velocities, accelerations and multipliers follow q by the step equations' factors
    gam' = gam / (beta h), beta' (module doc), so they are compared through q alone, and
    the power is checked as Q.qd of the same state.  Both sides converge on most steps."""
    both = [(s, w, g) for s, w, g in seen if w is not None and g is not None]
    assert both and len(both) >= 0.9 * len(seen), (len(both), len(seen))
    worst = 0.0
    for s, want, got in both:
        scale = s.atol + s.rtol * np.abs(want[0])
        d = rms_norm(got[0] - want[0], scale)
        worst = max(worst, d / s.newton_tol)
    assert worst <= 2.0, worst
    return worst


@pytest.mark.parametrize("deck, scene", DECKS, ids=[f"{d}-{s}" if s else d for d, s in DECKS])
def test_newton_in_c_takes_the_reference_step(deck, scene, monkeypatch):
    seen = compare_newton(monkeypatch)
    spec, model = load_model(MODELS / f"{deck}.yaml", scene=scene)
    opts = dict(spec.analysis.get("dynamic", {}))
    t0 = float(opts.get("t_start", 0.0))
    opts.update(integrator="genalpha", error_estimate=False, t_end=t0 + SPAN)
    res = run_model(model, "dynamic", opts)
    assert res.status == "complete", res.message
    assert_same_steps(seen)


@pytest.mark.parametrize("name", ["genalpha", "hht"])
def test_sparse_path_takes_the_reference_step(name, monkeypatch):
    """The iteration matrix through scipy's sparse LU (the callbacks of implicit.c), forced
    on a 6-link chain."""
    seen = compare_newton(monkeypatch)
    model = M.chain(6)
    q0, qd0 = M.consistent_state(model)
    res = dynamic(model, {"t_end": 0.05, "step": 0.01, "q0": q0, "qd0": qd0,
                             "integrator": name, "rtol": 1e-6, "atol": 1e-8, "sparse": True,
                             "jacobian": "fd", "error_estimate": False})
    assert res.complete, res.message
    assert seen and all(s.system.sparse for s, _, _ in seen)
    assert_same_steps(seen)


def residual_scale(ga, q, qd, qdd, lam, t):
    """(nq,) the size of the terms of r = M qdd + Phi_q^T lam - Q per row at the state."""
    r, T, Q, Mb = ref.residual(ga, q, qd, qdd, lam, t)
    mq = np.abs(np.einsum("bij,bj->bi", np.abs(Mb), np.abs(qdd).reshape(-1, 7)).reshape(-1))
    return mq + np.abs(T.jac).T @ np.abs(lam) + np.abs(Q)


@pytest.mark.parametrize("deck", ["vehicle", "governor", "andrews"])
def test_tangent_in_c_equals_the_reference(deck):
    """K = dr/dq and C = dr/dqd by forward differences, both ways at the run's start.  Each
    entry is (r(x + d e_j) - r(x)) / d; the two residuals of each side differ from the
    other side's by the round-off of their sums, at most 32 eps of the largest sum of the
    terms' sizes (the 7-term mass products, the Jacobian products, Q: a few dozen additions;
    the largest over the rows, as a perturbed state can give a row terms its base state
    lacks), so the entries differ by at most 2 x 32 eps scale / d_j.  (Measured: 1.7 eps
    scale / d_j at most, on the vehicle.)"""
    spec, model = load_model(MODELS / f"{deck}.yaml")
    opts = dict(spec.analysis.get("dynamic", {}))
    res = run_model(model, "dynamic", dict(opts, integrator="genalpha", error_estimate=False,
                                           t_end=float(opts.get("t_start", 0.0)) + 0.01))
    assert res.complete
    holder = {}
    init = GeneralizedAlpha.__init__

    def keep(self, *args, **kwargs):
        init(self, *args, **kwargs)
        holder.setdefault("ga", self)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(GeneralizedAlpha, "__init__", keep)
        run_model(model, "dynamic", dict(opts, integrator="genalpha", error_estimate=False,
                                         t_end=float(opts.get("t_start", 0.0)) + 0.01))
    ga = holder["ga"]
    state = (ga.q, ga.qd, ga.qdd, ga.lam, ga.t)
    Kc, Cc = ga._core.tangent(ga.t, *state[:4])
    Kr, Cr = ref.tangent(ga, *state)
    scale = residual_scale(ga, *state)
    dq = 1.5e-8 * np.maximum(1.0, np.abs(ga.q))
    dv = 1.5e-8 * np.maximum(1.0, np.abs(ga.qd))
    for got, want, d in ((Kc, Kr, dq), (Cc, Cr, dv)):
        bound = 64 * EPS * scale.max() / d[None, :]
        assert np.all(np.abs(got - want) <= bound), np.max(np.abs(got - want) / bound)
    assert np.abs(Kr).max() > 0 and np.abs(Cr).max() > 0


def test_a_python_load_that_raises_inside_the_step_is_raised(monkeypatch):
    """A Python force element that raises during the C iteration (the load callback returns
    1): the same exception reaches the integrator's caller, which ends the run incomplete
    and names it, as from a Python step; and a KeyboardInterrupt there (Ctrl-C) leaves the
    C call, is raised after it and ends the run as an interruption."""
    spec, model = load_model(MODELS / "compressor.yaml")
    python_loads_raise(monkeypatch, ZeroDivisionError("the element's law divided by zero"))
    opts = dict(spec.analysis.get("dynamic", {}), integrator="genalpha", error_estimate=False,
                t_end=0.05)
    res = run_model(model, "dynamic", opts)
    assert res.status == "incomplete"
    assert "ZeroDivisionError: the element's law divided by zero" in res.message
    assert 0.0 < res.t[-1] <= 0.01 + 1e-12

    python_loads_raise(monkeypatch, KeyboardInterrupt)
    res = run_model(model, "dynamic", opts)
    assert res.status == "incomplete" and "interrupted (Ctrl-C)" in res.message
