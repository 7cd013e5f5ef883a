"""The index-1 change-point switch (mbsim/integrators/changepoints.py, Policy.tangent): the
round-off of the two paths' accelerations, and the four cranks with the switch set by hand.

    python benchmarks/index1_switch.py                                   # the accelerations
    python benchmarks/index1_switch.py --switch 1e-4,2e-4,3e-4 --rtols 1e-9 [--integrators ..]

First table: on the four cranks (models/parallel_fourbar.yaml's mechanism) at crank angles
theta from the flat position, the accelerations of the Schur path (System.accelerations) and
of the tangent coordinates (changepoints.complete + accelerations, C taken --theta-ref rad
from the point) from q perturbed by 4 ulps, against the exact ones (the effective inertia is
constant: theta'' = -g cos(theta) (4 m_c L / 2 + M L) / I_eff), relative to max |qdd|, next to
the laws eps s^-2 and eps s^-3.  Second (with --switch): the four cranks' position error
(tests/integrators/test_singular_loops.run) with the index-1 switch replaced by each value
("law": the policy's own).  Set OPENBLAS_CORETYPE to compare BLAS kernels.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402

from mbsim.integrators import changepoints as cp  # noqa: E402
from tests.integrators import test_policy as TP  # noqa: E402
from tests.integrators import test_singular_loops as TS  # noqa: E402


def accelerations(theta_ref):
    print(f"C taken {theta_ref} rad from the point; errors relative to max |qdd|")
    print(f"{'theta rad':>10} {'s':>9} {'Schur':>9} {'eps s^-2':>9} {'tangent':>9} {'eps s^-3':>9}")
    for theta in np.logspace(-4, -1, 13):
        s, e_s, e_t = TP.four_cranks_accelerations(theta, theta_ref=theta_ref)
        print(f"{theta:10.2e} {s:9.2e} {e_s:9.2e} {cp.EPS / s**2:9.2e} {e_t:9.2e} "
              f"{cp.EPS / s**3:9.2e}")


def with_switch(switch, integrators, rtols):
    law = cp.Policy.for_run.__func__

    def for_run(cls, family, rtol, atol, fixed, tangent=True, **kw):
        p = law(cls, family, rtol, atol, fixed, tangent, **kw)
        if family == "index-1" and not fixed and p.tangent > 0.0 and switch is not None:
            p = dataclasses.replace(p, tangent=switch, branch_jump=cls.jump(switch, rtol))
        return p

    cp.Policy.for_run = classmethod(for_run)
    try:
        for name in integrators:
            for rtol in rtols:
                res, err = TS.run(name, rtol)
                print(f"{name:18s} {rtol:7.0e} {'law' if switch is None else f'{switch:.2g}':>7} "
                      f"{res.status:9s} {err:9.3g} {res.counters.get('tangent_stages', 0):7d}")
    finally:
        cp.Policy.for_run = classmethod(law)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--theta-ref", type=float, default=0.06)
    ap.add_argument("--switch", help="comma list of index-1 switches (s) or 'law'")
    ap.add_argument("--rtols", default="1e-9")
    ap.add_argument("--integrators", default="projection-dop853")
    a = ap.parse_args()
    if not a.switch:
        accelerations(a.theta_ref)
        return
    print(f"{'method':18s} {'rtol':>7} {'switch':>7} {'status':9s} {'error m':>9} {'tangent':>7}")
    for sw in a.switch.split(","):
        with_switch(None if sw == "law" else float(sw), a.integrators.split(","),
                    [float(r) for r in a.rtols.split(",")])


if __name__ == "__main__":
    main()
