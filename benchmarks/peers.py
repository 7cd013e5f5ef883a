"""mbsim and Exudyn side by side in one run (issue 24's baseline): CPU seconds per simulated
second at a given error, each code at its best, plus the costs around mbsim's integration.

    python benchmarks/peers.py [--cases governor,slider_crank,chain,fourbar40,user,share,startup]
                               [--sizes 4,16,64,256,1024] [--repeats 3] [--max-cpu 30]
                               [--refine 10] [--kt-max 256] [--kt-implicit-max 16]
                               [--exudyn-cap CPU_S] [--kt-cap CPU_S] [--quick] [--json OUT]

Cases (``--cases``; default all):

- governor: work_precision.py's problem (Table 12.6.6, spindle from 10 rad/s, 5 s); error
  at t_end = max(|collar r - ref| m, |spindle omega - ref| rad/s);
- slider_crank: the free slider-crank (scene free, 2 s); error max(|slider r - ref|,
  |crank omega - ref|);
- chain: spherical chains of N links (common.chain_spec, 2 s); error = distance of the last
  link's bottom point from the reference's;
- fourbar40: models/parallel_fourbar.yaml's construction with ``--loops`` (40) four-bar loops
  (41 cranks on one coupler), 20 s from the bottom at 20 rad/s; error = max over bodies of
  |r - r_exact| at t_end against the exact one-degree-of-freedom reduction (independent);
- user: a run as a user runs it (the deck's dynamic options and outputs, the error
  estimate on, the HDF5 file written) against the bare integration (one output, no
  estimate) on the governor, the free slider-crank and the vehicle;
- share: the compiled share of a default governor run (cProfile; see compiled_share);
- startup: ``mbsim --help`` and ``mbsim check models/governor.yaml`` wall time.

Fairness (the project's standard for peer figures):

- each code runs a ladder of settings (mbsim: rtol, atol = rtol/100, every integrator of
  ``--integrators``; Exudyn: the number of fixed steps, or the tolerance of its adaptive
  explicit methods) and its cost at each target error is interpolated log-log along the
  ladder (common.cost_at); the best over its methods is its figure.  On the chains mbsim's
  ladder is refined to ``--refine`` rungs per decade between a target's last miss and first
  hit (refined_rtols: its error is a jagged function of rtol, and the cheapest rtol that
  meets the target is what a user's --accuracy search finds; Exudyn's fixed-step explicit
  ladders, its best there, are smooth in h).  A cost past a ladder's end is extrapolated,
  printed as an estimate, and never turned into a ratio;
- Exudyn runs every solver and model type it offers for the problem: generalized-alpha and
  TrapezoidalIndex2 on the Cartesian twin (common.exudyn_rigid_system; its explicit solvers
  refuse constrained systems, which the script checks and prints), and for the chains also
  the minimal-coordinate ObjectKinematicTree (common.exudyn_chain_tree) under every explicit
  solver (RK44, RK67, DOPRI5, ODE23, DVERK6) and both implicit ones.  Each method is first
  run once at its cheapest ladder point with every linear solver (EXUdense, EigenDense,
  EigenSparse) and, implicit, full and modified Newton; the fastest configuration runs the
  ladder (the answer does not depend on the linear solver, only the cost);
- one reference per problem for both codes: mbsim projection-dop853 at rtol 1e-12 (chains
  1e-11), whose agreement with Exudyn's converging ladders is visible in the tables; the
  four-bar's reference is exact;
- both start from mbsim's consistent initial state; only the integration is timed (Exudyn:
  SolveDynamic; mbsim: dynamic() with one output and no error estimate, which includes its
  initial-state check and result building); process CPU time, median of ``--repeats`` with
  the spread min-max; BLAS single-threaded (common.py).

A ladder stops once it is 10x below the smallest target or a run costs over ``--max-cpu``
seconds (then that run is not repeated).  Running time: the full default run takes hours on
two shared cores (N = 1024: the reference alone 100 CPU s; Exudyn's trials of every linear
solver at 256 and 1024 links and on the 40 loops take minutes each); run cases or sizes
separately (``--cases chain --sizes 256``) to spread it.  Chains:
``--exudyn-cap`` (``--kt-cap`` for the ObjectKinematicTree) stops an Exudyn run after that
many CPU s, from its pre-step user function (checked between steps): the run is printed as
"cut", its CPU a lower bound on its cost, never a figure; without them no run is stopped.

``--quick``: small sizes, one repeat, short ladders, a 4-loop four-bar for 2 s; a smoke
test of every code path.  Without exudyn
installed the mbsim side is printed and Exudyn's columns say "exudyn not installed".
"""

from __future__ import annotations

import argparse
import copy
import cProfile
import inspect
import json
import math
import os
import pstats
import sys
import tempfile
import time
from pathlib import Path

# benchmarks/ for common.py and work_precision.py; common puts the measured checkout
# (common.ROOT: $MBSIM_ROOT, else this tree) first on sys.path
sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402
from common import (  # noqa: E402
    EXUDYN_ADAPTIVE,
    EXUDYN_FIXED,
    EXUDYN_IMPLICIT,
    ROOT,
    ExudynSolver,
    chain_model,
    chain_tip,
    cost_at,
    exudyn_available,
    exudyn_chain_tree,
    exudyn_rigid_system,
    exudyn_solve,
    figure,
    figure_failed,
    kernel_functions,
    load,
    mbsim_command,
    mbsim_env,
    run_child,
    run_with_deck,
)

TARGETS = (1e-3, 1e-6)
STOP = 0.1  # a ladder stops once its error is below STOP x the smallest target
RTOLS = (1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10)
FIXED_STEPS = (250, 500, 1000, 2000, 4000, 8000, 16000, 32000, 64000, 128000, 256000)  # implicit
EXPLICIT_STEPS = (25, 50, 100, 200, 400, 800, 1600, 3200, 6400, 12800)  # RK44 / RK67, per run
ADAPTIVE_TOLS = (1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11)
REFERENCE = {"integrator": "projection-dop853", "rtol": 1e-12, "atol": 1e-14}
CHAIN_REFERENCE = {"integrator": "projection-dop853", "rtol": 1e-11, "atol": 1e-13}
CHAIN_T_END = 2.0
REFINE = 10
"""Chains: mbsim's ladder refined to this many rungs per decade between the last rtol that
misses a target and the first that meets it (refined_rtols; ``--refine``)."""
KT_MAX_LINKS = 256  # ObjectKinematicTree: dense O(n^3) mass matrix; 1024 links = 3072 coords
KT_IMPLICIT_MAX_LINKS = 16
"""ObjectKinematicTree under Exudyn's implicit solvers only up to this size: at N = 4 and 16
they cost 10-40x its explicit solvers at every error (their Jacobian of the tree is dense
and computed by differences), so they are never its best beyond."""
DENSE_MAX_NQ = 200
"""Cartesian twin: dense linear solvers tried up to this many coordinates (chains to N = 16,
nq = 119): at N = 16 EigenSparse with modified Newton is already the fastest, and a dense
factorization grows as nq^3 (the EXUdense full-Newton trial alone took minutes at N = 64)."""
CASES = ("governor", "slider_crank", "chain", "fourbar40", "user", "share", "startup")


# ------------------------------------------------------------------ timing and ladders
def spread(values):
    """(median, min, max) of a list of numbers."""
    return float(np.median(values)), float(min(values)), float(max(values))


def run_ladder(run, settings, repeats, max_cpu, label, t_end, show=True):
    """Run `run(setting) -> (CPU s per simulated s, error, note)` over the settings,
    `repeats` times each; stop once the error is below STOP x min(TARGETS) or a run costs
    over max_cpu CPU s (t_end: the simulated seconds of a run).
    Returns [{"setting", "cpu": [..], "error", "note"}] (CPU per simulated second)."""
    points = []
    for s in settings:
        cpus, err, note = [], math.nan, None
        for _ in range(max(1, repeats)):
            cpu, err, note = run(s)
            cpus.append(cpu)
            if note or cpu * t_end > max_cpu:
                break
        med, lo, hi = spread(cpus)
        points.append({"setting": s, "cpu": cpus, "error": err, "note": note})
        if show:
            print(f"    {label:<46} {fmt_setting(s):>9}  CPU s/s {med:9.4g} [{lo:.3g}-{hi:.3g}]"
                  f"  error {err:9.2e}" + (f"  {note}" if note else ""), flush=True)
        if cpu * t_end > max_cpu or err < STOP * min(TARGETS) or is_cut(note):
            break
    return points


def refined_rtols(points, per_decade):
    """The rtols `per_decade` to a decade (10^(-k / per_decade) steps) strictly between each
    target's last missing rung and the next, the first that meets it (an adaptive method's
    error is a jagged function of rtol, so the cheapest run that meets a target can lie
    between two rungs: what a user's --accuracy search would find); none when
    per_decade < 2 or no rung pair brackets a target."""
    out = []
    for target in TARGETS:
        for p0, p1 in zip(points, points[1:]):
            if not (p0["error"] > target >= p1["error"]) or p0["note"] or p1["note"]:
                continue
            steps = round(per_decade * math.log10(p0["setting"] / p1["setting"]))
            out += [p0["setting"] * 10.0 ** (-k / per_decade) for k in range(1, steps)]
    return sorted(set(out), reverse=True)


def fmt_setting(s):
    return f"{s:d} st" if isinstance(s, int) else f"{s:.2g}"


def ladder_cost(points, target):
    """(median, min, max, extrapolated) CPU s/s at error `target` along a ladder."""
    ok = [p for p in points if not p["note"] and np.isfinite(p["error"]) and p["error"] > 0]
    if not ok:
        return (math.nan,) * 3 + (False,)
    out = []
    for f in (np.median, min, max):
        pts = [(float(f(p["cpu"])), p["error"]) for p in ok]
        cost, extrapolated = cost_at(pts, target)
        # never above the cheapest run that meets the target: an implicit solver's cost can
        # fall with more steps (fewer Newton iterations), so a ladder need not be monotone
        met = [c for c, e in pts if e <= target]
        if met and not cost <= min(met):
            cost, extrapolated = min(met), False
        out.append((cost, extrapolated))
    # the min and max ladders may cross the target on different segments: order the range
    costs = [c for c, _ in out]
    return costs[0], min(costs), max(costs), out[0][1]


def best(ladders, target):
    """(label, (median, min, max, extrapolated)) of the cheapest measured ladder at `target`
    (an extrapolated cost only when no ladder reaches the target)."""
    costs = [(lab, ladder_cost(pts, target)) for lab, pts in ladders.items()]
    costs = [c for c in costs if np.isfinite(c[1][0])]
    measured = [c for c in costs if not c[1][3]]
    pool = measured or costs
    return min(pool, key=lambda c: c[1][0]) if pool else (None, (math.nan,) * 3 + (False,))


# ------------------------------------------------------------------ mbsim
def mbsim_runner(model, t_end, q0, qd0, integrator, error):
    """run(rtol) for run_ladder: one dynamic run, one output at t_end, no estimate."""
    from mbsim.analyses.dynamic import dynamic

    def run(rtol):
        opts = {"t_end": t_end, "step": t_end, "integrator": integrator, "rtol": rtol,
                "atol": 1e-2 * rtol, "q0": q0.copy(), "qd0": qd0.copy(),
                "error_estimate": False}
        c0 = time.process_time()
        res = dynamic(model, opts)
        cpu = (time.process_time() - c0) / t_end
        note = None if res.complete else f"{res.status}: {res.message}"[:120]
        return cpu, (error(res) if res.complete else math.nan), note

    return run


def reference_run(model, t_end, q0, qd0, ref):
    from mbsim.analyses.dynamic import dynamic

    c0 = time.process_time()
    res = dynamic(model, dict(ref, t_end=t_end, step=t_end, q0=q0.copy(), qd0=qd0.copy(),
                              error_estimate=False))
    if not res.complete:
        raise RuntimeError(f"reference run failed: {res.status}: {res.message}")
    return res, time.process_time() - c0


# ------------------------------------------------------------------ Exudyn
CUT = "cut at the CPU cap"


def is_cut(note):
    return bool(note) and note.startswith(CUT)


def capped_solve(mbs, var, t_end, setting, cap):
    """exudyn_solve, stopped by Exudyn's pre-step user function once the run has used `cap`
    CPU s (None: no cap, no user function).  A stopped run returns the note CUT ...: its CPU
    time is then a lower bound on the whole run's cost."""
    if cap is None:
        return exudyn_solve(mbs, var, t_end, setting)
    c0, reached = time.process_time(), {"t": 0.0, "stopped": False}

    def within_cap(mbs, t):
        reached["t"] = t
        reached["stopped"] = time.process_time() - c0 > cap
        return not reached["stopped"]

    mbs.SetPreStepUserFunction(within_cap)
    cpu, msg = exudyn_solve(mbs, var, t_end, setting)
    if msg is None and reached["stopped"]:
        msg = (f"{CUT} ({cap:g} s) at t = {reached['t']:.3g} of {t_end:g} s: "
               f"> {cpu / t_end:.3g} CPU s/s")
    return cpu, msg


def exudyn_method_ladders(build, read_error, methods, t_end, a, label_prefix, dense_ok=True,
                          ignore_singular=False, cap=None):
    """For each method: try every linear solver (and Newton variant) at the cheapest ladder
    point, run the fastest's ladder.  build() -> (mbs, reader); read_error(reader) -> error;
    cap: CPU s after which a run is stopped (capped_solve).
    Returns ({label: points}, [notes])."""
    ladders, notes = {}, []
    for method in methods:
        probe = ExudynSolver(method, ignore_singular=ignore_singular)
        first = (a.adaptive_tols if probe.adaptive else
                 a.explicit_steps if method in EXUDYN_FIXED else a.fixed_steps)
        trials = []
        for var in probe.variants():
            if not dense_ok and var.linear != "EigenSparse":
                continue
            mbs, reader = build()
            cpu, msg = capped_solve(mbs, var, t_end, first[0], cap)
            trials.append((cpu if msg is None else math.inf, var, msg))
        cpu, var, msg = min(trials, key=lambda x: x[0])
        if msg is not None and all(is_cut(m) for _, _, m in trials):
            cut = ", ".join(f"{v.linear}{'+mN' if v.modified_newton else ''} {m[len(CUT):].strip()}"
                            for _, v, m in trials)
            notes.append(f"{label_prefix}{method}: every variant {CUT} at "
                         f"{fmt_setting(first[0])}: {cut}")
            print(f"    {notes[-1]}", flush=True)
            continue
        if msg is not None:
            notes.append(f"{label_prefix}{method}: not applicable ({msg})")
            print(f"    {label_prefix}{method}: not applicable ({msg})", flush=True)
            continue
        tried = ", ".join(f"{v.linear}{'+mN' if v.modified_newton else ''} "
                          f"{c / t_end:.3g}" if m is None else
                          f"{v.linear}{'+mN' if v.modified_newton else ''} "
                          + ("cut" if is_cut(m) else "failed")
                          for c, v, m in trials)
        print(f"    {label_prefix}{method}: CPU s/s at {fmt_setting(first[0])}: {tried}",
              flush=True)

        def run(setting, var=var):
            mbs, reader = build()
            c, m = capped_solve(mbs, var, t_end, setting, cap)
            return c / t_end, (read_error(reader) if m is None else math.nan), m

        label = label_prefix + var.label
        ladders[label] = run_ladder(run, first, a.repeats, a.max_cpu, label, t_end)
        if is_cut(ladders[label][-1]["note"]):
            notes.append(f"{label}: {fmt_setting(ladders[label][-1]['setting'])} "
                         f"{ladders[label][-1]['note']}")
    return ladders, notes


# ------------------------------------------------------------------ governor, slider-crank
def deck_case(key, a):
    """governor or slider_crank: work_precision.py's problem and error measure."""
    from work_precision import PROBLEMS

    from mbsim.analyses.initial import initial_state

    pr = PROBLEMS[key]
    model = load(pr["deck"], pr["scene"], pr["overrides"])
    t_end = pr["t_end"]
    body, _ = pr["position"]
    spin = pr["spin"]
    q, qd, *_ = initial_state(model)
    ref, ref_cpu = reference_run(model, t_end, q, qd, REFERENCE)
    r_ref = ref.channel(f"bodies/{body}/r").data[-1]
    w_ref = ref.channel(f"bodies/{spin}/omega").data[-1]
    print(f"\n=== {pr['title']}; reference {REFERENCE['integrator']} rtol "
          f"{REFERENCE['rtol']:g} ({ref_cpu:.2f} s CPU) ===", flush=True)

    def err_mbsim(res):
        return max(float(np.abs(res.channel(f"bodies/{body}/r").data[-1] - r_ref).max()),
                   float(np.abs(res.channel(f"bodies/{spin}/omega").data[-1] - w_ref).max()))

    mb = {f"mbsim {name}": run_ladder(mbsim_runner(model, t_end, q, qd, name, err_mbsim),
                                      a.rtols, a.repeats, a.max_cpu, f"mbsim {name}", t_end)
          for name in a.integrators}
    ex, notes = {}, []
    if a.exudyn:
        import exudyn as exu

        def build():
            _, mbs, items = exudyn_rigid_system(model, q, qd)
            return mbs, (mbs, items)

        def err_exudyn(reader):
            mbs, items = reader
            r = np.array(mbs.GetObjectOutputBody(items[body], exu.OutputVariableType.Position,
                                                 localPosition=[0, 0, 0]))
            w = np.array(mbs.GetObjectOutputBody(items[spin],
                                                 exu.OutputVariableType.AngularVelocity,
                                                 localPosition=[0, 0, 0]))
            return max(float(np.abs(r - r_ref).max()), float(np.abs(w - w_ref).max()))

        ex, notes = exudyn_method_ladders(build, err_exudyn, EXUDYN_IMPLICIT + ("DOPRI5",),
                                          t_end, a, "exudyn ")
    return {"case": key, "title": pr["title"], "mbsim": mb, "exudyn": ex, "notes": notes}


# ------------------------------------------------------------------ chains
def tree_twin(model, n, tip_ref):
    """(build, error) for exudyn_method_ladders: the chain of ``n`` links as Exudyn's
    ObjectKinematicTree, and its tip's distance from ``tip_ref`` (m)."""
    def build_tree():
        _, mbs, tip = exudyn_chain_tree(model, n)
        return mbs, (mbs, tip)

    def err_tree(reader):
        mbs, tip = reader
        return float(np.linalg.norm(np.array(mbs.GetSensorValues(tip)) - tip_ref))

    return build_tree, err_tree


def chain_case(n, a):
    model = chain_model(n)
    q, qd = model.q0.copy(), np.zeros(model.nq)
    ref, ref_cpu = reference_run(model, CHAIN_T_END, q, qd, CHAIN_REFERENCE)
    tip_ref = chain_tip(ref, n)
    title = f"spherical chain, N = {n}, {CHAIN_T_END:g} s"
    print(f"\n=== {title}; reference {CHAIN_REFERENCE['integrator']} rtol "
          f"{CHAIN_REFERENCE['rtol']:g} ({ref_cpu:.2f} s CPU) ===", flush=True)
    mb = {}
    for name in a.chain_integrators:
        run = mbsim_runner(model, CHAIN_T_END, q, qd, name,
                           lambda res: float(np.linalg.norm(chain_tip(res, n) - tip_ref)))
        points = run_ladder(run, a.rtols, a.repeats, a.max_cpu, f"mbsim {name}", CHAIN_T_END)
        mb[f"mbsim {name}"] = points + run_ladder(
            run, refined_rtols(points, a.refine), a.repeats, a.max_cpu,
            f"mbsim {name} (refined)", CHAIN_T_END)
    ex, notes = {}, []
    if a.exudyn:
        import exudyn as exu

        def build_cart():
            _, mbs, items = exudyn_rigid_system(model, q, qd)
            return mbs, (mbs, items[f"link{n - 1}"])

        def err_cart(reader):
            mbs, item = reader
            tip = mbs.GetObjectOutputBody(item, exu.OutputVariableType.Position,
                                          localPosition=[0, -0.25, 0])
            return float(np.linalg.norm(np.array(tip) - tip_ref))

        ex, notes = exudyn_method_ladders(build_cart, err_cart, EXUDYN_IMPLICIT, CHAIN_T_END,
                                          a, "exudyn Cartesian ",
                                          dense_ok=model.nq <= DENSE_MAX_NQ, cap=a.exudyn_cap)
        if model.nq > DENSE_MAX_NQ:
            notes.append(f"Cartesian twin: dense linear solvers not tried (nq = {model.nq} > "
                         f"{DENSE_MAX_NQ})")
        if n <= a.kt_max:
            build_tree, err_tree = tree_twin(model, n, tip_ref)
            methods = EXUDYN_ADAPTIVE + EXUDYN_FIXED
            if n <= a.kt_implicit_max:
                methods += EXUDYN_IMPLICIT
            else:
                notes.append("ObjectKinematicTree with implicit solvers not run above "
                             f"{a.kt_implicit_max} links (--kt-implicit-max)")
            kt, kt_notes = exudyn_method_ladders(build_tree, err_tree, methods, CHAIN_T_END,
                                                 a, "exudyn KinematicTree ",
                                                 cap=a.kt_cap if a.kt_cap else a.exudyn_cap)
            ex.update(kt)
            notes += kt_notes
        else:
            notes.append(f"ObjectKinematicTree not run above {a.kt_max} links (dense mass "
                         f"matrix of {3 * n} joint coordinates, O(n^3) per evaluation)")
            print(f"    {notes[-1]}")
    return {"case": f"chain{n}", "title": title, "mbsim": mb, "exudyn": ex, "notes": notes,
            "reference_cpu": ref_cpu}


# ------------------------------------------------------------------ 40 four-bar loops
def fourbar_deck(loops, t_end):
    """models/parallel_fourbar.yaml with `loops` + 1 cranks on the coupler (YAML text)."""
    import yaml

    d = yaml.safe_load((ROOT / "models" / "parallel_fourbar.yaml").read_text())
    d.pop("scenes", None)
    d.pop("studies", None)
    n = loops + 1
    d["parameters"]["W"] = f"{loops}*s"
    c0, g0, j0 = d["bodies"]["crank0"], d["joints"]["G0"], d["joints"]["C0"]
    c0, g0, j0 = copy.deepcopy(c0), copy.deepcopy(g0), copy.deepcopy(j0)
    bodies = {"ground": d["bodies"]["ground"], "coupler": d["bodies"]["coupler"]}
    joints = {}
    for i in range(n):
        x = f"{i}*s"
        body = copy.deepcopy({k: v for k, v in c0.items() if k != "omega"})
        body["r"] = [f"{x} + L/2*cos(theta0)", "L/2*sin(theta0)", 0]
        if i == 0:
            body["omega"] = c0["omega"]
        bodies[f"crank{i}"] = body
        joints[f"G{i}"] = {"type": "revolute", "bodies": ["ground", f"crank{i}"],
                           "points": {"ground": [x, 0, 0, x, 0, 1, f"{x} + 1", 0, 0],
                                      f"crank{i}": list(g0["points"]["crank0"])}}
        joints[f"C{i}"] = {"type": "revolute", "bodies": [f"crank{i}", "coupler"],
                           "points": {f"crank{i}": list(j0["points"]["crank0"]),
                                      "coupler": [f"{x} - W/2", 0, 0, f"{x} - W/2", 0, 1]}}
    d["bodies"], d["joints"] = bodies, joints
    d["title"] = f"Parallel four-bar linkage, {n} cranks ({loops} loops)"
    d["analysis"] = {"dynamic": {"t_end": t_end, "step": 0.01}}
    return yaml.safe_dump(d, sort_keys=False)


def fourbar_exact(model, p, n, t_end):
    """Positions at t_end from the exact reduction (models/parallel_fourbar.yaml's header):
    (N I_pivot + M L^2) theta'' = -g cos(theta) (N m_c L / 2 + M L); returns {body: r}.
    p: the deck's parameters (L, mc, M, s, theta0, w0)."""
    from scipy.integrate import solve_ivp

    L, mc, M, s = (float(p[k]) for k in ("L", "mc", "M", "s"))
    g = float(-model.gravity[1])
    mass = n * (mc * L * L / 12 + mc * L * L / 4) + M * L * L
    grav = g * (n * mc * L / 2 + M * L)
    sol = solve_ivp(lambda _, y: [y[1], -grav * np.cos(y[0]) / mass], (0, t_end),
                    [float(p["theta0"]), float(p["w0"])], method="DOP853", rtol=1e-13,
                    atol=1e-14)
    th = sol.y[0, -1]
    out = {f"crank{i}": np.array([i * s + L / 2 * np.cos(th), L / 2 * np.sin(th), 0])
           for i in range(n)}
    out["coupler"] = np.array([(n - 1) * s / 2 + L * np.cos(th), L * np.sin(th), 0])
    return out


def fourbar_case(a):
    from mbsim.analyses.initial import initial_state

    n = a.loops + 1
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"parallel_fourbar_{a.loops}.yaml"
        path.write_text(fourbar_deck(a.loops, a.fourbar_t_end))
        from mbsim.api import load_model

        spec, model = load_model(path)
    t_end = a.fourbar_t_end
    exact = fourbar_exact(model, spec.parameters, n, t_end)
    q, qd, *_ = initial_state(model)
    title = (f"parallel four-bar, {a.loops} loops ({n} cranks, nq = {model.nq}, m = "
             f"{model.m}), {t_end:g} s")
    print(f"\n=== {title}; reference: the exact one-DOF reduction ===", flush=True)

    def err(res):
        return max(float(np.linalg.norm(res.channel(f"bodies/{b}/r").data[-1] - r))
                   for b, r in exact.items())

    mb = {f"mbsim {name}": run_ladder(mbsim_runner(model, t_end, q, qd, name, err),
                                      a.fourbar_rtols, a.repeats, a.max_cpu,
                                      f"mbsim {name}", t_end)
          for name in ("projection-dop853",)}
    ex, notes = {}, []
    if a.exudyn:
        # the twin closes every loop with revolute joints (common.exudyn_rigid_system); its
        # redundant rows need Exudyn's ignoreSingularJacobian (dense solvers only)
        import exudyn as exu

        def build():
            _, mbs, items = exudyn_rigid_system(model, q, qd)
            return mbs, (mbs, items)

        def err_exudyn(reader):
            mbs, items = reader
            return max(float(np.linalg.norm(np.array(mbs.GetObjectOutputBody(
                items[b], exu.OutputVariableType.Position, localPosition=[0, 0, 0])) - r))
                for b, r in exact.items())

        ex, notes = exudyn_method_ladders(build, err_exudyn, EXUDYN_IMPLICIT, t_end, a,
                                          "exudyn (ignoreSingularJacobian) ",
                                          ignore_singular=True)
    return {"case": f"fourbar{a.loops}", "title": title, "mbsim": mb, "exudyn": ex,
            "notes": notes, "t_end": t_end}


# ------------------------------------------------------------------ a run as a user runs it
USER_DECKS = (("governor", "governor.yaml", None), ("slider-crank free", "slider_crank.yaml",
                                                   "free"), ("vehicle", "vehicle.yaml", None))


def user_case(a):
    """Per deck: CPU s per simulated second of (1) the user's run: the deck's dynamic
    options and outputs, estimate on, HDF5 written; (2) the same without writing; (3) the
    deck's outputs without the estimate; (4) the bare integration: one output, no
    estimate.  The initial state is computed in every variant (as in a user's run); one
    untimed user run first, so that first-use imports count in none of them."""
    from mbsim.api import load_model
    from mbsim.output.hdf5 import write_result

    print("\n=== a run as a user runs it against the bare integration ===", flush=True)
    rows = []
    decks = USER_DECKS[:1] if a.quick else USER_DECKS
    with tempfile.TemporaryDirectory() as tmp:
        for label, deck, scene in decks:
            spec, model = load_model(ROOT / "models" / deck, scene=scene)
            opts = dict(spec.analysis.get("dynamic", {}))
            t_end = float(opts.get("t_end", 1.0)) - float(opts.get("t_start", 0.0))
            variants = {
                "user run (deck outputs, estimate, HDF5)": (dict(opts), True),
                "deck outputs, estimate, no file": (dict(opts), False),
                "deck outputs, no estimate": (dict(opts, error_estimate=False), False),
                "bare (one output, no estimate)": (
                    dict(opts, error_estimate=False,
                         step=float(opts.get("t_end", 1.0)) - float(opts.get("t_start", 0))),
                    False),
            }
            got = {}
            user_key, nofile_key, noest_key, bare_key = variants
            # warm-up, not timed: first-use imports (h5py, the integrator's modules) and the
            # kernels' loading would land in the first variant's first repeat
            write_result(run_with_deck(model, "dynamic", dict(opts), spec),
                         Path(tmp) / "run.h5")
            # the variants in turn within each repeat, so that the ratios of one repeat
            # compare runs made at nearly the same time (the machine's load drifts)
            cpu_of, status = {name: [] for name in variants}, {}
            for _ in range(max(1, a.repeats)):
                for name, (o, write) in variants.items():
                    c0 = time.process_time()
                    res = run_with_deck(model, "dynamic", o, spec)
                    if write:
                        write_result(res, Path(tmp) / "run.h5")
                    cpu_of[name].append((time.process_time() - c0) / t_end)
                    status[name] = res.status
            for name in variants:
                got[name] = spread(cpu_of[name])
                print(f"    {label:<18} {name:<42} CPU s/s {got[name][0]:8.4f} "
                      f"[{got[name][1]:.4f}-{got[name][2]:.4f}]  ({status[name]})", flush=True)
            user, nofile, noest, bare = (got[k][0] for k in variants)
            each = {k: cpu_of[k] for k in variants}
            figure(f"user run / bare integration, {label}",
                   [u / b for u, b in zip(each[user_key], each[bare_key])], "x")
            figure(f"estimate alone / run without it, {label}",
                   [(f - e) / e for f, e in zip(each[nofile_key], each[noest_key])], "x")
            figure(f"user run, {label}", each[user_key], "CPU s per simulated s")
            figure(f"bare integration, {label}", each[bare_key], "CPU s per simulated s")
            ratios = {"user / bare": user / bare, "estimate / run without it":
                      (nofile - noest) / noest, "outputs / bare": noest / bare}
            print(f"    {label:<18} " + ", ".join(f"{k} {v:.2f}" for k, v in ratios.items()))
            rows.append({"deck": label, "t_end": t_end, "variants": got, "ratios": ratios})
    return {"case": "user", "rows": rows}


# ------------------------------------------------------------------ compiled share
def compiled_share(a):
    """cProfile of `mbsim run models/governor.yaml --mode dynamic -o FILE`'s work in process
    (load the deck, run, write), after one warm-up run (imports and the kernels' loading are
    not counted): the C kernels' ctypes functions are wrapped in one thin Python function
    each, so their time shows as the wrappers' own time; share = that / the profile's
    total.  Also printed: the same with perf_counter around each call and no profiler."""
    from mbsim.api import load_model
    from mbsim.fast import _lib
    from mbsim.output.hdf5 import write_result

    lib = _lib.library()
    names = kernel_functions(lib)
    print(f"    C functions timed: {', '.join(names)}", flush=True)
    originals = {n: getattr(lib, n) for n in names}
    spent = {"t": 0.0}

    def wrap_profiled(f):
        def c_kernel(*args):
            return f(*args)
        return c_kernel

    def wrap_timed(f):
        def c_kernel_timed(*args):
            t0 = time.perf_counter()
            out = f(*args)
            spent["t"] += time.perf_counter() - t0
            return out
        return c_kernel_timed

    # as `mbsim run` loads a deck: its studies left to `mbsim check` (where load_model can)
    for_run = {"studies": False} if "studies" in inspect.signature(load_model).parameters else {}

    def user_run(tmp):
        spec, model = load_model(ROOT / "models" / "governor.yaml", **for_run)
        res = run_with_deck(model, "dynamic", dict(spec.analysis.get("dynamic", {})), spec)
        write_result(res, Path(tmp) / "governor.h5")

    print("\n=== compiled share of a default governor run ===", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        user_run(tmp)  # warm-up
        shares, timed_shares = [], []
        try:
            for _ in range(max(1, a.repeats)):
                for n in names:
                    setattr(lib, n, wrap_profiled(originals[n]))
                prof = cProfile.Profile()
                prof.runcall(user_run, tmp)
                st = pstats.Stats(prof)
                c_time = sum(v[2] for k, v in st.stats.items() if k[2] == "c_kernel")
                shares.append(c_time / st.total_tt)
                for n in names:
                    setattr(lib, n, wrap_timed(originals[n]))
                spent["t"] = 0.0
                w0 = time.perf_counter()
                user_run(tmp)
                timed_shares.append(spent["t"] / (time.perf_counter() - w0))
        finally:
            for n in names:
                setattr(lib, n, originals[n])
    out = {"cprofile": spread(shares), "timers": spread(timed_shares)}
    figure("compiled share of a default governor run (cProfile)", [100 * x for x in shares],
           "%")
    figure("compiled share of a default governor run (timers, no profiler)",
           [100 * x for x in timed_shares], "%")
    print(f"    compiled share (cProfile) {100 * out['cprofile'][0]:.1f} % "
          f"[{100 * out['cprofile'][1]:.1f}-{100 * out['cprofile'][2]:.1f}]; without the "
          f"profiler (timers, wall) {100 * out['timers'][0]:.1f} % "
          f"[{100 * out['timers'][1]:.1f}-{100 * out['timers'][2]:.1f}]", flush=True)
    return {"case": "share", **out}


# ------------------------------------------------------------------ start-up
def startup(a):
    """Wall time of `mbsim --help` and `mbsim check models/governor.yaml` in fresh
    processes (``python -m mbsim``, the imports of the ``mbsim`` script, with the measured
    checkout on PYTHONPATH), median of 5 (3 with --quick); also the process's CPU (user +
    system, os.wait4), which a loaded machine inflates less than the wall time."""
    cmd = mbsim_command()
    print(f"\n=== start-up ({' '.join(cmd)}) ===", flush=True)
    out = {"command": cmd}
    for label, args in (("mbsim --help", ["--help"]),
                        ("mbsim check models/governor.yaml", ["check", "models/governor.yaml"])):
        walls, cpus = [], []
        for _ in range(3 if a.quick else 5):
            p = run_child(cmd + args, cwd=ROOT, env=mbsim_env(), timeout=120)
            if p.code:
                raise RuntimeError(f"{label}: {p.error_line()}")
            walls.append(p.wall)
            cpus.append(p.cpu)
        out[label] = spread(walls)
        print(f"    {label:<36} wall {out[label][0]:.3f} s [{out[label][1]:.3f}-"
              f"{out[label][2]:.3f}], CPU {np.median(cpus):.3f} s", flush=True)
        figure(f"{label} wall", walls, "s")
        figure(f"{label} CPU", cpus, "s")
    return {"case": "startup", **out}


# ------------------------------------------------------------------ summary
def figures_of_case(r, target, mb, ex, exudyn):
    """The figure lines of one case at one target error: mbsim's best, Exudyn's best and
    their ratio (CPU s per simulated s; the four-bar also in CPU s to its t_end).  A cost
    not reached or only extrapolated is a failed figure that says so."""
    mlab, m, mlo, mhi, mx = mb
    elab, e, elo, ehi, exx = ex
    n = max((len(p["cpu"]) for pts in r["mbsim"].values() for p in pts), default=1)
    key = f"{r['case']} at {target:.0e}"
    unit = "CPU s per simulated s"
    if not mlab or mx or not np.isfinite(m):
        figure_failed(f"{key}: mbsim best", "not reached" if not mlab else
                      f"only extrapolated ({m:.3g}, {mlab[6:]})")
    else:
        figure(f"{key}: mbsim best", [m] * n, unit, (m, mlo, mhi))
        if r.get("t_end"):
            t = r["t_end"]
            figure(f"{key}: mbsim best to {t:g} s", [m] * n, "CPU s",
                   (m * t, mlo * t, mhi * t))
    if not exudyn:
        return
    if not elab or exx or not np.isfinite(e):
        figure_failed(f"{key}: Exudyn best", "not reached" if not elab else
                      f"only extrapolated ({e:.3g}, {elab[7:]})")
        return
    figure(f"{key}: Exudyn best", [e] * n, unit, (e, elo, ehi))
    if mlab and not mx and np.isfinite(m):
        figure(f"{key}: Exudyn best / mbsim best", [e / m] * n, "x",
               (e / m, elo / mhi, ehi / mlo))


def summary(results, exudyn):
    print("\n=== summary: CPU s per simulated second at the error, median [min-max] ===")
    head = f"{'case':<34} {'error':>6}  {'mbsim best':<44} {'Exudyn best':<58} Exudyn/mbsim"
    print(head)
    print("-" * len(head))
    rows = []
    for r in results:
        if "mbsim" not in r:
            continue
        for target in TARGETS:
            mlab, (m, mlo, mhi, mx) = best(r["mbsim"], target)
            elab, (e, elo, ehi, ex) = best(r["exudyn"], target)
            mtxt = (f"{m:.3g} [{mlo:.3g}-{mhi:.3g}] {mlab[6:]}" if mlab else "not reached")
            if mx:
                mtxt = "estimate " + mtxt
            if not exudyn:
                etxt, ratio = "exudyn not run (not installed or --no-exudyn)", ""
            elif elab is None:
                etxt, ratio = "not reached", ""
            else:
                etxt = f"{e:.3g} [{elo:.3g}-{ehi:.3g}] {elab[7:]}"
                if ex:
                    etxt = "estimate (extrapolated) " + etxt
                ratio = ("" if (ex or mx or not mlab) else f"{e / m:.3g}")
            print(f"{r['case']:<34} {target:6.0e}  {mtxt:<44} {etxt:<58} {ratio}")
            figures_of_case(r, target, (mlab, m, mlo, mhi, mx), (elab, e, elo, ehi, ex),
                            exudyn)
            rows.append({"case": r["case"], "target": target, "mbsim": mlab,
                         "mbsim_cost": [m, mlo, mhi], "mbsim_extrapolated": mx,
                         "exudyn": elab, "exudyn_cost": [e, elo, ehi],
                         "exudyn_extrapolated": ex})
        for note in r.get("notes", []):
            print(f"    note: {note}")
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default=",".join(CASES), help=f"comma list of {', '.join(CASES)}")
    ap.add_argument("--sizes", default="4,16,64,256,1024", help="chain sizes N")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--max-cpu", type=float, default=30.0,
                    help="a ladder stops after a run over this many CPU s")
    ap.add_argument("--integrators", default="projection-dop853,projection,gcp-dop853",
                    help="mbsim integrators for the governor and the slider-crank")
    ap.add_argument("--chain-integrators", default="projection-dop853")
    ap.add_argument("--refine", type=int, default=REFINE,
                    help="chains: mbsim rungs per decade between a target's last miss and "
                         "first hit (0: the plain ladder)")
    ap.add_argument("--kt-max", type=int, default=KT_MAX_LINKS,
                    help="largest chain run as Exudyn's ObjectKinematicTree")
    ap.add_argument("--kt-implicit-max", type=int, default=KT_IMPLICIT_MAX_LINKS,
                    help="largest chain run as ObjectKinematicTree under Exudyn's implicit "
                         "solvers")
    ap.add_argument("--exudyn-cap", type=float, default=None, metavar="CPU_S",
                    help="chains: stop an Exudyn run after this many CPU s (its cost is then "
                         "a lower bound, printed as cut); default: no cap")
    ap.add_argument("--kt-cap", type=float, default=None, metavar="CPU_S",
                    help="chains: the same cap for the ObjectKinematicTree's runs (default: "
                         "--exudyn-cap)")
    ap.add_argument("--loops", type=int, default=40, help="four-bar loops (fourbar40)")
    ap.add_argument("--no-exudyn", action="store_true", help="skip Exudyn even if installed")
    ap.add_argument("--quick", action="store_true",
                    help="smoke test: N = 4; one repeat; short ladders; 4 loops for 2 s")
    ap.add_argument("--json", metavar="OUT", help="write every figure to this JSON file")
    a = ap.parse_args(argv)
    cases = [c.strip() for c in a.cases.split(",") if c.strip()]
    unknown = [c for c in cases if c not in CASES]
    if unknown:
        ap.error(f"unknown case(s) {', '.join(unknown)}; choose from {', '.join(CASES)}")
    a.integrators = a.integrators.split(",")
    a.chain_integrators = a.chain_integrators.split(",")
    a.rtols, a.fixed_steps = RTOLS, FIXED_STEPS
    a.explicit_steps, a.adaptive_tols = EXPLICIT_STEPS, ADAPTIVE_TOLS
    # the four-bar's error at t_end scatters with the round-off of its 98 flat passages
    # (benchmarks/singular_loops.py --passages): rtol 1e-9 closes the ladder below 1e-6
    a.fourbar_rtols, a.fourbar_t_end = (1e-6, 1e-7, 1e-8, 1e-9), 20.0
    sizes = [int(x) for x in a.sizes.split(",")]
    if a.quick:
        sizes = [n for n in sizes if n <= 4] or [4]
        a.repeats, a.max_cpu, a.loops, a.fourbar_t_end = 1, min(a.max_cpu, 1.0), 4, 2.0
        a.rtols, a.fixed_steps = (1e-3, 1e-6, 1e-8), (250, 1000)
        a.explicit_steps, a.adaptive_tols = (50, 200), (1e-5, 1e-8)
        a.fourbar_rtols = (1e-6,)
        a.integrators = a.integrators[:1]
        a.refine = 0
    a.exudyn = exudyn_available() and not a.no_exudyn
    load_avg = os.getloadavg()
    print(f"peers: cases {', '.join(cases)}; medians of {a.repeats}; CPU s per simulated s; "
          f"load average {load_avg[0]:.2f} {load_avg[1]:.2f} {load_avg[2]:.2f} on "
          f"{os.cpu_count()} CPUs; exudyn: " + (
              __import__("exudyn").__version__ if a.exudyn else
              ("skipped (--no-exudyn)" if a.no_exudyn else "not installed (mbsim side only)")),
          flush=True)
    t0 = time.perf_counter()
    results = []

    def save(rows=None):
        """The JSON so far (rewritten after each case, so a stopped run keeps its figures)."""
        if a.json:
            Path(a.json).write_text(json.dumps(
                {"load_start": load_avg, "load_end": os.getloadavg(), "argv": sys.argv[1:],
                 "exudyn": a.exudyn, "summary": rows, "results": results}, indent=1,
                default=str))

    for case in cases:
        if case in ("governor", "slider_crank"):
            results.append(deck_case(case, a))
        elif case == "chain":
            for n in sizes:
                results.append(chain_case(n, a))
                save()
        elif case == "fourbar40":
            results.append(fourbar_case(a))
        elif case == "user":
            results.append(user_case(a))
        elif case == "share":
            results.append(compiled_share(a))
        elif case == "startup":
            results.append(startup(a))
        save()
    rows = summary(results, a.exudyn)
    load_end = os.getloadavg()
    print(f"\nwall {time.perf_counter() - t0:.0f} s; load average at the end "
          f"{load_end[0]:.2f} {load_end[1]:.2f} {load_end[2]:.2f}")
    save(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
