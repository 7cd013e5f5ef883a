"""Before/after table: every figure script run under two checkouts of mbsim, back to back.

    python benchmarks/before_after.py --before /work/before --after /work/main
        [--before-python PY] [--after-python PY] [--python PY] [--quick]
        [--scripts startup,share,...] [--rounds 1] [--timeout S] [--side both]
        [--log-dir DIR]
        [--markdown OUT] [--json OUT]

Each script of ``SCRIPTS`` (this file's folder) prints its figures as lines
``figure: <name> = <value> <unit> (median of N, spread lo..hi)`` (common.figure); this
harness runs each one under the *before* side, then under the *after* side, then the next
script (with ``--rounds R``, R times before/after in turn), and prints a markdown table of
every figure: the median and spread on each side and the ratio after / before.

A side is a checkout (the folder that holds ``mbsim/`` and ``models/``): its script runs
with that checkout first on PYTHONPATH and as ``$MBSIM_ROOT`` (common.ROOT: the decks run
are the checkout's own), its working folder the checkout, under ``--python`` (default: this
interpreter), or ``--before-python`` / ``--after-python`` for one side (a venv with exudyn,
say).  The scripts themselves are always this folder's, so both sides are measured by the
same code.  Both sides in one run on one machine: the ratios are the figures to quote; run
both sides as the same checkout to see the noise floor.

``--quick`` passes ``--quick`` to every script (fewer repeats, smaller sizes: a smoke test
of the harness and every script, not figures to quote).  A script that fails or times out
keeps the figures it printed; its exit and its last error line are listed under the table,
and a figure it printed as ``failed (...)`` shows that text in its cell.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from common import exit_on_sigterm, parse_figure, run_child  # noqa: E402

# label: (script, arguments of the full run, arguments of --quick or None: not run with
# --quick); every "Must show"
# figure of issue 24 comes from one of these (docs/benchmarks.md, "Issue 24: before/after")
SCRIPTS = {
    "startup": ("peers.py", ["--cases", "startup", "--no-exudyn"],
                ["--cases", "startup", "--no-exudyn", "--quick"]),
    "share": ("peers.py", ["--cases", "share", "--no-exudyn"],
              ["--cases", "share", "--no-exudyn", "--quick"]),
    "user": ("peers.py", ["--cases", "user", "--no-exudyn"],
             ["--cases", "user", "--no-exudyn", "--quick"]),
    "user_run": ("user_run.py", [], ["--repeats", "1", "--decks", "governor"]),
    "kinematic": ("kinematic_outputs.py", [], ["--quick"]),
    "chain_scaling": ("chain_scaling.py", [], ["--quick"]),
    "large_chain": ("large_chain.py", [], ["--quick"]),
    "peers_decks": ("peers.py", ["--cases", "governor,slider_crank", "--max-cpu", "20"],
                    ["--cases", "governor,slider_crank", "--quick"]),
    "peers_chains": ("peers.py", ["--cases", "chain", "--sizes", "4,16,64,256",
                                  "--max-cpu", "10"],
                     ["--cases", "chain", "--quick"]),
    "peers_chain1024": ("peers.py", ["--cases", "chain", "--sizes", "1024", "--max-cpu", "60"],
                        None),  # peers' --quick runs N = 4 only: peers_chains covers it
    "fourbar40": ("peers.py", ["--cases", "fourbar40", "--max-cpu", "150"],
                  ["--cases", "fourbar40", "--quick"]),
    "passages": ("passage_scatter.py", ["--starts", "5,5,5,3,3"], ["--quick"]),  # issue 23
    "gcp_stage": ("gcp_stage.py", [], ["--repeats", "1", "--decks", "governor",
                                       "--integrators", "gcp-dop853"]),
}
DEFAULT_SCRIPTS = tuple(SCRIPTS)


# ------------------------------------------------------------------ collecting figures
def collect(text):
    """{figure name: parsed figure} of a script's output (common.parse_figure); a name
    printed twice keeps the last."""
    out = {}
    for line in text.splitlines():
        fig = parse_figure(line)
        if fig:
            out[fig["name"]] = fig
    return out


def merge_rounds(rounds):
    """One figure from the same figure of several rounds: the median of the round medians,
    the spread over every round's spread, N summed; a round that failed makes it failed
    unless another round measured it."""
    ok = [f for f in rounds if "error" not in f]
    if not ok:
        return rounds[-1]
    if len(ok) == 1:
        return ok[0]
    vals = sorted(f["value"] for f in ok)
    k = len(vals)
    med = vals[k // 2] if k % 2 else 0.5 * (vals[k // 2 - 1] + vals[k // 2])
    return {"name": ok[0]["name"], "value": med, "unit": ok[0]["unit"],
            "n": sum(f["n"] for f in ok), "lo": min(f["lo"] for f in ok),
            "hi": max(f["hi"] for f in ok)}


def cell(fig):
    if fig is None:
        return "not printed"
    if "error" in fig:
        return f"failed ({fig['error'].replace('|', '/')})"
    return f"{fig['value']:.4g} [{fig['lo']:.3g}..{fig['hi']:.3g}]"


def ratio(before, after):
    if not before or not after or "error" in before or "error" in after:
        return ""
    if before["value"] == 0:
        return ""
    return f"{after['value'] / before['value']:.3g}"


def format_table(before, after, labels=("before", "after")):
    """Markdown table of two {name: figure} dicts (the union of the names, in the order
    first printed): figure, unit, median [spread] on each side, after / before."""
    names = list(before) + [n for n in after if n not in before]
    head = f"| figure | unit | {labels[0]} | {labels[1]} | after / before |"
    lines = [head, "|---|---|---|---|---|"]
    for n in names:
        b, a = before.get(n), after.get(n)
        unit = next((f["unit"] for f in (b, a) if f and "unit" in f), "")
        lines.append(f"| {n} | {unit} | {cell(b)} | {cell(a)} | {ratio(b, a)} |")
    return "\n".join(lines)


# ------------------------------------------------------------------ running the sides
def describe(checkout):
    """`<short commit>` of a checkout (with `+dirty` when its tree differs), or its path."""
    try:
        head = subprocess.run(["git", "-C", str(checkout), "rev-parse", "--short", "HEAD"],
                              capture_output=True, text=True, timeout=30).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(checkout), "status", "--porcelain",
                                "--untracked-files=no"], capture_output=True, text=True,
                               timeout=30).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return str(checkout)
    return (head + ("+dirty" if dirty else "")) if head else str(checkout)


def side_env(checkout):
    env = dict(os.environ)
    env["MBSIM_ROOT"] = str(checkout)
    env["PYTHONPATH"] = os.pathsep.join([str(checkout)] + [p for p in env.get(
        "PYTHONPATH", "").split(os.pathsep) if p])
    return env


def run_side(python, checkout, script, args, timeout, log=None):
    cmd = [python, str(HERE / script)] + list(args)
    return cmd, run_child(cmd, cwd=str(checkout), env=side_env(checkout), timeout=timeout,
                          log=log)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", required=True, type=Path, help="checkout measured as before")
    ap.add_argument("--after", required=True, type=Path, help="checkout measured as after")
    ap.add_argument("--python", default=sys.executable, help="interpreter of both sides")
    ap.add_argument("--before-python", help="interpreter of the before side")
    ap.add_argument("--after-python", help="interpreter of the after side")
    ap.add_argument("--scripts", default=",".join(DEFAULT_SCRIPTS),
                    help=f"comma list of {', '.join(SCRIPTS)}")
    ap.add_argument("--quick", action="store_true", help="each script's --quick (smoke test)")
    ap.add_argument("--side", choices=("both", "before", "after"), default="both",
                    help="measure one side only (its column alone: a first look, not the "
                         "back-to-back table)")
    ap.add_argument("--rounds", type=int, default=1, help="before/after runs of each script")
    ap.add_argument("--timeout", type=float, default=None,
                    help="seconds one script run may take (default 600 quick, 10800 full)")
    ap.add_argument("--log-dir", type=Path,
                    help="every run's output, written as it runs (<script>.<side>.<round>.log)")
    ap.add_argument("--markdown", type=Path, help="also write the table to this file")
    ap.add_argument("--json", type=Path, help="also write every figure to this file")
    a = ap.parse_args(argv)
    exit_on_sigterm()
    argv_text = list(sys.argv[1:] if argv is None else argv)
    names = [s.strip() for s in a.scripts.split(",") if s.strip()]
    unknown = [s for s in names if s not in SCRIPTS]
    if unknown:
        ap.error(f"unknown script(s) {', '.join(unknown)}; choose from {', '.join(SCRIPTS)}")
    for side in (a.before, a.after):
        if not (side / "mbsim" / "__init__.py").exists():
            ap.error(f"{side}: not an mbsim checkout (no mbsim/__init__.py)")
    timeout = a.timeout or (600.0 if a.quick else 10800.0)
    sides = (("before", a.before.resolve(), a.before_python or a.python),
             ("after", a.after.resolve(), a.after_python or a.python))
    labels = tuple(f"{k} {describe(c)}" for k, c, _ in sides)
    if a.log_dir:
        a.log_dir.mkdir(parents=True, exist_ok=True)
    load0 = os.getloadavg()
    print(f"before/after: {labels[0]} ({sides[0][1]}, {sides[0][2]}) against {labels[1]} "
          f"({sides[1][1]}, {sides[1][2]}); {'quick' if a.quick else 'full'} mode, "
          f"{a.rounds} round(s); load average {load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f} "
          f"on {os.cpu_count()} CPUs", flush=True)
    t0 = time.perf_counter()
    figs = {"before": {}, "after": {}}  # name -> [figure of each round]
    runs = []
    for name in names:
        script, full, quick = SCRIPTS[name]
        args = quick if a.quick else full
        if args is None:
            print(f"  {name:<16} not run with --quick", flush=True)
            continue
        for rnd in range(max(1, a.rounds)):
            for side, checkout, python in sides:
                if a.side not in ("both", side):
                    continue
                log = a.log_dir / f"{name}.{side}.{rnd}.log" if a.log_dir else None
                cmd, child = run_side(python, checkout, script, args, timeout, log)
                got = collect(child.out)
                for fname, fig in got.items():
                    figs[side].setdefault(fname, []).append(fig)
                status = "ok" if child.code == 0 else child.error_line()
                runs.append({"script": name, "round": rnd, "side": side, "command": cmd,
                             "exit": child.code, "wall": child.wall, "cpu": child.cpu,
                             "figures": len(got), "status": status})
                print(f"  {name:<16} {side:<6} exit {child.code} wall {child.wall:7.1f} s "
                      f"CPU {child.cpu:7.1f} s  {len(got)} figures"
                      + ("" if child.code == 0 else f"  {status}"), flush=True)
                if log:
                    log.write_text(" ".join(cmd) + "\n\n" + child.out + "\n--- stderr ---\n"
                                   + child.err)
    merged = {s: {n: merge_rounds(r) for n, r in figs[s].items()} for s in figs}
    table = format_table(merged["before"], merged["after"], labels)
    load1 = os.getloadavg()
    failures = [r for r in runs if r["exit"] != 0]
    notes = [f"- {r['script']} ({r['side']}, round {r['round']}): {r['status']}"
             for r in failures]
    text = (table + "\n\n" + (("Script runs that did not end with exit 0:\n" + "\n".join(notes)
                               + "\n\n") if notes else "")
            + f"Measured by `python benchmarks/before_after.py {' '.join(argv_text)}` in "
              f"{time.perf_counter() - t0:.0f} s "
              f"wall; load average {load0[0]:.2f} at the start, {load1[0]:.2f} at the end "
              f"({os.cpu_count()} CPUs).")
    print("\n" + text)
    if a.markdown:
        a.markdown.write_text(text + "\n")
    if a.json:
        a.json.write_text(json.dumps({"labels": labels, "figures": merged, "rounds": figs,
                                      "runs": runs}, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
