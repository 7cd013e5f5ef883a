"""Work-precision of every integrator on the free slider-crank and the governor: a table per
deck and the CPU time per simulated second needed for an error of 1e-3, 1e-6 and 1e-9;
with ``exudyn`` installed, Exudyn's generalized-alpha on the governor side by side.

    python benchmarks/work_precision.py [--t-end 1] [--repeats 3] [-o plots_dir]

Error: the largest deviation of every body's centroid (m) from a projection-dop853 run at
rtol 1e-12, over 10 outputs (see mbsim.analyses.bench).  For the Exudyn comparison both
codes are judged at t_end only (Exudyn is read out once).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402
from common import exudyn_available, exudyn_run, load  # noqa: E402

from mbsim.analyses.bench import interpolate_cost, work_precision  # noqa: E402
from mbsim.analyses.initial import initial_state  # noqa: E402

TARGETS = (1e-3, 1e-6, 1e-9)
DECKS = {"slider-crank (free, w0 = 2 pi)": ("slider_crank.yaml", "free"),
         "governor (Sec. 12.6, g = 9.80)": ("governor.yaml", None)}


def report(bench, key="cpu"):
    print(bench.table())
    print(f"\n{key.upper()} s per simulated second to reach a max position error of:")
    for target in TARGETS:
        cost = bench.cost_to_reach(target, key)
        ranked = sorted(((v, k) for k, v in cost.items() if v == v))
        print(f"  {target:7.0e}: " + (", ".join(f"{k} {v:.3g}" for v, k in ranked)
                                      or "not reached"))


def exudyn_governor(model, bench, t_end, repeats, steps_ladder):
    """Exudyn on the governor from mbsim's consistent initial state; errors at t_end of all
    body centroids against the same reference as the bench."""
    q, qd, *_ = initial_state(model)
    names = [n for n, g in zip(model.body_names, model.is_ground) if not g]
    points = {n: (n, (0.0, 0.0, 0.0)) for n in names}
    from mbsim.analyses.dynamic import dynamic

    ref = dynamic(model, dict(bench.reference, t_end=t_end, step=t_end))
    ref_end = {n: ref.channel(f"bodies/{n}/r").data[-1] for n in names}
    # Exudyn's faster linear solver for this size (dense LU or Eigen sparse)
    trial = {sp: min(exudyn_run(model, q, qd, 400, t_end, points, sp)[2] for _ in range(2))
             for sp in (False, True)}
    sparse = trial[True] < trial[False]
    print(f"\nExudyn generalized-alpha (fixed steps, {'sparse' if sparse else 'dense'} linear "
          "solver: the faster here) on the governor, error at t_end:")
    pts = []
    for steps in steps_ladder:
        runs = [exudyn_run(model, q, qd, steps, t_end, points, sparse) for _ in range(repeats)]
        err = max(float(np.abs(runs[-1][0][n] - ref_end[n]).max()) for n in names)
        cpu = float(np.median([r[2] for r in runs])) / t_end
        wall = float(np.median([r[1] for r in runs])) / t_end
        pts.append((cpu, err))
        print(f"  {steps:6d} steps: wall {wall:.4f} s/s, CPU {cpu:.4f} s/s, error {err:.2e}")
    print("  CPU s/s to reach an error at t_end of (exudyn vs the best mbsim integrator):")
    for target in TARGETS:
        exu = interpolate_cost(sorted(pts), target)
        best = {}
        for name in dict.fromkeys(r.integrator for r in bench.rows):
            rows = sorted(((r.cpu, r.error_end) for r in bench.rows
                           if r.integrator == name and r.status == "complete"
                           and r.error_end > 0))
            best[name] = interpolate_cost(rows, target)
        ranked = sorted((v, k) for k, v in best.items() if v == v)
        top = f"{ranked[0][1]} {ranked[0][0]:.3g}" if ranked else "not reached"
        ratio = exu / ranked[0][0] if ranked and exu == exu else float("nan")
        print(f"    {target:7.0e}: exudyn {exu:.3g}, mbsim {top}, ratio exudyn/mbsim {ratio:.2f}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--t-end", type=float, default=1.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--integrators", default=None, help="comma list (default: all)")
    ap.add_argument("--tolerances", default="1e-3,1e-5,1e-7,1e-9,1e-11")
    ap.add_argument("--steps", default="1e-2,5e-3,2.5e-3,1.25e-3,6.25e-4")
    ap.add_argument("--exudyn-steps", default="100,400,1600,6400,25600")
    ap.add_argument("--decks", default="slider_crank,governor", help="which of the two")
    ap.add_argument("-o", "--output", help="directory for the work-precision plots (PNG)")
    a = ap.parse_args(argv)
    names = a.integrators.split(",") if a.integrators else None
    tols = tuple(float(x) for x in a.tolerances.split(","))
    steps = tuple(float(x) for x in a.steps.split(","))
    for title, (deck, scene) in DECKS.items():
        if deck.replace(".yaml", "") not in a.decks.split(","):
            continue
        model = load(deck, scene)
        print(f"\n=== {title}: t_end = {a.t_end:g} s, medians of {a.repeats} ===")
        bench = work_precision(model, names, tols, steps, t_end=a.t_end,
                               output_step=a.t_end / 10, repeats=a.repeats)
        report(bench)
        if a.output:
            from mbsim.analyses.bench import work_precision_figure
            from mbsim.output import save_figure

            out = Path(a.output) / (deck.replace(".yaml", "") + "_work_precision.png")
            out.parent.mkdir(parents=True, exist_ok=True)
            save_figure(work_precision_figure(bench, f"work-precision: {title}"), out)
            print(f"plot -> {out}")
        if deck == "governor.yaml" and exudyn_available():
            exudyn_governor(model, bench, a.t_end, a.repeats,
                            [int(x) for x in a.exudyn_steps.split(",")])


if __name__ == "__main__":
    main()
