"""Per-frame CPU of ``mbsim animate``: the 2D sketch (``--style sketch``, matplotlib, what
mbsim drew before issue 26) against the 3D shapes (``--style 3d``, mbsim/view/render.py).

    python benchmarks/animation.py [--frames 30] [--pixels 400] [--decks vehicle governor]

Each deck's dynamic run (its deck settings, no error estimate) is done once; each style then
writes a GIF of --frames frames at --pixels x --pixels (dpi 80, size pixels/80 in), and the
process CPU time of the whole animate_result call (drawing and GIF encoding) is divided by
the number of frames.  The printed ratio is sketch / 3d.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this checkout's mbsim


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--pixels", type=int, default=400)
    ap.add_argument("--decks", nargs="+", default=["vehicle", "governor"])
    args = ap.parse_args()

    from mbsim.animate import animate_result
    from mbsim.api import load_model, run_model
    from mbsim.output import read_result, write_result

    print(f"{'deck':<12} {'style':<7} {'frames':>6} {'CPU/frame ms':>13} {'wall/frame ms':>14}")
    with tempfile.TemporaryDirectory() as tmp:
        for deck in args.decks:
            spec, model = load_model(ROOT / "models" / f"{deck}.yaml")
            h5 = write_result(run_model(model, "dynamic", {"error_estimate": False}, deck=spec),
                              Path(tmp) / f"{deck}.h5")  # fmt: skip
            result = read_result(h5)
            every = max(1, len(result.t) // args.frames)
            per = {}
            for style in ("sketch", "3d"):
                c0, w0 = time.process_time(), time.perf_counter()
                _, n = animate_result(result, Path(tmp) / f"{deck}-{style}.gif", every=every,
                                      dpi=80, size=args.pixels / 80, style=style)  # fmt: skip
                cpu, wall = time.process_time() - c0, time.perf_counter() - w0
                per[style] = cpu / n
                print(f"{deck:<12} {style:<7} {n:>6} {1e3 * cpu / n:>13.1f} "
                      f"{1e3 * wall / n:>14.1f}")
            print(f"{deck:<12} sketch / 3d CPU per frame: {per['sketch'] / per['3d']:.1f}x")


if __name__ == "__main__":
    main()
