"""The four parallel cranks through their singular positions, every integrator (issue 11).

    python benchmarks/singular_loops.py [--integrators a,b] [--rtols 1e-6,1e-8,1e-10] [--cranks N]
                                        [--perturb N]

One run per (method, rtol) of tests/integrators/test_singular_loops.py's problem (atol =
rtol/100; fixed-step methods at the step that test uses for that rtol), against its exact
one-DOF reduction: status, true position error, the issue's bound 10 rtol + 1e-9 m, the
error estimate and estimate / true error, CPU s (whole analysis with its estimate) and its
ratio to the method's first rtol (issue 11's budget: at most 10x from rtol 1e-6 to 1e-10;
the unit tests assert no timings).  --cranks N: N parallel cranks (N - 1 loops, 4 (N - 2)
+ 3 redundant rows; 41 is the 40-loop linkage) instead of four.  A run still going after
300 s wall is interrupted (a failure).  --perturb N: each setting also runs N more times from
the start perturbed by ROUNDOFF_ULPS ulps (random signs, seeds 1..N): the spread of their
errors is the passages' round-off floor on this machine.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import dataclasses  # noqa: E402
import functools  # noqa: E402

import numpy as np  # noqa: E402

from mbsim.integrators import INTEGRATORS  # noqa: E402
from mbsim.integrators.base import ROUNDOFF_ULPS  # noqa: E402
from tests.integrators import models as M  # noqa: E402
from tests.integrators.test_singular_loops import run  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--integrators", default=",".join(INTEGRATORS))
    ap.add_argument("--rtols", default="1e-6,1e-8,1e-10")
    ap.add_argument("--cranks", type=int, default=4)
    ap.add_argument("--perturb", type=int, default=0)
    a = ap.parse_args(argv)
    pb = M.reference_problem("parallel_fourbar")
    if a.cranks != 4:
        model = M.parallel_fourbar(a.cranks)
        q, qd = M.parallel_fourbar_state(model, 20.0)
        pb = dataclasses.replace(pb, model=model, q0=q, qd0=qd, reference=functools.partial(
            M.parallel_fourbar_reference, thetad0=20.0, N=a.cranks))
    rtols = [float(r) for r in a.rtols.split(",")]
    print(f"{'method':18s} {'rtol':>7s} {'status':10s} {'error m':>9s} {'bound':>8s} "
          f"{'estimate':>9s} {'est/err':>7s} {'CPU s':>7s} {'x first':>7s}")
    for name in a.integrators.split(","):
        first = None
        for r, seed in ((r, s) for r in rtols for s in range(a.perturb + 1)):
            p = pb
            if seed:
                signs = np.random.default_rng(seed).choice([-1.0, 1.0], pb.q0.size)
                p = dataclasses.replace(pb, q0=pb.q0 + ROUNDOFF_ULPS * np.finfo(float).eps
                                        * signs * np.maximum(1.0, np.abs(pb.q0)))
            c0 = time.process_time()
            res, err = run(name, r, p)
            cpu = time.process_time() - c0
            est = res.summary.get("error_estimate", {}).get("position")
            est = float("nan") if est is None else est  # no estimate (run interrupted)
            first = first or cpu
            print(f"{name:18s} {r:7.0e}{f' #{seed}' if seed else ''} {res.status:10s} "
                  f"{err:9.3g} {10 * r + 1e-9:8.2g} "
                  f"{est:9.3g} {est / err if err else float('nan'):7.3g} {cpu:7.2f} "
                  f"{cpu / first:7.2f}{'' if res.complete else '  ' + res.message[:90]}",
                  flush=True)


if __name__ == "__main__":
    main()
