"""CPU time and peak memory of `mbsim check` on decks at or past the deck limits.

    python benchmarks/deck_limits.py [--only NAME ...]

Each deck is written to a temporary folder and checked by its own process
(``python -m mbsim check DECK``); the figures are that process's CPU time (user + system)
and peak resident memory, from ``os.wait4``.  They include Python's start-up and mbsim's
imports (about 0.3 s and 60 MB here), which is what a user waits for.

Decks (issue 23, item 7; targets: <= 2 s CPU each, <= 200 MB for the refused table):

- ``chain_N``: N chained parameters ``q_i: q_(i-1) + 1`` (9 990: 172 kB; took 22 s in
  ``check``, 1.2 s at 1 000, 4.3 s at 4 000 before parameter evaluation was made linear);
- ``table_1e6``: an 8.9 MB deck whose driver is a table of 10^6 points in flow style,
  refused by the item limit while parsing (took 17 s and 730 MB before);
- ``study_mode_1e5``: a 1.2 MB deck whose study case ``mode`` is a 10^5-element list (was
  18 s: the message was built from every item);
- ``sum_4999``: a parameter that is a sum of 4 999 terms, just under the 10 000-character
  formula limit (was refused with a recursion message);
- ``table_1e5``: the largest table the limits allow (99 999 points), a valid deck;
- ``values_5e5``: five lists of 99 000 numbers, just under the limit of 500 000 values in a
  deck (refused afterwards for its unknown keys): the most a deck can cost to compose.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SLIDER = (ROOT / "models" / "slider_crank.yaml").read_text()


def chain(n: int) -> str:
    head, rest = SLIDER.split("parameters:\n", 1)
    lines = ["  q_0: 1"] + [f"  q_{i}: q_{i - 1} + 1" for i in range(1, n)]
    return head + "parameters:\n" + "\n".join(lines) + "\n" + rest


def table(n: int) -> str:
    t = ",".join(str(i) for i in range(n))
    v = ",".join(str(i % 10) for i in range(n))
    return SLIDER.replace(
        "function: pi/2 + omega*t", f"function: {{table: {{t: [{t}], value: [{v}]}}}}"
    )


def table_points(n: int) -> str:
    t = ",".join(f"{i * 1e-5:.5f}" for i in range(n))
    v = ",".join(f"{(i % 100) * 0.01:.2f}" for i in range(n))
    return SLIDER.replace(
        "function: pi/2 + omega*t", f"function: {{table: {{t: [{t}], value: [{v}]}}}}"
    )


def many_values(lists: int, n: int) -> str:
    return (
        SLIDER
        + "\n"
        + "\n".join(f"z{k}: [" + ",".join(["1.25"] * n) + "]" for k in range(lists))
        + "\n"
    )


def study_mode(n: int) -> str:
    modes = "[" + ", ".join(["kinematic"] * n) + "]"
    return (
        "bodies:\n  ground: {ground: true}\n  b: {mass: 1, inertia: [1, 1, 1]}\n"
        f"studies:\n  s: {{cases: [{{label: a, mode: {modes}}}]}}\n"
    )


def long_sum(n: int) -> str:
    return SLIDER.replace("  ell: 0.3 ", "  ell: 0.3" + "+0" * (n - 1) + " ")


DECKS = {
    "chain_1000": lambda: chain(1000),
    "chain_4000": lambda: chain(4000),
    "chain_9990": lambda: chain(9990),
    "table_1e6": lambda: table(10**6),
    "study_mode_1e5": lambda: study_mode(99_999),
    "sum_4999": lambda: long_sum(4999),
    "table_1e5": lambda: table_points(99_999),
    "values_5e5": lambda: many_values(5, 99_000),
}


def measure(path: Path) -> tuple[float, float, int, str]:
    """(CPU s, peak MB, exit code, last stderr line) of `mbsim check path`."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    with tempfile.TemporaryFile() as err:
        p = subprocess.Popen(
            [sys.executable, "-m", "mbsim", "check", str(path)],
            stdout=subprocess.DEVNULL,
            stderr=err,
            env=env,
            cwd=ROOT,
        )
        _, status, usage = os.wait4(p.pid, 0)
        p.returncode = os.waitstatus_to_exitcode(status)
        err.seek(0)
        lines = err.read().decode(errors="replace").strip().splitlines()
    cpu = usage.ru_utime + usage.ru_stime
    return cpu, usage.ru_maxrss / 1024, p.returncode, (lines[-1] if lines else "")[:110]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--only", nargs="*", choices=list(DECKS), help="decks to measure")
    args = ap.parse_args()
    print(f"{'deck':<16} {'size':>9} {'CPU s':>7} {'peak MB':>8} {'exit':>4}  message")
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.only or DECKS:
            path = Path(tmp) / f"{name}.yaml"
            path.write_text(DECKS[name]())
            cpu, mb, code, msg = measure(path)
            size = path.stat().st_size
            print(f"{name:<16} {size / 1e3:>7.0f}kB {cpu:>7.2f} {mb:>8.0f} {code:>4}  {msg}")


if __name__ == "__main__":
    main()
