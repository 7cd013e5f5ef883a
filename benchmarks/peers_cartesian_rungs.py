"""Exudyn's Cartesian twin of the spherical chain under one implicit solver at chosen fixed
step counts: CPU s per simulated second (median of --repeats [min-max]) and the tip error
against peers.py's reference run, peers.py's own functions throughout
(``common.exudyn_rigid_system``, ``peers.capped_solve``, ``peers.reference_run``).  For the
rungs between peers.py's doubling ladder (a step count where the error just meets 1e-6),
so that Exudyn's best at a target is measured, not bounded:

    python benchmarks/peers_cartesian_rungs.py --links 256 --method TrapezoidalIndex2 \
        --steps 2800,3000,3200
    python benchmarks/peers_cartesian_rungs.py --links 1024 --method GeneralizedAlpha \
        --steps 900,1000

(Exudyn installed; docs/benchmarks.md "Chains at 256 and 1024 links, measured again".)"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402
from common import ExudynSolver, chain_model, chain_tip, exudyn_rigid_system  # noqa: E402
from peers import CHAIN_REFERENCE, CHAIN_T_END, capped_solve, reference_run  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--links", type=int, default=256)
    ap.add_argument("--method", default="TrapezoidalIndex2",
                    help="GeneralizedAlpha or TrapezoidalIndex2")
    ap.add_argument("--linear", default="EigenSparse", help="EXUdense, EigenDense, EigenSparse")
    ap.add_argument("--full-newton", action="store_true", help="default: modified Newton")
    ap.add_argument("--steps", default="1000,2000", help="comma list of step counts")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cap", type=float, default=120.0, help="CPU s after which a run stops")
    a = ap.parse_args(argv)
    import exudyn as exu

    n = a.links
    model = chain_model(n)
    q, qd = model.q0.copy(), np.zeros(model.nq)
    print(f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)
    ref, ref_cpu = reference_run(model, CHAIN_T_END, q, qd, CHAIN_REFERENCE)
    tip_ref = chain_tip(ref, n)
    print(f"reference {ref_cpu:.1f} s CPU", flush=True)
    for steps in (int(s) for s in a.steps.split(",")):
        cpus, err, msg = [], float("nan"), None
        for _ in range(max(1, a.repeats)):
            _, mbs, items = exudyn_rigid_system(model, q, qd)
            var = ExudynSolver(a.method, a.linear, not a.full_newton)
            cpu, msg = capped_solve(mbs, var, CHAIN_T_END, steps, a.cap)
            cpus.append(cpu / CHAIN_T_END)
            if msg is None:
                tip = mbs.GetObjectOutputBody(items[f"link{n - 1}"],
                                              exu.OutputVariableType.Position,
                                              localPosition=[0, -0.25, 0])
                err = float(np.linalg.norm(np.array(tip) - tip_ref))
        print(f"    exudyn Cartesian {var.label:<48} {steps} st  CPU s/s {np.median(cpus):.4g} "
              f"[{min(cpus):.4g}-{max(cpus):.4g}]  error {err:.2e}  {msg or ''}", flush=True)
    print(f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
