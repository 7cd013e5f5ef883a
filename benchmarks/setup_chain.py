"""CPU cost of a dynamic run's set-up on the spherical chain of benchmarks/common.py
(chain_spec: N links hanging from a spherical joint, DOF 3N): compiling the model, the
consistent initial state (assembly, rank and redundancy, initial velocities and
accelerations: mbsim.analyses.initial.initial_state), the dynamic path's row selection
(rank_and_redundant of Phi_q) and the equations-of-motion object (mbsim.fast.System).

    python benchmarks/setup_chain.py [--n 300 1024] [--repeat 3]

Prints per N the median over --repeat of the CPU seconds (time.process_time) of each part
and of their sum, with the spread of the sum, and the peak resident memory of the process.
"""

from __future__ import annotations

import argparse
import resource
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from common import chain_spec  # noqa: E402

from mbsim.analyses.common import rank_and_redundant  # noqa: E402
from mbsim.analyses.initial import initial_state  # noqa: E402
from mbsim.model import compile_model  # noqa: E402


def _jac(model, q):
    try:  # the dynamic path's Phi_q (sparse from DENSE_NQ coordinates on, where it exists)
        from mbsim.analyses.diagnosis import jacobian

        return jacobian(model, q, 0.0)
    except ImportError:
        pass
    try:
        from mbsim.analyses.dynamic import _jac as jac

        return jac(model, q, 0.0)
    except ImportError:  # pragma: no cover - older layouts
        from mbsim import equations

        return equations.phi_q(model, q, 0.0)


def setup(n):
    """{part: CPU seconds} of one set-up of the N-link chain."""
    from mbsim.fast import System

    out = {}
    t = time.process_time()
    model = compile_model(chain_spec(n))
    out["compile"] = time.process_time() - t
    t = time.process_time()
    q, qd, qdd, lam, info = initial_state(model, 0.0)
    out["initial_state"] = time.process_time() - t
    t = time.process_time()
    rank, red = rank_and_redundant(model, _jac(model, q))
    out["rank"] = time.process_time() - t
    t = time.process_time()
    System(model, info["active_rows"])
    out["System"] = time.process_time() - t
    assert red.size == 0 and rank == model.m
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, nargs="+", default=[300, 1024])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    setup(4)  # first use: compile the kernels, imports
    for n in args.n:
        runs = [setup(n) for _ in range(args.repeat)]
        parts = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
        sums = [sum(r.values()) for r in runs]
        text = ", ".join(f"{k} {v:.3f}" for k, v in parts.items())
        print(f"chain N = {n} (nq = {7 * (n + 1)}): set-up {statistics.median(sums):.3f} s CPU "
              f"(spread {min(sums):.3f}..{max(sums):.3f}, {args.repeat} runs; {text})")
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak resident memory of the process: {peak:.0f} MB")


if __name__ == "__main__":
    main()
