"""What each reduced model of Haug (1989) Ch. 12 costs and saves (issue 15, item 5).

    python benchmarks/reduced_models.py [--repeats 3] [--only slider_crank,four_bar,compressor]

For each pair (slider-crank 4 vs 3 bodies, Project 12.1; four-bar model 1 vs 2, Sec. 12.3;
compressor 15 vs 9 bodies, Project 12.2) it runs the cases of the deck's comparison study
(``project12_1``, ``reduced_model``, ``project12_2``: both models on the same tasks) exactly
as ``mbsim study`` runs them, and prints one row per case: bodies (moving, as the book
counts: ground included), coordinates nc = 7 nb, constraint equations nh (``mbsim info``),
the CPU time of the analysis alone per simulated second (``time.process_time``, the median
of ``--repeats`` runs after one warm-up run; deck loading and file writing excluded), on
the reduced model's row the full model's CPU over the reduced one's (same task), and the
study's numbers (the chapter's quantities).  The machine is shared:
quote ratios from one run, and rerun to see the spread.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np  # noqa: E402

import mbsim  # noqa: F401  first: one BLAS thread, as the mbsim command runs (mbsim/__init__)
from mbsim.api import load_model, run_model  # noqa: E402
from mbsim.study import load_studies, number_values, overrides_of  # noqa: E402

MODELS = Path(__file__).resolve().parents[1] / "models"
PAIRS = {  # deck -> (study, [(full model's case, reduced model's case), ...]: same task)
    "slider_crank": ("project12_1", [("inverse_4body", "inverse_3body"),
                                     ("free_4body", "free_3body")]),
    "four_bar": ("reduced_model", [("inverse1", "inverse2"), ("dynamic1", "dynamic2")]),
    "compressor": ("project12_2", [("inverse15", "inverse9"),
                                   ("inverse15_psi0", "inverse9_psi0"),
                                   ("dynamic15", "dynamic9")]),
}  # fmt: skip


def counts(model) -> tuple[int, int, int]:
    """(bodies, nc, nh) as ``mbsim info`` prints them (Haug's count, ground included)."""
    nh = sum(it.rows.size for it in model.items)
    return model.nb, model.nq, nh


def measure(deck: Path, case: dict, repeats: int):
    """(counts, median CPU s per simulated second, the last result) of one study case."""
    spec, model = load_model(str(deck), overrides=overrides_of(case), scene=case["scene"])
    run_model(model, case["mode"], case["options"], deck=spec)  # warm-up: compiled kernels, caches
    cpus, result = [], None
    for _ in range(repeats):
        c0 = time.process_time()
        result = run_model(model, case["mode"], case["options"], deck=spec)
        cpus.append(time.process_time() - c0)
    t_sim = float(result.t[-1] - result.t[0])
    return counts(model), float(np.median(cpus)) / t_sim, result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--only", default=",".join(PAIRS), help="decks, comma-separated")
    args = ap.parse_args()
    for name in args.only.split(","):
        study, members = PAIRS[name]
        deck = MODELS / f"{name}.yaml"
        st = load_studies(deck).studies[study]
        print(f"\n{name}: study {study} ({args.repeats} repeats, median CPU)")
        print("| case | bodies | nc | nh | CPU per simulated s [s] | CPU ratio | numbers |")
        print("|---|---|---|---|---|---|---|")
        cases = {c["name"]: c for c in st["cases"]}
        for full, reduced in members:
            cpu = {}
            for name_ in (full, reduced):
                case = cases[name_]
                (nb, nc, nh), cpu[name_], result = measure(deck, case, args.repeats)
                nums = []
                for number in st["numbers"]:
                    if number["cases"] and name_ not in number["cases"]:
                        continue
                    for col, value in number_values(result, number):
                        nums.append(f"{col} {value:.6g}")
                ratio = f"{cpu[full] / cpu[reduced]:.2f}" if name_ == reduced else ""
                print(f"| {case['label']} | {nb} | {nc} | {nh} | {cpu[name_]:.3g} | {ratio} | "
                      f"{'; '.join(nums)} |")  # fmt: skip

if __name__ == "__main__":
    main()
