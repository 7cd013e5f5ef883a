"""peers.py's trials of Exudyn's ObjectKinematicTree on one spherical chain, alone: each
method with every linear solver (and Newton variant) at its cheapest ladder setting, every run
stopped at a CPU cap (peers.capped_solve).  A run cut at the cap is a lower bound on that
configuration's cost at its cheapest setting; a run that completes prints its CPU (its error
is not computed: no reference run here).  For chains where the tree's runs cannot finish in
the time peers.py has (1024 links: 3072 joint coordinates, a dense mass matrix), so that
several methods can be tried side by side.

    python benchmarks/peers_tree_trials.py --links 1024 --cap 15 --methods DOPRI5,ODE23,RK44
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import (  # noqa: E402
    EXUDYN_ADAPTIVE,
    EXUDYN_FIXED,
    EXUDYN_IMPLICIT,
    ExudynSolver,
    chain_model,
    exudyn_chain_tree,
)
from peers import (  # noqa: E402
    ADAPTIVE_TOLS,
    CHAIN_T_END,
    EXPLICIT_STEPS,
    FIXED_STEPS,
    capped_solve,
    fmt_setting,
)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--links", type=int, default=1024)
    ap.add_argument("--cap", type=float, default=15.0, help="CPU s after which a run stops")
    ap.add_argument("--methods", default=",".join(EXUDYN_ADAPTIVE + EXUDYN_FIXED + EXUDYN_IMPLICIT))
    a = ap.parse_args(argv)
    model = chain_model(a.links)
    print(f"tree trials: N = {a.links}, cap {a.cap:g} CPU s per run; load average "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)
    for method in a.methods.split(","):
        probe = ExudynSolver(method)
        first = (ADAPTIVE_TOLS if probe.adaptive else
                 EXPLICIT_STEPS if method in EXUDYN_FIXED else FIXED_STEPS)[0]
        for var in probe.variants():
            w0 = time.perf_counter()
            _, mbs, _ = exudyn_chain_tree(model, a.links)
            build = time.perf_counter() - w0
            cpu, msg = capped_solve(mbs, var, CHAIN_T_END, first, a.cap)
            print(f"    exudyn KinematicTree {var.label:<44} {fmt_setting(first):>7}  "
                  + (f"CPU s/s {cpu / CHAIN_T_END:.4g} (completed; error not computed)"
                     if msg is None else msg) + f"  [build {build:.1f} s wall]", flush=True)
    print(f"load average at the end {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
