"""The driver's outputs in bulk (mbsim.analyses.trajectory): the accelerations, multipliers
and residuals of every output in one C call (``output_rows``, mbsim/fast/outputs.c) against
the same quantities output by output (``output_row``: System.accelerations and
System.residuals), and the time targets of all outputs at once (``output_targets``) against
FastConstraints.targets at each time.

Both paths evaluate the same C kernels on the same inputs, so they agree to round-off: the
bound is 1e-12 of each quantity's scale (about 5e3 machine epsilons; no summation order
differs between them)."""

from pathlib import Path

import numpy as np
import pytest

from mbsim.analyses import trajectory as T
from mbsim.api import load_model
from mbsim.options import run_options

ROOT = Path(__file__).resolve().parents[2]
ROUND_OFF = 1e-12  # relative to the quantity's scale (module doc)


def kept_run(deck, scene=None, **overrides):
    """(model, trajectory) of the deck's dynamic run with its outputs, estimate off."""
    spec, model = load_model(ROOT / "models" / deck, scene=scene)
    opt = dict(run_options("dynamic", spec, dict(spec.analysis.get("dynamic", {}),
                                                 error_estimate=False, **overrides)))
    prep = T.Prepared(model, opt)
    return model, T.main_trajectory(model, prep, opt)


def close(a, b):
    scale = max(1.0, float(np.abs(b).max(initial=0.0)))
    np.testing.assert_allclose(a, b, rtol=0.0, atol=ROUND_OFF * scale)


@pytest.mark.parametrize("deck, scene, overrides", [
    ("governor.yaml", None, {}),  # closed loops, no driver
    ("vehicle.yaml", None, {"t_end": 0.5}),  # a driver (time targets), Python tire loads
    ("parallel_fourbar.yaml", None, {"t_end": 0.2}),  # redundant rows: lam zero on them
])
def test_output_rows_equal_output_row_at_every_output(deck, scene, overrides):
    model, tr = kept_run(deck, scene, **overrides)
    n = len(tr)
    system = tr.systems[0]
    assert all(s is system for s in tr.systems[:n])
    loads = T.output_loads(model, system.py_forces, np.asarray(tr.t), np.array(tr.q),
                           np.array(tr.qd))
    done, qdd, lam, ph, v = T.output_rows(system, tr.t, np.array(tr.q), np.array(tr.qd),
                                          loads)
    assert done == n
    for k in range(n):
        one = T.output_row(model, system, tr.t[k], tr.q[k], tr.qd[k],
                           None if loads is None else loads[k])
        for bulk, single in zip((qdd[k], lam[k], ph[k], v[k]), one):
            close(bulk, single)


def test_output_targets_equal_the_targets_at_each_time():
    """The vehicle's steering driver: every function once over the output times."""
    model, tr = kept_run("vehicle.yaml", t_end=0.5)
    fc = tr.systems[0].fc
    assert fc.funcs
    t = np.asarray(tr.t)
    tv = T.output_targets(fc, t)
    for k, tk in enumerate(t):
        close(tv[k], fc.targets(float(tk)).copy())


def test_output_targets_none_without_drivers():
    model, tr = kept_run("governor.yaml", t_end=0.1)
    assert T.output_targets(tr.systems[0].fc, np.asarray(tr.t)) is None
