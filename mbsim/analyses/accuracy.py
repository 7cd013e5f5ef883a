"""``accuracy`` (a position error in m, orientation in rad): the dynamic run whose
estimated global error (:mod:`mbsim.analyses.estimate`) is within the request, the
tolerance chosen from the estimate of a first run (:func:`accuracy_run`), with the default
method as a fallback for a deck's method that cannot deliver
(:func:`accuracy_with_fallback`)."""

from __future__ import annotations

import logging
import math

from mbsim.analyses.estimate import attach_estimate, estimate
from mbsim.analyses.trajectory import Prepared, build_result, main_trajectory, motion_span
from mbsim.integrators import ALIASES, DEFAULT, INTEGRATORS
from mbsim.options import NO_DECK

log = logging.getLogger(__name__)

ACCURACY_START = 3e-3
"""--accuracy: first tolerance = this x the requested error (rtol = atol).  The ratio true
error / rtol of projection-dop853 on the reference problems is 1-650 at loose and 1-220 at
tight tolerances (largest on the fast top: orientation phase error over 300 rad of spin),
so tol/300 meets the request at the first attempt on all but the loosest top request, and
for an order-8 method a tolerance 100x tighter than needed costs only ~100^(1/9) = 1.7x
the steps, less than a missed attempt (benchmarks/accuracy.py; 0.2 missed on 12 of 15
cases and cost 2.5-3.7x the cheapest pair)."""
ACCURACY_MARGIN = 0.5  # a refinement aims at this fraction of the request


def accuracy_with_fallback(model, opt, progress, given, deck_opt, context=NO_DECK):
    """``accuracy``: the deck's integrator is a preference, one asked for by the caller
    (``--integrator``, the API's options) a requirement.  When the preferred method cannot
    deliver (the run stops, or no estimate covers it, or the request is missed), the
    default method is tried and the better of the two kept, saying so.  ``context``: the
    run's :class:`~mbsim.options.DeckContext`."""
    explicit = {k for k in ("integrator", "h") if k in given or (k == "h" and k in deck_opt)}
    res = accuracy_run(model, opt, progress, explicit, context)
    acc = res.summary["accuracy"]
    name = str(opt["integrator"])
    if ("integrator" in explicit or acc["met"] or acc.get("interrupted")
            or INTEGRATORS.get(ALIASES.get(name, name)) is INTEGRATORS[DEFAULT]):
        return res
    why = (res.message if not res.complete else acc.get("reason")
           or f"estimated {acc['estimate']:.3g} after {acc['runs']} run(s)")
    log.info("accuracy: the deck's integrator %s did not deliver (%s); trying %s", name, why,
             DEFAULT)
    alt = accuracy_run(model, dict(opt, integrator=DEFAULT, h=None), progress, set(), context)
    alt_acc = alt.summary["accuracy"]
    better = alt_acc["met"] or (alt.complete and not res.complete) or (
        alt.complete and math.isfinite(alt_acc["estimate"])
        and not alt_acc["estimate"] >= acc["estimate"])
    if not better:
        return res
    alt_acc["fallback"] = (f"the deck's integrator {name} could not deliver it ({why}); "
                           f"{DEFAULT} used instead")
    alt_acc["cpu"] += acc["cpu"]
    alt.summary.setdefault("warnings", []).append(f"--accuracy: {alt_acc['fallback']}")
    return alt


def accuracy_run(model, opt, progress, explicit, context=NO_DECK):
    """``accuracy`` = TOL: the run whose estimated position (m) and orientation (rad) errors
    are at most TOL.

    The integrator is the user's, else the default.  An adaptive method starts at
    rtol = atol = ACCURACY_START x TOL, a fixed-step one at its step; the error estimate of
    that run (its companion at rtol/rho, or h/2) decides.  If it missed, the tolerance (or
    step) is refined once by the measured ratio, assuming the error proportional to
    rtol^kappa (the method's error model, Integrator.error_ratio: kappa = 1 for the
    Runge-Kutta pairs, 2/3 for genalpha/hht above rtol 1e-6; h^p for a fixed step) and aiming at
    ACCURACY_MARGIN x TOL; when that refinement is no tighter than the companion's own
    setting, the companion (already computed, and about rho^kappa times more accurate)
    becomes the run and only a new companion is integrated.  Only the kept run's channels
    are computed."""
    tol = float(opt["accuracy"])
    opt = dict(opt, error_estimate=True)
    prep = Prepared(model, opt, context)
    cls = prep.cls
    fixed = (not cls.adaptive) or ("h" in explicit and opt.get("h") is not None)
    if fixed:
        opt["h"] = float(opt.get("h") or opt["step"])
    else:
        opt["rtol"] = opt["atol"] = ACCURACY_START * tol
    tr = main_trajectory(model, prep, opt, progress)
    history, cpu, est, companion = [], prep.cpu, None, None
    interrupted = False  # a Ctrl-C after a run that is kept whole
    while len(tr) >= 2 and not tr.interrupted:
        try:
            est = estimate(model, prep, opt, tr, companion)
        except KeyboardInterrupt:  # outside the companion's own handling: the run is kept
            est = {"method": "not computed: the error estimate was interrupted",
                   "position": None,
                   "reason": "the error estimate was interrupted (Ctrl-C or SIGTERM)"}
            interrupted = True
        e = (math.nan if est.get("position") is None
             else max(est["position"], est["orientation"]))
        cpu += tr.cpu + est.get("cpu", 0.0)
        history.append({"rtol": float(opt["rtol"]), "atol": float(opt["atol"]),
                        "h": opt.get("h"), "estimate": e, "status": tr.status,
                        "promoted": companion is not None})
        if e <= tol or not tr.complete or len(history) == 2 or est.get("position") is None:
            break
        ratio = min(max(ACCURACY_MARGIN * tol / e, 1e-4), 0.5)
        new = dict(opt)
        if fixed:
            new["h"] = float(opt["h"]) * ratio ** (1.0 / max(cls.order, 1))
        else:  # error ~ rtol^kappa (Integrator.error_ratio)
            ratio = cls.rtol_for_error_ratio(float(opt["rtol"]), ratio) / float(opt["rtol"])
            new["rtol"] = max(float(opt["rtol"]) * ratio, 1e-13)
            new["atol"] = max(float(opt["atol"]) * ratio, 1e-15)
        copt, comp = est["_copt"], est["_companion"]
        # (a companion of another method, estimate.fallback_companion, is not the run's)
        promote = (copt is not None and comp.complete
                   and copt.get("integrator") == opt.get("integrator")
                   and (new["h"] >= copt["h"] if fixed else new["rtol"] >= copt["rtol"]))
        log.info("accuracy %.3g: estimate %.3g missed; %s", tol, e,
                 "the companion becomes the run" if promote else
                 f"refining (rtol {new['rtol']:.3g}, h {new.get('h')})")
        if promote:
            opt, tr, companion = dict(copt, h0=opt.get("h0")), comp, None
        else:
            kept = (opt, tr)
            opt, companion = new, None
            tr = main_trajectory(model, prep, opt, progress)
            if tr.interrupted:  # the refinement stopped: the run before it is kept, whole
                cpu += tr.cpu
                (opt, tr), interrupted = kept, True
                break
    if est is not None:
        est = {k: v for k, v in est.items() if not k.startswith("_")}
    span = motion_span(model, tr)
    res = build_result(model, prep, opt, tr, span)
    if est is not None:
        attach_estimate(model, res, est, len(prep.times), span)
    e = history[-1]["estimate"] if history else math.nan
    # met: the run reached t_end and an estimate covering all of it is within the request
    met = bool(res.complete and e <= tol)
    res.summary["accuracy"] = {
        "requested": tol, "integrator": cls.name, "rtol": float(opt["rtol"]),
        "atol": float(opt["atol"]), "h": opt.get("h"), "runs": len(history),
        "estimate": e, "met": met, "cpu": cpu, "history": history,
        "interrupted": bool(tr.interrupted) or interrupted}
    if not math.isfinite(e):
        why = (est or {}).get("reason") or (est or {}).get("method") or "no run to compare"
        res.summary["accuracy"]["reason"] = str(why)
    if res.complete and not met:
        res.summary.setdefault("warnings", []).append(
            f"accuracy {tol:g} not reached: estimated error {e:.3g} after {len(history)} runs"
            if math.isfinite(e) else
            f"accuracy {tol:g} not checked: no error estimate covers the run "
            f"({res.summary['accuracy']['reason']})")
    res.settings["accuracy"] = tol
    return res


