"""Compiled fast path (mbsim.fast) against the numpy path, per call, and its compile times.

Run: python benchmarks/kernels.py [--repeat 15] [--no-compile]

For the governor (models/governor.yaml, with its TSDA) and the spatial chains of issue #3
(benchmarks/eval_constraints.py:chain_yaml, N = 4, 16, 64, 256) it prints the median over
repeats of the mean time per call (each repeat times a batch of calls) of

- Phi + Phi_q: ``equations.constraints(model, q, t)`` vs ``FastConstraints.constraints``;
- Phi + Phi_q + gamma (+ nu): the same with qd;
- accelerations: ``integrators.system.System.accelerations`` (the numpy path the
  integrators use: Schur complement, Cholesky or sparse LU) vs
  ``FastDynamics.accelerations``;

both sides return fresh arrays; the Jacobian is CSR from nq >= 700 on both sides, as in
System.  The fast path's minimum over the batches is printed too: on a shared machine it is
the figure without the other processes' interference.

Then the one-off cost of the compiled code in a fresh process: cold (empty numba cache:
compiling every kernel) and warm (loading them from the cache), each the time from
``import mbsim.fast`` to the first results of all entry points.  The machine's load average
is printed with the figures: they are wall-clock times.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from eval_constraints import chain_yaml  # noqa: E402

from mbsim import equations as eq  # noqa: E402
from mbsim import fast  # noqa: E402
from mbsim.deck import load_deck, load_deck_text  # noqa: E402
from mbsim.integrators.system import System  # noqa: E402
from mbsim.model import compile_model  # noqa: E402

FIRST_USE = """
import time
import numpy as np
from mbsim.deck import load_deck
from mbsim.model import compile_model
models = [compile_model(load_deck("models/" + name + ".yaml")) for name in ("governor", "four_bar")]
t0 = time.perf_counter()
from mbsim import fast  # numba's import counts too
for model in models:  # governor: the Schur path; four-bar (singular J'): the KKT path
    q, qd = model.q0, np.full(model.nq, 0.1)
    fd = fast.FastDynamics(model)
    fd.accelerations(q, qd, 0.0)
    fd.terms(q, 0.0, qd=qd, gamma=True, nu=True)
    fd.violations(q, qd, 0.0)
    fd.mass_matrix(q)
    fd.project_velocities(fd.project_positions(q, 0.0)[0], qd, 0.0)
    fast.FastConstraints(model, sparse=True).constraints(q, 0.0)
print(time.perf_counter() - t0)
"""


def first_use_seconds(cache_dir: str) -> float:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir)
    out = subprocess.run(
        [sys.executable, "-c", FIRST_USE],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    return float(out.stdout.strip().splitlines()[-1])


def timeit(fn, repeat: int, number: int) -> tuple[float, float]:
    """(median, min) over ``repeat`` batches of the mean time per call in a batch."""
    fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        times.append((time.perf_counter() - t0) / number)
    return statistics.median(times), min(times)


def bench(name: str, model, repeat: int) -> None:
    rng = np.random.default_rng(1)
    q = model.q0.copy()
    qd = rng.normal(size=model.nq) * 0.1
    t = 0.1
    sparse = model.nq >= fast.SPARSE_NQ
    fc = fast.FastConstraints(model)
    sy, fd = System(model), fast.FastDynamics(model)
    number = max(5, int(2000 / model.nb))
    rows = [
        (
            "Phi+Phi_q",
            lambda: eq.constraints(model, q, t, sparse=sparse),
            lambda: fc.constraints(q, t),
        ),
        (
            "Phi+Phi_q+gamma",
            lambda: eq.constraints(model, q, t, qd=qd, gamma=True, nu=True, sparse=sparse),
            lambda: fc.constraints(q, t, qd=qd, gamma=True, nu=True),
        ),
        ("accelerations", lambda: sy.accelerations(q, qd, t), lambda: fd.accelerations(q, qd, t)),
    ]
    for what, slow, quick in rows:
        t_np, _ = timeit(slow, repeat, max(3, number // 10))
        t_fast, t_min = timeit(quick, repeat, 10 * number)
        print(
            f"{name:<14} {model.nb:>4} {model.m:>5} {what:<16} {t_np * 1e6:10.1f} "
            f"{t_fast * 1e6:10.2f} {t_min * 1e6:10.2f} {t_np / t_fast:8.0f}x"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeat", type=int, default=15)
    ap.add_argument("--no-compile", action="store_true", help="skip the compile timings")
    args = ap.parse_args()
    if not fast.AVAILABLE:
        sys.exit("numba is not installed: nothing to compare (pip install numba)")
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    print(f"load average {load} on {os.cpu_count()} CPUs; median (and min) time per call, us")
    print(
        f"{'model':<14} {'nb':>4} {'m':>5} {'quantity':<16} {'numpy us':>10} "
        f"{'fast us':>10} {'fast min':>10} {'ratio':>9}"
    )
    bench("governor", compile_model(load_deck(ROOT / "models" / "governor.yaml")), args.repeat)
    for n in (4, 16, 64, 256):
        bench(
            f"chain N={n}", compile_model(load_deck_text(chain_yaml(n), f"chain{n}")), args.repeat
        )
    if not args.no_compile:
        with tempfile.TemporaryDirectory() as cache:
            cold = first_use_seconds(cache)
            warm = first_use_seconds(cache)
        print(
            f"first use in a fresh process (all entry points, governor + four-bar): "
            f"cold (no cache, compiling) {cold:.1f} s, warm (numba cache) {warm:.2f} s"
        )


if __name__ == "__main__":
    main()
