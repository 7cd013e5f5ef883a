"""Work-precision: every integrator over a ladder of tolerances (or steps) against a tight
reference run, as a table and a log-log plot of error against wall time.

Columns ``err/tol`` (achieved error / requested rtol: does the method keep its word?) and
``est/err`` (the run's own global error estimate / its error against the reference: is the
estimate honest?).  Times are of the run alone; the estimate is computed in a second run.

Error of a run: the largest absolute difference, over the output times and the chosen
channels (default: every body's centroid position ``bodies/*/r``), from the reference run
(``projection-dop853`` at rtol 1e-12 unless told otherwise).  Constraint drift: the largest
``monitors/position_violation``.  Wall time: the median of ``repeats`` runs, per simulated
second.  ``cost_to_reach`` interpolates, per integrator, the wall time per simulated second
needed for a target error (log-log between the two ladder points around it).
"""

from __future__ import annotations

import fnmatch
import time
from dataclasses import dataclass, field

import numpy as np

from mbsim.analyses.dynamic import dynamic
from mbsim.analyses.trajectory import integrator_class
from mbsim.integrators import INTEGRATORS
from mbsim.options import NO_DECK, context_options

TOLERANCES = (1e-3, 1e-5, 1e-7, 1e-9, 1e-11)
STEPS = (1e-2, 5e-3, 2.5e-3, 1.25e-3, 6.25e-4)  # fixed-step methods, s
REFERENCE = {"integrator": "projection-dop853", "rtol": 1e-12, "atol": 1e-14}


@dataclass
class BenchRow:
    integrator: str
    setting: str  # 'rtol=1e-06' or 'h=0.001'
    wall: float  # s per simulated second (median of the repeats)
    steps: int
    evaluations: int
    error: float  # max abs error of the chosen outputs against the reference
    drift: float  # max |Phi| over the run
    status: str = "complete"
    error_end: float = float("nan")  # the same at t_end only
    cpu: float = float("nan")  # CPU s per simulated second (median)
    requested: float = float("nan")  # the rtol asked for (nan for a fixed step)
    estimate: float = float("nan")  # the run's own error estimate (error_estimate.position)

    @property
    def achieved_ratio(self) -> float:
        """achieved error / requested tolerance: ~1 or below for a method that keeps its word"""
        return self.error / self.requested if self.requested > 0 else float("nan")

    @property
    def estimate_ratio(self) -> float:
        """the run's error estimate / its true error (1: exact; 0.1 .. 10: honest)"""
        return self.estimate / self.error if self.error > 0 else float("nan")


@dataclass
class Bench:
    deck: str
    t_end: float
    outputs: list[str]
    reference: dict
    rows: list[BenchRow] = field(default_factory=list)

    def table(self) -> str:
        """Plain-text table, one line per run."""
        head = (f"{'integrator':<18} {'setting':<11} {'wall s/s':>9} {'steps':>7} "
                f"{'f-evals':>8} {'max error':>10} {'err/tol':>8} {'est/err':>8} "
                f"{'drift':>9}  status")
        lines = [head, "-" * len(head)]
        for r in self.rows:
            lines.append(f"{r.integrator:<18} {r.setting:<11} {r.wall:9.4f} {r.steps:7d} "
                         f"{r.evaluations:8d} {r.error:10.3e} {r.achieved_ratio:8.3g} "
                         f"{r.estimate_ratio:8.3g} {r.drift:9.2e}  {r.status}")
        return "\n".join(lines)

    def cost_to_reach(self, target: float, key: str = "wall") -> dict[str, float]:
        """Wall (or CPU, key="cpu") s per simulated second to reach error `target`, per
        integrator (nan: not reached by the ladder)."""
        out = {}
        for name in dict.fromkeys(r.integrator for r in self.rows):
            rows = sorted((r for r in self.rows if r.integrator == name and r.status == "complete"
                           and np.isfinite(r.error) and r.error > 0),
                          key=lambda r: getattr(r, key))
            out[name] = interpolate_cost([(getattr(r, key), r.error) for r in rows], target)
        return out


def interpolate_cost(points, target):
    """Cost at error `target`, log-log between the two (cost, error) points around it
    (points sorted by cost); nan when the ladder does not reach it."""
    for (c0, e0), (c1, e1) in zip(points, points[1:]):
        if (e0 - target) * (e1 - target) <= 0 and e0 != e1:
            x = np.log(target / e0) / np.log(e1 / e0)
            return float(np.exp(np.log(c0) + x * np.log(c1 / c0)))
    ok = [c for c, e in points if e <= target]
    return float(min(ok)) if ok else float("nan")


def select_channels(result, patterns) -> list[str]:
    """Channel names matching the glob patterns (dots or slashes)."""
    names = []
    for pat in patterns:
        pat = pat.replace(".", "/")
        hit = [n for n in result.channels if fnmatch.fnmatch(n, pat)]
        if not hit:
            result.channel(pat)  # raises KeyError with a suggestion
        names += [h for h in hit if h not in names]
    return names


def _stack(result, names):
    return np.hstack([result.channels[n].data.reshape(len(result.t), -1) for n in names])


def work_precision(model, integrators=None, tolerances=TOLERANCES, steps=STEPS, t_end=1.0,
                   outputs=("bodies/*/r",), output_step=None, repeats=1, reference=None,
                   options=None, progress=None, low_order_rtol=1e-8,
                   context=NO_DECK) -> Bench:
    """Run the ladder (module doc).  integrators: names (default all); tolerances: rtol values
    of the adaptive methods (atol = 1e-2 rtol); steps: h of the fixed-step ones; options:
    extra dynamic options for every run (e.g. q0/qd0); progress: callback(row);
    low_order_rtol: second-order methods skip tighter tolerances (their step count grows as
    rtol^-1/2 there: minutes per run, nothing learnt); context: the deck's
    :class:`~mbsim.options.DeckContext` (its ``analysis: dynamic:`` settings under every
    run's, the assembly's hold: :func:`mbsim.options.deck_context`)."""

    def dynamic_run(opts):
        return dynamic(model, context_options("dynamic", context, opts))

    names = list(integrators or INTEGRATORS)
    classes = {n: integrator_class(n) for n in names}
    base = dict(options or {}, t_end=float(t_end),
                step=float(output_step or t_end / 20.0))
    ref_opts = dict(REFERENCE, **(reference or {}))
    ref = dynamic_run(dict(base, error_estimate=False, **ref_opts))
    if not ref.complete:
        raise RuntimeError(f"the reference run failed: {ref.message}")
    channels = [c for c in select_channels(ref, outputs) if not c.startswith("bodies/ground")]
    yref = _stack(ref, channels)
    bench = Bench(getattr(model, "file", ""), float(t_end), channels, ref_opts)
    for name in names:
        cls = classes[name]
        ladder = ([("rtol", tol) for tol in tolerances
                   if cls.order > 2 or tol >= low_order_rtol] if cls.adaptive
                  else [("h", h) for h in steps])
        for key, value in ladder:
            opts = dict(base, integrator=name)
            opts.update({"rtol": value, "atol": 1e-2 * value} if key == "rtol" else {"h": value})
            walls, cpus, res = [], [], None
            for _ in range(max(1, int(repeats))):
                # the run's cost without its error estimate (the estimate is timed apart)
                c0 = time.process_time()
                res = dynamic_run(dict(opts, error_estimate=False))
                cpus.append(time.process_time() - c0)
                walls.append(res.wall_time)
            est = dynamic_run(opts).summary.get("error_estimate", {}).get("position")
            n = min(len(res.t), len(ref.t))
            full = n == len(ref.t)
            dev = np.abs(_stack(res, channels)[:n] - yref[:n]) if n else np.zeros((0, 1))
            err = float(dev.max()) if full else float("nan")
            err_end = float(dev[-1].max()) if full else float("nan")
            drift = float(res.channel("monitors/position_violation").data.max()) if n else np.nan
            row = BenchRow(cls.name, f"{key}={value:g}", float(np.median(walls)) / t_end,
                           int(res.counters.get("steps", 0)),
                           int(res.counters.get("function_evaluations", 0)), err, drift,
                           res.status, err_end, float(np.median(cpus)) / t_end,
                           value if key == "rtol" else float("nan"),
                           float("nan") if est is None else float(est))
            bench.rows.append(row)
            if progress is not None:
                progress(row)
    return bench


ERROR_UNITS = {"r": "m", "position": "m", "rd": "m/s", "velocity": "m/s", "omega": "rad/s",
               "omega_local": "rad/s", "p": "-"}  # fmt: skip  # last segment of an output


def _error_unit(outputs) -> str:
    """The unit of the benchmarked outputs' error (their channels' unit), when they share one."""
    units = {ERROR_UNITS.get(o.rstrip("/").split("/")[-1], "?") for o in outputs}
    return units.pop() if len(units) == 1 and "?" not in units else "output units"


def work_precision_figure(bench: Bench, title: str = ""):
    """Log-log error against wall time per simulated second, one line per integrator
    (a matplotlib Figure, no pyplot)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7, 5), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    for name in dict.fromkeys(r.integrator for r in bench.rows):
        rows = [r for r in bench.rows if r.integrator == name and r.status == "complete"
                and np.isfinite(r.error) and r.error > 0]
        if rows:
            ax.loglog([r.wall for r in rows], [r.error for r in rows], "o-", label=name)
    ax.set_xlabel("wall time per simulated second [s/s]")
    ax.set_ylabel("max error of " + (", ".join(o.replace("/", ".") for o in bench.outputs[:3])
                                     + (" ..." if len(bench.outputs) > 3 else ""))
                  + f" [{_error_unit(bench.outputs)}]")
    ax.set_title(title or f"work-precision: {bench.deck} (t_end = {bench.t_end:g} s)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize="small")
    return fig
