"""The error estimate's two companions side by side on the reference problems of issue 11:
estimate / true error and the estimate's CPU relative to the run's (issue 24).

    python benchmarks/estimate_cost.py [--integrator projection-dop853] [--rtols 1e-5,1e-7,1e-9]

For each problem of tests/integrators/models.py:REFERENCE_PROBLEMS (independent references:
tests/integrators/references.py) and each rtol (atol = rtol/100) it runs the dynamic analysis
with ``estimate_method`` coarse (the companion on the run's mesh coarsened by two, where it
applies) and tighter (the companion at rtol/5) and prints est/true for positions and, where
a body rotates, orientations, the estimate's ``relative_cost`` (its CPU / the run's CPU,
outputs included) and which companion was used.  A true error below 1e-12 is round-off: its
ratio is not meaningful (printed as it is).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path[:0] = [str(Path(__file__).resolve().parents[1])]

from mbsim.analyses.dynamic import dynamic  # noqa: E402
from tests.integrators import models as M  # noqa: E402
from tests.integrators import references as R  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--integrator", default="projection-dop853")
    ap.add_argument("--rtols", default="1e-5,1e-7,1e-9")
    a = ap.parse_args()
    rtols = [float(x) for x in a.rtols.split(",")]
    print(f"{a.integrator}: est/true (position, orientation), estimate CPU / run CPU")
    for name in M.REFERENCE_PROBLEMS:
        pb = M.reference_problem(name)
        for rtol in rtols:
            cols = []
            for how in ("coarse", "tighter"):
                res = dynamic(pb.model, {"t_end": pb.t_end, "step": pb.step, "q0": pb.q0,
                                         "qd0": pb.qd0, "rtol": rtol, "atol": rtol * 1e-2,
                                         "integrator": a.integrator, "estimate_method": how})
                ref = pb.reference(res.t)
                pos = R.position_error(res, ref).max()
                ori = R.orientation_error(res, ref).max()
                e = res.summary["error_estimate"]
                used = "coarse" if "coarsened" in e["method"] else "rtol/5"
                ro = f"{e['orientation'] / ori:6.2f}" if pb.rotating else "     -"
                cols.append(f"{how} [{used:>6}] {e['position'] / pos:6.2f} {ro} "
                            f"cost {e['relative_cost']:.2f}")
            print(f"  {name:<17} rtol {rtol:.0e}  true {pos:.2e} m | " + " | ".join(cols),
                  flush=True)


if __name__ == "__main__":
    main()
