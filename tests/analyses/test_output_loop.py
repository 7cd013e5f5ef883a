"""The outputs given by the C step loop (issue 24 item 2) against one call per output.

mbsim/fast/step.c's mb_rk_steps takes the steps of a whole output window and writes the
outputs of each step as it goes (the shared per-sample code of mb_rk_dense); the coarse
companion of the error estimate runs as one such loop on its mesh with unprojected outputs
(Index1.advance_outputs).  Both do the same arithmetic in the same order as the path they
replace (one C call per output time, the outputs sampled by trajectory.step_outputs; the
companion one Python call per step, estimate.interpolant_many), in the same process on the
same kernels, so every channel must be equal bit for bit: no tolerance is needed, and any
difference is a change of what is computed, not round-off.  The switches
trajectory.OUTPUT_LOOP and estimate.COARSE_LOOP force the old paths.
"""

import collections

import numpy as np
import pytest

from mbsim.analyses import estimate, trajectory
from mbsim.analyses.dynamic import dynamic
from mbsim.api import load_model, run_model
from mbsim.fast import stepper
from tests.integrators import models as M


def _loop_calls(monkeypatch):
    """Counter of the C loop's calls by (LOOP_* code, outputs asked, mesh given)."""
    calls = collections.Counter()
    steps = stepper.CompiledStep.steps

    def counted(self, y, f, loop):
        why = steps(self, y, f, loop)
        calls[(why, bool(loop.n_out), bool(loop.n_mesh))] += 1
        return why

    monkeypatch.setattr(stepper.CompiledStep, "steps", counted)
    return calls


def _both_ways(monkeypatch, run):
    """(result with the output loop, result with one call per output and step)."""
    out = []
    for loop in (True, False):
        monkeypatch.setattr(trajectory, "OUTPUT_LOOP", loop)
        monkeypatch.setattr(estimate, "COARSE_LOOP", loop)
        out.append(run())
    return out


def _assert_same(new, old):
    assert new.status == old.status, new.message
    assert np.array_equal(new.t, old.t)
    assert new.channels.keys() == old.channels.keys()
    differ = [k for k, c in old.channels.items()
              if not np.array_equal(new.channels[k].data, c.data, equal_nan=True)]
    assert not differ, f"channels not bit-identical: {differ[:5]}"
    for key in ("position", "orientation", "velocity", "angular_velocity", "method", "steps"):
        assert new.summary["error_estimate"].get(key) == old.summary["error_estimate"].get(key)
    assert new.counters["steps"] == old.counters["steps"]


@pytest.mark.parametrize("deck,scene", [("governor", None), ("slider_crank", "free"),
                                        ("vehicle", None)])
def test_deck_outputs_from_the_loop_equal_the_per_output_path(monkeypatch, deck, scene):
    """A run as a user runs it (the deck's outputs, the estimate on): every output channel
    and the estimate bit for bit as with one call per output."""
    spec, model = load_model(f"models/{deck}.yaml", scene=scene)
    calls = _loop_calls(monkeypatch)
    new, old = _both_ways(monkeypatch, lambda: run_model(model, "dynamic", None, spec))
    _assert_same(new, old)
    assert new.complete and "coarsened by 2" in new.summary["error_estimate"]["method"]
    if model_uses_loop := any(n_out for (_, n_out, _) in calls):
        # the index-1 decks: the run's outputs and the companion's both came from the loop
        assert any(mesh for (_, _, mesh) in calls)
    assert model_uses_loop == (deck != "vehicle")  # (the vehicle: generalized-alpha)


@pytest.mark.parametrize("rtol", [3e-9, 1e-9, 1e-10])
def test_outputs_through_the_flat_passages_equal_the_per_output_path(monkeypatch, rtol):
    """The four parallel cranks through the flat positions (projection-dop853): the loop
    stops after a step whose output the projection check flags (LOOP_OUTPUT) and Python
    gives that step's outputs as before, and stops where the change-point approach begins;
    the outputs with the loop are the per-output path's, bit for bit.  Whether an output is
    flagged is the run's round-off (measured: one at rtol 3e-9 under the default OpenBLAS
    kernel, none under Haswell or Prescott, none at 1e-9 or 1e-10), so that is not asserted;
    what is asserted holds either way."""
    pb = M.reference_problem("parallel_fourbar")
    opts = {"t_end": pb.t_end, "step": pb.step, "q0": pb.q0, "qd0": pb.qd0,
            "integrator": "projection-dop853", "rtol": rtol, "atol": rtol / 100}
    calls = _loop_calls(monkeypatch)
    new, old = _both_ways(monkeypatch, lambda: dynamic(pb.model, dict(opts)))
    _assert_same(new, old)
    assert any(n_out for (_, n_out, _) in calls)  # the loop gave outputs


def test_ctrl_c_in_the_loop_keeps_the_outputs_it_gave(monkeypatch):
    """A Ctrl-C met in the loop's Python loads is raised once the C call is back
    (CompiledStep._counted); here one is raised after a loop stopped at the step across
    t = 0.5 s: the run ends as incomplete, interrupted, with every output the loop gave up to
    that step's end, each with its monitors (all channels the same length)."""
    spec, model = load_model("models/governor.yaml")
    steps = stepper.CompiledStep.steps

    def interrupted(self, y, f, loop):
        if not loop.n_out:
            return steps(self, y, f, loop)
        loop.t_stop = 0.5
        steps(self, y, f, loop)
        raise KeyboardInterrupt

    monkeypatch.setattr(stepper.CompiledStep, "steps", interrupted)
    res = run_model(model, "dynamic", None, spec)
    assert res.status == "incomplete" and "interrupted (Ctrl-C)" in res.message
    # the outputs of the steps taken: up to the end of the step across t = 0.5 s
    h = res.channels["monitors/step_size"].data
    assert 0.5 <= res.t[-1] <= 0.5 + h[-1] and np.all(np.isfinite(h))
    assert all(c.data.shape[0] == len(res.t) for c in res.channels.values())
