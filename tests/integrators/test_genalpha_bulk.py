"""Generalized-alpha's work done once for many (mbsim/integrators/genalpha.py): the dense
output of all outputs of a step at once (``dense_output_many``) against the same interpolant
output by output, and the coarse companion of the error estimate taking the run's
finite-difference tangent at their common start (``offer_tangent``) instead of computing it
again."""

import numpy as np
import pytest

from mbsim.analyses.dynamic import dynamic
from mbsim.integrators.base import Integrator, IntegratorFailure
from mbsim.integrators.genalpha import GeneralizedAlpha
from tests.integrators import models as M

ULPS = 4  # the two paths compute the same operations; allow a few ulp of the state's size


def run(pb, name="genalpha", **opt):
    return dynamic(pb.model, {"t_end": 0.5, "step": 0.001, "q0": pb.q0, "qd0": pb.qd0,
                              "integrator": name, "rtol": 1e-6, "atol": 1e-8, **opt})


@pytest.mark.parametrize("name", ["genalpha", "hht"])
def test_dense_outputs_of_a_step_at_once_equal_them_one_by_one(name, monkeypatch):
    """Every step's outputs of a slider-crank run (several per step, and the step's end)
    from the column evaluation equal Integrator.dense_output_many's output-by-output
    evaluation to ULPS ulp of max(1, |y|)."""
    pb = M.reference_problem("slider_crank")
    seen, solvers = [], []
    many = GeneralizedAlpha.dense_output_many

    def both(self, times):
        got = many(self, times)
        want = Integrator.dense_output_many(self, times)
        seen.append((len(times), [np.abs(a - b).max() / max(1.0, np.abs(b).max())
                                  for a, b in zip(got, want)]))
        solvers.append(self)
        return got

    monkeypatch.setattr(GeneralizedAlpha, "dense_output_many", both)
    res = run(pb, name, error_estimate=False)
    assert res.complete, res.message
    assert sum(k for k, _ in seen) == len(res.t) - 1 and max(k for k, _ in seen) > 1
    worst = max(max(d) for _, d in seen)
    assert worst <= ULPS * np.finfo(float).eps, worst
    # a state that is not finite: the outputs before it are kept, the failure names its time
    s = solvers[-1]
    t0, t1 = s._dense[0], s._dense[1]
    # (q1 huge: finite at t0, where its weight is 0, beyond double range far past t1)
    s._dense = s._dense[:3] + (np.full_like(s._dense[3], 1e300),) + s._dense[4:]
    with np.errstate(over="ignore"), pytest.raises(IntegratorFailure, match="not finite") as exc:
        many(s, [t0, t0 + 1e5 * (t1 - t0)])
    assert len(exc.value.done[0]) == 1 and np.all(np.isfinite(exc.value.done[0]))


@pytest.mark.parametrize("name", ["genalpha", "hht"])
def test_coarse_companion_takes_the_runs_start_tangent(name, monkeypatch):
    """The companion starts where the run started: with the run's tangent offered it
    computes none at its start, and its estimate is the same to the bit as with its own."""
    pb = M.reference_problem("slider_crank")
    computed = []
    fd = GeneralizedAlpha._tangent_fd

    def counted(self, *args):
        computed.append(self)
        return fd(self, *args)

    monkeypatch.setattr(GeneralizedAlpha, "_tangent_fd", counted)
    shared = run(pb, name)
    n_shared = len(computed)
    monkeypatch.setattr(GeneralizedAlpha, "offer_tangent", lambda self, tangent: None)
    computed.clear()
    alone = run(pb, name)
    assert shared.complete and alone.complete
    assert "coarsened by 2" in shared.summary["error_estimate"]["method"]
    assert n_shared == len(computed) - 1  # the companion's start tangent, not repeated
    for key in ("position", "orientation", "velocity", "angular_velocity"):
        a, b = shared.channels[f"error/{key}"].data, alone.channels[f"error/{key}"].data
        assert np.array_equal(a, b), key


@pytest.mark.parametrize("name", ["genalpha", "hht"])
def test_companion_stops_newton_on_its_remaining_error(name, monkeypatch):
    """The coarse companion's Newton stops on theta/(1 - theta) err <= newton_tol
    (``newton_contraction``): fewer iterations than on the correction alone, and an
    estimate that differs by at most what the looser stop may leave in each companion step,
    newton_tol (atol + rtol max|q|), summed over its steps and divided by 2^p - 1 (p = 2)."""
    pb = M.reference_problem("slider_crank")
    rtol, atol, newton_tol = 1e-4, 1e-6, 1e-3
    companion = []  # the companion's factorizations (its steps have a fixed size)
    newton = GeneralizedAlpha._newton

    def counted(self, *args, **kwargs):
        before = self.system.counters["factorizations"]
        out = newton(self, *args, **kwargs)
        if self.h_fixed is not None:
            companion.extend([1] * (self.system.counters["factorizations"] - before))
        return out

    monkeypatch.setattr(GeneralizedAlpha, "_newton", counted)
    fast = run(pb, name, rtol=rtol, atol=atol)
    n_fast = len(companion)
    init = GeneralizedAlpha.__init__

    def correction_only(self, *args, **kwargs):
        init(self, *args, **kwargs)
        self.newton_contraction = False
        self._core.g.contraction = 0  # the flag as the C iteration reads it

    monkeypatch.setattr(GeneralizedAlpha, "__init__", correction_only)
    companion.clear()
    slow = run(pb, name, rtol=rtol, atol=atol)
    assert fast.complete and slow.complete
    assert "coarsened by 2" in fast.summary["error_estimate"]["method"]
    assert 0 < n_fast < len(companion)
    qmax = max(np.abs(ch.data).max() for path, ch in fast.channels.items()
               if path.startswith("bodies/") and path.endswith("/r"))
    steps = fast.summary["error_estimate"]["steps"]
    bound = steps * newton_tol * (atol + rtol * max(1.0, qmax)) / (2**2 - 1)
    diff = np.abs(fast.channels["error/position"].data - slow.channels["error/position"].data)
    assert diff.max() <= bound, (diff.max(), bound)
