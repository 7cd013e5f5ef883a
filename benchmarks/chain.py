"""Spherical chain of N = 4, 16, 64 links for 2 s (spec in benchmarks/common.py): time and
error of the last link's bottom point against a tight reference, cost growth with N, and,
when ``exudyn`` is installed, Exudyn's implicit solver side by side in the same run.

    python benchmarks/chain.py [--sizes 4,16,64,256] [--repeats 3]

Reference: projection-dop853 at rtol 1e-11.  Each code runs a ladder (mbsim: rtol;
Exudyn's generalized-alpha with its sparse linear solver: number of fixed steps); times
are medians of the repeats; the CPU time per simulated second needed for a tip error of
1e-3 and 1e-6 is interpolated log-log along each ladder, and the ratio Exudyn / mbsim is
printed (> 1: mbsim faster).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402
from common import (  # noqa: E402
    chain_model,
    chain_tip,
    cost_at,
    exudyn_available,
    exudyn_run,
    timed,
)

from mbsim.analyses.dynamic import dynamic  # noqa: E402

T_END = 2.0
TARGETS = (1e-3, 1e-6)


def run_mbsim(model, n, integrator, rtol):
    opts = {"t_end": T_END, "step": T_END, "integrator": integrator, "rtol": rtol,
            "atol": 1e-2 * rtol, "q0": model.q0.copy(), "qd0": np.zeros(model.nq)}
    res = dynamic(model, opts)
    return res, chain_tip(res, n)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="4,16,64,256")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--rtols", default="1e-4,1e-6,1e-8")
    ap.add_argument("--exudyn-steps", default="250,1000,4000,16000")
    ap.add_argument("--integrators", default="projection-dop853,gcp-dop853")
    ap.add_argument("--no-exudyn", action="store_true")
    a = ap.parse_args(argv)
    sizes = [int(x) for x in a.sizes.split(",")]
    names = a.integrators.split(",")
    rtols = [float(x) for x in a.rtols.split(",")]
    use_exu = exudyn_available() and not a.no_exudyn
    print(f"spherical chain, t_end = {T_END} s; medians of {a.repeats}; "
          f"exudyn: {'yes' if use_exu else 'not installed'}")
    head = (f"{'N':>3} {'code':<22} {'setting':<12} {'wall s':>8} {'CPU s':>8} "
            f"{'CPU s/s':>8} {'tip error m':>12} {'steps':>6}")
    print(head)
    print("-" * len(head))
    ladders = {}
    for n in sizes:
        model = chain_model(n)
        _, tip_ref = run_mbsim(model, n, "projection-dop853", 1e-11)
        for name in names:
            for rtol in rtols:
                (res, tip), wall, cpu = timed(run_mbsim, model, n, name, rtol, repeats=a.repeats)
                err = float(np.linalg.norm(tip - tip_ref))
                ladders.setdefault((n, name), []).append((cpu / T_END, err))
                print(f"{n:3d} {'mbsim ' + name:<22} {'rtol=%g' % rtol:<12} {wall:8.3f} "
                      f"{cpu:8.3f} {cpu / T_END:8.3f} {err:12.2e} {res.counters['steps']:6d}"
                      + ("" if res.complete else f"  {res.status}: {res.message}"))
        if use_exu:
            points = {"tip": (f"link{n - 1}", (0, -0.25, 0))}
            for steps in (int(s) for s in a.exudyn_steps.split(",")):
                runs = [exudyn_run(model, model.q0.copy(), np.zeros(model.nq), steps, T_END,
                                   points) for _ in range(a.repeats)]
                wall = float(np.median([r[1] for r in runs]))
                cpu = float(np.median([r[2] for r in runs]))
                err = float(np.linalg.norm(runs[-1][0]["tip"] - tip_ref))
                ladders.setdefault((n, "exudyn"), []).append((cpu / T_END, err))
                print(f"{n:3d} {'exudyn generalized-alpha':<22} {'%d steps' % steps:<12} "
                      f"{wall:8.3f} {cpu:8.3f} {cpu / T_END:8.3f} {err:12.2e} {steps:6d}")
    codes = names + (["exudyn"] if use_exu else [])
    for target in TARGETS:
        print(f"\nCPU s per simulated second for a tip error of {target:g} "
              "(interpolated; * extrapolated past the ladder):")
        cost = {(n, c): cost_at(ladders[(n, c)], target) for n in sizes for c in codes}
        for code in codes:
            cs = [cost[(n, code)] for n in sizes]
            growth = " ".join(f"x{b[0] / a_[0]:.1f}" for a_, b in zip(cs, cs[1:]))
            print(f"  {code:<20} " + "  ".join(f"N={n}: {c:7.3f}{'*' if x else ' '}"
                                              for n, (c, x) in zip(sizes, cs))
                  + f"   growth with N: {growth}")
        if use_exu:
            for name in names:
                rs = [cost[(n, "exudyn")][0] / cost[(n, name)][0] for n in sizes]
                print(f"  exudyn / {name:<20}" + "  ".join(f"N={n}: {r:5.2f}  "
                                                          for n, r in zip(sizes, rs)))


if __name__ == "__main__":
    main()
