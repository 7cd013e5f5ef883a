"""Spherical chains: CPU per integration step against the number of links, and its growth
exponent from 64 to 1024 links (issue 24: at most N^1.05).

    python benchmarks/chain_scaling.py [--sizes 64,256,1024] [--repeats 3] [--quick]

The chain of common.chain_deck (links of 1 kg, 0.5 m, hanging from spherical joints, at
rest), loaded as a deck (mbsim.api.load_model) and run in process with the default
integrator at rtol 1e-6, atol 1e-8, the error estimate off, one output.  Per size and
repeat two runs, to T1 = 0.1 s and T2 = 5 s; the cost per step is

    (median CPU to T2 - median CPU to T1) / (steps to T2 - steps to T1),

which leaves out what a run costs once (the initial state, set-up, the result); its spread
is that of the same difference within each repeat.  Where the
version measured takes the internal settings q0/qd0 the runs start from the deck's
positions at rest without the initial-condition analysis (the same state: the deck's chain
is assembled and at rest), which only saves time.

Figures: CPU per step at each size (ms), the exponent p of cost ~ N^p from the smallest to
the largest size and the least-squares slope over all sizes (from the medians: printed as
one value, the spread of the per-step costs says how far to trust it).
``--quick``: sizes 16 and 64, one repeat.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402
from common import chain_deck, figure, figure_failed  # noqa: E402

T1, T2 = 0.1, 5.0
"""s: the two run lengths.  T2 long enough that the steps between them cost well over the
noise of what a run costs once (on aeac177 at 1024 links about 25 CPU s a run, +-1.5 s,
against 185 steps a simulated second of about 10-20 ms each); --quick: T2 = 1 s."""
OPTIONS = {"rtol": 1e-6, "atol": 1e-8, "error_estimate": False}


def per_step_cost(c1, c2, s1, s2):
    """(ms per step from the medians, [ms per step of each repeat]) of the CPU lists c1, c2
    of the runs to T1 and T2, which took s1 and s2 steps."""
    each = [1e3 * (b - a) / (s2 - s1) for a, b in zip(c1, c2)]
    return 1e3 * (float(np.median(c2)) - float(np.median(c1))) / (s2 - s1), each


def run(model, t_end, start):
    """(CPU s, accepted steps) of one run to t_end; start: the q0/qd0 settings or {}."""
    from mbsim.api import run_model

    c0 = time.process_time()
    res = run_model(model, "dynamic", dict(OPTIONS, t_end=t_end, step=t_end, **start))
    cpu = time.process_time() - c0
    if not res.complete:
        raise RuntimeError(f"run to {t_end} s: {res.status}: {res.message}")
    return cpu, int(res.counters["steps"])


def start_state(model):
    """The q0/qd0 settings (the deck's positions, at rest) where this version takes them."""
    from mbsim.api import run_model

    q0 = getattr(model, "q0", None)
    if q0 is None:
        return {}
    start = {"q0": np.array(q0, float), "qd0": np.zeros(len(q0))}
    try:
        run_model(model, "dynamic", dict(OPTIONS, t_end=1e-3, step=1e-3, **start))
    except Exception as exc:  # noqa: BLE001 - any refusal: fall back to the deck's analysis
        print(f"    q0/qd0 not taken ({type(exc).__name__}: {exc}); runs start from the "
              "initial-condition analysis", flush=True)
        return {}
    return start


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="64,256,1024")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="sizes 16, 64; one repeat")
    a = ap.parse_args(argv)
    sizes = [int(s) for s in a.sizes.split(",")]
    t2 = T2
    if a.quick:
        sizes, a.repeats, t2 = [16, 64], 1, 1.0
    from mbsim.api import load_model

    per_step, spread_of = {}, {}  # N -> ms per step; N -> (lo, hi) over the repeats
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            deck = Path(tmp) / f"chain{n}.yaml"
            deck.write_text(chain_deck(n, t2))
            try:
                c0 = time.process_time()
                _, model = load_model(deck)
                load_cpu = time.process_time() - c0
                start = start_state(model)
                c1, c2 = [], []
                for _ in range(max(1, a.repeats)):
                    cpu1, s1 = run(model, T1, start)
                    cpu2, s2 = run(model, t2, start)
                    c1.append(cpu1)
                    c2.append(cpu2)
                    print(f"    N = {n}: load {load_cpu:.2f} s; to {T1} s {cpu1:.3f} s CPU "
                          f"{s1} steps; to {t2} s {cpu2:.3f} s CPU {s2} steps", flush=True)
            except Exception as exc:  # noqa: BLE001 - a size that fails is a figure that says so
                figure_failed(f"chain N = {n}: CPU per step", f"{type(exc).__name__}: {exc}")
                continue
            cost, each = per_step_cost(c1, c2, s1, s2)
            if cost <= 0:
                figure_failed(f"chain N = {n}: CPU per step", f"the runs' noise exceeds the "
                              f"steps' cost ({c1} s to {T1} s, {c2} s to {t2} s)")
                continue
            per_step[n], spread_of[n] = cost, (min(each), max(each))
            figure(f"chain N = {n}: CPU per step", each, "ms", (cost, min(each), max(each)))
    done = [n for n in sizes if n in per_step]
    if len(done) < 2:
        figure_failed(f"chain cost per step growth exponent, N = {sizes[0]} to {sizes[-1]}",
                      "fewer than two sizes measured")
        return 1
    lo, hi = done[0], done[-1]
    span = math.log(hi / lo)
    p = math.log(per_step[hi] / per_step[lo]) / span
    # the widest range the repeats allow: the cheapest large against the dearest small, and
    # the reverse (where a repeat's difference is not positive the range is left open)
    (a_lo, a_hi), (b_lo, b_hi) = spread_of[lo], spread_of[hi]
    p_lo = math.log(b_lo / a_hi) / span if b_lo > 0 and a_hi > 0 else -math.inf
    p_hi = math.log(b_hi / a_lo) / span if b_hi > 0 and a_lo > 0 else math.inf
    figure(f"chain cost per step growth exponent, N = {lo} to {hi}", [p] * a.repeats,
           "power of N", (p, p_lo, p_hi))
    if len(done) > 2:
        slope = float(np.polyfit(np.log(done), np.log([per_step[n] for n in done]), 1)[0])
        figure(f"chain cost per step growth exponent, least squares over N = "
               f"{', '.join(map(str, done))}", [slope], "power of N")
    return 0


if __name__ == "__main__":
    sys.exit(main())
