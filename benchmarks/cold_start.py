"""First run after a fresh install, and the runs after it: CPU and wall seconds (issue 12).

Run: python benchmarks/cold_start.py [--keep]
     python benchmarks/cold_start.py --startup [--repeat 5] [--tree DIR]

``--startup`` (issue 24, item 5): the wall seconds of ``python -m mbsim --help`` and
``python -m mbsim check models/governor.yaml`` from the source tree (or the tree DIR, e.g.
an export of an older commit for a before/after), each run --repeat times after one
unmeasured warm-up (compile cache and bytecode warm): median, min and max, the median CPU
seconds (user + system; steadier than wall on a shared machine), and whether the
process imported scipy (``-X importtime``).  Nothing else runs in these processes, so on an
idle machine this is the start-up a user waits for.

1. Installed: a new venv (``--system-site-packages``: numpy, scipy, h5py, matplotlib are
   reused, as a user's environment would already hold them), ``pip install wheel`` (the
   venv's setuptools needs it), ``pip install --no-deps --no-build-isolation <repo>`` into
   it (setup.py builds the C kernels then), an empty compile cache (MBSIM_CACHE_DIR), then
   each command twice: cold (the first run after the install) and warm.
2. Source tree: ``python -m mbsim`` from the repository root (what ``python -m pytest`` and
   an unbuilt checkout run: no built library next to the package), an empty compile cache:
   the first run compiles kernels.c into the cache (it prints "compiling kernels (first run
   only) ..." on stderr), the second loads it.

Commands (the README's example and the dynamic run of issue 12):

    mbsim run models/slider_crank.yaml --mode kinematic -o x.h5 --plot
    mbsim run models/governor.yaml --mode dynamic -o g.h5

Printed per run: user + system CPU seconds of the process and its children (the compiler
included; resource.getrusage RUSAGE_CHILDREN deltas), wall seconds, and whether the run
compiled the kernels.  The machine's load average is printed too: on a shared machine the
wall times include waiting.  Not measured: Python's own bytecode caches (pip writes them at
install time) and matplotlib's font cache (built once per user, before this script).
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
COMMANDS = {
    "slider-crank kinematic --plot": ["run", "{models}/slider_crank.yaml", "--mode", "kinematic",
                                      "-o", "{out}/x.h5", "--plot"],
    "governor dynamic": ["run", "{models}/governor.yaml", "--mode", "dynamic", "-o", "{out}/g.h5"],
}


def timed(cmd, cwd, env):
    """(CPU s of the process and its children, wall s, stderr) of one command."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    out = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if out.returncode != 0:
        sys.exit(f"{' '.join(map(str, cmd))} failed ({out.returncode}):\n{out.stderr}")
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return cpu, wall, out.stderr


def run_both(label, prefix, cwd, env, out):
    for name, args in COMMANDS.items():
        for run in ("cold", "warm"):
            cmd = prefix + [a.format(models=ROOT / "models", out=out) for a in args]
            cpu, wall, err = timed(cmd, cwd, env)
            compiled = "compiling kernels" in err
            print(f"{label:<12} {name:<30} {run:<5} {cpu:8.2f} {wall:8.2f}   "
                  f"{'yes' if compiled else 'no'}", flush=True)


STARTUP = {"mbsim --help": ["--help"], "mbsim check governor": ["check", "models/governor.yaml"]}


def startup(tree: Path, repeat: int) -> None:
    """Median wall seconds of the start-up commands (module docstring, --startup)."""
    import statistics

    env = dict(os.environ, PYTHONPATH=str(tree))
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    print(f"tree {tree}; load average {load} on {os.cpu_count()} CPUs")
    print(f"{'command':<22} {'wall median':>11} {'min':>6} {'max':>6} {'CPU median':>11}"
          "   scipy imported")
    for name, args in STARTUP.items():
        cmd = [sys.executable, "-m", "mbsim", *args]
        subprocess.run(cmd, cwd=tree, env=env, capture_output=True)  # warm-up
        walls, cpus = [], []
        for _ in range(repeat):
            cpu, wall, _ = timed(cmd, tree, env)
            walls.append(wall)
            cpus.append(cpu)
        imports = subprocess.run([sys.executable, "-X", "importtime", *cmd[1:]], cwd=tree,
                                 env=env, capture_output=True, text=True).stderr
        scipy = any(line.split("|")[-1].strip() == "scipy" for line in imports.splitlines())
        print(f"{name:<22} {statistics.median(walls):11.3f} {min(walls):6.3f} {max(walls):6.3f}"
              f" {statistics.median(cpus):11.3f}   {'yes' if scipy else 'no'}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--keep", action="store_true", help="keep the temporary venv and caches")
    ap.add_argument("--startup", action="store_true",
                    help="only the start-up commands' wall time (issue 24)")
    ap.add_argument("--repeat", type=int, default=5, help="runs per start-up command")
    ap.add_argument("--tree", type=Path, default=ROOT, help="source tree for --startup")
    args = ap.parse_args()
    if args.startup:
        startup(args.tree.resolve(), args.repeat)
        return
    tmp = Path(tempfile.mkdtemp(prefix="mbsim-cold-"))
    try:
        load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
        print(f"load average {load} on {os.cpu_count()} CPUs; scratch {tmp}")
        venv = tmp / "venv"
        subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", str(venv)],
                       check=True)
        py = venv / "bin" / "python"
        # --no-build-isolation builds with the venv's setuptools, whose bdist_wheel needs the
        # wheel package before setuptools 70.1 (Python 3.11's venvs bring 65.5)
        subprocess.run([py, "-m", "pip", "install", "-q", "wheel"], check=True)
        src = tmp / "src"  # a copy: pip builds in the source folder (build/, *.egg-info)
        shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(
            ".git", "build", "*.egg-info", "__pycache__", "results", "*.h5", "*.so"))
        t0 = time.perf_counter()
        cpu, wall, _ = timed([py, "-m", "pip", "install", "-q", "--no-deps",
                              "--no-build-isolation", str(src)], tmp, dict(os.environ))
        where = subprocess.run([py, "-c", "import mbsim.fast._lib as L, glob; "
                                "print(L.HERE); print(glob.glob(str(L.HERE / '_kernels*')))"],
                               cwd=tmp, capture_output=True, text=True, check=True)
        here, built = where.stdout.splitlines()
        if not here.startswith(str(venv)):
            sys.exit(f"the venv imports mbsim from {here}, not from its own install")
        print(f"pip install: {cpu:.1f} s CPU, {time.perf_counter() - t0:.1f} s wall; "
              f"built kernels: {built}")
        print(f"{'where':<12} {'command':<30} {'run':<5} {'CPU s':>8} {'wall s':>8}   compiled")
        work = tmp / "work"
        work.mkdir()
        env = dict(os.environ, MBSIM_CACHE_DIR=str(tmp / "cache-installed"))
        run_both("installed", [str(venv / "bin" / "mbsim")], work, env, work)
        env = dict(os.environ, MBSIM_CACHE_DIR=str(tmp / "cache-source"))
        run_both("source tree", [sys.executable, "-m", "mbsim"], ROOT, env, work)
    finally:
        if not args.keep:
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
