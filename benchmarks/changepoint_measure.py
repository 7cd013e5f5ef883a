"""The change-point measure s against the singular values of the active constraints.

    python benchmarks/changepoint_measure.py [--cranks 41] [--thetas 0.1,1e-2,3e-3,1e-3,3e-4]

For tests/integrators/models.py's parallel four-bar with N cranks at angles theta (rad) from
the flat position: s = sqrt(smallest Schur pivot / its diagonal) as the index-1 family reads
it (System.accelerations, then System.pivot_ratio; changepoints.measure_from_schur), with the
held bodies left out of S where mbsim/fast/dynamics.py's schur_structure does so and without
(HELD_GAIN = inf), against the two smallest and the largest singular values of
W = Phi_q[act] Mt^-1/2 (S = W W^T).  The active rows are those a run chooses at its start
(theta0 = -pi/2; the assembly's active_rows), or with --rows qr those of scipy's QR with
column pivoting of Phi_q^T, whose choice among rows of equal norm is not reproducible
(another process picked a row set whose sigma_min goes as theta^2).  One line per theta.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402
import scipy.linalg as la  # noqa: E402

from mbsim import fast  # noqa: E402
from mbsim.analyses.assembly import assemble  # noqa: E402
from mbsim.fast import dynamics  # noqa: E402
from mbsim.integrators import changepoints as cp  # noqa: E402
from tests.integrators import models as M  # noqa: E402
from tests.reference import equations as eq  # noqa: E402
from tests.test_kernels import _independent_rows, _modified_mass  # noqa: E402


def measure(n_cranks, theta, rows, held_gain):
    """s at crank angle theta with HELD_GAIN = held_gain (a fresh model: the Schur structure
    is cached per model); also returns (model, q)."""
    saved = dynamics.HELD_GAIN
    dynamics.HELD_GAIN = held_gain
    try:
        model = M.parallel_fourbar(n_cranks, theta0=theta)
        q, qd = M.parallel_fourbar_state(model, 20.0)
        system = fast.System(model, rows)
        system.accelerations(q, qd, 0.0)
        cut = bool(np.any(system.inc[:, 1] >= dynamics.CROSS))
        return cp.measure_from_schur(system.pivot_ratio), cut, model, q
    finally:
        dynamics.HELD_GAIN = saved


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cranks", type=int, default=41)
    ap.add_argument("--thetas", default="0.1,1e-2,3e-3,1e-3,3e-4")
    ap.add_argument("--rows", choices=("run", "qr"), default="run",
                    help="active rows: a run's (the assembly's) or scipy's QR with column "
                         "pivoting (tests/test_kernels.py; its ties among equal column norms "
                         "are broken differently from one process to another)")
    a = ap.parse_args(argv)
    start = M.parallel_fourbar(a.cranks)
    if a.rows == "run":
        rows = assemble(start, M.parallel_fourbar_state(start, 20.0)[0]).active_rows
    else:
        rows = _independent_rows(start, M.parallel_fourbar_state(start, 20.0)[0])
    print(f"{a.cranks} cranks, {rows.size} active rows; s with the held bodies cut / "
          f"without; singular values of W = Phi_q[act] Mt^-1/2")
    print(f"{'theta':>8} {'s cut':>10} {'s no cut':>10} {'sigma_1':>10} {'sigma_2':>10} "
          f"{'sigma_max':>10}")
    for theta in (float(x) for x in a.thetas.split(",")):
        s_cut, cut, model, q = measure(a.cranks, theta, rows, dynamics.HELD_GAIN)
        s_plain, _, _, _ = measure(a.cranks, theta, rows, np.inf)
        J = eq.constraints(model, q, 0.0).jac[rows]
        Li = la.inv(la.cholesky(_modified_mass(model, q), lower=True))  # Mt^-1 = Li^T Li
        sv = la.svdvals(J @ Li.T)
        print(f"{theta:8.2g} {s_cut:10.3g} {s_plain:10.3g} {sv[-1]:10.3g} {sv[-2]:10.3g} "
              f"{sv[0]:10.3g}" + ("" if cut else "  (no cut taken)"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
