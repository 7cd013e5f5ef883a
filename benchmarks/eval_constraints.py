"""Cost of one evaluation of Phi and Phi_q (and gamma) for the governor and spatial chains.

Run: python benchmarks/eval_constraints.py [--repeat 7]
Prints the median over repeats of the mean time per evaluation (each repeat times a batch of
evaluations), dense and sparse Jacobians, and the per-body cost growth of the chains.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests.reference

from mbsim.deck import load_deck, load_deck_text  # noqa: E402
from mbsim.model import compile_model  # noqa: E402
from tests.reference import equations as eq  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def chain_yaml(n: int) -> str:
    """Spherical chain of issue #3: links 1 kg, 0.5 m along y', J' = diag(1/48, 1e-4, 1/48),
    link i rotated 0.3 rad about (cos phi_i, 0, sin phi_i), phi_i = 2 pi i / n, hanging from
    a ground ball joint at the origin, gravity -y."""
    from mbsim.rotations import A, from_axis_angle

    lines = ["title: spherical chain", "gravity: [0, -9.81, 0]", "bodies:",
             "  ground: {ground: true}"]
    top = np.zeros(3)
    joints = ["joints:", "  J0: {type: spherical, bodies: [ground, L0], "
              "points: {ground: [0, 0, 0], L0: [0, 0.25, 0]}}"]
    for i in range(n):
        phi = 2 * np.pi * i / n
        p = from_axis_angle([np.cos(phi), 0, np.sin(phi)], 0.3)
        Ai = A(p)
        r = top - Ai @ np.array([0, 0.25, 0])
        top = r + Ai @ np.array([0, -0.25, 0])
        lines.append(f"  L{i}: {{mass: 1.0, inertia: [{1 / 48!r}, 1.0e-4, {1 / 48!r}], "
                     f"r: {list(map(float, r))}, p: {list(map(float, p))}}}")
        if i > 0:
            joints.append(f"  J{i}: {{type: spherical, bodies: [L{i - 1}, L{i}], "
                          f"points: {{L{i - 1}: [0, -0.25, 0], L{i}: [0, 0.25, 0]}}}}")
    return "\n".join(lines + joints) + "\n"


def timeit(fn, repeat: int, number: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        times.append((time.perf_counter() - t0) / number)
    return statistics.median(times)


def bench(name: str, model, repeat: int) -> None:
    rng = np.random.default_rng(1)
    q = model.q0.copy()
    qd = rng.normal(size=model.nq) * 0.1
    number = max(20, int(2000 / model.nb))
    t_phi = timeit(lambda: eq.constraints(model, q, 0.1, jac=False), repeat, number)
    t_pj = timeit(lambda: eq.constraints(model, q, 0.1), repeat, number)
    t_sp = timeit(lambda: eq.constraints(model, q, 0.1, sparse=True), repeat, number)
    t_all = timeit(lambda: eq.constraints(model, q, 0.1, qd=qd, gamma=True, nu=True), repeat,
                   number)
    print(f"{name:<16} nb={model.nb:<4} m={model.m:<5} Phi {t_phi * 1e6:8.1f} us  "
          f"Phi+Phi_q {t_pj * 1e6:8.1f} us  (sparse {t_sp * 1e6:8.1f} us)  "
          f"Phi+Phi_q+nu+gamma {t_all * 1e6:8.1f} us  per body {t_pj * 1e6 / model.nb:6.2f} us")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args()
    spec = load_deck(ROOT / "models" / "governor.yaml")
    spec.forces = {}  # constraint evaluation only
    bench("governor", compile_model(spec), args.repeat)
    for n in (4, 16, 64, 256):
        bench(f"chain N={n}", compile_model(load_deck_text(chain_yaml(n), f"chain{n}")),
              args.repeat)


if __name__ == "__main__":
    main()
