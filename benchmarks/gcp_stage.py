"""The step of coordinate partitioning in C (mbsim/fast/partition.c) against the Python
stages, both paths side by side in one run: CPU per simulated second of gcp-dop853 and
gcp-rk45 runs, and their ratio.

    python benchmarks/gcp_stage.py [--repeats 5]
        [--decks governor,compressor,andrews,parallel_fourbar] [--integrators a,b]

Per deck and integrator: the deck's dynamic run with that integrator, its outputs, no error
estimate (the estimate's companion is another integrator's run), rtol 1e-8, atol 1e-10 (the
compressor and Andrews' mechanism at their decks' settings; the four parallel cranks of
models/parallel_fourbar.yaml pass their flat positions in tangent coordinates), as
``run_model`` runs it after one untimed warm-up run; the two paths by the deck option
``compiled_step`` (true: each trial step and each step's outputs in one C call; false: the
same equations through Python), alternated repeat by repeat so that both see the same load.
Under a checkout without the compiled step (``before_after.py --scripts gcp_stage`` with an
older "before") both paths are its Python stages.  Printed: process CPU per simulated
second, median [min-max] over the repeats, for each path; the figure ``gcp stage: compiled
/ Python`` is the median of the repeats' ratios; and the counters of both runs, which agree
up to round-off (tests/integrators/test_gcp_compiled.py; a Newton iteration more or less
can follow).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

# common.ROOT: the checkout measured ($MBSIM_ROOT, set by before_after.py for each side,
# else this tree), put first on sys.path by common
sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import ROOT, figure  # noqa: E402

from mbsim.api import load_model, run_model  # noqa: E402

TIGHT = {"rtol": 1e-8, "atol": 1e-10}
OWN = {"compressor", "andrews"}  # run at their decks' own tolerances


def measure(deck, integrator, repeats):
    spec, model = load_model(ROOT / "models" / f"{deck}.yaml")
    base = dict(spec.analysis.get("dynamic", {}), integrator=integrator, error_estimate=False)
    if deck not in OWN:
        base.update(TIGHT)
    span = float(base.get("t_end", 1.0)) - float(base.get("t_start", 0.0))
    cpu = {True: [], False: []}
    counters = {}
    for compiled in (True, False):  # warm-up: imports, the kernels' loading, first-use caches
        run_model(model, "dynamic", dict(base, compiled_step=compiled))
    for _ in range(repeats):
        for compiled in (True, False):
            c0 = time.process_time()
            res = run_model(model, "dynamic", dict(base, compiled_step=compiled))
            cpu[compiled].append((time.process_time() - c0) / span)
            if res.status != "complete":
                raise SystemExit(f"{deck} {integrator}: {res.status}: {res.message}")
            counters[compiled] = {k: res.counters.get(k) for k in
                                  ("steps", "rejected_steps", "function_evaluations",
                                   "newton_iterations")}
    print(f"\n=== {deck}, {integrator}, rtol {base.get('rtol', 'default')}, {span:g} s; CPU s per "
          f"simulated s, median [min-max] of {repeats} ===")
    for compiled in (True, False):
        v = cpu[compiled]
        print(f"    {'compiled stage' if compiled else 'Python stage  '}  "
              f"{statistics.median(v):.4g} [{min(v):.4g}-{max(v):.4g}]   {counters[compiled]}")
    name = f"gcp stage: {deck} {integrator}"
    figure(f"{name}, compiled", cpu[True], "CPU s/s")
    figure(f"{name}, Python", cpu[False], "CPU s/s")
    ratios = [a / b for a, b in zip(cpu[True], cpu[False])]
    figure(f"{name}: compiled / Python", ratios, "x")
    if counters[True] != counters[False]:
        print(f"    counters differ: {counters}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--decks", default="governor,compressor,andrews,parallel_fourbar")
    ap.add_argument("--integrators", default="gcp-dop853,gcp-rk45")
    a = ap.parse_args(argv)
    for deck in a.decks.split(","):
        for integrator in a.integrators.split(","):
            measure(deck, integrator, a.repeats)


if __name__ == "__main__":
    main()
