"""Large models set up and written: a spherical chain of 1024 links run for two steps (CPU
and peak memory), and one of 4096 links run and written (wall, file size) (issue 24).

    python benchmarks/large_chain.py [--size 1024] [--big 4096] [--repeats 3]
                                     [--timeout 900] [--memory-limit 8000] [--quick]

Each run is the command a user types, in a fresh process:

    python -m mbsim run chainN.yaml --mode dynamic -o chainN.h5

on common.chain_deck's chain with t_end 0.01 s and output step 0.005 s (two steps of the
default integrator at rtol 1e-6, the error estimate on, three outputs): nearly all of its
cost is set-up (load, compile, initial state) and writing the results file.  Measured from
outside with os.wait4 (common.run_child): the process's CPU (user + system) and its peak
resident memory (ru_maxrss).  Figures:

- N = size: CPU of the whole process (imports, set-up, two steps, writing), and the same
  less the same run of a 4-link chain (imports and what every run costs once), i.e. what
  the size costs in set-up, two steps and writing; peak memory (MB); wall and file size;
- N = big (one run): CPU, peak memory, wall and file size.

CPU and peak memory are figures of every process that ran to its end, also one that then
failed (a run that cannot write its file has still paid for its set-up); wall and file size
only of runs that wrote their file, else a failed figure with the process's last error line
(exit 1 at writing, a memory error under --memory-limit MB of address space, or the
--timeout).  ``--quick``: sizes 64 and 256, one repeat.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import (  # noqa: E402
    ROOT,
    chain_deck,
    exit_on_sigterm,
    figure,
    figure_failed,
    mbsim_command,
    mbsim_env,
    run_child,
)

T_END, STEP = 0.01, 0.005
SIZE_TIMEOUT = 3600.0
"""s of wall for each N = size run: aeac177's 1024-link run takes 190 CPU s, 450-600 s of
wall at load 8 (a 600 s limit cut it short once); --timeout is for the N = big run."""


def run_chain(n, tmp, timeout, memory_limit):
    """(ChildRun, file size in MB or None) of one `mbsim run` of an n-link chain."""
    deck = Path(tmp) / f"chain{n}.yaml"
    if not deck.exists():
        deck.write_text(chain_deck(n, T_END, STEP))
    out = Path(tmp) / f"chain{n}.h5"
    if out.exists():
        out.unlink()
    child = run_child(mbsim_command() + ["run", str(deck), "--mode", "dynamic", "-o", str(out),
                                         "--no-progress"],
                      cwd=str(ROOT), env=mbsim_env(), timeout=timeout,
                      memory_limit_mb=memory_limit)
    size = out.stat().st_size / 2**20 if out.exists() else None
    print(f"    N = {n}: exit {child.code}, wall {child.wall:.2f} s, CPU {child.cpu:.2f} s, "
          f"peak {child.maxrss_mb:.0f} MB, file "
          + (f"{size:.1f} MB" if size is not None else "none")
          + ("" if child.code == 0 else f"; {child.error_line()}"), flush=True)
    return child, size


def report(name, runs, small):
    """The figures of the runs of one size: CPU (and, with `small`, the runs of the 4-link
    chain, CPU less theirs) and peak memory of every process that ran to its end, whatever
    its exit (a run that fails at writing has still paid for its set-up); wall and the
    file's size only from runs that wrote their file, else the first failure's error line."""
    ended = [(c, size) for c, size in runs if not c.timed_out]
    wrote = [(c, size) for c, size in runs if c.code == 0 and size is not None]
    bad = next((c for c, size in runs if c.code != 0 or size is None), None)
    why = (bad.error_line() if bad.code or bad.timed_out else "no file written") if bad else ""
    if ended:
        figure(f"{name}: CPU", [c.cpu for c, _ in ended], "s")
        if small:
            figure(f"{name}: CPU less N = 4", [c.cpu - s.cpu for (c, _), (s, _) in
                                               zip(ended, small)], "s")
        figure(f"{name}: peak memory", [c.maxrss_mb for c, _ in ended], "MB")
    else:
        for what in ("CPU", "CPU less N = 4", "peak memory") if small else ("CPU",
                                                                            "peak memory"):
            figure_failed(f"{name}: {what}", why)
    if bad is None:
        figure(f"{name}: wall", [c.wall for c, _ in wrote], "s")
        figure(f"{name}: file size", [size for _, size in wrote], "MB")
    else:
        figure_failed(f"{name}: wall", why)
        figure_failed(f"{name}: file size", why)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--big", type=int, default=4096)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--timeout", type=float, default=900.0,
                    help="s of wall, the N = big run (the N = size runs: 3600 s)")
    ap.add_argument("--memory-limit", type=float, default=8000.0,
                    help="MB of address space per run (RLIMIT_AS)")
    ap.add_argument("--quick", action="store_true", help="sizes 64 and 256, one repeat")
    a = ap.parse_args(argv)
    exit_on_sigterm()
    if a.quick:
        a.size, a.big, a.repeats = 64, 256, 1
    with tempfile.TemporaryDirectory() as tmp:
        small = [run_chain(4, tmp, SIZE_TIMEOUT, a.memory_limit) for _ in range(a.repeats)]
        runs = [run_chain(a.size, tmp, SIZE_TIMEOUT, a.memory_limit) for _ in range(a.repeats)]
        report(f"chain N = {a.size}, 2-step run and file", runs, small)
        report(f"chain N = {a.big}, 2-step run and file",
               [run_chain(a.big, tmp, a.timeout, a.memory_limit)], None)
    return 0


if __name__ == "__main__":
    sys.exit(main())
