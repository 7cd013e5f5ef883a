"""The completion's Newton stop (mbsim/integrators/changepoints.py, Policy.newton_tol and
NEWTON_FLOOR) on the four cranks with gcp-dop853: candidate stopping rules, and one stage
next to the flat position taken apart.

    python benchmarks/newton_floor.py --rules const:1e-12,const:2.22e-12,ball,stagnation
    python benchmarks/newton_floor.py --stage 0.463195 --floor 2.220446049250313e-12
    python benchmarks/newton_floor.py --ball
    python benchmarks/newton_floor.py --probe --floor 2.220446049250313e-12

--rules: the four cranks' position error (tests/integrators/test_singular_loops.run against
the exact reduction) with the completion's Newton stop replaced by each rule: ``const:F``
newton_tol = max(1e-2 atol, F) (the policy's form; F = 1e-12 is NEWTON_FLOOR); ``ball``
stop once max |dx| <= max(1e-2 atol, eps max |x| / s), s the pivot ratio of the factor just
solved with (the round-off of a correction through it); ``stagnation`` stop once max |dx|
<= max(1e-2 atol, eps max |x|) or the correction fails to halve (quadratic convergence
stopped: the corrections are round-off).
--stage T: the run with newton_tol's floor --floor, its tangent stage nearest time T taken
apart: the completion's q, qd and v'' = C qdd against the exact reduction at the same
(v, vd) (tests/integrators/models.py: parallel_fourbar_motion, theta'' in closed form), from
the stage's own prediction at several Newton tolerances, from the exact q, from the
completed q moved by 4 ulps, from the prediction moved by 1e-10 m (its own distance from
the solution) and by 4 ulps; then the run again with only that stage completed from the
exact q.  (The trial steps over T are printed with their error norms, those of the run's
error-estimate companion included.)
--ball: at crank angles theta from the flat position (C taken 0.06 rad from it, theta' = 10
rad/s), the completion from 16 starts 1e-10 m around the exact q (a prediction's distance) at
Newton tolerances 1e-12, 2.2e-12, 1e-14: the largest |q - q*| in units of the round-off ball
eps max|q| / s, and the largest v'' = C qdd error relative to |v''| in units of eps s^-2.
--probe: the run with newton_tol's floor --floor; after each accepted tangent step, its stage
with the smallest s completed twice again from its prediction moved by the prediction's own
distance max |prediction - q| (random directions), twice from the prediction moved by 4 ulps
(random signs) and twice from the completed q moved by 4 ulps; each pair's v'' difference
carried to the step's end (Policy.stage_reach) in tolerances.  Printed: the steps with a
stage below s = 1e-3 or a probe above one tolerance.
(DOP853's stages 2-5 have b = 0: their row of stage_reach is 0, their probe too.)
Set OPENBLAS_CORETYPE to compare BLAS kernels.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402

from mbsim.integrators import changepoints as cp  # noqa: E402
from mbsim.integrators import gcp as G  # noqa: E402
from tests.integrators import models as M  # noqa: E402
from tests.integrators import test_policy as TP  # noqa: E402
from tests.integrators import test_singular_loops as TS  # noqa: E402

ORIGINAL_NEWTON = cp.newton
ORIGINAL_FLOOR = cp.NEWTON_FLOOR


def rule_newton(rule):
    """changepoints.newton with the stop ``rule`` (module doc)."""

    def newton(system, t, q, correction, tol, max_iter):
        x = np.array(q, dtype=float)
        prev = np.inf
        for i in range(max_iter):
            T = system.terms(x, t, jac=True, nu=system.rheonomic)
            dx, fac = correction(T, x)
            x -= dx
            system.counters["newton_iterations"] += 1
            d = np.abs(dx).max(initial=0.0)
            if rule == "ball":
                stop = d <= max(
                    tol, cp.EPS * np.abs(x).max() / cp.measure_from_lu(fac, system.sparse)
                )
            else:
                stop = d <= max(tol, cp.EPS * np.abs(x).max()) or (i >= 1 and d > 0.5 * prev)
            if stop:
                return x, T, fac, True
            prev = d
        return x, T, fac, bool(np.abs(T.phi).max(initial=0.0) <= max(tol, 1e-12))

    return newton


def set_rule(rule):
    if rule.startswith("const:"):
        cp.newton, cp.NEWTON_FLOOR = ORIGINAL_NEWTON, float(rule[6:])
    elif rule in ("ball", "stagnation"):
        cp.newton, cp.NEWTON_FLOOR = rule_newton(rule), 0.0
    else:
        raise SystemExit(f"error: --rules: unknown rule {rule!r}")


def rules(names, rtols):
    print(f"{'rule':>28} " + " ".join(f"{'rtol ' + format(r, 'g'):>11}" for r in rtols))
    for rule in names:
        set_rule(rule)
        errs = [TS.run("gcp-dop853", rtol)[1] for rtol in rtols]
        print(f"{rule:>28} " + " ".join(f"{e:11.3g}" for e in errs), flush=True)
    set_rule(f"const:{ORIGINAL_FLOOR}")


class Exact:
    """The exact state of the four cranks at the tangent coordinates (v, vd): theta from
    C q(theta) = v by Newton, theta' from vd, theta'' in closed form."""

    def __init__(self):
        pb = M.reference_problem("parallel_fourbar")
        self.model = pb.model
        P = M.FOURBAR
        L, mc, Mc, g = P["L"], P["m_crank"], P["M"], P["g"]
        self.i_eff = 4 * (M.fourbar_crank_inertia(L, mc)[2] + mc * L * L / 4) + Mc * L * L
        self.grav = g * (4 * mc * L / 2 + Mc * L)
        self.o = 7 * self.model.body_names.index("crank0")

    def __call__(self, C, v, vd, q_near):
        o, motion = self.o, M.parallel_fourbar_motion
        th = 2 * np.arctan2(q_near[o + 6], q_near[o + 3])
        for _ in range(8):
            q, dq, _ = motion(self.model, th, 1.0, 0.0)
            th -= (C @ q - v)[0] / (C @ dq)[0]
        dq = motion(self.model, th, 1.0, 0.0)[1]
        thd = vd[0] / (C @ dq)[0]
        return motion(self.model, th, thd, -self.grav * np.cos(th) / self.i_eff)


@contextlib.contextmanager
def gcp_patched(floor, **methods):
    """NEWTON_FLOOR = floor and gcp's methods replaced (name=function) for the block, both
    restored after it."""
    cls = G.GeneralizedCoordinatePartitioning
    saved = {name: getattr(cls, name) for name in methods}
    cp.NEWTON_FLOOR = floor
    for name, f in methods.items():
        setattr(cls, name, f)
    try:
        yield
    finally:
        for name, f in saved.items():
            setattr(cls, name, f)
        cp.NEWTON_FLOOR = ORIGINAL_FLOOR


def stage(t_stage, floor, rtol):
    exact = Exact()
    captured = []
    original = G.GeneralizedCoordinatePartitioning._complete

    def capture(self, t, v, vd, part):
        if part.C is not None and abs(t - t_stage) < 2e-6 and not captured:
            captured.append((self, t, v.copy(), vd.copy(), part, self._pred.copy()))
        return original(self, t, v, vd, part)

    steps = []
    attempt = G.GeneralizedCoordinatePartitioning._attempt

    def record(self, h):  # the error test of each trial step over the stage
        t0, out = self.t, attempt(self, h)
        if t0 < t_stage < t0 + h:
            tab, scale = self.tableau, self._scale(self.y, out[1])
            e5 = h * (self.K.T @ tab.E5)[: scale.size] / scale
            e3 = h * (self.K.T @ tab.E3)[: scale.size] / scale
            steps.append((t0, h, tab.error_norm(self.K, h, scale), self._extra_error(h), e5, e3))
        return out

    with gcp_patched(floor, _complete=capture, _attempt=record):
        err = TS.run("gcp-dop853", rtol)[1]
    if not captured:
        raise SystemExit(f"error: --stage: no tangent stage within 2e-6 s of {t_stage}")
    integ, t, v, vd, part, pred = captured[0]
    system, C, k = integ.system, part.C, part.k
    qe, qde, qdde = exact(C, v, vd, pred)
    vdd = (C @ qdde)[0]
    s = cp.measure_from_lu(cp.factor(system, system.terms(qe, t, phi=False).jac, C), False)
    print(f"run: floor {floor:g}, rtol {rtol:g}: position error {err:.3g} m")
    for t0, h, e_v, e_q, e5, e3 in steps:
        print(
            f"trial step {t0:.6f} + {h:.4g} s: error norm (v, vd) {e_v:.3g}, full q "
            f"{e_q:.3g}; h err5 / scale (v, vd) = {e5[0]:.3g}, {e5[1]:.3g}; "
            f"h err3 / scale = {e3[0]:.3g}, {e3[1]:.3g}"
        )
    print(
        f"stage t = {t:.6f} s: s = {s:.3g}, v'' = {vdd:.6g}, |prediction - exact q| = "
        f"{np.abs(pred - qe).max():.3g} m, eps max|q| / s = "
        f"{cp.EPS * np.abs(qe).max() / s:.3g} m"
    )

    def complete(q0, tol):
        q, qd, fac, _ = cp.complete(system, t, q0, v, vd, C, tol, integ.policy.newton_iter)
        if qd is None:
            return q, None
        qdd = cp.accelerations(system, t, q, qd, fac, k)[0]
        return q, (np.abs(q - qe).max(), np.abs(qd - qde).max(), (C @ qdd)[0] - vdd)

    head = "v'' - v''*"
    print(f"{'start':>34} {'newton_tol':>10} {'|q - q*|':>9} {'|qd - qd*|':>10} {head:>10}")
    for tol in (floor, 1e-12, 3e-13, 1e-13):
        print(
            f"{'the prediction':>34} {tol:10.3g} "
            + "{:9.3g} {:10.3g} {:10.3g}".format(*complete(pred, tol)[1])
        )
    print(
        f"{'the exact q':>34} {floor:10.3g} "
        + "{:9.3g} {:10.3g} {:10.3g}".format(*complete(qe, floor)[1])
    )
    qc = complete(pred, floor)[0]
    rng = np.random.default_rng(1)
    for label, starts in (
        (
            "the completed q moved by 4 ulps",
            [qc + 4 * np.spacing(qc) * rng.choice([-1.0, 1.0], qc.size) for _ in range(8)],
        ),
        (
            "the prediction moved by 1e-10 m",
            [pred + 1e-10 * rng.standard_normal(pred.size) for _ in range(8)],
        ),
        (
            "the prediction moved by 4 ulps",
            [pred + 4 * np.spacing(pred) * rng.choice([-1.0, 1.0], pred.size) for _ in range(8)],
        ),
    ):
        dv = [complete(q0, floor)[1][2] for q0 in starts]
        print(f"{label:>34} {floor:10.3g} v'' - v''*: " + " ".join(f"{x:.2g}" for x in dv))

    once = []

    def from_exact(self, t_, v_, vd_, part_):
        if part_.C is not None and t_ == t and not once:
            once.append(t_)
            self._pred = exact(part_.C, v_, vd_, self._pred)[0]
        return original(self, t_, v_, vd_, part_)

    with gcp_patched(floor, _complete=from_exact):
        err = TS.run("gcp-dop853", rtol)[1]
    print(f"run with this stage completed from the exact q: position error {err:.3g} m")


def ball():
    tols = (1e-12, 2.220446049250313e-12, 1e-14)
    rng = np.random.default_rng(1)
    print(
        f"{'theta rad':>9} {'s':>8} " + " ".join(f"{'tol ' + format(t, '.2g'):>19}" for t in tols)
    )
    print(f"{'':>18} " + " ".join(f"{'|dq|/ball':>9} {'dv/eps s-2':>9}" for _ in tols))
    for theta in (3e-2, 1e-2, 3e-3, 1e-3, 3e-4, 1e-4):
        system, q, qd, qdd, C = TP.four_cranks_state(theta)  # (C taken 0.06 rad out)
        s = cp.measure_from_lu(cp.factor(system, system.terms(q, 0.0, phi=False).jac, C), False)
        width, vdd = cp.EPS * np.abs(q).max() / s, np.abs(C @ qdd).max()
        row = []
        for tol in tols:
            dq = dv = 0.0
            for _ in range(16):
                q0 = q + 1e-10 * rng.standard_normal(q.size)
                x, xd, fac, _ = cp.complete(system, 0.0, q0, C @ q, C @ qd, C, tol, 8)
                a = cp.accelerations(system, 0.0, x, xd, fac, C.shape[0])[0]
                dq = max(dq, np.abs(x - q).max() / width)
                dv = max(dv, np.abs(C @ (a - qdd)).max() / vdd / (cp.EPS / s**2))
            row.append(f"{dq:9.2g} {dv:9.2g}")
        print(f"{theta:9.0e} {s:8.2g} " + " ".join(row))


def probe(floor, rtol):
    rng = np.random.default_rng(7)
    stages, log = [], []
    complete0 = G.GeneralizedCoordinatePartitioning._complete
    attempt0 = G.GeneralizedCoordinatePartitioning._attempt

    def complete(self, t, v, vd, part):
        pred = None if self._pred is None else self._pred.copy()
        q, qd, fac = complete0(self, t, v, vd, part)
        if part.C is not None and pred is not None:
            s = cp.measure_from_lu(fac, self.system.sparse)
            stages.append((t, v.copy(), vd.copy(), pred, q.copy(), s))
        return q, qd, fac

    def attempt(self, h):
        stages.clear()
        t0, y0, part, tab = self.t, self.y.copy(), self.part, self.tableau
        out = attempt0(self, h)
        if part.C is None or out[0] > 1 or len(stages) < tab.n_stages:
            return out
        done = stages[: tab.n_stages]  # stages 1 ... n_stages - 1, then the end
        i = int(np.argmin([x[5] for x in done]))
        t, v, vd, pred, q, s = done[i]
        C, k = part.C, part.k

        def vdd(q0):
            x, xd, fac, _ = cp.complete(
                self.system, t, q0, v, vd, C, self.newton_tol, self.policy.newton_iter
            )
            if xd is None:
                return np.nan
            return (C @ cp.accelerations(self.system, t, x, xd, fac, k)[0])[0]

        reach = cp.Policy.stage_reach(tab, h)[i + 1]
        scale = self._scale(y0, out[1])
        d = np.abs(pred - q).max()
        near = [vdd(pred + d * rng.standard_normal(q.size)) for _ in range(2)]
        pred_ulps = [
            vdd(pred + 4 * np.spacing(pred) * rng.choice([-1.0, 1.0], q.size)) for _ in range(2)
        ]
        ulps = [vdd(q + 4 * np.spacing(q) * rng.choice([-1.0, 1.0], q.size)) for _ in range(2)]
        tols = [
            max(reach[0] * abs(a - b) / scale[k], reach[1] * abs(a - b) / scale[0])
            for a, b in (near, pred_ulps, ulps)
        ]
        log.append((t0, h, out[0], s, t, *tols))
        return out

    with gcp_patched(floor, _complete=complete, _attempt=attempt):
        err = TS.run("gcp-dop853", rtol)[1]
    print(f"run: floor {floor:g}, rtol {rtol:g}: position error {err:.3g} m")
    for t0, h, e, s, t, p_near, p_pred, p_ulps in log:
        if s < 1e-3 or max(p_near, p_pred, p_ulps) > 1:
            print(
                f"step {t0:.6f} + {h:.4g} s, error norm {e:.3g}: smallest s {s:.3g} at "
                f"{t:.6f} s; probes (tolerances) from the prediction moved by its distance "
                f"{p_near:.3g}, by 4 ulps {p_pred:.3g}; from the completed q moved by 4 ulps "
                f"{p_ulps:.3g}"
            )
    over = [sum(x[i] > 1 for x in log) for i in (5, 6, 7)]
    big = [max(x[i] for x in log) for i in (5, 6, 7)]
    print(
        f"accepted tangent steps {len(log)}; probes over 1 tolerance: {over[0]}, {over[1]}, "
        f"{over[2]}; largest {big[0]:.3g}, {big[1]:.3g}, {big[2]:.3g}"
    )


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rules", help="comma-separated stopping rules (module doc)")
    ap.add_argument("--rtols", default="1e-10,1e-11,1e-12")
    ap.add_argument("--stage", type=float, help="take the tangent stage nearest this time apart")
    ap.add_argument(
        "--floor",
        type=float,
        default=ORIGINAL_FLOOR,
        help="newton_tol's floor for --stage, --probe (m)",
    )
    ap.add_argument("--rtol", type=float, default=1e-11, help="the run's rtol for --stage, --probe")
    ap.add_argument("--ball", action="store_true", help="the completion's round-off ball")
    ap.add_argument("--probe", action="store_true", help="probe every accepted tangent step")
    args = ap.parse_args(argv)
    if args.rules:
        rules(args.rules.split(","), [float(r) for r in args.rtols.split(",")])
    if args.stage is not None:
        stage(args.stage, args.floor, args.rtol)
    if args.ball:
        ball()
    if args.probe:
        probe(args.floor, args.rtol)
    if not (args.rules or args.stage is not None or args.ball or args.probe):
        ap.error("give --rules, --stage, --ball or --probe")


if __name__ == "__main__":
    main()
