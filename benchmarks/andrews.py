"""Andrews' squeezing mechanism at tight tolerances, every adaptive integrator.

    python benchmarks/andrews.py [--integrators a,b] [--settings 1e-10,1e-11,3e-11/3e-11,1e-12]

models/andrews.yaml (seven bodies, one DOF, nine redundant rows, Phi_q condition ~360: a
regular mechanism, no change point) to t = 0.03 s, against the test set's own equations in
minimal coordinates (tests/integrators/andrews.py; 4.7e-12 m from the published solution).
A setting is rtol or rtol/atol (atol defaults to rtol / 100).  Per run: status, the
centroids' largest error at 0.03 s, the bound 10 rtol + 1e-12 m of issue 23, accepted
steps, CPU s (time.process_time, the analysis alone: no error estimate).
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
    a = ap.parse_args(argv)
    _, model = load_model(ROOT / "models" / "andrews.yaml")
    ref = A.solve(np.array([0.0, A.T_REF]))[-1]
    print(f"{'method':18s} {'setting':>12s} {'status':10s} {'error m':>9s} {'bound':>8s} "
          f"{'steps':>7s} {'CPU s':>7s}")
    for name in a.integrators.split(","):
        for setting in a.settings.split(","):
            rtol, _, atol = setting.partition("/")
            opt = {"integrator": name, "rtol": float(rtol), "t_end": A.T_REF,
                   "error_estimate": False, "max_steps": 10 ** 6}
            if atol:
                opt["atol"] = float(atol)
            c0 = time.process_time()
            res = dynamic(model, opt)
            cpu = time.process_time() - c0
            err = A.position_error(res, ref) if res.complete else float("nan")
            print(f"{name:18s} {setting:>12s} {res.status:10s} {err:9.3g} "
                  f"{10 * float(rtol) + 1e-12:8.2g} {res.counters.get('steps', 0):7d} "
                  f"{cpu:7.2f}{'' if res.complete else '  ' + res.message[:90]}", flush=True)


if __name__ == "__main__":
    main()
