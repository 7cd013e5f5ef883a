"""The output samples' projections on factors already made (mbsim/fast/step.c:
project_sample) against fresh factorisations at every sample (``stepper.REUSE_FACTOR``
off): per deck's default dynamic run (no estimate), the factorisations, the projections
made on a factor already made and those that fell back, and the process CPU of the run,
median of the repeats, the two settings alternated.

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

from mbsim.api import load_model, run_model  # noqa: E402
from mbsim.fast import stepper  # noqa: E402


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
        for reuse, name in ((False, "fresh at every sample"), (True, "factors already made")):
            f, kept, fresh, _ = counts[reuse]
            t = ms[reuse]
            print(f"  {name:24s} factorizations {f:6d}  kept {kept:5d}  fresh {fresh:5d}  "
                  f"run {statistics.median(t):7.2f} ms [{min(t):.2f}-{max(t):.2f}]")
        saved = statistics.median(ms[False]) - statistics.median(ms[True])
        print(f"figure: output projection, {item}: factorizations {counts[False][0]} -> "
              f"{counts[True][0]}, run CPU saved {saved:.2f} ms (median of {args.repeats})")
    stepper.CompiledStep.__init__ = init


if __name__ == "__main__":
    main()
