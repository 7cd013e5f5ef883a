"""Writing and reading the results file of a spherical chain (issue 24, item 3).

Run: python benchmarks/write_results.py [--links 300,1024,4096] [--repeat 5]

The Result is what a two-step dynamic run of the chain (benchmarks/common.chain_spec)
records: 3 outputs of the 8 standard body channels of every body, the five monitors, the
multipliers (nt, m) and the bodies' shapes (mbsim.view.geometry.scene_arrays); it is
built by the run's own recorder from the initial state, so that large chains are measured
without their run (which is not what is timed here).  Printed per size: channels, arrays,
the median and spread (min-max) of wall and CPU seconds of ``write_result`` and of
``read_result`` over --repeat repeats, and the file size.  A write that fails prints its
error (the version-1 layout failed from about 1000 links).

Before/after: run the same script with ``PYTHONPATH`` set to an export of the older tree
(``git archive REV | tar -x -C /tmp/old``): the script uses whatever mbsim it imports.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from functools import partial
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import chain_spec  # noqa: E402

from mbsim.model import compile_model  # noqa: E402
from mbsim.output import read_result, write_result  # noqa: E402


def chain_result(n: int, nt: int = 3):
    """The Result of a short run of an n-link chain, recorded from its initial state."""
    from mbsim.analyses.common import Recorder
    from mbsim.view.geometry import scene_arrays

    spec = chain_spec(n)
    model = compile_model(spec)
    rec = Recorder(model)
    zero = np.zeros(model.nq)
    for k in range(nt):
        rec.add(0.005 * k, model.q0, zero, zero)
    res = rec.result("dynamic")
    for name in ("position_violation", "velocity_violation", "energy", "work_nonconservative",
                 "step_size"):
        res.add(f"monitors/{name}", np.zeros(nt), "", name)
    res.add("constraints/lam", np.zeros((nt, model.m)), "", "Lagrange multipliers")
    res.arrays.update(scene_arrays(spec))
    return res


def timed(fn, repeat):
    walls, cpus = [], []
    for _ in range(repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        fn()
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
    return walls, cpus


def spread(xs) -> str:
    return f"{np.median(xs):7.3f} ({min(xs):.3f}-{max(xs):.3f})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--links", default="300,1024,4096")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    print(f"{'links':>6} {'channels':>8} {'arrays':>6}  {'write wall s':>22} "
          f"{'write CPU s':>22}  {'read wall s':>22} {'read CPU s':>22} {'file MB':>8}")
    for n in (int(x) for x in args.links.split(",")):
        res = chain_result(n)
        with tempfile.TemporaryDirectory() as d:
            path = Path(d) / f"chain{n}.h5"
            try:
                ww, wc = timed(partial(write_result, res, path), args.repeat)
            except Exception as exc:  # noqa: BLE001 - the old layout's failure is a finding
                print(f"{n:>6} {len(res.channels):>8} {len(res.arrays):>6}  write failed: "
                      f"{' '.join(str(exc).split())[:150]}")
                continue
            rw, rc = timed(partial(read_result, path), args.repeat)
            back = read_result(path)
            assert list(back.channels) == list(res.channels)
            size = path.stat().st_size / 1e6
        print(f"{n:>6} {len(res.channels):>8} {len(res.arrays):>6}  {spread(ww):>22} "
              f"{spread(wc):>22}  {spread(rw):>22} {spread(rc):>22} {size:8.2f}", flush=True)


if __name__ == "__main__":
    main()
