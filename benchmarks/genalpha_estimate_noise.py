"""How far above its own round-off does genalpha/HHT's local error estimate sit on Andrews'
squeezing mechanism?

    python benchmarks/genalpha_estimate_noise.py [--integrator hht] [--rtol 1e-11] [--t-end 0.004]

Runs models/andrews.yaml with the family's error-controlled step and records, for every
accepted step, the estimate est = q1 - p(t1) (q1 minus the cubic Hermite extrapolation from
the last two accepted states) and the scale it was held to (GeneralizedAlpha._step_impl).
Prints, per body and per Euler-parameter or position coordinate that moves: the RMS of est,
its round-off sigma (the RMS of its third difference along the steps / sqrt(20): a smooth
local error cancels there, independent round-off of variance s^2 gives 20 s^2), the RMS of
est / scale (which coordinates decide the steps) and the mean |q|.  A coordinate whose est is
near sigma is measured as noise; est / scale near 1 decides the steps.  Windows start after
the first 0.3 ms (the start-up steps).  docs/benchmarks.md, "genalpha and HHT: tolerance
proportionality below rtol 1e-6", quotes it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from mbsim.analyses.dynamic import dynamic  # noqa: E402
from mbsim.api import load_model  # noqa: E402
from mbsim.integrators import INTEGRATORS  # noqa: E402

LABELS = ("x", "y", "z", "p0", "p1", "p2", "p3")


def recording(cls, rows):
    """A subclass of the family ``cls`` that appends (t, est (nq,), scale (nq,), q (nq,)) of
    every accepted step to ``rows`` (est: the accepted trial's q1 - p(t1))."""

    class Recording(cls):
        def _predict(self, t):
            self._last_prediction = super()._predict(t)
            return self._last_prediction

        def _step_impl(self):
            t0, q0 = self.t, self.q
            out = super()._step_impl()
            if self.t > t0:
                qmax = np.maximum(np.abs(self.q), np.abs(q0))
                rows.append((self.t, self.q - self._last_prediction,
                             self.atol_step + self.rtol_step * qmax, self.q.copy()))
            return out

    return Recording


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--integrator", default="hht", choices=("genalpha", "hht"))
    ap.add_argument("--rtol", type=float, default=1e-11)
    ap.add_argument("--t-end", type=float, default=0.004)
    ap.add_argument("--t-from", type=float, default=3e-4)
    a = ap.parse_args(argv)
    _, model = load_model(ROOT / "models" / "andrews.yaml")
    rows = []
    family = INTEGRATORS[a.integrator]
    INTEGRATORS[a.integrator] = recording(family, rows)
    try:
        res = dynamic(model, {"integrator": a.integrator, "rtol": a.rtol, "t_end": a.t_end,
                              "error_estimate": False, "max_steps": 10 ** 7})
    finally:
        INTEGRATORS[a.integrator] = family
    t = np.array([r[0] for r in rows])
    keep = t > a.t_from
    est, scale, q = (np.array([r[k] for r in rows])[keep] for k in (1, 2, 3))
    sigma = np.sqrt((np.diff(est, 3, axis=0) ** 2).mean(axis=0) / 20.0)
    rms = np.sqrt((est ** 2).mean(axis=0))
    ratio = np.sqrt(((est / scale) ** 2).mean(axis=0))
    print(f"{a.integrator} rtol {a.rtol:g} to {a.t_end:g} s: {res.status}, "
          f"{res.counters.get('steps', 0)} steps, {int(keep.sum())} after {a.t_from:g} s")
    print(f"{'body':>4s} {'coord':>5s} {'rms est':>9s} {'sigma':>9s} {'est/scale':>9s} "
          f"{'mean |q|':>9s}")
    for j in range(q.shape[1]):
        if rms[j] == 0.0 or np.abs(q[:, j]).max() < 1e-12:
            continue  # fixed or identically zero (a planar mechanism's z, p1, p2)
        b = model.body_names[j // 7]
        print(f"{b:>4s} {LABELS[j % 7]:>5s} {rms[j]:9.2g} {sigma[j]:9.2g} {ratio[j]:9.2f} "
              f"{np.abs(q[:, j]).mean():9.3g}")


if __name__ == "__main__":
    main()
