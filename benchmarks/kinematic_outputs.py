"""Kinematic analysis: CPU milliseconds per output time on the slider-crank (issue 24).

    python benchmarks/kinematic_outputs.py [--repeats 3] [--t-end 20] [--quick]

models/slider_crank.yaml as the deck has it (the crank driven at 2 pi rad/s), `mbsim run
--mode kinematic`'s analysis in process (mbsim.api.load_model, run_model; the results file
is not written), output step 0.005 s.  Two runs per repeat, to t_end and to t_end / 10:

- per output, whole run: CPU of the run to t_end / its number of outputs (issue 24's
  figure: 20 s, 4001 outputs, 17.4 s CPU = 4.3 ms per output on 685442c);
- per output, marginal: (CPU to t_end - CPU to t_end / 10) / the difference in outputs,
  which leaves out what a run costs once (assembly, the first evaluation, the result).

Process CPU time (time.process_time), median of the repeats with the spread.  ``--quick``:
one repeat, t_end 2 s.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import ROOT, figure, figure_failed, run_with_deck  # noqa: E402

STEP = 0.005  # s, the deck's kinematic output step


def run(model, spec, t_end):
    """(CPU s, number of outputs, status) of one kinematic run to t_end (``spec``: the deck,
    as ``mbsim run`` runs it)."""
    c0 = time.process_time()
    res = run_with_deck(model, "kinematic", {"t_end": t_end, "step": STEP}, spec)
    cpu = time.process_time() - c0
    return cpu, len(res.t), res.status


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--t-end", type=float, default=20.0)
    ap.add_argument("--quick", action="store_true", help="one repeat, t_end 2 s")
    a = ap.parse_args(argv)
    if a.quick:
        a.repeats, a.t_end = 1, 2.0
    from mbsim.api import load_model

    spec, model = load_model(ROOT / "models" / "slider_crank.yaml")
    run(model, spec, 0.1)  # warm-up: the kernels' loading, first-call imports
    whole, marginal, n_long = [], [], 0
    for _ in range(max(1, a.repeats)):
        c_long, n_long, s_long = run(model, spec, a.t_end)
        c_short, n_short, s_short = run(model, spec, a.t_end / 10)
        if "complete" not in (s_long, s_short) or s_long != s_short:
            figure_failed(f"kinematic per output, slider-crank, {n_long} outputs",
                          f"run {s_long} / {s_short}")
            return 1
        whole.append(1e3 * c_long / n_long)
        marginal.append(1e3 * (c_long - c_short) / (n_long - n_short))
        print(f"    {n_long} outputs {c_long:.3f} s CPU; {n_short} outputs {c_short:.3f} s",
              flush=True)
    figure(f"kinematic per output, slider-crank, {n_long} outputs (whole run)", whole,
           "ms CPU")
    figure("kinematic per output, slider-crank (marginal)", marginal, "ms CPU")
    return 0


if __name__ == "__main__":
    sys.exit(main())
