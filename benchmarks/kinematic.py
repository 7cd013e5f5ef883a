"""CPU cost per output of a kinematic analysis: the slider-crank (models/slider_crank.yaml,
driven crank, DOF 0) from 0 to 20 s every 5 ms (4001 outputs), in process (the analysis
alone: deck loading and writing excluded; `mbsim run ... --mode kinematic` adds them).

    python benchmarks/kinematic.py [--repeat 3] [--t-end 20] [--deck models/slider_crank.yaml]

Prints the median over --repeat runs of the CPU seconds per output (time.process_time), the
spread (min..max), and the Newton iterations per output.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this checkout's mbsim

from mbsim.analyses.kinematic import kinematic  # noqa: E402
from mbsim.api import load_model  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--t-end", type=float, default=20.0)
    ap.add_argument("--step", type=float, default=0.005)
    ap.add_argument("--deck", default=str(ROOT / "models" / "slider_crank.yaml"))
    args = ap.parse_args()
    _, model = load_model(args.deck)
    kinematic(model, {"t_end": 0.05, "step": args.step})  # first use: compile, caches
    per_output, res = [], None
    for _ in range(args.repeat):
        t0 = time.process_time()
        res = kinematic(model, {"t_end": args.t_end, "step": args.step})
        per_output.append((time.process_time() - t0) / len(res.t))
    assert res.status == "complete", res.message
    med = statistics.median(per_output)
    print(f"{Path(args.deck).name}: kinematic, {len(res.t)} outputs, "
          f"{res.counters['newton_iterations'] / len(res.t):.2f} Newton iterations per output")
    print(f"CPU per output: median {1e3 * med:.3f} ms (spread {1e3 * min(per_output):.3f}.."
          f"{1e3 * max(per_output):.3f} ms, {args.repeat} runs)")


if __name__ == "__main__":
    main()
