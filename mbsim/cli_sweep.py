"""``mbsim sweep``: the click layer over :mod:`mbsim.sweep` (parse -> plan -> run -> lines ->
exit code). Registered by ``mbsim.cli._register_optional``; it imports ``mbsim.cli`` only
inside the command, so importing this module first does not loop.
"""

from __future__ import annotations

import math
import os
import re
import signal
import sys

import click

from mbsim.cli_options import (
    analysis_settings,
    deck_options,
    jobs_option,
    mode_option,
    quiet_option,
    settings_of,
)

# a Dask scheduler's address: [protocol://]host:port, the host a name, IPv4 or [IPv6]
SCHEDULER_ADDRESS = re.compile(r"(?:[a-z][a-z0-9+.-]*://)?(?:\[[0-9A-Fa-f:.]+\]|[^\s:/\[\]]+):\d{1,5}")


def _echo(line: str, err: bool = False) -> None:
    """click.echo, but a reader that went away (`mbsim sweep ... | head`) only silences the
    stream: the sweep goes on, its files and index are the output that matters."""
    try:
        click.echo(line, err=err)
    except BrokenPipeError:
        stream = sys.stderr if err else sys.stdout
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, stream.fileno())  # later writes and the exit's flush go nowhere
        os.close(devnull)


@click.command("sweep")
@click.argument("deck", type=click.Path(dir_okay=False))
@click.option("--param", "params", multiple=True, metavar="NAME=V1,V2,...",
              help="Values of a deck parameter (k=1000,2000) or key path "
                   "(forces.spring.c=10,20); repeatable: the cases are the product.")
@click.option("--zip", "zip_", is_flag=True,
              help="Take the --param lists element by element (equal lengths), not the product.")
@mode_option(help="Analysis to run for every case.")
@jobs_option(help="Parallel processes (default: min(CPUs, cases)); ignored with --scheduler.")
@click.option("-o", "--output", "out_dir",
              help="Folder for the case files and the index (default <deck>_<mode>_sweep).")
@click.option("--summary", "summaries", multiple=True, metavar="CHANNEL:NAME[:from=T]",
              help="A value per case in the index, e.g. bodies.spindle.omega.y:final or "
                   "bodies.spindle.omega.y:settle:from=0.1 (transition time after t = 0.1 s); "
                   "NAME is a study statistic: final, initial, min, max, absmax, mean, range, "
                   "t_max, t_min, t_absmax, period, settle (band=B, default 0.02), growth "
                   "(repeatable).")
@deck_options(set_help="Override a deck value in every case (repeatable).",
              scene_help="Apply a named scene of the deck to every case.")
@analysis_settings()
@click.option("--scheduler", metavar="ADDRESS",
              help="Run on a Dask cluster, e.g. tcp://host:8786 (pip install 'mbsim[cluster]').")
@quiet_option()
def sweep_command(deck, params, zip_, mode, jobs, out_dir, summaries, sets, scene, t_end, step,
                  integrator, rtol, atol, accuracy, error_estimate, method, scheduler, quiet):
    """Run DECK once per combination of --param values, in parallel; one HDF5 file per case
    and an index (index.csv, index.h5) in the output folder. Re-running the same command
    runs only the cases that are missing, failed or incomplete.

    Example: mbsim sweep models/governor.yaml --mode dynamic --scene governed
    --param k=1000,2000,3000 -j 2 --summary bodies.spindle.omega.y:final
    --summary bodies.spindle.omega.y:settle:from=0.1 -o gov_k
    """
    from mbsim.cli import _fail, _parse_sets, _warn, check_accuracy_alone
    from mbsim.errors import MbsimError, UsageError

    if hasattr(signal, "SIGPIPE"):
        # Python's own setting again (mbsim's main sets the default action, for `| head`):
        # the sweep talks to its workers through pipes and to a Dask scheduler through
        # sockets, where a peer that went away must be an error, not the silent end of the
        # sweep with its workers left running
        signal.signal(signal.SIGPIPE, signal.SIG_IGN)
    from mbsim.sweep import default_out_dir, parse_param, parse_summary, plan_sweep

    if scheduler is not None and not SCHEDULER_ADDRESS.fullmatch(scheduler):
        # Dask takes any text and fails 20-60 s later, with a traceback from its client's
        # __del__ ('nonsense'): the form is checked first
        _fail(UsageError(f"--scheduler {scheduler!r}: expected an address with a port, e.g. "
                         "tcp://10.0.0.5:8786"), deck)
    options = settings_of(locals())
    # the command line's tolerances and step are the same for every case: a bad one is a
    # usage error now (exit 2), not one failed case after another
    from mbsim.deck.limits import OPEN_UNIT
    from mbsim.deck.schema import ANALYSIS_SETTINGS
    from mbsim.options import resolve_options

    given = {k: v for k, v in options.items() if v is not None and k in (*OPEN_UNIT, "step")
             and k in ANALYSIS_SETTINGS.get(mode, ())}
    try:  # the values only: the deck and its cases are merged in each case's run_model
        check_accuracy_alone({k for k, v in options.items() if v is not None})
        resolve_options(mode, None, given, defaults={}, internal=False)
    except MbsimError as exc:
        _fail(exc, deck)
    try:
        plan = plan_sweep(
            deck, mode, [parse_param(p) for p in params],
            out_dir or default_out_dir(deck, mode, scene), zip_=zip_,
            overrides=_parse_sets(sets), scene=scene, options=options,
            summaries=[parse_summary(s) for s in summaries])
    except MbsimError as exc:
        _fail(exc, deck)
    from mbsim.lock import OutputLock
    from mbsim.sweep import prepare_out_dir

    try:
        prepare_out_dir(plan.out_dir)  # a folder that cannot be written: nothing has run
        # one sweep per folder: a second one is refused (exit 2) while this one holds
        # DIR/sweep.lock (released when this command ends, however it ends)
        lock = OutputLock(plan.out_dir / "sweep.lock", f"sweep folder {plan.out_dir}").acquire()
    except MbsimError as exc:
        _fail(exc, deck)
    _warn(lock.warnings)
    try:
        _run_and_report(plan, deck, mode, params, jobs, scheduler, quiet)
    finally:
        lock.release()


def _run_and_report(plan, deck, mode, params, jobs, scheduler, quiet) -> None:
    """Run the planned sweep, print its lines, exit with its code (sweep_command's tail)."""
    from mbsim.cli import EXIT_FAILED, EXIT_OK, EXIT_USAGE, _fail, _warn
    from mbsim.errors import MbsimError
    from mbsim.output.hdf5 import remove_stale_temporaries
    from mbsim.sweep import STATUS_COMPLETE, parse_param, run_sweep

    ncases = len(plan.cases)
    done = 0
    remove_stale_temporaries(plan.out_dir)  # .X.h5.tmp-PID of a sweep killed (kill -9) mid-write

    def on_case(rec) -> None:
        nonlocal done
        done += 1
        if quiet:
            return
        how = f"{rec.status} (kept: up to date)" if rec.skipped else rec.status
        wall = "wall -" if math.isnan(rec.wall_time) else f"wall {rec.wall_time:.3g} s"
        line = f"[{done}/{ncases}] {rec.case.name}: {how}, {wall}"
        if rec.message:
            line += f": {rec.message}"
        _echo(line)

    if not quiet:
        where = f"Dask scheduler {scheduler}" if scheduler else \
            f"up to {min(jobs or os.cpu_count() or 1, ncases)} process(es)"
        _echo(f"sweep: {ncases} case(s) of {mode} on {where} -> {plan.out_dir}")
    try:
        outcome = run_sweep(plan, on_case=on_case, jobs=jobs, scheduler=scheduler)
    except KeyboardInterrupt:
        _echo(f"error: interrupted after {done} of {ncases} case(s); finished files kept, "
              f"index written to {plan.out_dir}/index.csv (re-run the same command to "
              "continue)", err=True)
        sys.exit(EXIT_FAILED)
    except MbsimError as exc:
        _fail(exc, deck)
    except OSError as exc:  # the disk filled or went read-only under the sweep
        from mbsim.errors import AnalysisError

        _fail(AnalysisError(f"sweep into {plan.out_dir} stopped after {done} of {ncases} "
                            f"case(s): {exc.strerror or exc}; the files written are kept "
                            "(re-run the same command to continue)"), deck)
    counts = {s: outcome.count(s) for s in ("complete", "incomplete", "failed", "cancelled")}
    skipped = sum(r.skipped for r in outcome.records)
    if not quiet:
        listed = ", ".join(f"{n} {s}" for s, n in counts.items() if n)
        _echo(f"sweep: {listed} ({skipped} kept from an earlier run) -> "
              f"{outcome.index_csv}, {outcome.index_h5.name}")
    if mode == "linear":  # a root locus over the last --param, threshold by interpolation
        from mbsim.output.locus import sweep_root_locus

        path, found = sweep_root_locus(plan.out_dir, outcome.records,
                                       [parse_param(p).label for p in params])
        if path is not None and not quiet:
            _echo(f"root locus -> {path}")
            for c in found:
                grp = f" ({c.group})" if c.group else ""
                _echo(f"  stability threshold{grp}: {c.value:.6g} ({c.direction}; between "
                      f"{c.low:g} and {c.high:g}, linear interpolation of max Re(lambda))")
    _warn([e + " (value left empty)" for e in outcome.summary_errors])
    if outcome.summary_errors:
        sys.exit(EXIT_USAGE)
    bad = ncases - counts[STATUS_COMPLETE]
    if bad:
        _echo(f"error: {deck}: {bad} of {ncases} case(s) not complete "
              f"(see {outcome.index_csv})", err=True)
        sys.exit(EXIT_FAILED)
    sys.exit(EXIT_OK)

