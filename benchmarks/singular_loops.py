"""The four parallel cranks through their singular positions, every integrator (issue 11).

    python benchmarks/singular_loops.py [--integrators a,b] [--rtols 1e-6,1e-8,1e-10] [--cranks N]
                                        [--perturb N] [--passages [--t-end T]]

One run per (method, rtol) of tests/integrators/test_singular_loops.py's problem (atol =
rtol/100; fixed-step methods at the step that test uses for that rtol), against its exact
one-DOF reduction: status, true position error, the issue's bound 10 rtol + 1e-9 m, the
error estimate and estimate / true error, CPU s (whole analysis with its estimate) and its
ratio to the method's first rtol (issue 11's budget: at most 10x from rtol 1e-6 to 1e-10;
the unit tests assert no timings).  --cranks N: N parallel cranks (N - 1 loops, 4 (N - 2)
+ 3 redundant rows; 41 is the 40-loop linkage) instead of four.  A run still going after
300 s wall is interrupted (a failure).  --perturb N: each setting also runs N more times from
the start perturbed by ROUNDOFF_ULPS ulps (random signs, seeds 1..N): the spread of their
errors is the passages' round-off floor on this machine.

--passages (issue 24's diagnosis; e.g. ``--cranks 41 --passages --t-end 20 --integrators
projection-dop853 --rtols 1e-6,1e-7,1e-8``): one run per (method, rtol) to T (default 20 s)
with outputs every 2.5 ms and no estimate, and where its error arises: the crank angle's
error against the exact reduction at the end (and L x that, the coupler's position error),
the energy monitor's change across each flat passage (outputs 2 before to 2 after the
crossing of theta = k pi) and between passages, in units of the initial kinetic energy
(median |jump|, largest, and the sums, whose total is the drift that turns into a phase
error), and where the CPU goes: steps, evaluations, factorizations, tangent stages, CPU s.  With
--perturb N the runs from the perturbed starts follow: the spread of their errors is what the
passages' round-off alone leaves.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import dataclasses  # noqa: E402
import functools  # noqa: E402

import numpy as np  # noqa: E402

from mbsim.integrators import INTEGRATORS  # noqa: E402
from mbsim.integrators.base import ROUNDOFF_ULPS  # noqa: E402
from tests.integrators import models as M  # noqa: E402
from tests.integrators.test_singular_loops import run  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--integrators", default=",".join(INTEGRATORS))
    ap.add_argument("--rtols", default="1e-6,1e-8,1e-10")
    ap.add_argument("--cranks", type=int, default=4)
    ap.add_argument("--perturb", type=int, default=0)
    ap.add_argument("--passages", action="store_true", help="error and cost per flat passage")
    ap.add_argument("--t-end", type=float, default=20.0, help="--passages: run length, s")
    a = ap.parse_args(argv)
    pb = M.reference_problem("parallel_fourbar")
    if a.cranks != 4:
        model = M.parallel_fourbar(a.cranks)
        q, qd = M.parallel_fourbar_state(model, 20.0)
        pb = dataclasses.replace(pb, model=model, q0=q, qd0=qd, reference=functools.partial(
            M.parallel_fourbar_reference, thetad0=20.0, N=a.cranks))
    rtols = [float(r) for r in a.rtols.split(",")]
    if a.passages:
        for name in a.integrators.split(","):
            for r, seed in ((r, s) for r in rtols for s in range(a.perturb + 1)):
                passages(perturbed(pb, seed), a.cranks, name, r, a.t_end, seed)
        return
    print(f"{'method':18s} {'rtol':>7s} {'status':10s} {'error m':>9s} {'bound':>8s} "
          f"{'estimate':>9s} {'est/err':>7s} {'CPU s':>7s} {'x first':>7s}")
    for name in a.integrators.split(","):
        first = None
        for r, seed in ((r, s) for r in rtols for s in range(a.perturb + 1)):
            p = perturbed(pb, seed)
            c0 = time.process_time()
            res, err = run(name, r, p)
            cpu = time.process_time() - c0
            est = res.summary.get("error_estimate", {}).get("position")
            est = float("nan") if est is None else est  # no estimate (run interrupted)
            first = first or cpu
            print(f"{name:18s} {r:7.0e}{f' #{seed}' if seed else ''} {res.status:10s} "
                  f"{err:9.3g} {10 * r + 1e-9:8.2g} "
                  f"{est:9.3g} {est / err if err else float('nan'):7.3g} {cpu:7.2f} "
                  f"{cpu / first:7.2f}{'' if res.complete else '  ' + res.message[:90]}",
                  flush=True)


def perturbed(pb, seed):
    """pb with q0 moved by ROUNDOFF_ULPS ulps, random signs (seed 0: pb itself)."""
    if not seed:
        return pb
    signs = np.random.default_rng(seed).choice([-1.0, 1.0], pb.q0.size)
    return dataclasses.replace(pb, q0=pb.q0 + ROUNDOFF_ULPS * np.finfo(float).eps * signs
                               * np.maximum(1.0, np.abs(pb.q0)))


def passages(pb, n, name, rtol, t_end, seed=0):
    """One run to t_end: error at the end, energy change across / between passages, cost."""
    from mbsim.analyses.dynamic import dynamic

    opts = {"t_end": t_end, "step": 2.5e-3, "q0": pb.q0, "qd0": pb.qd0, "integrator": name,
            "rtol": rtol, "atol": 1e-2 * rtol, "error_estimate": False}
    if not INTEGRATORS[name].adaptive:
        opts["h"] = 1e-3
    c0 = time.process_time()
    res = dynamic(pb.model, opts)
    cpu = time.process_time() - c0
    ref = pb.reference(res.t)
    L = M.FOURBAR["L"]
    xbar = (n - 1) * M.FOURBAR["spacing"] / 2
    r = res.channel("bodies/coupler/r").data
    th = np.unwrap(np.arctan2(r[:, 1], r[:, 0] - xbar))
    dth = th - np.unwrap(ref["theta"])
    energy = res.channel("monitors/energy").data.reshape(-1)
    scale = 0.5 * _inertia(n) * ref["thetad"][0] ** 2  # J, the initial kinetic energy
    cross = np.nonzero(np.diff(np.floor(th / np.pi)))[0]
    lo, hi = np.maximum(cross - 2, 0), np.minimum(cross + 3, len(energy) - 1)
    across = (energy[hi] - energy[lo]) / scale
    between = (energy[lo[1:]] - energy[hi[:-1]]) / scale
    c = res.counters
    tag = f" #{seed}" if seed else ""
    print(f"{name} rtol {rtol:.0e}{tag}: {res.status}, {t_end:g} s, {cross.size} passages; "
          f"theta error {abs(dth[-1]):.2e} rad (x L = {L * abs(dth[-1]):.2e} m); energy / T0: "
          f"drift {(energy[-1] - energy[0]) / scale:+.1e}, across each passage median "
          f"{np.median(np.abs(across)):.1e} largest {np.abs(across).max():.1e} sum "
          f"{across.sum():+.1e}, between passages median {np.median(np.abs(between)):.1e} "
          f"sum {between.sum():+.1e}; CPU {cpu:.2f} s: {c['steps']} steps "
          f"({c.get('rejected_steps', 0)} rejected), {c['function_evaluations']} evaluations, "
          f"{c['factorizations']} factorizations, {c.get('tangent_stages', 0)} tangent stages",
          flush=True)
    worst = np.argsort(np.abs(across))[::-1][:3]
    print("    largest passages: " + "; ".join(
        f"t {res.t[cross[k]]:.3f} s: energy {across[k]:+.1e}, theta error {dth[lo[k]]:+.2e} -> "
        f"{dth[hi[k]]:+.2e} rad" for k in worst), flush=True)


def _inertia(n):
    """N I_pivot + M L^2 of the reduction (tests/integrators/references.parallel_fourbar)."""
    P = M.FOURBAR
    L, mc = P["L"], P["m_crank"]
    return n * (M.fourbar_crank_inertia(L, mc)[2] + mc * L * L / 4) + P["M"] * L * L


if __name__ == "__main__":
    main()
