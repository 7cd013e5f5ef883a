"""Spherical chain of N = 4, 16, 64 links for 2 s (spec in benchmarks/common.py): wall time,
error of the last link's bottom point against a tight reference, cost growth with N, and,
when ``exudyn`` is installed, Exudyn's implicit solver side by side in the same run.

    python benchmarks/chain.py [--sizes 4,16,64] [--repeats 3] [--rtol 1e-6]

The reference is projection-dop853 at rtol 1e-11.  Exudyn (generalized-alpha, fixed step)
runs over a halving ladder of steps until its error is at most mbsim's; both times are the
median of the repeats, the ratio is Exudyn / mbsim.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402
from common import (chain_model, chain_tip, exudyn_available, exudyn_run,  # noqa: E402
                    timed)

from mbsim.analyses.dynamic import dynamic  # noqa: E402

T_END = 2.0


def run_mbsim(model, n, integrator, rtol):
    opts = {"t_end": T_END, "step": T_END, "integrator": integrator, "rtol": rtol,
            "atol": 1e-2 * rtol, "q0": model.q0.copy(), "qd0": np.zeros(model.nq)}
    res = dynamic(model, opts)
    return res, chain_tip(res, n)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="4,16,64")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--rtol", type=float, default=1e-6)
    ap.add_argument("--integrators", default="projection-dop853,gcp-dop853")
    ap.add_argument("--no-exudyn", action="store_true")
    a = ap.parse_args(argv)
    sizes = [int(x) for x in a.sizes.split(",")]
    names = a.integrators.split(",")
    use_exu = exudyn_available() and not a.no_exudyn
    print(f"spherical chain, t_end = {T_END} s, rtol = {a.rtol:g}, medians of {a.repeats} "
          f"(wall / CPU s); exudyn: {'yes' if use_exu else 'not installed'}")
    head = (f"{'N':>3} {'code':<30} {'wall s':>8} {'CPU s':>8} {'s/s (CPU)':>10} "
            f"{'tip error m':>12} {'steps':>7}")
    print(head)
    print("-" * len(head))
    rows = {}
    for n in sizes:
        model = chain_model(n)
        ref, tip_ref = run_mbsim(model, n, "projection-dop853", 1e-11)
        for name in names:
            (res, tip), wall, cpu = timed(lambda: run_mbsim(model, n, name, a.rtol), a.repeats)
            err = float(np.linalg.norm(tip - tip_ref))
            rows[(n, name)] = (wall, cpu, err)
            print(f"{n:3d} {'mbsim ' + name:<30} {wall:8.3f} {cpu:8.3f} {cpu / T_END:10.3f} "
                  f"{err:12.2e} {res.counters['steps']:7d}  {res.status}")
        if use_exu:
            best = min(rows[(n, nm)][2] for nm in names)
            points = {"tip": (f"link{n - 1}", (0, -0.25, 0))}
            steps = 250
            while True:
                (out, w1, c1), wall, cpu = timed(
                    lambda: exudyn_run(model, model.q0.copy(), np.zeros(model.nq), steps, T_END,
                                       points), a.repeats)
                # exudyn_run times the solve alone: use its own medians
                err = float(np.linalg.norm(out["tip"] - tip_ref))
                if err <= max(best, 1e-9) or steps >= 64000:
                    break
                steps *= 2
            ws = [exudyn_run(model, model.q0.copy(), np.zeros(model.nq), steps, T_END,
                             points)[1:] for _ in range(a.repeats)]
            wall, cpu = float(np.median([w for w, _ in ws])), float(np.median([c for _, c in ws]))
            rows[(n, "exudyn")] = (wall, cpu, err)
            print(f"{n:3d} {'exudyn genalpha, ' + str(steps) + ' steps':<30} {wall:8.3f} "
                  f"{cpu:8.3f} {cpu / T_END:10.3f} {err:12.2e} {steps:7d}")
    print("\ncost growth with N (CPU time ratio between consecutive sizes):")
    for name in names + (["exudyn"] if use_exu else []):
        ts = [rows[(n, name)][1] for n in sizes if (n, name) in rows]
        growth = ", ".join(f"x{b / a_:.2f} for N x{sizes[i + 1] / sizes[i]:g}"
                           for i, (a_, b) in enumerate(zip(ts, ts[1:])))
        print(f"  {name:<20} {growth}")
    if use_exu:
        print("\nExudyn / mbsim CPU time at comparable or better error (>1: mbsim faster):")
        for n in sizes:
            for name in names:
                r = rows[(n, "exudyn")][1] / rows[(n, name)][1]
                print(f"  N = {n:3d} {name:<20} {r:6.2f}  (errors: exudyn "
                      f"{rows[(n, 'exudyn')][2]:.1e}, mbsim {rows[(n, name)][2]:.1e})")


if __name__ == "__main__":
    main()
