"""Dynamic analysis (Haug Ch. 11): integrate the constrained equations of motion from
consistent initial conditions with one of the integrators of :mod:`mbsim.integrators`,
and estimate the global error of what it computed.

The analysis (options in, :class:`~mbsim.result.Result` out) is here; its parts are in
their own modules:

- :mod:`mbsim.analyses.trajectory`: the driver: set-up shared by every integration of the
  analysis, stepping with row re-selection, the state at the output times (dense output:
  output sampling is independent of the step size), and the channels and monitors of the
  kept run;
- :mod:`mbsim.analyses.estimate`: the global error estimate (a companion integration);
- :mod:`mbsim.analyses.accuracy`: ``accuracy``: the tolerance chosen from the estimate;
- :mod:`mbsim.analyses.diagnosis`: what is special where a run stopped.
"""

from __future__ import annotations

import time as _time

import numpy as np

from mbsim.analyses.accuracy import accuracy_with_fallback
from mbsim.analyses.estimate import attach_estimate, estimate
from mbsim.analyses.trajectory import Prepared, build_result, main_trajectory, motion_span
from mbsim.integrators import DEFAULT
from mbsim.options import NO_DECK, analysis_options

DEFAULTS = {"t_start": 0.0, "t_end": 1.0, "step": 0.01, "integrator": DEFAULT, "rtol": 1e-6,
            "atol": None, "h": None, "max_steps": 1_000_000, "tol": 1e-10, "sparse": None,
            "error_estimate": True, "estimate_method": "coarse", "estimate_ratio": 5.0,
            "accuracy": None}


def dynamic(model, options=None):
    """Run a dynamic analysis; returns a Result (status incomplete, with the data up to the
    failure, when the integrator fails).

    options: a :class:`~mbsim.options.RunOptions` (merged and checked where the run was
    requested, :func:`mbsim.options.run_options`, with the deck's settings and context), or
    a dict merged here over DEFAULTS alone and checked: t_start, t_end, step (output step, s),
    integrator (name, see
    ``mbsim list integrators``), rtol, atol, h (fixed step: no error control; a fixed-step
    method without h steps at ``step``), h_max, max_steps, sparse (None: by size), q0/qd0 (a
    consistent initial state instead of the deck's), error_estimate (bool, default True),
    estimate_ratio (rho, default 5), accuracy (the position error wanted, m, and
    orientation error, rad: chooses the tolerances, see
    :func:`mbsim.analyses.accuracy.accuracy_run`), and the integrator's own options
    (alpha, beta, rho_inf, repartition_ratio, jacobian, newton_tol).
    """
    wall0 = _time.perf_counter()
    options = analysis_options("dynamic", model, options, DEFAULTS)
    opt = dict(options)
    progress = opt.pop("progress", None)  # progress(t, t_end) per output (mbsim.progress)
    # NaN and overflow are detected and reported by the integrators (non-finite error norms,
    # states), so numpy's RuntimeWarning lines would only be noise on stderr
    with np.errstate(all="ignore"):
        if opt.get("accuracy") is not None:
            res = accuracy_with_fallback(model, opt, progress, options.given, options.deck,
                                         options.context)
        else:
            res = _single_run(model, opt, progress, options.context)
    res.wall_time = _time.perf_counter() - wall0
    return res


def _single_run(model, opt, progress=None, context=NO_DECK):
    """One integration with its error estimate: the Result of :func:`dynamic` (``context``:
    the run's :class:`~mbsim.options.DeckContext`)."""
    opt = dict(opt)
    prep = Prepared(model, opt, context)
    if not prep.cls.adaptive and opt.get("h") is None:
        opt["h"] = float(opt["step"])
    tr = main_trajectory(model, prep, opt, progress)
    est = None
    if tr.interrupted:  # the user asked to stop: not another integration now
        est = {"method": "not computed: the run was interrupted", "position": None,
               "reason": "the run was interrupted (Ctrl-C or SIGTERM) before t_end"}
    elif opt.get("error_estimate", True) and len(tr) >= 2:
        try:
            est = estimate(model, prep, opt, tr)
        except KeyboardInterrupt:  # outside the companion's own handling: the run is kept
            est = {"method": "not computed: the error estimate was interrupted",
                   "position": None,
                   "reason": "the error estimate was interrupted (Ctrl-C or SIGTERM)"}
    span = motion_span(model, tr)
    try:
        res = build_result(model, prep, opt, tr, span)
    except KeyboardInterrupt:  # after the integration: its outputs are built again, whole
        res = build_result(model, prep, opt, tr, span)
    if est is not None:
        attach_estimate(model, res, est, len(prep.times), span)
    return res

