"""The output samples' velocities projected on the factor of their positions' Newton step
(mbsim/fast/step.c: project_sample) against a fresh factorisation per sample
(``stepper.REUSE_FACTOR`` off, as before): per deck's default dynamic run (no estimate), the
factorisations, the samples whose velocities were projected on the positions' factor
(kept) and on a fresh one (fresh), and the process CPU of the run, median of the repeats,
the two settings alternated; then the projection's own cost per sample: the dense output of
12 steps' samples (4 per step) taken 200 times with and without the projection, best of 5.

    python benchmarks/output_projection.py [--repeats 11] [--decks governor,slider_crank:free]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from mbsim.analyses.trajectory import Stepper, initial_conditions  # noqa: E402
from mbsim.api import load_model, run_model  # noqa: E402
from mbsim.fast import stepper  # noqa: E402
from mbsim.integrators import INTEGRATORS  # noqa: E402
from mbsim.options import deck_context  # noqa: E402


def per_sample(spec, model, opts, steps=12, calls=200, best_of=5):
    """{setting: us per output sample} of the dense output of ``steps`` steps' samples (4 per
    step) in C: "none" unprojected (the interpolant and DOP853's extra stages), "fresh" and
    "kept" projected as REUSE_FACTOR off / on."""
    q, qd, _ = initial_conditions(model, 0.0, {"tol": 1e-10}, deck_context(spec, shapes=False).hold)
    method = opts.get("integrator", "projection-dop853")
    tol = {k: opts[k] for k in ("rtol", "atol") if k in opts}
    s = Stepper(model, INTEGRATORS[method], tol, 0.0, q, qd, 10.0, None).solver
    c = s._compiled
    settings = {"none": (0, 0), "fresh": (1, 0), "kept": (1, 1)}  # (project, reuse)
    total = dict.fromkeys(settings, 0.0)
    for _ in range(steps):
        assert s.step()[0]
        t0, h = s._dense_args[:2]
        times = t0 + np.array([0.1, 0.35, 0.6, 0.85]) * h
        for name, (project, reuse) in settings.items():
            c.r.project, c.r.reuse = project, reuse
            best = np.inf
            for _ in range(best_of):
                a = time.perf_counter()
                for _ in range(calls):
                    c.dense(t0, h, times)
                best = min(best, (time.perf_counter() - a) / calls)
            total[name] += best / times.size
        c.r.project, c.r.reuse = 1, int(stepper.REUSE_FACTOR)
    return {k: 1e6 * v / steps for k, v in total.items()}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=11)
    ap.add_argument("--decks", default="governor,slider_crank:free,parallel_fourbar")
    args = ap.parse_args(argv)
    made = []
    init = stepper.CompiledStep.__init__

    def recording(self, *a, **k):
        init(self, *a, **k)
        made.append(self)

    stepper.CompiledStep.__init__ = recording
    for item in args.decks.split(","):
        deck, _, scene = item.partition(":")
        spec, model = load_model(ROOT / "models" / f"{deck}.yaml", scene=scene or None,
                                 studies=False)
        opts = dict(spec.analysis.get("dynamic", {}), error_estimate=False)
        ms = {True: [], False: []}
        counts = {}
        for k in range(args.repeats + 1):
            for reuse in (True, False):
                stepper.REUSE_FACTOR = reuse
                made.clear()
                c0 = time.process_time()
                res = run_model(model, "dynamic", dict(opts), spec)
                c1 = time.process_time()
                if k == 0:  # (a warm-up: counted, not timed)
                    counts[reuse] = (res.counters["factorizations"],
                                     sum(c.output_projections["kept"] for c in made),
                                     sum(c.output_projections["fresh"] for c in made),
                                     len(res.t))
                else:
                    ms[reuse].append(1e3 * (c1 - c0))
        print(f"=== {item}: {opts.get('integrator', 'projection-dop853')}, "
              f"{counts[True][3]} outputs ===")
        for reuse, name in ((False, "fresh factor"), (True, "on the positions' factor")):
            f, kept, fresh, _ = counts[reuse]
            t = ms[reuse]
            print(f"  {name:24s} factorizations {f:6d}  kept {kept:5d}  fresh {fresh:5d}  "
                  f"run {statistics.median(t):7.2f} ms [{min(t):.2f}-{max(t):.2f}]")
        saved = statistics.median(ms[False]) - statistics.median(ms[True])
        print(f"figure: output projection, {item}: factorizations {counts[False][0]} -> "
              f"{counts[True][0]}, run CPU saved {saved:.2f} ms (median of {args.repeats})")
        us = per_sample(spec, model, opts)
        fresh, kept = us["fresh"] - us["none"], us["kept"] - us["none"]
        print(f"  per sample, us: interpolant and extra stages {us['none']:.2f}, projection "
              f"fresh {fresh:.2f}, on the positions' factor {kept:.2f}")
        print(f"figure: output projection per sample, {item}: {fresh:.2f} -> {kept:.2f} us "
              f"({100 * (kept / fresh - 1):+.0f} %)")
    stepper.CompiledStep.__init__ = init


if __name__ == "__main__":
    main()
