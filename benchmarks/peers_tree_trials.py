"""peers.py's trials of Exudyn's ObjectKinematicTree on one spherical chain, alone: each
method with every linear solver (and Newton variant) at its cheapest ladder setting, every run
stopped at a CPU cap (peers.capped_solve).  A run cut at the cap is a lower bound on that
configuration's cost at its cheapest setting; a run that completes prints its CPU (its error
is not computed: no reference run here).  For chains where the tree's runs cannot finish in
the time peers.py has (1024 links: 3072 joint coordinates, a dense mass matrix), so that
several methods can be tried side by side.  With ``--ladders``: peers.py's own path for the
given methods (the trials, then the fastest variant's ladder with errors against peers.py's
reference run, stopped at ``--max-cpu``), its ladder lines in peers.py's format.

    python benchmarks/peers_tree_trials.py --links 1024 --cap 15 --methods DOPRI5,ODE23,RK44
    python benchmarks/peers_tree_trials.py --links 64 --cap 30 --methods RK67 --ladders
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


def ladders(model, a):
    """peers.chain_case's tree branch for a.methods: trials, then ladders with errors."""
    import numpy as np
    from common import chain_tip
    from peers import CHAIN_REFERENCE, exudyn_method_ladders, reference_run, tree_twin

    n = a.links
    q, qd = model.q0.copy(), np.zeros(model.nq)
    ref, ref_cpu = reference_run(model, CHAIN_T_END, q, qd, CHAIN_REFERENCE)
    tip_ref = chain_tip(ref, n)
    print(f"tree ladders: N = {n}, cap {a.cap:g} CPU s per run, --max-cpu {a.max_cpu:g}; "
          f"reference {ref_cpu:.2f} s CPU; load average "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)

    build_tree, err_tree = tree_twin(model, n, tip_ref)
    a.adaptive_tols, a.explicit_steps, a.fixed_steps = ADAPTIVE_TOLS, EXPLICIT_STEPS, FIXED_STEPS
    _, notes = exudyn_method_ladders(build_tree, err_tree, a.methods.split(","), CHAIN_T_END,
                                     a, "exudyn KinematicTree ", cap=a.cap)
    for note in notes:
        print(f"    note: {note}")
    print(f"load average at the end {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    return 0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--links", type=int, default=1024)
    ap.add_argument("--cap", type=float, default=15.0, help="CPU s after which a run stops")
    ap.add_argument("--methods", default=",".join(EXUDYN_ADAPTIVE + EXUDYN_FIXED + EXUDYN_IMPLICIT))
    ap.add_argument("--ladders", action="store_true",
                    help="peers.py's trials and ladders, errors against its reference")
    ap.add_argument("--max-cpu", type=float, default=10.0, help="--ladders: as peers.py's")
    ap.add_argument("--repeats", type=int, default=3, help="--ladders: as peers.py's")
    a = ap.parse_args(argv)
    model = chain_model(a.links)
    if a.ladders:
        return ladders(model, a)
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
