"""Where the CPU time of ``mbsim study`` goes: the analyses, the figures, and the rest.

    python benchmarks/study_overhead.py [--repeats 3] [--study DECK:NAME ...]

Each study runs as the command does (``mbsim study DECK NAME -q``, one process per run, so
the imports are counted), with the process CPU time (``time.process_time``) measured around

- the analyses (``mbsim.api.run_model``, with the imports it makes on first use),
- figure drawing (``mbsim.study.study_figure`` and ``mbsim.output.save_figure``),
- writing the HDF5 files (``mbsim.output.write_result``), compiling the models
  (``mbsim.model.compile_model``) and reading and validating the deck
  (``mbsim.deck.loader.parse_deck`` and ``ParsedDeck.spec``: once for the study, once per
  case),

and the total CPU of the process; "other" is everything outside the analyses and figures
(writing, compiling, the deck, the imports of the command itself, the tables).
Issue 12's target: other <= 15 % of the total for ``vehicle.yaml lane_change``.
Figures are medians over the repeats (the CPU time is the steadier figure on a shared
machine; wall time printed too).  Default studies: the vehicle's lane changes (four
dynamic runs, 6 s each) and the slider-crank's rod-length study (three short inverse runs,
where the fixed costs weigh most).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
STUDIES = ("vehicle.yaml:lane_change", "slider_crank.yaml:inverse_rod_length")
PARTS = ("analyses", "figures", "write", "compile", "deck")

# Runs in the child: wrap the functions, run the CLI, print the CPU split as JSON.
CHILD = r"""
import json, sys, time
t_start = time.perf_counter()
spent = dict.fromkeys(PARTS, 0.0)
depth = [0]

def timed(part, fn):
    def wrapper(*args, **kwargs):
        if depth[0]:
            return fn(*args, **kwargs)
        depth[0] += 1
        c0 = time.process_time()
        try:
            return fn(*args, **kwargs)
        finally:
            spent[part] += time.process_time() - c0
            depth[0] -= 1
    return wrapper

import mbsim.api, mbsim.deck.loader, mbsim.model, mbsim.output, mbsim.study
mbsim.api.run_model = timed("analyses", mbsim.api.run_model)
mbsim.study.study_figure = timed("figures", mbsim.study.study_figure)

def save_figure(*args, **kwargs):  # mbsim.output.plots is imported on first use, as unwrapped
    from mbsim.output.plots import save_figure as real
    return real(*args, **kwargs)

mbsim.output.save_figure = timed("figures", save_figure)
mbsim.output.write_result = timed("write", mbsim.output.write_result)
mbsim.model.compile_model = timed("compile", mbsim.model.compile_model)
loader = mbsim.deck.loader
loader.parse_deck = timed("deck", loader.parse_deck)
loader.ParsedDeck.spec = timed("deck", loader.ParsedDeck.spec)
from mbsim.cli import main
code = 0
try:
    main(sys.argv[1:], standalone_mode=False)
except SystemExit as exc:
    code = exc.code or 0
spent["total"] = time.process_time()
spent["wall"] = time.perf_counter() - t_start
spent["code"] = code
print("SPLIT " + json.dumps(spent))
"""


def run_once(deck: str, study: str, out_dir: str) -> dict:
    """One ``mbsim study DECK STUDY -q`` in a fresh process; its CPU split (s)."""
    code = f"PARTS = {PARTS!r}\n" + CHILD
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    args = [sys.executable, "-c", code, "study", str(ROOT / "models" / deck), study, "-q",
            "-o", out_dir]  # fmt: skip
    proc = subprocess.run(args, capture_output=True, text=True, env=env, cwd=ROOT)
    line = [ln for ln in proc.stdout.splitlines() if ln.startswith("SPLIT ")]
    if not line:
        raise RuntimeError(f"{deck} {study}: no figures\n{proc.stdout}\n{proc.stderr}")
    split = json.loads(line[-1][6:])
    if split["code"] not in (0, None):
        print(f"  (exit code {split['code']}: {proc.stderr.strip().splitlines()[-1:]})")
    return split


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--study", action="append", help="DECK:NAME (decks in models/)")
    args = ap.parse_args(argv)
    print("CPU s of `mbsim study DECK NAME -q` (medians of", args.repeats, "runs)")
    print(f"{'study':<40} {'total':>6} {'analyses':>9} {'figures':>8} {'other':>6} "
          f"{'other %':>7}  (write, compile, deck; wall)")  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        for item in args.study or STUDIES:
            deck, _, study = item.partition(":")
            runs = [run_once(deck, study, tmp) for _ in range(max(1, args.repeats))]
            med = {k: float(np.median([r[k] for r in runs])) for k in (*PARTS, "total", "wall")}
            other = [r["total"] - r["analyses"] - r["figures"] for r in runs]
            share = [100 * o / r["total"] for o, r in zip(other, runs)]
            print(f"{deck + ' ' + study:<40} {med['total']:6.2f} {med['analyses']:9.2f} "
                  f"{med['figures']:8.2f} {np.median(other):6.2f} {np.median(share):6.1f}%  "
                  f"({med['write']:.2f}, {med['compile']:.2f}, {med['deck']:.2f}; "
                  f"{med['wall']:.2f} s)")  # fmt: skip


if __name__ == "__main__":
    main()
