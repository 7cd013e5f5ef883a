"""What each reduced model of Haug (1989) Ch. 12 costs and saves (issue 15, item 5).

    python benchmarks/reduced_models.py [--repeats 3] [--only slider_crank,four_bar,compressor]

For each pair (slider-crank 4 vs 3 bodies, Project 12.1; four-bar model 1 vs 2, Sec. 12.3;
compressor 15 vs 9 bodies, Project 12.2) it runs the cases of the deck's comparison study
(``project12_1``, ``reduced_model``, ``project12_2``: both models on the same tasks) exactly
as ``mbsim study`` runs them, and prints one row per case: bodies (moving, as the book
counts: ground included), coordinates nc = 7 nb, constraint equations nh (``mbsim info``),
the CPU time of the analysis alone per simulated second (``time.process_time``, the median
of ``--repeats`` runs; deck loading and file writing excluded), the full model's CPU over the
reduced one's, and the study's numbers (the chapter's quantities).  The machine is shared:
quote ratios from one run, and rerun to see the spread.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from mbsim.api import load_model, run_model
from mbsim.study import load_studies, number_values, overrides_of

MODELS = Path(__file__).resolve().parents[1] / "models"
PAIRS = {  # deck -> (study, {case name: the model it belongs to})
    "slider_crank": ("project12_1", {"inverse_4body": "4 bodies", "inverse_3body": "3 bodies",
                                     "free_4body": "4 bodies", "free_3body": "3 bodies"}),
    "four_bar": ("reduced_model", {"inverse1": "model 1", "inverse2": "model 2",
                                   "dynamic1": "model 1", "dynamic2": "model 2"}),
    "compressor": ("project12_2", {"inverse9": "9 bodies", "inverse15": "15 bodies",
                                   "inverse9_psi0": "9 bodies", "inverse15_psi0": "15 bodies",
                                   "dynamic9": "9 bodies", "dynamic15": "15 bodies"}),
}  # fmt: skip


def counts(model) -> tuple[int, int, int]:
    """(bodies, nc, nh) as ``mbsim info`` prints them (Haug's count, ground included)."""
    nh = sum(it.rows.size for it in model.items)
    return model.nb, model.nq, nh


def measure(deck: Path, case: dict, repeats: int):
    """(counts, median CPU s per simulated second, the last result) of one study case."""
    _, model = load_model(str(deck), overrides=overrides_of(case), scene=case["scene"])
    cpus, result = [], None
    for _ in range(repeats):
        c0 = time.process_time()
        result = run_model(model, case["mode"], case["options"])
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
        cpu_of = {}
        for case in st["cases"]:
            if case["name"] not in members:
                continue
            (nb, nc, nh), cpu, result = measure(deck, case, args.repeats)
            cpu_of[case["name"]] = cpu
            nums = []
            for number in st["numbers"]:
                if number["cases"] and case["name"] not in number["cases"]:
                    continue
                for col, value in number_values(result, number):
                    nums.append(f"{col} {value:.6g}")
            # the ratio: full model's CPU over the reduced one's, same task (the pair's
            # other case has the same mode and options; its name differs in the model only)
            mates = [c["name"] for c in st["cases"] if c["name"] in members
                     and members[c["name"]] != members[case["name"]]
                     and c["mode"] == case["mode"] and c["options"] == case["options"]
                     and c["name"] in cpu_of]  # fmt: skip
            ratio = f"{cpu / cpu_of[mates[-1]]:.2f}" if mates else ""
            print(f"| {case['label']} | {nb} | {nc} | {nh} | {cpu:.3g} | {ratio} | "
                  f"{'; '.join(nums)} |")  # fmt: skip


if __name__ == "__main__":
    main()
