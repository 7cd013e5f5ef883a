"""The C kernels (mbsim.fast) against the numpy reference, per call, and the one-off compile.

Run: python benchmarks/kernels.py [--repeat 15] [--no-compile]

For the governor (models/governor.yaml, with its TSDA) and the spatial chains of issue #3
(benchmarks/eval_constraints.py:chain_yaml, N = 4, 16, 64, 256) it prints the median over
repeats of the mean time per call (each repeat times a batch of calls) of

- Phi + Phi_q: ``equations.constraints(model, q, t)`` vs ``FastConstraints.constraints``;
- Phi + Phi_q + gamma (+ nu): the same with qd;
- accelerations: ``equations.accelerations`` (the numpy reference: dense LU of the KKT
  matrix; skipped above N = 64, where it is seconds per call) vs ``System.accelerations``
  (the C kernels the integrators use: Schur complement, envelope L D L^T);

both sides return fresh arrays; the Jacobian is CSR from nq >= SPARSE_NQ (250) on both
sides.  The C path's minimum over the batches is printed too: on a shared machine it is
the figure without the other processes' interference.

Then the one-off cost in a fresh process with an empty compile cache (MBSIM_CACHE_DIR: the
C compiler runs) and with the cache filled, each the time from ``import mbsim.fast`` to the
first results of all entry points, and the compile alone (CPU s of the compiler).  The
machine's load average is printed with the figures: they are wall-clock times.
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
sys.path.insert(0, str(ROOT))  # tests.reference: the numpy reference

from eval_constraints import chain_yaml  # noqa: E402

from mbsim import fast  # noqa: E402
from mbsim.deck import load_deck, load_deck_text  # noqa: E402
from mbsim.model import compile_model  # noqa: E402
from tests.reference import equations as eq  # noqa: E402

FIRST_USE = """
import time
import numpy as np
from mbsim.deck import load_deck
from mbsim.model import compile_model
models = [compile_model(load_deck("models/" + name + ".yaml")) for name in ("governor", "four_bar")]
t0 = time.perf_counter()
from mbsim import fast
from mbsim.fast import _lib
_lib._installed = lambda digest: None  # as a source checkout: the cache or a compile
for model in models:  # governor: the Schur path; four-bar (singular J'): the KKT path
    q, qd = model.q0, np.full(model.nq, 0.1)
    fd = fast.System(model)
    fd.accelerations(q, qd, 0.0)
    fd.terms(q, 0.0, qd=qd, gamma=True, nu=True)
    fd.violations(q, qd, 0.0)
    fd.mass_matrix(q)
    fd.project_velocities(fd.project_positions(q, 0.0)[0], qd, 0.0)
    fast.FastConstraints(model, sparse=True).constraints(q, 0.0)
print(time.perf_counter() - t0)
"""


def first_use_seconds(cache_dir: str) -> float:
    env = dict(os.environ, MBSIM_CACHE_DIR=cache_dir)
    out = subprocess.run(
        [sys.executable, "-c", FIRST_USE],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    return float(out.stdout.strip().splitlines()[-1])


def compile_cpu_seconds(dest: Path) -> float:
    """User + system CPU seconds of the C compiler building kernels.c (mbsim.fast._lib)."""
    from mbsim.fast import _lib

    r0 = os.times()
    cmd = _lib.compile_command(_lib.compiler(), _lib.SOURCE, dest, _lib.source_hash())
    subprocess.run(cmd, check=True)
    r1 = os.times()
    return (r1.children_user - r0.children_user) + (r1.children_system - r0.children_system)


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
    fd = fast.System(model)
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
        (
            "accelerations",
            (lambda: eq.accelerations(model, q, qd, t)) if model.nb <= 65 else None,
            lambda: fd.accelerations(q, qd, t),
        ),
    ]
    for what, slow, quick in rows:
        if slow is None:
            t_fast, t_min = timeit(quick, repeat, 10 * number)
            print(
                f"{name:<14} {model.nb:>4} {model.m:>5} {what:<16} {'-':>10} "
                f"{t_fast * 1e6:10.2f} {t_min * 1e6:10.2f} {'-':>9}"
            )
            continue
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
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    print(f"load average {load} on {os.cpu_count()} CPUs; median (and min) time per call, us")
    print(
        f"{'model':<14} {'nb':>4} {'m':>5} {'quantity':<16} {'numpy us':>10} "
        f"{'C us':>10} {'C min':>10} {'ratio':>9}"
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
            cc = compile_cpu_seconds(Path(cache) / "k.so")
        print(
            f"first use in a fresh process (all entry points, governor + four-bar): "
            f"cold (empty cache, compiling) {cold:.2f} s, warm (cached library) {warm:.2f} s; "
            f"the compile alone {cc:.2f} s CPU"
        )


if __name__ == "__main__":
    main()
