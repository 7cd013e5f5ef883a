"""Cost of recording outputs: Recorder.result (all channels vs ``outputs: only:``) and the
size of the written file, on the vehicle's lane change 1 (models/vehicle.yaml, scene lane1).

    python benchmarks/recorder.py [--repeat 5] [--old path/to/old_common.py]

The dynamic run is done once; its raw states (t, q, qd, qdd) are kept and fed to the
recorder again and again, so the timings are of the recording alone.  ``--old`` times another
version of mbsim/analyses/common.py (e.g. `git show REV:mbsim/analyses/common.py > old.py`)
on the same states.  Prints seconds per Recorder.result (best of --repeat) and file sizes.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import tempfile
import time
from pathlib import Path
from types import MappingProxyType

import numpy as np

import mbsim.analyses.common as common
import mbsim.analyses.dynamic as dynamic
import mbsim.analyses.trajectory as trajectory
from mbsim.api import load_model
from mbsim.measures import OutputMeasure
from mbsim.options import run_options
from mbsim.output import write_result

DECK = Path(__file__).resolve().parents[1] / "models" / "vehicle.yaml"
ONLY = ("bodies/chassis/r", "measures")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--old", help="another common.py to time on the same states")
    args = ap.parse_args()
    spec, model = load_model(DECK, scene="lane1")
    model = dataclasses.replace(model, measures=MappingProxyType({
        # what a lane-change scene needs: heading and roll
        "yaw": OutputMeasure("yaw", "body_angle", {"body": "chassis", "axis": np.eye(3)[2]}),
        "roll": OutputMeasure("roll", "body_angle", {"body": "chassis", "axis": np.eye(3)[0],
                                                     "ref": np.eye(3)[1]})}))
    kept = []

    class Keep(common.Recorder):
        def __init__(self, m):
            super().__init__(m)
            kept.append(self)

    trajectory.Recorder = Keep
    res = dynamic.dynamic(model, run_options("dynamic", spec, {}))
    rec = kept[-1]
    print(f"vehicle lane change 1: {len(rec)} outputs, {model.nb} bodies, "
          f"{len(model.forces)} force elements")

    def best(fn):
        times = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            out = fn()
            times.append(time.perf_counter() - t0)
        return min(times), out

    rows = [("all channels", None), ("only " + ", ".join(ONLY), ONLY)]
    if args.old:
        spec = importlib.util.spec_from_file_location("old_common", args.old)
        old = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(old)
        orec = old.Recorder(model)
        for k in range(len(rec)):
            orec.add(rec.t[k], rec.q[k], rec.qd[k], rec.qdd[k])
        dt, _ = best(lambda: orec.result("dynamic"))
        print(f"  {'old recorder (' + args.old + ')':45s} {dt:8.3f} s")
    for label, only in rows:
        dt, out = best(lambda only=only: rec.result("dynamic", only=only))
        for k in ("monitors", "constraints"):  # as run_model would keep them
            if only is None:
                out.channels.update({n: c for n, c in res.channels.items() if n.startswith(k)})
        with tempfile.TemporaryDirectory() as d:
            t0 = time.perf_counter()
            path = write_result(out, Path(d) / "v.h5")
            tw = time.perf_counter() - t0
            size = path.stat().st_size
        print(f"  {label:45s} {dt:8.3f} s  {len(out.channels):4d} channels  "
              f"write {tw:6.3f} s  file {size / 1e3:8.1f} kB")


if __name__ == "__main__":
    main()
