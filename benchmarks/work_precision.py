"""Work-precision of every mbsim integrator on the governor and the free slider-crank, with
Exudyn's generalized-alpha side by side in the same run (issue #3's speed target).

    python benchmarks/work_precision.py [--repeats 5] [--problems governor,slider_crank]
                                        [--integrators a,b] [-o plots_dir]

The problems (PROBLEMS below):

- governor: Table 12.6.6 configuration, g = 9.80, spindle started at 10 rad/s instead of
  its 11.0174 rad/s steady state (the arms drop and swing), 5 s; error at t = 5 s =
  max(|collar r - ref| in m, |spindle omega - ref| in rad/s): issue #3's definition;
- slider_crank: the free slider-crank (scene ``free``, rod 0.3 m, w0 = 2 pi rad/s), 2 s
  (three periods); error at t = 2 s = max(|slider r - ref| in m, |crank omega - ref| in
  rad/s).

Reference: projection-dop853 at rtol 1e-12 (gcp-dop853 and gcp-rk45 at 1e-12 agree with it
to 1e-12 on the governor and 1e-11 on the slider-crank, so errors down to 1e-10 are real).
Costs are process CPU seconds per simulated second, medians of ``--repeats`` runs (CPU time
is the steadier figure on a shared machine; wall times are printed in the tables too).
For each target error (1e-3, 1e-6, 1e-9) the cost is interpolated log-log along each
ladder, and the ratio Exudyn / best mbsim integrator is printed (> 1: mbsim is faster).
Exudyn is optional (``pip install exudyn``); without it the mbsim tables are printed alone.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402
from common import cost_at, exudyn_available, exudyn_run, load  # noqa: E402

from mbsim.analyses.bench import interpolate_cost, work_precision  # noqa: E402
from mbsim.analyses.initial import initial_state  # noqa: E402

TARGETS = (1e-3, 1e-6, 1e-9)
PROBLEMS = {
    "governor": dict(
        title="governor (Table 12.6.6, g = 9.80, spindle from 10 rad/s), 5 s",
        deck="governor.yaml", scene=None, overrides={"parameters.omega0": 10.0}, t_end=5.0,
        position=("collar", "collar"), spin="spindle"),
    "slider_crank": dict(
        title="slider-crank (free, rod 0.3 m, w0 = 2 pi rad/s), 2 s",
        deck="slider_crank.yaml", scene="free", overrides=None, t_end=2.0,
        position=("slider", "slider"), spin="crank"),
}
EXUDYN_STEPS = (250, 500, 1000, 2000, 4000, 8000, 16000, 32000)


def mbsim_ladder(problem, integrators, repeats, progress=True):
    """The bench of mbsim.analyses.bench with the problem's error channels."""
    model = load(problem["deck"], problem["scene"], problem["overrides"])
    body, _ = problem["position"]
    outputs = (f"bodies/{body}/r", f"bodies/{problem['spin']}/omega")

    def show(row):
        if progress:
            print(f"  {row.integrator:<18} {row.setting:<11} CPU {row.cpu:8.4f} s/s  "
                  f"error at t_end {row.error_end:9.2e}  {row.status}", flush=True)

    bench = work_precision(model, integrators, t_end=problem["t_end"],
                           tolerances=(1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11),
                           outputs=outputs, output_step=problem["t_end"], repeats=repeats,
                           progress=show)
    return model, bench


def exudyn_ladder(model, bench, problem, repeats):
    """Exudyn generalized-alpha (fixed steps) from mbsim's consistent initial state; its
    errors at t_end against the bench's reference run.  Returns [(CPU s/s, error)]."""
    from mbsim.analyses.dynamic import dynamic

    q, qd, *_ = initial_state(model)
    t_end = problem["t_end"]
    body, point_body = problem["position"]
    spin = problem["spin"]
    ref = dynamic(model, dict(bench.reference, t_end=t_end, step=t_end))
    ref_r = ref.channel(f"bodies/{body}/r").data[-1]
    ref_w = ref.channel(f"bodies/{spin}/omega").data[-1]
    points = {body: (point_body, (0.0, 0.0, 0.0))}
    # Exudyn's faster linear solver for this size (dense LU or Eigen sparse)
    trial = {sp: min(exudyn_run(model, q, qd, 500, t_end, points, sp)[2] for _ in range(2))
             for sp in (False, True)}
    sparse = trial[True] < trial[False]
    print(f"\n  Exudyn generalized-alpha, fixed steps, {'sparse' if sparse else 'dense'} "
          "linear solver (the faster here):")
    pts = []
    for steps in EXUDYN_STEPS:
        runs = [exudyn_run(model, q, qd, steps, t_end, points, sparse, omegas=(spin,))
                for _ in range(repeats)]
        out = runs[-1][0]
        err = max(float(np.abs(out[body] - ref_r).max()),
                  float(np.abs(out[f"{spin}.omega"] - ref_w).max()))
        cpu = float(np.median([r[2] for r in runs])) / t_end
        wall = float(np.median([r[1] for r in runs])) / t_end
        pts.append((cpu, err))
        print(f"  {steps:6d} steps: wall {wall:8.4f} s/s, CPU {cpu:8.4f} s/s, "
              f"error at t_end {err:9.2e}", flush=True)
    return sorted(pts)


def summary(bench, exudyn_points):
    """CPU s/s to reach each target: every mbsim integrator, Exudyn, and the ratio."""
    print("\n  CPU s per simulated second to reach an error at t_end of:")
    for target in TARGETS:
        cost = {}
        for name in dict.fromkeys(r.integrator for r in bench.rows):
            rows = sorted((r.cpu, r.error_end) for r in bench.rows
                          if r.integrator == name and r.status == "complete"
                          and np.isfinite(r.error_end) and r.error_end > 0)
            cost[name] = interpolate_cost(rows, target)
        ranked = sorted((v, k) for k, v in cost.items() if v == v)
        line = ", ".join(f"{k} {v:.3g}" for v, k in ranked[:4]) or "not reached"
        print(f"    {target:7.0e}: mbsim: {line}")
        if exudyn_points is not None:
            exu, extrapolated = cost_at(exudyn_points, target)
            if extrapolated:  # an estimate, never made a ratio
                print(f"             exudyn {exu:.3g} (an estimate, extrapolated past its "
                      "ladder: no ratio)")
                continue
            ratio = exu / ranked[0][0] if ranked and exu == exu else float("nan")
            print(f"             exudyn {exu:.3g}; ratio exudyn / best mbsim = {ratio:.2f}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--integrators", default=None, help="comma list (default: all)")
    ap.add_argument("--problems", default="governor,slider_crank")
    ap.add_argument("--no-exudyn", action="store_true", help="skip Exudyn even if installed")
    ap.add_argument("-o", "--output", help="directory for the work-precision plots (PNG)")
    a = ap.parse_args(argv)
    names = a.integrators.split(",") if a.integrators else None
    use_exudyn = exudyn_available() and not a.no_exudyn
    if not use_exudyn:
        print("(exudyn not installed or --no-exudyn: mbsim only)")
    for key in a.problems.split(","):
        problem = PROBLEMS[key]
        print(f"\n=== {problem['title']}: medians of {a.repeats} ===", flush=True)
        model, bench = mbsim_ladder(problem, names, a.repeats)
        pts = exudyn_ladder(model, bench, problem, a.repeats) if use_exudyn else None
        summary(bench, pts)
        if a.output:
            from mbsim.analyses.bench import work_precision_figure
            from mbsim.output import save_figure

            out = Path(a.output) / f"{key}_work_precision.png"
            out.parent.mkdir(parents=True, exist_ok=True)
            save_figure(work_precision_figure(bench, f"work-precision: {problem['title']}"),
                        out)
            print(f"  plot -> {out}")


if __name__ == "__main__":
    main()
