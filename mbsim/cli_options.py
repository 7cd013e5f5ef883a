"""Click options shared by several commands, written once (run, sweep, study, info, check,
bench).

Each function returns a decorator that adds one option or a group of options with the same
parameter names in every command, so a command's signature reads the same everywhere.  A
command whose wording differs (``--set`` "in every case" for a sweep) passes its own help.
This module imports click only: ``mbsim --help`` lists the commands of every module that
uses it without importing numpy or the analyses.
"""

from __future__ import annotations

from collections.abc import Callable

import click

MODES = ("kinematic", "equilibrium", "inverse", "dynamic", "linear")  # mbsim.api.ANALYSES

SETTINGS = ("t_end", "step", "integrator", "rtol", "atol", "accuracy", "error_estimate",
            "method")  # the analysis settings of :func:`analysis_settings`, parameter names
SETTING_OPTIONS = {"t_end": "--t-end", "step": "--step", "integrator": "--integrator",
                   "rtol": "--rtol", "atol": "--atol", "accuracy": "--accuracy",
                   "error_estimate": "--error-estimate", "method": "--method"}
"""setting -> its command-line option, for error messages"""


def _stack(*decorators: Callable) -> Callable:
    """One decorator applying `decorators` so that they show in the help in the given order."""
    def apply(f: Callable) -> Callable:
        for d in reversed(decorators):
            f = d(f)
        return f

    return apply


def mode_option(help: str = "Analysis to run.") -> Callable:  # noqa: A002 - click's name
    """``--mode/-m``, one of :data:`MODES`, required."""
    return click.option("--mode", "-m", type=click.Choice(list(MODES)), required=True,
                        help=help)


def deck_options(set_help: str = "Override a deck value.",
                 scene_help: str = "Apply a named scene of the deck.") -> Callable:
    """``--set PATH=VALUE`` (parameter ``sets``, repeatable) and ``--scene``."""
    return _stack(
        click.option("--set", "sets", multiple=True, metavar="PATH=VALUE", help=set_help),
        click.option("--scene", help=scene_help),
    )


def analysis_settings(step_help: str = "Output step, s.",
                      integrator_help: str = "Integrator name (dynamic mode).") -> Callable:
    """The analysis settings of a run or a sweep (parameters :data:`SETTINGS`; None when
    not given): --t-end, --step, --integrator, --rtol, --atol, --accuracy,
    --error-estimate/--no-error-estimate, --method."""
    return _stack(
        click.option("--t-end", type=float, help="End time, s."),
        click.option("--step", type=float, help=step_help),
        click.option("--integrator", help=integrator_help),
        click.option("--rtol", type=float, help="Relative tolerance (dynamic mode)."),
        click.option("--atol", type=float, help="Absolute tolerance (dynamic mode)."),
        click.option("--accuracy", type=float, metavar="TOL",
                     help="Dynamic mode: the position error wanted (m; orientation, rad): mbsim "
                          "chooses the tolerance, checks its error estimate, refines once."),
        click.option("--error-estimate/--no-error-estimate", "error_estimate", default=None,
                     help="Dynamic mode: estimate the global error by a companion run "
                          "(default on)."),
        click.option("--method", help="Equilibrium method: minimum | settle | steady."),
    )


def settings_of(values: dict) -> dict:
    """The :data:`SETTINGS` of a command's parameters, as the analyses take them (all keys;
    None where not given)."""
    return {k: values[k] for k in SETTINGS}


def quiet_option(help: str = "Print nothing but errors.") -> Callable:  # noqa: A002
    """``-q/--quiet`` (a flag, parameter ``quiet``)."""
    return click.option("-q", "--quiet", is_flag=True, help=help)


JOBS_PER_CPU = 4  # most processes -j starts per CPU: each imports numpy (~50 MB), and cases
# are CPU-bound, so more only share the CPUs (`-j 100000` forked until the machine hung)


def _cap_jobs(ctx, param, value):
    """-j above JOBS_PER_CPU x the CPUs is lowered to that, with a warning line."""
    import os

    cap = JOBS_PER_CPU * (os.cpu_count() or 1)
    if value is not None and value > cap:
        click.echo(f"warning: --jobs {value} lowered to {cap} ({JOBS_PER_CPU} x the "
                   f"{os.cpu_count() or 1} CPUs of this machine)", err=True)
        return cap
    return value


def jobs_option(help: str, default: int | None = None) -> Callable:  # noqa: A002
    """``-j/--jobs``: processes that run cases at once: at least 1, at most JOBS_PER_CPU x
    the CPUs (more is lowered to that, with a warning)."""
    return click.option("-j", "--jobs", type=click.IntRange(min=1), default=default,
                        callback=_cap_jobs, show_default=default is not None, help=help)
