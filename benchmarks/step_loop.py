"""The step in C (mbsim/fast/step.c) against the Python step: CPU per simulated second and
the compiled share of default runs, both paths side by side in one run.

    python benchmarks/step_loop.py [--repeats 3] [--chain 64]

Cases: the governor and the free slider-crank as their decks run them (``dynamic(model,
{})``: the deck's outputs, the error estimate on, the default integrator projection-dop853)
and a spherical chain of 64 links (benchmarks/common.py, 1 s, outputs every 0.01 s, the
same defaults); then two bare integrations (one output, no estimate: what
benchmarks/peers.py times) at the issue's peer targets, the governor at rtol 1e-3 and the
4-link chain at rtol 1e-6 (2 s each; set-up included).  Paths: ``compiled_step: false``
(every stage, projection and output through Python) and true (the trial step and the
outputs of a step in one C call each).

Printed per case and path: the median CPU seconds (``time.process_time``) of the whole
analysis over the repeats with the spread (min-max), per simulated second; and the
compiled share: the fraction of a run's time spent inside the C library.  cProfile does
not see calls through ctypes, so every C entry point of the library is wrapped in a small
Python function for these runs (the CPU runs come first, unwrapped); under cProfile the
wrappers' own time (tottime) is the time inside C (a Python callback made from C, as for
driven rows or Python force elements, is a function of its own and is not counted), and
the share is their sum over the profile's total (``share``).  cProfile slows the Python
side more than C, so this share is a lower bound of the unprofiled one, printed beside it
(``run``: the time inside C over the run's time, timed with ``time.perf_counter`` around
each C call, medians of the repeats), with the share of the step loop alone (``loop``):
the time inside C during the driver's loop (``mbsim.analyses.dynamic._integrate``: steps
and outputs, both integrations of the run) over the loop's time, the recording of the
outputs (its ``record`` callback) taken out of both.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "benchmarks")]

from common import chain_model  # noqa: E402

from mbsim.analyses import trajectory as dyn  # noqa: E402
from mbsim.analyses.dynamic import dynamic  # noqa: E402
from mbsim.deck import load_deck  # noqa: E402
from mbsim.fast import _lib  # noqa: E402
from mbsim.model import compile_model  # noqa: E402

ENTRY_POINTS = ("mb_constraints", "mb_terms", "mb_gather_dense", "mb_jac_times",
                "mb_applied_forces", "mb_mass_blocks", "mb_accelerations", "mb_project",
                "mb_rk_trial", "mb_rk_dense", "mb_rk_steps")
WRAPPER_FILE = "<mbsim C library>"


CLOCK = {"on": False, "c": 0.0, "loop": 0.0, "all": 0.0}  # the timed shares (module doc)


def wrap_library():
    """Every C entry point of the loaded library replaced by a Python function that calls
    it (compiled from a pseudo file name, so the profile tells them apart) and, while
    CLOCK["on"], adds its time to CLOCK["c"].  Call before the models' Systems are built
    (they bind the functions then)."""
    lib = _lib.library()
    for name in ENTRY_POINTS:
        f = getattr(lib, name, None)
        if f is None or getattr(f, "_wrapped", False):
            continue
        ns = {"f": f, "clock": CLOCK, "now": time.perf_counter}
        src = (f"def {name}(*a):\n    t0 = now()\n    r = f(*a)\n    dt = now() - t0\n"
               f"    clock['all'] += dt\n    if clock['on']:\n        clock['c'] += dt\n"
               f"    return r\n")
        exec(compile(src, WRAPPER_FILE, "exec"), ns)
        w = ns[name]
        w._wrapped = True
        setattr(lib, name, w)
    integrate = dyn.integrate

    def timed_integrate(run, times, record, max_steps, record_many=None):
        def untimed(rec):
            """``rec`` (a recorder of outputs) with its time taken out of the loop's."""
            if rec is None:
                return None

            def timed_record(*a):
                CLOCK["on"] = False
                t0 = time.perf_counter()
                try:
                    return rec(*a)
                finally:
                    CLOCK["loop"] -= time.perf_counter() - t0
                    CLOCK["on"] = True

            return timed_record

        CLOCK["on"] = True
        t0 = time.perf_counter()
        try:
            return integrate(run, times, untimed(record), max_steps, untimed(record_many))
        finally:
            CLOCK["loop"] += time.perf_counter() - t0
            CLOCK["on"] = False

    dyn.integrate = timed_integrate


def timed_shares(model, opt):
    """(share of the run, share of the step loop) timed without the profiler."""
    CLOCK.update(c=0.0, loop=0.0, all=0.0)
    t0 = time.perf_counter()
    dynamic(model, opt)
    run = time.perf_counter() - t0
    return CLOCK["all"] / run, CLOCK["c"] / CLOCK["loop"]


def cases(n_chain):
    """(name, model, options) of the runs: the default runs, then the bare integrations
    (one output, no estimate) of the issue's peer targets."""
    gov = compile_model(load_deck(ROOT / "models" / "governor.yaml"))
    sc = compile_model(load_deck(ROOT / "models" / "slider_crank.yaml"))
    chain = chain_model(n_chain)
    chain_opt = {"t_end": 1.0, "step": 0.01, "q0": chain.q0.copy()}
    chain4 = chain_model(4)

    def bare(rtol, t_end=2.0, **o):
        return dict(o, t_end=t_end, step=t_end, rtol=rtol, atol=1e-2 * rtol,
                    error_estimate=False)

    return [("governor", gov, {}), ("slider-crank", sc, {}),
            (f"chain {n_chain}", chain, chain_opt),
            ("bare gov 1e-3", gov, bare(1e-3)),
            ("bare chain4 1e-6", chain4, bare(1e-6, q0=chain4.q0.copy()))]


def cpu_run(model, opt):
    t0 = time.process_time()
    res = dynamic(model, opt)
    cpu = time.process_time() - t0
    if not res.complete:
        raise SystemExit(f"run did not complete: {res.message}")
    span = float(res.t[-1] - res.t[0])
    return cpu, span, res


def compiled_share(model, opt):
    prof = cProfile.Profile()
    prof.enable()
    dynamic(model, opt)
    prof.disable()
    st = pstats.Stats(prof)
    inside = sum(v[2] for k, v in st.stats.items() if k[0] == WRAPPER_FILE)
    return inside / st.total_tt


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--chain", type=int, default=64)
    a = ap.parse_args(argv)
    runs = [(name, model, dict(opt, compiled_step=compiled))
            for name, model, opt in cases(a.chain) for compiled in (False, True)]
    cpu = {}
    for name, model, o in runs:  # CPU first, with the library as it is
        cpu_run(model, o)  # warm-up: the library, caches
        out = [cpu_run(model, o) for _ in range(a.repeats)]
        cpu[name, o["compiled_step"]] = ([c / span for c, span, _ in out], out[-1][2].counters)
    wrap_library()
    print(f"projection-dop853; default runs: deck outputs, error estimate on; CPU s per "
          f"simulated s: median of {a.repeats} (min-max); compiled share: under cProfile, "
          f"and timed (run, step loop)")
    print(f"{'case':<16} {'path':<7} {'CPU s/s':>9} {'spread':>20} {'share':>7} {'run':>7} "
          f"{'loop':>7} {'steps':>6} {'f evals':>8}")
    for name, model, o in runs:
        compiled = o["compiled_step"]
        per, c = cpu[name, compiled]
        share = compiled_share(model, o)
        timed = [timed_shares(model, o) for _ in range(a.repeats)]
        run = statistics.median(x[0] for x in timed)
        loop = statistics.median(x[1] for x in timed)
        print(f"{name:<16} {'C' if compiled else 'Python':<7} {statistics.median(per):9.4f} "
              f"{min(per):9.4f}-{max(per):<10.4f} {100 * share:6.1f}% {100 * run:6.1f}% "
              f"{100 * loop:6.1f}% {c.get('steps', 0):6d} {c.get('function_evaluations', 0):8d}")
        if compiled:
            ratio = statistics.median(cpu[name, False][0]) / statistics.median(per)
            print(f"{'':<16} Python / C = {ratio:.2f}")


if __name__ == "__main__":
    main()
