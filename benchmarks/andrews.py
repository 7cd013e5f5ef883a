"""Andrews' squeezing mechanism at tight tolerances, every adaptive integrator.

    python benchmarks/andrews.py [--integrators a,b] [--settings 1e-10,1e-11,3e-11/3e-11,1e-12]
                                 [--along N] [--fixed]

models/andrews.yaml (seven bodies, one DOF, nine redundant rows, Phi_q condition ~360: a
regular mechanism, no change point) to t = 0.03 s, against the test set's own equations in
minimal coordinates (tests/integrators/andrews.py; 4.7e-12 m from the published solution).
A setting is rtol or rtol/atol (atol defaults to rtol / 100).  Per run: status, the
centroids' largest error at 0.03 s, the bound 10 rtol + 1e-12 m of issue 23, accepted
steps, CPU s (time.process_time, the analysis alone: no error estimate).

--along N: also the error at N equally spaced outputs along the run (the reference at each) and
its largest value: the end value alone is a noisy measure (the error oscillates along the run).
--fixed: each adaptive run is followed by a fixed-step run of the same family with as many
steps (h = 0.03 s / steps): at equal work, does the step control place its steps better than
a uniform grid?  (HHT at rtol 1e-11 before GeneralizedAlpha._shifted_a: adaptive 2.27e-10 m,
fixed 1.10e-10 m; docs/benchmarks.md, "genalpha and HHT: tolerance proportionality below rtol
1e-6".)
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
from mbsim.integrators import INTEGRATORS  # noqa: E402
from tests.integrators import andrews as A  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--integrators",
                    default=",".join(n for n, c in INTEGRATORS.items() if c.adaptive))
    ap.add_argument("--settings", default="1e-10,1e-11,3e-11/3e-11,1e-12")
    ap.add_argument("--along", type=int, default=0, metavar="N",
                    help="also the error at N outputs along the run and its largest value")
    ap.add_argument("--fixed", action="store_true",
                    help="each run again at fixed steps, as many as the adaptive run took")
    a = ap.parse_args(argv)
    _, model = load_model(ROOT / "models" / "andrews.yaml")
    times = np.linspace(0.0, A.T_REF, a.along + 1) if a.along else np.array([0.0, A.T_REF])
    ref = A.solve(times)
    print(f"{'method':18s} {'setting':>12s} {'status':10s} {'error m':>9s} {'bound':>8s} "
          f"{'steps':>7s} {'CPU s':>7s}" + (f" {'max along':>9s}" if a.along else ""))

    def run(name, setting, opt, bound):
        if a.along:
            opt["step"] = A.T_REF / a.along
        c0 = time.process_time()
        res = dynamic(model, opt)
        cpu = time.process_time() - c0
        err = A.position_error(res, ref[-1]) if res.complete else float("nan")
        line = (f"{name:18s} {setting:>12s} {res.status:10s} {err:9.3g} {bound:8.2g} "
                f"{res.counters.get('steps', 0):7d} {cpu:7.2f}")
        if a.along and res.complete:
            along = [A.position_error(res, ref[k], k) for k in range(len(times))]
            line += f" {max(along):9.3g}\n    along: " + " ".join(f"{e:.2g}" for e in along)
        print(line + ("" if res.complete else "  " + res.message[:90]), flush=True)
        return res

    for name in a.integrators.split(","):
        for setting in a.settings.split(","):
            rtol, _, atol = setting.partition("/")
            opt = {"integrator": name, "rtol": float(rtol), "t_end": A.T_REF,
                   "error_estimate": False, "max_steps": 10 ** 6}
            if atol:
                opt["atol"] = float(atol)
            bound = 10 * float(rtol) + 1e-12
            res = run(name, setting, opt, bound)
            steps = res.counters.get("steps", 0)
            if a.fixed and res.complete and steps:
                run(name, f"h={A.T_REF / steps:.4g}", dict(opt, h=A.T_REF / steps), bound)


if __name__ == "__main__":
    main()
