"""Tolerance proportionality of generalized-alpha and HHT on Andrews' squeezing mechanism.

    python benchmarks/genalpha_proportionality.py [--integrators genalpha,hht]
        [--settings 1e-4,1e-6,1e-8,1e-10,3e-11/3e-11] [--per-step]

models/andrews.yaml to t = 0.03 s against the test set's own equations (tests/integrators/
andrews.py, scipy DOP853 at rtol 1e-13).  A setting is rtol or rtol/atol (atol defaults to
rtol / 100).  Per run: the centroids' largest error at 0.03 s (what
tests/integrators/test_tight_tolerances.py bounds by 10 rtol + 1e-12 m) and over the 31
outputs 0, 1 ms, ..., 30 ms (the error oscillates along the run, so the end value alone
is a noisy measure of the rate), both divided by rtol, accepted steps, CPU s
(time.process_time, the analysis alone).  ``--per-step`` runs the control as it was before
issue 23 (the local error held to the tolerances at every rtol, tolerance_factor = 1): the
"before" column of docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from mbsim.analyses.dynamic import dynamic  # noqa: E402
from mbsim.api import load_model  # noqa: E402
from mbsim.integrators.genalpha import GeneralizedAlpha  # noqa: E402
from tests.integrators import andrews as A  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--integrators", default="genalpha,hht")
    ap.add_argument("--settings", default="1e-4,1e-6,1e-8,1e-10,3e-11/3e-11")
    ap.add_argument("--per-step", action="store_true",
                    help="the control before issue 23 (tolerance_factor = 1)")
    a = ap.parse_args(argv)
    if a.per_step:
        GeneralizedAlpha.tolerance_factor = classmethod(lambda cls, rtol: 1.0)
    _, model = load_model(ROOT / "models" / "andrews.yaml")
    times = np.linspace(0.0, A.T_REF, 31)
    ref = A.solve(times)
    print(f"{'method':9s} {'setting':>12s} {'end err m':>10s} {'/rtol':>6s} {'max err m':>10s} "
          f"{'/rtol':>6s} {'steps':>7s} {'CPU s':>7s}")
    for name in a.integrators.split(","):
        for setting in a.settings.split(","):
            rtol, _, atol = setting.partition("/")
            rtol = float(rtol)
            opt = {"integrator": name, "rtol": rtol, "t_end": A.T_REF, "step": 1e-3,
                   "error_estimate": False, "max_steps": 10 ** 7}
            if atol:
                opt["atol"] = float(atol)
            c0 = time.process_time()
            res = dynamic(model, opt)
            cpu = time.process_time() - c0
            if not res.complete:
                print(f"{name:9s} {setting:>12s} {res.status}: {res.message[:90]}", flush=True)
                continue
            errs = [A.position_error(res, ref[k], k) for k in range(times.size)]
            print(f"{name:9s} {setting:>12s} {errs[-1]:10.3g} {errs[-1] / rtol:6.2f} "
                  f"{max(errs):10.3g} {max(errs) / rtol:6.2f} "
                  f"{res.counters.get('steps', 0):7d} {cpu:7.2f}", flush=True)


if __name__ == "__main__":
    main()
