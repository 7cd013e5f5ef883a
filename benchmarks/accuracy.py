"""Does ``accuracy`` keep its word, and at what price?  (issue 11)

    python benchmarks/accuracy.py [--repeats 3] [--problems pendulum,heavy_top]
                                  [--integrators a,b] [--requests 1e-4,1e-6,1e-8]
                                  [--max-cpu 20] [--accuracy-integrator NAME]

The problems are the five of tests/integrators/models.py:reference_problem, each with an
independent reference (tests/integrators/references.py: scipy DOP853 at rtol 1e-13 or a
closed form, no mbsim dynamics): free_body, heavy_top (150 rad/s, 2 s), pendulum (150 deg,
3 s), slider_crank (free, 1 s), parallel_fourbar (four cranks, 5 singular passages in 1 s).

"error" is the true error that ``accuracy`` promises to bound: the maximum over output
times and bodies of the position error (m) and, for rotating bodies, the orientation error
(rotation angle, rad); the position error alone is printed beside it.

1. For each problem and request (1e-4, 1e-6, 1e-8): the ``accuracy`` run (its integrator,
   final rtol, number of runs, error estimate, true error, CPU including the estimate and
   any refinement).
2. A sweep of every integrator at rtol = 1e-3 ... 1e-12 (atol = rtol / 100; fixed-step
   methods at h = step / 2^k, k = 0 ... 9, printed as their h), without the error estimate:
   true error and CPU.  A method's ladder stops at its first failure or past --max-cpu s;
   a run still going after --timeout s (wall, default 60) is interrupted and is a failure.
3. Per problem and request: the cheapest (method, tolerance) of the sweep whose true error
   is <= the request, its CPU, and the CPU ratio accuracy / cheapest (issue 11 asks <= 3).
4. Per problem and method: achieved error / requested tolerance at each rtol (the "keeps
   its word" figure of ``mbsim bench``).

CPU: process CPU seconds (time.process_time), medians of --repeats runs.
"""

from __future__ import annotations

import argparse
import signal
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from mbsim.analyses.dynamic import dynamic  # noqa: E402
from mbsim.integrators import INTEGRATORS  # noqa: E402
from tests.integrators import models as M  # noqa: E402
from tests.integrators import references as R  # noqa: E402

RTOLS = tuple(10.0 ** -k for k in range(3, 13))
REQUESTS = (1e-4, 1e-6, 1e-8)


def true_error(pb, res):
    """(error, position error): error = max(position m, orientation rad if rotating)."""
    if len(res.t) < 2 or not res.complete:
        return np.inf, np.inf
    ref = pb.reference(res.t)
    pos = float(R.position_error(res, ref).max())
    ori = float(R.orientation_error(res, ref).max()) if pb.rotating else 0.0
    return max(pos, ori), pos


TIMEOUT = 60.0  # s wall per run (--timeout)


def _interrupt(signum, frame):
    # the dynamic analysis treats Ctrl-C as "stop, keep the data, mark incomplete"
    raise KeyboardInterrupt


def timed(pb, opts, repeats):
    """(Result, median CPU s) of ``repeats`` runs of the problem with these options; a run
    still going after TIMEOUT s (wall) is interrupted and counts as a failure."""
    cpus, res = [], None
    signal.signal(signal.SIGALRM, _interrupt)
    for _ in range(repeats):
        c0 = time.process_time()
        signal.setitimer(signal.ITIMER_REAL, TIMEOUT)
        try:
            res = dynamic(pb.model, dict({"t_end": pb.t_end, "step": pb.step, "q0": pb.q0,
                                          "qd0": pb.qd0}, **opts))
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
        cpus.append(time.process_time() - c0)
        if not res.complete:
            break
    return res, statistics.median(cpus)


def accuracy_runs(pb, requests, repeats, integrator=None):
    rows = []
    for tol in requests:
        opts = {"accuracy": tol}
        if integrator:
            opts["integrator"] = integrator
        res, cpu = timed(pb, opts, repeats)
        err, pos = true_error(pb, res)
        acc = res.summary.get("accuracy", {})
        est = res.summary.get("error_estimate", {})
        e = max(est.get("position") or 0.0, (est.get("orientation") or 0.0) if pb.rotating
                else 0.0)
        rows.append({"request": tol, "integrator": acc.get("integrator", "?"),
                     "rtol": acc.get("rtol", np.nan), "h": acc.get("h"),
                     "runs": acc.get("runs", 0), "error": err, "position": pos,
                     "estimate": e, "cpu": cpu, "status": res.status})
    return rows


def sweep(pb, names, repeats, max_cpu):
    """{name: [(tolerance, h or None, error, position error, cpu)]} without error estimate."""
    out = {}
    for name in names:
        cls = INTEGRATORS[name]
        ladder = ([(r, None) for r in RTOLS] if cls.adaptive
                  else [(None, pb.step / 2**k) for k in range(10)])
        out[name] = []
        for rtol, h in ladder:
            opts = {"integrator": name, "error_estimate": False}
            if rtol is not None:
                opts.update(rtol=rtol, atol=rtol * 1e-2)
            else:
                opts["h"] = h
            res, cpu = timed(pb, opts, repeats)
            err, pos = true_error(pb, res)
            out[name].append((rtol, h, err, pos, cpu))
            print(f"  {pb.name:17s} {name:18s} "
                  f"{'rtol %.0e' % rtol if rtol else 'h %.3g' % h:11s} error {err:9.3g} "
                  f"cpu {cpu:7.3f} s {'' if res.complete else res.message[:60]}",
                  file=sys.stderr, flush=True)
            if not res.complete or cpu > max_cpu:
                break
    return out


def cheapest(sw, tol):
    best = None
    for name, ladder in sw.items():
        for rtol, h, err, _, cpu in ladder:
            if err <= tol and (best is None or cpu < best[-1]):
                best = (name, rtol, h, err, cpu)
    return best


def fmt_tol(rtol, h):
    return f"h {h:.3g}" if h else f"rtol {rtol:.2g}"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--problems", default=",".join(M.REFERENCE_PROBLEMS))
    ap.add_argument("--integrators", default=",".join(INTEGRATORS))
    ap.add_argument("--requests", default=",".join(f"{r:g}" for r in REQUESTS))
    ap.add_argument("--max-cpu", type=float, default=20.0,
                    help="stop a method's ladder after a run over this CPU (s)")
    ap.add_argument("--timeout", type=float, default=TIMEOUT,
                    help="interrupt a run after this wall time (s); it counts as failed")
    ap.add_argument("--accuracy-integrator", default=None,
                    help="the integrator of the accuracy runs (default: mbsim's default)")
    a = ap.parse_args(argv)
    globals()["TIMEOUT"] = a.timeout
    names = [n for n in a.integrators.split(",") if n]
    requests = [float(r) for r in a.requests.split(",")]
    table, ratios = [], {}
    for prob in a.problems.split(","):
        pb = M.reference_problem(prob)
        pb.reference(np.linspace(0.0, pb.t_end, 2))  # sympy set-up outside the timings
        acc = accuracy_runs(pb, requests, a.repeats, a.accuracy_integrator)
        sw = sweep(pb, names, a.repeats, a.max_cpu)
        for row in acc:
            table.append((prob, row, cheapest(sw, row["request"])))
        ratios[prob] = sw

    print("\naccuracy runs against the cheapest (method, tolerance) of the sweep reaching the "
          "request (error = max(position m, orientation rad); CPU s, median of "
          f"{a.repeats})")
    hdr = (f"{'problem':17s} {'request':>8s} {'accuracy run':>30s} {'runs':>4s} {'error':>9s} "
           f"{'position':>9s} {'estimate':>9s} {'est/err':>7s} {'CPU':>7s} | "
           f"{'cheapest pair':>30s} {'CPU':>7s} {'ratio':>6s}")
    print(hdr)
    print("-" * len(hdr))
    for prob, row, best in table:
        run = f"{row['integrator']} {fmt_tol(row['rtol'], row['h'])}"
        ok = "" if row["error"] <= 3 * row["request"] else " !>3x"
        b = f"{best[0]} {fmt_tol(best[1], best[2])}" if best else "none reaches it"
        bc = f"{best[4]:7.3f}" if best else f"{'-':>7s}"
        ratio = f"{row['cpu'] / best[4]:6.2f}" if best else f"{'-':>6s}"
        print(f"{prob:17s} {row['request']:8.0e} {run:>30s} {row['runs']:4d} "
              f"{row['error']:9.2e} {row['position']:9.2e} {row['estimate']:9.2e} "
              f"{row['estimate'] / row['error'] if row['error'] > 0 else np.nan:7.2f} "
              f"{row['cpu']:7.3f} | {b:>30s} {bc} {ratio}{ok}")

    print("\nachieved error / requested tolerance (true error / rtol; fixed-step methods: "
          "error at h = step / 2^k, not a ratio)")
    for prob, sw in ratios.items():
        print(f"\n{prob}")
        print(f"{'method':18s} " + " ".join(f"{r:8.0e}" for r in RTOLS))
        for name, ladder in sw.items():
            if ladder and ladder[0][0] is None:
                cells = [f"{err:8.1e}" for _, _, err, _, _ in ladder]
                print(f"{name:18s} " + " ".join(cells) + "   (error at h = step/2^k)")
                continue
            got = {rtol: err for rtol, _, err, _, _ in ladder}
            cells = [(f"{got[r] / r:8.2g}" if np.isfinite(got[r]) else "    fail")
                     if r in got else "       -" for r in RTOLS]
            print(f"{name:18s} " + " ".join(cells))


if __name__ == "__main__":
    main()
