"""A linkage that swings to its dead centre, every integrator.

    python benchmarks/dead_centre.py [--integrators a,b] [--rtols 1e-6,1e-8,1e-10]
                                     [--steps 1e-3,5e-4] [--w0 10.505,10.51] [--timeout 60]
                                     [--perturb N]

models/parallel_fourbar.yaml (four parallel cranks, 11 redundant rows) started at the bottom
with a crank speed w0 near 10.505 rad/s, the speed that just reaches the flat position
(theta = 0, where Phi_q loses one more rank): w0 = 10.505 turns 0.004 deg short of it and
swings back, w0 = 10.51 crosses it at 0.32 rad/s and turns 0.054 deg beyond.  Unlike the
fast passages of benchmarks/singular_loops.py, the motion dwells next to the change point.
2 s, against the deck's exact one-DOF reduction (tests/integrators/references.py).

Per (method, w0, rtol; fixed-step methods at the steps of --steps, 1 ms and 0.5 ms unless
given): status, true position error, the bound 10 rtol + 1e-9 m of issue 11, estimate /
error, CPU s (the analysis with its error estimate).  A run still going after --timeout s
(wall) is interrupted: status "interrupted", with what it computed.

--perturb N: each setting also runs N more times from the start perturbed by 4 ulps
(ROUNDOFF_ULPS, random signs, seeds 1..N): the spread of their errors is the round-off floor
of the passage on this machine (tests/integrators/test_changepoints.py, CROSSING_ROUNDOFF).
"""

from __future__ import annotations

import argparse
import signal
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from mbsim.analyses.dynamic import dynamic  # noqa: E402
from mbsim.api import load_model  # noqa: E402
from mbsim.integrators import INTEGRATORS  # noqa: E402
from mbsim.integrators.base import ROUNDOFF_ULPS  # noqa: E402
from tests.integrators import models as M  # noqa: E402
from tests.integrators import references as R  # noqa: E402

DECK = ROOT / "models" / "parallel_fourbar.yaml"
FIXED_STEPS = (1e-3, 5e-4)


def _interrupt(signum, frame):
    raise KeyboardInterrupt  # the analysis stops, keeps its data, marks it incomplete


def run(name, w0, rtol=None, h=None, timeout=60.0, seed=None):
    """(Result, CPU s, true position error m) of one 2-s run; seed: from the exact start
    perturbed by ROUNDOFF_ULPS ulps with random signs (None: the deck's own start)."""
    _, model = load_model(DECK, overrides={"parameters.w0": w0})
    opts = {"integrator": name, "t_end": 2.0}
    opts.update({"h": h} if h else {"rtol": rtol})
    if seed is not None:
        q0, qd0 = M.parallel_fourbar_state(model, w0)[:2]
        signs = np.random.default_rng(seed).choice([-1.0, 1.0], q0.size)
        q0 = q0 + ROUNDOFF_ULPS * np.finfo(float).eps * signs * np.maximum(1.0, np.abs(q0))
        opts.update(q0=q0, qd0=qd0)
    signal.signal(signal.SIGALRM, _interrupt)
    c0 = time.process_time()
    signal.setitimer(signal.ITIMER_REAL, timeout)
    try:
        res = dynamic(model, opts)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
    cpu = time.process_time() - c0
    err = float(R.position_error(res, M.parallel_fourbar_reference(res.t, w0)).max())
    return res, cpu, err


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--integrators", default=",".join(INTEGRATORS))
    ap.add_argument("--rtols", default="1e-6,1e-8,1e-10")
    ap.add_argument("--steps", default=",".join(f"{h:g}" for h in FIXED_STEPS))
    ap.add_argument("--w0", default="10.505,10.51")
    ap.add_argument("--timeout", type=float, default=60.0)
    ap.add_argument("--perturb", type=int, default=0)
    a = ap.parse_args(argv)
    print(f"{'method':18s} {'w0':>7s} {'setting':>10s} {'status':11s} {'error m':>9s} "
          f"{'bound':>8s} {'est/err':>7s} {'CPU s':>7s}")
    for name in a.integrators.split(","):
        adaptive = INTEGRATORS[name].adaptive
        settings = ([("rtol", float(r)) for r in a.rtols.split(",")] if adaptive
                    else [("h", float(h)) for h in a.steps.split(",")])
        for w0 in (float(w) for w in a.w0.split(",")):
            for (key, value), seed in ((kv, s) for kv in settings
                                       for s in [None, *range(1, a.perturb + 1)]):
                res, cpu, err = run(name, w0, **{key: value}, timeout=a.timeout, seed=seed)
                bound = 10 * value + 1e-9 if key == "rtol" else float("nan")
                est = res.summary.get("error_estimate", {}).get("position")
                est = float("nan") if est is None else est  # no estimate (reason in the file)
                flag = " !" if err > bound else ""
                print(f"{name:18s} {w0:7.5g} {key} {value:<5.3g}"
                      f"{'' if seed is None else f' ulps#{seed}'} {res.status:11s} "
                      f"{err:9.3g}{flag:2s} {bound:8.2g} "
                      f"{est / err if err else float('nan'):7.3g} {cpu:7.2f}"
                      f"{'' if res.complete else '  ' + res.message[:80]}", flush=True)


if __name__ == "__main__":
    main()
