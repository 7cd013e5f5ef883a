"""The 40-loop four-bar's error at t_end over perturbed starts (issue 23, singular passages).

    python benchmarks/passage_scatter.py [--checkout DIR] [--loops 40] [--t-end 20]
        [--rtols 1e-6,1e-7,1e-8,1e-9,1e-10] [--starts 5 | --starts 5,5,5,3,3] [--seeds 1,2]
        [--ulps 4] [--integrators projection-dop853] [--trace [--save DIR]] [--quick]
    python benchmarks/passage_scatter.py [--checkout DIR] [--loops 40] --summary DIR

e.g. the after side of docs/benchmarks.md's "Passages over perturbed starts (issue 23)":
``python benchmarks/passage_scatter.py --checkout /work/main --starts 5``.

The error at t_end of peers.py's fourbar40 case (``peers.fourbar_deck``: `loops` + 1 cranks
on one coupler, 20 s, 98 flat passages; error = the largest position error of a body at
t_end against the exact one-DOF reduction, scipy DOP853 at rtol 1e-13; bare integration:
one output, no estimate, atol = rtol / 100) is set by its worst flat passage and depends on
the last bits of the start.  So one run per rtol compares nothing: this script runs each
rtol from K starts, the assembled start (start 0) and K - 1 starts whose q0 is moved by
`ulps` x eps x max(1, |q0_i|) with random signs (numpy seeds 1 .. K - 1; the same pattern
in every checkout: singular_loops.py's ``perturbed``), and prints per (method, rtol) the
median, geometric mean, min and max of the error and the CPU s per run, as ``figure:``
lines (common.figure) for before_after.py (registered there as ``passages``).

--checkout DIR: the mbsim measured (default $MBSIM_ROOT, else this script's checkout): it
goes first on sys.path, and its models/parallel_fourbar.yaml is the deck.  --starts takes
one K or one K per rtol (the tight rtols cost the most); --seeds 3,4 runs those starts
alone (a setting split over processes; the figures are then of those starts only).
--ulps 0 runs the assembled start K times (the run's own repeatability).

--trace: where the error arises.  Every accepted step the Python driver takes (the steps at
and across a passage; the C loop's stretches between passages count as one record each) is
recorded with its state and, for the index-1 family, the smallest change-point measure s of
its stages (``_trial_s``); the crank angle's error e = (dtheta, dtheta') at each record is
carried to t_end through the exact reduction's linearised flow Phi(T, t), so that a stretch
between two records contributes Phi(T, t1) e1 - Phi(T, t0) e0 to the final angle error
(the contributions add up to it).  Printed: the three passages that contribute most (their
time, share of |dtheta(T)|, the smallest stage s in their steps and the number of tangent
steps), and the sum of the passages' and of the stretches between them.  The script also
prints the reduction's own sensitivity |Phi(T, 0)|: what a perturbation of the start does
to the exact solution.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ULPS = 4  # singular_loops.py's default perturbation (mbsim's ROUNDOFF_ULPS)
WINDOW = 10e-3  # s: --trace counts a stretch within this of a passage as the passage's
# (the crank turns at about 15 rad/s: 0.15 rad, where the measure s ~ 0.04 theta is 6e-3)


def parse(argv):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkout", type=Path, help="the mbsim checkout measured "
                    "(default $MBSIM_ROOT, else this script's)")
    ap.add_argument("--loops", type=int, default=40)
    ap.add_argument("--t-end", type=float, default=20.0)
    ap.add_argument("--rtols", default="1e-6,1e-7,1e-8,1e-9,1e-10")
    ap.add_argument("--starts", default="5", help="K, or one K per rtol (comma list)")
    ap.add_argument("--seeds", help="these starts only (comma list, e.g. 3,4), for every "
                    "rtol: one setting split over processes")
    ap.add_argument("--ulps", type=float, default=ULPS)
    ap.add_argument("--integrators", default="projection-dop853")
    ap.add_argument("--trace", action="store_true", help="where the error arises (above)")
    ap.add_argument("--save", type=Path, help="--trace: also write each run's records "
                    "(t, coupler q and qd, stage s, tangent) to DIR/<loops>_<rtol>_<start>.npz")
    ap.add_argument("--summary", type=Path, help="no runs: the passages of the records "
                    "--save wrote to DIR, by the smallest stage measure s of their steps")
    ap.add_argument("--quick", action="store_true",
                    help="smoke test: 3 loops (4 cranks), 2 s, 2 starts")
    return ap.parse_args(argv)


def main(argv=None):
    a = parse(argv)
    if a.checkout:
        if not (a.checkout / "mbsim" / "__init__.py").exists():
            sys.stderr.write(f"error: --checkout {a.checkout}: not an mbsim checkout (no "
                             f"mbsim/__init__.py)\n")
            return 2
        os.environ["MBSIM_ROOT"] = str(a.checkout.resolve())
    sys.path.insert(0, str(HERE))
    from common import ROOT, figure, figure_failed  # noqa: PLC0415 (ROOT read from the env)

    if a.quick:
        a.loops, a.t_end, a.rtols, a.starts = 3, 2.0, "1e-6,1e-8", "2"
    rtols = [float(r) for r in a.rtols.split(",")]
    ks = [int(k) for k in a.starts.split(",")]
    ks = ks * len(rtols) if len(ks) == 1 else ks
    if len(ks) != len(rtols):
        sys.stderr.write(f"error: --starts {a.starts}: one K, or one K for each of the "
                         f"{len(rtols)} rtols\n")
        return 2
    load = os.getloadavg()
    args = sys.argv[1:] if argv is None else list(argv)
    print(f"command: {' '.join([sys.executable, str(Path(__file__).resolve())] + args)}")
    now = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())
    print(f"checkout: {ROOT} ({_describe(ROOT)}); {now}; "
          f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} CPUs",
          flush=True)
    case = FourBar(a.loops, a.t_end)
    if a.summary:
        return summary(case, a.summary)
    print(f"{a.loops} loops ({case.n} cranks, nq = {case.model.nq}), {a.t_end:g} s; start "
          f"perturbed by {a.ulps:g} ulps; reduction's |Phi(T, 0)| = {case.sensitivity():.3g} "
          f"(theta, theta' to theta at T)", flush=True)
    tag = f"fourbar{a.loops}" + ("" if a.t_end == 20.0 else f" {a.t_end:g} s")
    for name in a.integrators.split(","):
        for rtol, k in zip(rtols, ks):
            errs, cpus, notes = [], [], []
            seeds = [int(x) for x in a.seeds.split(",")] if a.seeds else range(k)
            for seed in seeds:
                out = case.run(name, rtol, seed, a.ulps, a.trace)
                cpus.append(out["cpu"])
                if out["note"]:
                    notes.append(f"start {seed}: {out['note']}")
                else:
                    errs.append(out["error"])
                print(f"  {name} rtol {rtol:.0e} start {seed}: error {out['error']:.3e} m, "
                      f"CPU {out['cpu']:.1f} s, {out['steps']} steps, "
                      f"{out['tangent']} tangent stages" + (f"  {out['note']}" if out["note"]
                                                          else ""), flush=True)
                if a.trace and "passages" in out:
                    _print_trace(out)
                    if a.save:
                        a.save.mkdir(parents=True, exist_ok=True)
                        np.savez(a.save / f"{a.loops}_{rtol:.0e}_{seed}.npz", **out["rows"])
            label = f"{tag} {name} rtol {rtol:.0e}"
            if errs:
                gm = float(np.exp(np.mean(np.log(errs))))
                print(f"{label}: error m over {len(errs)} starts: median {np.median(errs):.3g}, "
                      f"geometric mean {gm:.3g}, min {min(errs):.3g}, max {max(errs):.3g}; "
                      f"CPU s per run median {np.median(cpus):.1f}", flush=True)
                figure(f"{label} error (min..max of starts)", errs, "m")
                figure(f"{label} error, geometric mean", errs, "m",
                       spread=(gm, min(errs), max(errs)))
                figure(f"{label} CPU per run", cpus, "CPU s")
            for note in notes:
                figure_failed(f"{label} {note.split(':')[0]}", note)
    return 0


def _describe(root):
    import subprocess

    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"],
                              capture_output=True, text=True, timeout=30).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        head = ""
    return head or "no git"


class FourBar:
    """The deck of peers.fourbar_deck, assembled once, and its exact reduction."""

    def __init__(self, loops, t_end):
        from peers import fourbar_deck
        from scipy.integrate import solve_ivp

        from mbsim.analyses.initial import initial_state
        from mbsim.api import load_model

        self.loops, self.n, self.t_end = loops, loops + 1, t_end
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / f"parallel_fourbar_{loops}.yaml"
            path.write_text(fourbar_deck(loops, t_end))
            spec, self.model = load_model(path)
        p = spec.parameters
        self.L, mc, M, self.s = (float(p[k]) for k in ("L", "mc", "M", "s"))
        g = float(-self.model.gravity[1])
        n = self.n
        mass = n * (mc * self.L ** 2 / 12 + mc * self.L ** 2 / 4) + M * self.L ** 2
        grav = g * (n * mc * self.L / 2 + M * self.L)
        self.k = grav / mass  # theta'' = -k cos(theta)

        def rhs(_, y):  # (theta, theta', Phi(t, 0) row-major): the flow and its Jacobian
            th, w, P = y[0], y[1], y[2:].reshape(2, 2)
            Jf = np.array([[0.0, 1.0], [self.k * np.sin(th), 0.0]])
            return np.concatenate([[w, -self.k * np.cos(th)], (Jf @ P).ravel()])

        y0 = np.concatenate([[float(p["theta0"]), float(p["w0"])], np.eye(2).ravel()])
        self.ref = solve_ivp(rhs, (0, t_end), y0, method="DOP853", rtol=1e-13, atol=1e-14,
                             dense_output=True)
        q, qd, *_ = initial_state(self.model)
        self.q0, self.qd0 = np.asarray(q, float), np.asarray(qd, float)
        self.coupler = list(self.model.body_names).index("coupler")
        self.xbar = (n - 1) * self.s / 2
        th = self.ref.y[0, -1]
        self.exact = {f"crank{i}": np.array([i * self.s + self.L / 2 * np.cos(th),
                                             self.L / 2 * np.sin(th), 0]) for i in range(n)}
        self.exact["coupler"] = np.array([self.xbar + self.L * np.cos(th),
                                          self.L * np.sin(th), 0])

    def sensitivity(self):
        """|d theta(T) / d(theta0, theta'0)| of the reduction (2-norm of Phi's first row)."""
        return float(np.linalg.norm(self.ref.y[2:4, -1]))

    def flow(self, t):
        """Phi(T, t) = Phi(T, 0) Phi(t, 0)^-1, (2, 2)."""
        return self.ref.y[2:, -1].reshape(2, 2) @ np.linalg.inv(
            self.ref.sol(t)[2:].reshape(2, 2))

    def start(self, seed, ulps):
        if not seed:
            return self.q0.copy()
        signs = np.random.default_rng(seed).choice([-1.0, 1.0], self.q0.size)
        return self.q0 + ulps * np.finfo(float).eps * signs * np.maximum(1.0, np.abs(self.q0))

    def run(self, name, rtol, seed, ulps, trace):
        from mbsim.analyses.dynamic import dynamic

        opts = {"t_end": self.t_end, "step": self.t_end, "integrator": name, "rtol": rtol,
                "atol": 1e-2 * rtol, "q0": self.start(seed, ulps), "qd0": self.qd0.copy(),
                "error_estimate": False}
        records = _Recorder(name) if trace else None
        try:
            c0 = time.process_time()
            res = dynamic(self.model, opts)
            cpu = time.process_time() - c0
        finally:
            if records:
                records.remove()
        c = res.counters
        out = {"cpu": cpu, "steps": c.get("steps", 0),
               "tangent": c.get("tangent_stages", 0), "note": None, "error": math.nan}
        if not res.complete:
            out["note"] = f"{res.status}: {res.message}"[:160]
            return out
        out["error"] = max(float(np.linalg.norm(res.channel(f"bodies/{b}/r").data[-1] - r))
                           for b, r in self.exact.items())
        if records and records.rows:
            out.update(self.passages(records.rows))
        return out

    def passages(self, rows):
        """Each record's angle error carried to t_end; contributions per passage (the
        stretch between the records that bracket theta = k pi of the reduction)."""
        b = self.coupler
        t = np.array([r[0] for r in rows])
        s_min = np.array([r[3] for r in rows])
        tangent = np.array([r[4] for r in rows])
        e_T = []
        for ti, q, qd, *_ in rows:
            x, y = q[7 * b] - self.xbar, q[7 * b + 1]
            xd, yd = qd[7 * b], qd[7 * b + 1]
            th, w = math.atan2(y, x), (x * yd - y * xd) / (x * x + y * y)
            ref = self.ref.sol(ti)
            dth = (th - ref[0] + math.pi) % (2 * math.pi) - math.pi
            e_T.append(float(self.flow(ti)[0] @ np.array([dth, w - ref[1]])))
        e_T = np.array(e_T)
        saved = {"t": t, "s": s_min, "tangent": tangent, "e_T": e_T,
                 "q": np.array([r[1][7 * b:7 * b + 7] for r in rows]),
                 "qd": np.array([r[2][7 * b:7 * b + 7] for r in rows])}
        return dict(self.attribute(t, s_min, tangent, e_T), rows=saved)

    def attribute(self, t, s_min, tangent, e_T):
        """The contributions Phi(T, t1) e1 - Phi(T, t0) e0 of the stretches between records
        summed per passage (the stretches within ``WINDOW`` of it) and between passages."""
        # the passages: theta of the reduction through k pi
        grid = np.linspace(0, self.t_end, int(self.t_end * 2000) + 1)
        k = np.floor(self.ref.sol(grid)[0] / math.pi)
        tp = grid[1:][np.diff(k) != 0]
        contrib = np.diff(e_T)
        # a passage owns the stretches (t[i], t[i+1]] that come within WINDOW of it (the
        # approach, the tangent steps and the step across); the rest is "between"
        owner = np.full(contrib.size, -1)
        for j, tk in enumerate(tp):
            owner[(t[1:] > tk - WINDOW) & (t[:-1] < tk + WINDOW)] = j
        per = {}
        for i, j in enumerate(owner):
            if j >= 0:
                d = per.setdefault(j, {"t": tp[j], "e": 0.0, "s": np.inf, "tangent": 0})
                d["e"] += contrib[i]
                if np.isfinite(s_min[i + 1]):
                    d["s"] = min(d["s"], float(s_min[i + 1]))
                d["tangent"] += int(tangent[i + 1])
        between = float(contrib[owner < 0].sum())
        return {"passages": sorted(per.values(), key=lambda d: -abs(d["e"])),
                "between": between, "final": float(e_T[-1] - e_T[0]), "records": t.size,
                "count": tp.size}


S_BINS = (0.0, 1e-5, 3e-5, 1e-4, 1e-3, np.inf)  # --summary's bins of the smallest stage s


def summary(case, folder):
    """Per rtol, over every saved run of `case`'s loops: the passages by the smallest stage
    measure s of their steps (count, median and largest |contribution| to the angle at T,
    rad), and how much of each run's |angle error at T| its worst passage carries."""
    by_rtol = {}
    for f in sorted(folder.glob(f"{case.loops}_*.npz")):
        rtol = float(f.stem.split("_")[1])
        d = np.load(f)
        out = case.attribute(d["t"], d["s"], d["tangent"], d["e_T"])
        by_rtol.setdefault(rtol, []).append((f.stem, out))
    for rtol, runs in sorted(by_rtol.items(), reverse=True):
        ps = [p for _, out in runs for p in out["passages"]]
        s = np.array([p["s"] for p in ps])
        e = np.abs([p["e"] for p in ps])
        print(f"rtol {rtol:.0e}, {len(runs)} runs, {len(ps)} passages; |contribution to the "
              f"angle at T| rad by the smallest stage s in the passage's steps:")
        for lo, hi in zip(S_BINS, S_BINS[1:]):
            m = (s >= lo) & (s < hi)
            if m.any():
                print(f"    s in [{lo:.0e}, {hi:.0e}): {m.sum():4d} passages, median "
                      f"{np.median(e[m]):.2e}, largest {e[m].max():.2e}, sum "
                      f"{e[m].sum():.2e}", flush=True)
        for name, out in runs:
            w = out["passages"][0]
            print(f"    {name}: angle error at T {out['final']:+.2e} rad, worst passage t "
                  f"{w['t']:.3f} s {w['e']:+.2e} rad (smallest stage s {w['s']:.1e}, "
                  f"{w['tangent']} tangent records), between passages {out['between']:+.2e}",
                  flush=True)
    return 0


def _print_trace(out):
    ps = out["passages"]
    tot = sum(d["e"] for d in ps)
    print(f"      angle error at T {out['final']:+.2e} rad from {out['records']} records: "
          f"{len(ps)} of {out['count']} passages bracketed, passages {tot:+.2e}, between "
          f"{out['between']:+.2e}; below s 1e-4 in {sum(d['s'] < 1e-4 for d in ps)} passages",
          flush=True)
    print("      largest: " + "; ".join(
        f"t {d['t']:.3f} s {d['e']:+.2e} rad (min stage s {d['s']:.1e}, {d['tangent']} "
        f"tangent steps)" for d in ps[:3]), flush=True)


class _Recorder:
    """Records (t, q, qd, smallest stage s, tangent?) after every accepted Python step and
    every C stretch (there s is the last stage's: the C trial hands a stage below the
    switch to Python) of the integrator class `name` (wrapping _step_impl and advance in this
    process only; nothing in mbsim/ changes).  The C loop is held to 2 steps a call, so that
    a record falls at least every 2 steps; its controller carries over between calls, and
    the traced run's error at t_end is printed beside the bare run's to show they agree."""

    def __init__(self, name):
        from mbsim.integrators import INTEGRATORS

        self.cls, self.rows, self.saved = INTEGRATORS[name], [], {}
        rows = self.rows

        def record(self_, C=False):
            n = self_.n
            y = np.asarray(self_.y)
            rows.append((float(self_.t), y[:n].copy(), y[n:2 * n].copy(),
                         float(getattr(self_, "_s" if C else "_trial_s", math.nan)),
                         bool(getattr(self_, "_tangent", False) or
                              getattr(self_, "_step_tangent", False))))

        for meth in ("_step_impl", "advance"):
            orig = getattr(self.cls, meth, None)
            if orig is None:
                continue
            self.saved[meth] = self.cls.__dict__.get(meth)

            def wrapped(self_, *args, _orig=orig, _meth=meth, **kw):
                before = self_.t
                if _meth == "advance":  # at most 2 C steps a call (1 would be Python's)
                    args = (args[0], min(2, args[1] if len(args) > 1 else
                                         kw.pop("max_steps", 1))) + tuple(args[2:])
                res = _orig(self_, *args, **kw)
                if self_.t != before:
                    record(self_, C=_meth == "advance")
                return res

            setattr(self.cls, meth, wrapped)

    def remove(self):
        for meth, orig in self.saved.items():
            if orig is None:
                delattr(self.cls, meth)
            else:
                setattr(self.cls, meth, orig)


if __name__ == "__main__":
    sys.exit(main())
