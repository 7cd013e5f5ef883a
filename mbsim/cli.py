"""The command line: parse -> API call -> summary -> exit code.

Exit codes: 0 success; 1 the analysis failed part-way (partial results written, marked
incomplete) or a comparison found differences; 2 a deck or usage error.  Only this module
talks to the terminal; the library reports through exceptions, Results and ``logging``.
"""

from __future__ import annotations

import logging
import os
import signal
import sys
from pathlib import Path

import click

from mbsim import __version__
from mbsim.cli_options import (
    SETTING_OPTIONS,
    analysis_settings,
    deck_options,
    mode_option,
    quiet_option,
    settings_of,
)
from mbsim.errors import DeckError, MbsimError, UsageError

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2


MAX_MESSAGE = 600  # characters of an error line (user text inside is quoted at most ~80)


def _one_line(msg: str) -> str:
    msg = " ".join(str(msg).split())
    return msg if len(msg) <= MAX_MESSAGE else f"{msg[:MAX_MESSAGE]} ... (message cut)"


def _fail(exc: Exception, deck: str | None = None) -> None:
    """One line on stderr, then the exit code of the error's class (2 input, 1 analysis)."""
    code = getattr(exc, "exit_code", EXIT_FAILED)
    msg = str(exc).replace("\n", " ")
    if deck:
        msg = msg.replace("<deck>", str(deck))  # errors raised past the loader (--integrator)
    if deck and not isinstance(exc, DeckError) and not msg.startswith(str(deck)):
        msg = f"{deck}: {msg}"  # model/analysis errors name the deck too
    click.echo(f"error: {_one_line(msg)}", err=True)
    sys.exit(code)


def _check_settings(deck, mode: str, spec, opts: dict, names: dict[str, str]):
    """The run's settings merged and checked once (mbsim.options.run_options): the
    analysis's defaults, the deck's ``analysis: <mode>:``, the command line's ``opts``, with
    what the run takes from the deck besides the model (hold, ``outputs: only:``, text).  A
    problem names the option when it came from the command line (``names``: setting ->
    option), else the deck key (exit 2).  Returns the RunOptions for run_model."""
    from mbsim.options import run_options

    try:
        return run_options(mode, spec, opts, option_names=names, internal=False)
    except MbsimError as exc:
        _fail(exc, deck)


def overwrite_problem(path, inputs=(), hdf5: bool = False) -> str | None:
    """Why writing the output ``path`` would destroy a file the user keeps (None when it
    would not): ``-`` (a file named so, not standard output), one of the command's
    ``inputs`` (the deck of ``run -o``, the results file of ``export --csv``, also through a
    link), and a file of the other kind: an existing non-empty file that is not HDF5 where
    the command writes HDF5 (``hdf5``: a deck or script typed as ``-o``), an HDF5 file where
    it writes something else (CSV, HTML, a figure over a results file)."""
    import h5py

    path = Path(path)
    if str(path) == "-":
        return "'-': writing to standard output is not supported; give a file name"
    try:
        if not path.is_file():
            return None
    except OSError as exc:  # a name longer than the file system takes (ENAMETOOLONG)
        return f"output {path}: {exc.strerror or exc}"
    for f in inputs:
        try:
            if os.path.samefile(path, f):
                return (f"output {path} is the input file {f}; writing it would destroy it: "
                        "give another name")
        except OSError:  # an input that is not a file (a folder of cases): not this one
            continue
    try:
        is_hdf5 = h5py.is_hdf5(str(path))
        empty = path.stat().st_size == 0
    except OSError:
        return None  # unreadable: the write itself will say so
    if hdf5 and not is_hdf5 and not empty:
        return (f"output {path} exists and is not an HDF5 file (not an earlier result to "
                "replace); delete it or give another name")
    if not hdf5 and is_hdf5:
        return (f"output {path} is an HDF5 file (results?); it is not replaced by this "
                "output: delete it or give another name")
    return None


def _is_folder(path: Path) -> bool:
    """``path.is_dir()``, False where the name cannot be looked up (too long)."""
    try:
        return path.is_dir()
    except OSError:
        return False


SETTLE_ONLY = ("t_end", "step", "integrator", "rtol", "atol")  # settings of equilibrium's
# settling run: without it (--method minimum, steady) they would be ignored without a word


def _settle_only(mode: str, opts) -> None:
    """A command-line setting of the settling run given to an equilibrium by another method,
    or --accuracy with a tolerance, is a UsageError (exit 2)."""
    check_accuracy_alone(opts.given)
    if mode != "equilibrium" or opts.get("method") == "settle":
        return
    given = [SETTING_OPTIONS[k] for k in SETTLE_ONLY if k in opts.given]
    if given:
        raise UsageError(f"{given[0]} applies to --mode equilibrium only with --method settle "
                         f"(the method here is {opts.get('method')})")


def check_accuracy_alone(given) -> None:
    """--accuracy chooses the tolerances: with --rtol or --atol on the same command line
    (which it overrode without a word) a UsageError."""
    both = [SETTING_OPTIONS[k] for k in ("rtol", "atol") if k in given]
    if "accuracy" in given and both:
        raise UsageError(f"--accuracy and {both[0]}: give one (--accuracy chooses the "
                         "tolerances itself)")


def check_output(path, option: str, figure: bool = False, inputs=()) -> Path:
    """Before a command's work: ``path`` (given with ``option``) is not a folder, its folder
    exists and takes a new file, (``figure``) its suffix is a figure format, and writing it
    destroys neither one of the command's ``inputs`` nor a results file
    (:func:`overwrite_problem`); otherwise one ``error:`` line naming the option and the
    path, exit 2."""
    from mbsim.output.hdf5 import prepare_output

    try:
        if figure:
            from mbsim.output.plots import figure_suffix_problem

            why = figure_suffix_problem(path)
            if why:
                raise UsageError(why)
        why = overwrite_problem(path, inputs)
        if why:
            raise UsageError(why)
        return prepare_output(path)
    except UsageError as exc:
        _fail(UsageError(f"{option}: {exc}"))


def _warn(lines) -> None:
    for w in lines:
        click.echo(f"warning: {w}", err=True)


def _parse_sets(sets: tuple[str, ...]) -> dict[str, str]:
    out = {}
    for s in sets:
        if "=" not in s:
            raise click.UsageError(f"--set {s!r}: expected PATH=VALUE, e.g. parameters.k=2000")
        k, v = s.split("=", 1)
        out[k.strip()] = v.strip()
    return out


def _load(deck, sets=(), scene=None, studies=True):
    from mbsim.api import load_model

    spec, model = load_model(deck, overrides=_parse_sets(sets), scene=scene, studies=studies)
    _warn(spec.warnings)
    return spec, model


class _ErrorsOnly:
    """stderr under -q: only the ``error:`` lines get through (warnings and logs do not)."""

    def __init__(self, stream):
        self._stream = stream

    def write(self, text):
        if text.startswith("error:"):
            return self._stream.write(text)
        return len(text)

    def __getattr__(self, name):
        return getattr(self._stream, name)


class _EchoHandler(logging.Handler):
    """Log records to the current sys.stderr (click's test runner swaps it per call)."""

    def emit(self, record):
        try:
            click.echo(self.format(record), err=True)
        except Exception:  # noqa: BLE001 - logging must never break a run
            self.handleError(record)


_HANDLER = _EchoHandler()
_HANDLER.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
VERBOSE = ("-v", "-vv", "-vvv", "--verbose")
_NO_ARGS = getattr(click.exceptions, "NoArgsIsHelpError", ())  # click >= 8.2


def setup_logging(verbose: int, quiet: bool = False) -> None:
    """mbsim's own loggers ("mbsim", "mbsim.*") at INFO with -v, DEBUG with -vv, ERROR with
    -q; everything else (h5py, matplotlib) stays at WARNING."""
    level = logging.ERROR if quiet else logging.WARNING - 10 * min(verbose, 2)
    root = logging.getLogger()
    if _HANDLER not in root.handlers:
        root.addHandler(_HANDLER)
    root.setLevel(logging.WARNING if not quiet else logging.ERROR)
    _HANDLER.setLevel(level)
    logging.getLogger("mbsim").setLevel(level)
    logging.getLogger("py.warnings").setLevel(logging.DEBUG if verbose >= 2 else logging.ERROR)


class _NoErrstate:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def _raise_interrupt(signum, frame):
    raise KeyboardInterrupt


def _sigterm_as_interrupt():
    """SIGTERM raises KeyboardInterrupt, as Ctrl-C does, where it still has its default
    action (main thread only); returns the handler to restore, or None."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        return None
    old = signal.getsignal(signal.SIGTERM)
    if old not in (signal.SIG_DFL, None):
        return None
    signal.signal(signal.SIGTERM, _raise_interrupt)
    return old


class LazyGroup(click.Group):
    """Commands contributed by other modules, imported only when listed or invoked (keeps
    `mbsim --help` fast and avoids import cycles: those modules import helpers from here).

    Also the one place that turns click's own usage errors into one ``error:`` line with exit
    2, and that reads ``-v``/``-vv``/``-q`` wherever they stand on the command line (before
    or after the subcommand; a subcommand with its own ``-q`` keeps it)."""

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True,
             **extra):  # fmt: skip
        args = list(sys.argv[1:] if args is None else args)
        verbose, quiet, rest = 0, False, []
        cut = args.index("--") if "--" in args else len(args)
        cmd = next((a for a in args[:cut] if not a.startswith("-")), None)
        own_q = cmd in ("run", "sweep", "study")
        for i, a in enumerate(args):
            if i < cut and a in VERBOSE:
                verbose += 2 if a == "-vv" else 3 if a == "-vvv" else 1
            elif i < cut and a in ("-q", "--quiet"):
                quiet = True
            else:
                rest.append(a)
        if quiet and own_q:  # the subcommand's own -q decides what it prints
            rest.insert(rest.index(cmd) + 1, "-q")
        setup_logging(verbose, quiet)
        if not standalone_mode:
            return super().main(rest, prog_name, complete_var, False, **extra)
        old_out, old_err = sys.stdout, sys.stderr
        if quiet:
            sys.stderr = _ErrorsOnly(sys.stderr)
            if not own_q:
                sys.stdout = _ErrorsOnly(sys.stdout)
        # numpy's floating-point warnings are off and other warnings are log records (shown
        # with -vv): overflow and NaN are reported as errors where they matter, never as
        # stray lines; both are restored afterwards (the CLI also runs in-process in tests).
        # (numpy is imported here only for a command that runs: `mbsim --help` needs none)
        help_only = cmd is None or any(a in ("-h", "--help", "--version") for a in args[:cut])
        errstate = _NoErrstate()
        logging.captureWarnings(True)
        # the commands set SIGPIPE's action for the process (`main`, `sweep`); an in-process
        # call (a script, the tests) gets its own back, or a later pipe to a gone worker
        # would end that process silently
        sigpipe = signal.getsignal(signal.SIGPIPE) if hasattr(signal, "SIGPIPE") else None
        # SIGTERM as Ctrl-C from here on (it killed a command silently, exit -15, while it
        # loaded its modules and the deck): one `error: interrupted` line, exit 1
        sigterm = _sigterm_as_interrupt()
        try:
            if not help_only:  # inside the try: Ctrl-C while numpy loads is an interrupt
                entered = __import__("numpy").errstate(all="ignore")
                entered.__enter__()
                errstate = entered  # left in the finally below once entered
            rv = super().main(rest, prog_name, complete_var, False, **extra)
        except _NO_ARGS as exc:  # `mbsim` alone: the help, as click prints it
            click.echo(exc.ctx.get_help())
            sys.exit(EXIT_USAGE)
        except click.exceptions.UsageError as exc:  # also BadParameter, NoSuchOption
            path = exc.ctx.command_path if exc.ctx is not None else "mbsim"
            click.echo(f"error: {path}: {_one_line(exc.format_message())} "
                       f"(see '{path} --help')", err=True)  # fmt: skip
            sys.exit(EXIT_USAGE)
        except (click.exceptions.Abort, KeyboardInterrupt):  # Ctrl-C outside an analysis
            click.echo("error: interrupted", err=True)  # (or EOF at a prompt)
            sys.exit(EXIT_FAILED)
        except click.exceptions.ClickException as exc:  # file errors and the like
            click.echo(f"error: {_one_line(exc.format_message())}", err=True)
            sys.exit(exc.exit_code)
        finally:
            sys.stdout, sys.stderr = old_out, old_err
            if sigterm is not None:
                signal.signal(signal.SIGTERM, sigterm)
            if sigpipe is not None and signal.getsignal(signal.SIGPIPE) != sigpipe:
                signal.signal(signal.SIGPIPE, sigpipe)
            logging.captureWarnings(False)
            errstate.__exit__(None, None, None)
        sys.exit(rv if isinstance(rv, int) else EXIT_OK)

    LAZY = {
        "bench": ("mbsim.cli_dynamic", "bench_command"),
        "sweep": ("mbsim.cli_sweep", "sweep_command"),
        "study": ("mbsim.cli_study", "study_command"),
        "animate": ("mbsim.cli_study", "animate_command"),
        "view": ("mbsim.cli_view", "view_command"),
    }

    def list_commands(self, ctx):
        return sorted(set(super().list_commands(ctx)) | set(self._available()))

    def _available(self):
        import importlib.util

        return [n for n, (mod, _) in self.LAZY.items() if importlib.util.find_spec(mod)]

    def get_command(self, ctx, name):
        cmd = super().get_command(ctx, name)
        if cmd is None and name in self.LAZY:
            import importlib

            mod, attr = self.LAZY[name]
            try:
                cmd = getattr(importlib.import_module(mod), attr)
            except ImportError:
                return None
        return cmd


@click.group("mbsim", cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="mbsim")
@click.option("-v", "--verbose", count=True,
              help="Log mbsim's progress (-vv for debug); also after the command.")
@click.option("-q", "--quiet", is_flag=True, help="Print nothing but the error line.")
def main(verbose: int, quiet: bool) -> None:
    """mbsim: spatial multibody kinematics and dynamics (Haug 1989) from YAML decks."""
    if hasattr(signal, "SIGPIPE"):  # `mbsim info deck | head` ends quietly, as cat does
        signal.signal(signal.SIGPIPE, signal.SIG_DFL)
    # -v/-q were read by LazyGroup.main (they may also follow the subcommand)
    import mbsim.fast  # light: the C kernels load on first use

    mbsim.fast.on_compile = lambda line: click.echo(line, err=True)  # one line, first run only


@main.command()
@click.argument("deck", type=click.Path(dir_okay=False))
@mode_option()
@click.option("-o", "--output", help="Results file (HDF5); may hold {param} fields. "
              "Default: <deck>_<mode>.h5")
@deck_options(set_help="Override a deck value, e.g. parameters.k=2000 (repeatable).")
@analysis_settings(step_help="Output step, s (fixed step for fixed-step methods).",
                   integrator_help="Integrator name (dynamic mode); see `mbsim list "
                                   "integrators`.")
@click.option("--plot", "make_plot", is_flag=True, help="Also write a PNG of the main outputs.")
@quiet_option()
@click.option("--progress/--no-progress", default=None,
              help="Progress line on stderr (default: when stderr is a terminal and not -q).")
def run(deck, mode, output, sets, scene, t_end, step, integrator, rtol, atol, accuracy,
        error_estimate, method, make_plot, quiet, progress):
    """Run an analysis of DECK and write the results to HDF5.

    Example: mbsim run models/governor.yaml --mode dynamic --t-end 2 -o gov.h5
    """
    from mbsim.api import interrupted_result, output_path, run_model
    from mbsim.lock import OutputLock, lock_path
    from mbsim.output import write_result
    from mbsim.output.hdf5 import prepare_output
    from mbsim.progress import terminal_progress

    lock = signals = None
    try:
        spec, model = _load(deck, sets, scene, studies=False)  # `mbsim check` validates them
        out = output_path(output, deck, mode, spec.parameters, scene)
        opts = settings_of(locals())
        opts = {k: v for k, v in opts.items() if v is not None}
        opts = _check_settings(deck, mode, spec, opts, SETTING_OPTIONS)
        _settle_only(mode, opts)
        why = overwrite_problem(out, inputs=(deck,), hdf5=True)
        if why:
            raise UsageError(f"-o: {why}")
        prepare_output(out)  # before the analysis: a bad -o costs nothing
        # SIGTERM as Ctrl-C from before the lock is taken: a kill at any point after it
        # goes through the finally below, never leaving the lock behind
        with _Interrupts() as signals:
            # one writer per file: a second run to the same -o is refused (exit 2) while
            # this one holds OUT.lock (released below, also on errors and Ctrl-C)
            lock = OutputLock(lock_path(out), f"output {out}").acquire()
            _warn(lock.warnings)
            prog = terminal_progress(sys.stderr, False if quiet and progress is None
                                     else progress, label=mode)
            if prog is not None:
                opts = opts.replace(progress=prog)  # progress(t, t_end) per output
            result = None
            try:
                result = run_model(model, mode, opts, keep_start_failure=True)
                signals.hold()  # from here a signal waits until the file is written
            except KeyboardInterrupt:  # outside the analysis' own handling of it
                signals.hold()
                if result is None:
                    result = interrupted_result(mode)
            finally:
                if prog is not None:
                    prog.close()
            result.settings.pop("progress", None)  # an analysis that stored it as a setting
            result.settings.setdefault("overrides", _parse_sets(sets))
            if scene:
                result.settings.setdefault("scene", scene)
            write_result(result, out)
    except MbsimError as exc:
        _fail(exc, deck)
    finally:
        if lock is not None:
            lock.release()
    if signals is not None and signals.held:
        click.echo(_one_line(f"error: {deck}: interrupted (Ctrl-C or SIGTERM) after the "
                             f"analysis; its results are kept in {out}"), err=True)
        sys.exit(EXIT_FAILED)
    if not quiet:
        _warn(result.summary.get("warnings", ()))  # standard error, as cli.md says
    if make_plot:
        _default_plot(result, out.with_suffix(".png"), quiet)
    if not quiet:
        _summary(result, out)
    if not result.complete:
        kept = (f"results up to t = {result.t[-1]:.6g} s kept in {out}" if len(result.t)
                else f"no output reached; {out} written")
        click.echo(_one_line(f"error: {deck}: {result.message} ({kept}, marked incomplete)"),
                   err=True)
        sys.exit(EXIT_FAILED)
    if signals.caught:  # taken by a part the analysis may skip (the error estimate's
        # companion) after the run reached t_end: its results are whole, the command was not
        estimate = result.summary.get("error_estimate")
        without = (", without an error estimate" if isinstance(estimate, dict)
                   and estimate.get("position") is None else "")
        click.echo(_one_line(f"error: {deck}: interrupted (Ctrl-C or SIGTERM) after the run "
                             f"reached its end; its results are kept in {out}, complete"
                             f"{without}"), err=True)
        sys.exit(EXIT_FAILED)


class _Interrupts:
    """Ctrl-C and SIGTERM (kill, a CI timeout) while a run holds its output.

    During the analysis both raise KeyboardInterrupt: the analyses catch it and return the
    outputs reached, marked incomplete (``caught`` records it: a part that may be skipped,
    the error estimate's companion, takes it and returns the whole run).  After
    :meth:`hold` (the analysis has returned) a signal only sets ``held``: the results file
    is written whole, and the caller then ends the run.  Only in the main thread (signal
    handlers cannot be set elsewhere)."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __enter__(self):
        import threading

        self.old, self.raising, self.held, self.caught = {}, True, False, False
        if threading.current_thread() is threading.main_thread():
            self.old = {sig: signal.signal(sig, self._handle) for sig in self.SIGNALS}
        return self

    def _handle(self, signum, frame):
        if self.raising:
            self.caught = True  # the analysis may catch it and still return whole results
            raise KeyboardInterrupt
        self.held = True

    def hold(self):
        self.raising = False

    def __exit__(self, *exc):
        for sig, old in self.old.items():
            signal.signal(sig, old)
        return False


def _describe_estimate(key, v) -> str:
    """One line for the dynamic analysis' error estimate or accuracy choice."""
    import numpy as np

    if key == "accuracy":
        step = f", h = {v['h']:.3g} s" if v.get("h") else f", rtol = atol = {v['rtol']:.3g}"
        if v.get("estimate") is None or not np.isfinite(v["estimate"]):
            verdict = f"no estimate covers the run ({v.get('reason', 'not computed')}), NOT met"
        else:
            verdict = f"estimated {v['estimate']:.3g}, {'met' if v.get('met') else 'NOT met'}"
        fallback = f"; {v['fallback']}" if v.get("fallback") else ""
        return (f"requested {v['requested']:.3g} (m, rad): {v['integrator']}{step}; {verdict}; "
                f"{v['runs']} run(s), {v['cpu']:.3g} CPU s in all{fallback}")
    if v.get("position") is None:
        return f"none: {v.get('reason') or v.get('method', 'not available')}"
    note = f"; {v['note']}" if v.get("note") else ""
    return (f"position {v['position']:.3g} m, orientation {v['orientation']:.3g} rad, "
            f"velocity {v['velocity']:.3g} m/s ({v['method']}; +{100 * v['relative_cost']:.0f} % "
            f"CPU){note}")


SUMMARY_INTERNALS = ("sparse", "equations", "formulation", "t_reached", "row_changes")
SUMMARY_DIGITS = 4  # significant digits of the numbers a summary prints (the file keeps all)


def _value_text(v) -> str:
    """A summary value for the terminal: floats to SUMMARY_DIGITS significant digits."""
    import numpy as np

    if isinstance(v, (bool, type(None), str, int)):
        return str(v)
    if isinstance(v, (float, np.floating)):
        return f"{v:.{SUMMARY_DIGITS}g}"
    if isinstance(v, (complex, np.complexfloating)):
        return f"{v.real:.{SUMMARY_DIGITS}g}{v.imag:+.{SUMMARY_DIGITS}g}j"
    if isinstance(v, (list, tuple)):
        if len(v) > 8:
            return f"[{len(v)} values]"
        return "[" + ", ".join(_value_text(x) for x in v) + "]"
    return str(v)


def _summary(result, out) -> None:
    """The run's findings, rounded; internals (solver switches, empty lists, None, counters
    that stayed 0) only with -v."""
    verbose = logging.getLogger("mbsim").isEnabledFor(logging.INFO)
    nt = len(result.t)
    span = f"t = {result.t[0]:.6g} .. {result.t[-1]:.6g} s, {nt} outputs" if nt else "no outputs"
    click.echo(f"{result.mode}: {result.status}; {span}; wall {result.wall_time:.3g} s -> {out}")
    if result.mode == "linear":
        _linear_table(result)
        return
    for k, v in result.summary.items():
        empty = v is None or v is False or (isinstance(v, (list, tuple, dict)) and not v)
        if k == "warnings" or (not verbose and (k in SUMMARY_INTERNALS or empty)):
            continue  # warnings: on standard error already
            continue
        if k in ("error_estimate", "accuracy") and isinstance(v, dict):
            click.echo(f"  {k}: {_describe_estimate(k, v)}")
            continue
        if k == "events" and isinstance(v, list):
            click.echo(f"  events: {_events_text(v, result)}")
            continue
        if isinstance(v, dict):
            v = f"({len(v)} entries, stored in the file's summary)"
        click.echo(f"  {k}: {_value_text(v)}")
    counters = {k: v for k, v in result.counters.items() if verbose or v}
    if counters:
        click.echo("  " + ", ".join(f"{k} {_value_text(v)}" for k, v in counters.items()))


SUMMARY_EVENTS = 6  # events listed on the terminal (all are in the file)


def _events_text(events, result) -> str:
    """'n: name at t s (element: mode a -> b), ...' for the first SUMMARY_EVENTS events."""
    total = len(result.arrays.get("events/time", ((),))[0]) or len(events)
    parts = []
    for e in events[:SUMMARY_EVENTS]:
        text = f"{e['event']} at {e['t']:.9g} s"
        if "mode" in e:
            text += f" ({e.get('element', '')}: {e['mode']})"
        parts.append(text)
    more = f", ... ({total} in all; the file's events/time)" if total > len(parts) else ""
    return f"{total}: " + ", ".join(parts) + more


def _linear_table(result) -> None:
    """The linear analysis: verdict, neutral modes and one line per eigenvalue (units in
    the header; conjugate pairs shown once)."""
    import numpy as np

    s = result.summary
    click.echo(f"  about: {s['about']}; {s['dof']} independent coordinates")
    click.echo(f"  stability: {s['stability']} (stable: {s['stable']})")
    for name in s.get("neutral_modes", []):
        click.echo(f"  neutral: {name}")
    lam = result.arrays["linear/eigenvalues"][0]
    neutral = result.arrays["linear/neutral"][0]
    growing = result.arrays["linear/growing"][0] if "linear/growing" in result.arrays else \
        np.zeros(len(lam), bool)  # a file written before the mask was stored
    zeta = result.arrays["linear/damping_ratio"][0]
    click.echo("  mode  Re(lambda) 1/s  Im(lambda) rad/s  f_n Hz      omega_n rad/s  zeta")
    for k, lk in enumerate(lam):
        if lk.imag < 0 and not neutral[k]:
            continue  # the conjugate of the line above
        note = "  neutral" if neutral[k] else ("  growing" if growing[k] else "")
        wn = 0.0 if neutral[k] else abs(lk)
        click.echo(f"  {k + 1:4d}  {lk.real:14.6g}  {abs(lk.imag):16.6g}  {wn / 2 / np.pi:10.6g}"
                   f"  {wn:13.6g}  {(zeta[k] if abs(zeta[k]) > 1e-9 else 0.0):6.4g}{note}")
    extra = {k: s[k] for k in ("residual", "fd_check", "jacobian") if k in s}
    click.echo("  " + "; ".join(f"{k}: {v:.3g}" if isinstance(v, float) else f"{k}: {v}"
                                for k, v in extra.items()))


def _default_plot(result, path: Path, quiet: bool = False) -> None:
    """--plot: the quick look of mbsim.output.quicklook (by mode), saved as PNG."""
    from mbsim.output import save_figure
    from mbsim.output.quicklook import quick_look

    fig = quick_look(result)
    if fig is None:
        return
    save_figure(fig, path)
    if not quiet:
        click.echo(f"  plot -> {path}")


@main.command()
@click.argument("deck", type=click.Path(dir_okay=False))
@deck_options()
def info(deck, sets, scene):
    """Print the kinematic model as the book lists it: bodies, nc, constraints, nh, DOF,
    and the rank of Phi_q at the assembled configuration.

    Example: mbsim info models/governor.yaml
    """
    from mbsim.analyses.assembly import assemble

    try:
        spec, model = _load(deck, sets, scene)
    except MbsimError as exc:
        _fail(exc, deck)
    nc = model.nq
    click.echo(f"{model.title or Path(deck).name}")
    click.echo("Bodies")
    click.echo(f"  {model.nb} bodies{'':<31}nc = {nc}")
    for n in model.body_names:
        b = spec.bodies[n]
        tag = "ground" if b.ground else f"m = {b.mass:g} kg"
        click.echo(f"    {n:<24} {tag}")
    click.echo("Constraints")
    nh = 0
    groups: dict[str, int] = {}
    for it in model.items:
        if it.kind in ("joint", "driver"):
            label = f"{it.type} {'driver' if it.kind == 'driver' else 'joint'}: {it.name}"
            click.echo(f"  {label:<40}{it.rows.size}")
        else:
            groups[it.kind] = groups.get(it.kind, 0) + it.rows.size
        nh += it.rows.size
    if groups.get("ground"):
        click.echo(f"  {'Ground constraint':<40}{groups['ground']}")
    click.echo(f"  {'Euler parameter normalization':<40}{groups.get('normalization', 0)}")
    click.echo(f"  {'':<40}nh = {nh}")
    click.echo(f"DOF = {nc} - {nh} = {nc - nh}")
    try:
        asm = assemble(model, hold=_hold(spec))
        red = f"redundant: {', '.join(asm.redundant_items)}" if asm.redundant_items else \
            "no redundant constraints"
        click.echo(f"Rank of Phi_q at the assembled configuration: {asm.rank} of {model.m} rows "
                   f"({red}); DOF = {asm.dof}")
        _info_forces(spec, model)
    except MbsimError as exc:
        click.echo(f"assembly failed: {exc}", err=True)
        sys.exit(EXIT_FAILED)


def _hold(spec) -> tuple[str, ...]:
    """The deck's ``analysis.assembly.hold`` (the model does not carry its deck)."""
    from mbsim.options import deck_context

    return deck_context(spec, shapes=False).hold


def _info_forces(spec, model) -> None:
    """The force elements: type, name, bodies and the element's own line (``describe``)."""
    if not model.forces:
        return
    click.echo("Forces")
    for el in model.forces:
        bodies = ", ".join(b for b in spec.forces[el.name].bodies if b)
        line = f"  {el.type + ' force: ' + el.name:<40}{bodies}"
        if hasattr(el, "describe"):
            line += f"; {el.describe(model)}"
        click.echo(line)


@main.command()
@click.argument("deck", type=click.Path(dir_okay=False))
@deck_options()
@click.option("-n", "--worst", type=click.IntRange(min=0), default=5, show_default=True,
              help="How many residuals to print.")
def check(deck, sets, scene, worst):
    """Validate DECK, assemble it, and print the worst constraint residuals before and after.

    Example: mbsim check models/slider_crank.yaml
    """
    import numpy as np

    from mbsim import core
    from mbsim.analyses.assembly import assemble

    try:
        spec, model = _load(deck, sets, scene)
        ph0 = core.phi(model, None, model.q0)
    except MbsimError as exc:
        _fail(exc, deck)

    def estimates():
        click.echo(f"deck estimates: max |Phi| = {np.abs(ph0).max(initial=0):.3e}")
        for r in np.argsort(-np.abs(ph0))[:worst]:
            if abs(ph0[r]) > 0:
                click.echo(f"    {model.row_label[r]:<40} {ph0[r]: .3e}")

    try:
        asm = assemble(model, lapack=False, hold=_hold(spec))  # numpy QR: no scipy import
    except MbsimError as exc:  # the residuals at the estimates say where to look
        click.echo(f"{deck}: {model.nb} bodies, {model.m} constraint equations; "
                   "assembly failed")
        estimates()
        _fail(exc, deck)
    ph = core.phi(model, None, asm.q)
    click.echo(f"{deck}: {model.nb} bodies, {model.m} constraint equations, DOF {asm.dof}")
    estimates()
    click.echo(f"assembled in {asm.iterations} Newton iterations: max |Phi| = "
               f"{np.abs(ph).max(initial=0):.3e}")
    for r in np.argsort(-np.abs(ph))[:worst]:
        click.echo(f"    {model.row_label[r]:<40} {ph[r]: .3e}")
    dq = (asm.q - model.q0).reshape(model.nb, 7)
    moved = np.argsort(-np.linalg.norm(dq[:, :3], axis=1))[:3]
    for b in moved:
        click.echo(f"  body {model.body_names[b]} moved {np.linalg.norm(dq[b, :3]):.3e} m")
    _warn(asm.warnings)


@main.command()
@click.argument("args", nargs=-1, required=True, metavar="FILE... [CHANNEL...]")
@click.option("-y", "ys", multiple=True, help="Channel(s) to plot, e.g. drivers.crank.torque "
              "(the same as naming them after the files).")
@click.option("-x", "x", default="time", show_default=True, help="Channel for the x axis.")
@click.option("-o", "--output", default="plot.png", show_default=True,
              help="Figure file: .png, .svg or .pdf.")
@click.option("--label", "labels", multiple=True, help="Curve label per file (with several files).")
@click.option("--title", help="Figure title.")
@click.option("--list", "list_only", is_flag=True, help="List the channels of the file(s).")
@click.option("--units", "units", multiple=True, metavar="UNIT[,UNIT...]",
              help="Display units, e.g. deg,mm,rpm: a curve of that dimension is shown in it "
              "(the file keeps SI).")
@click.option("--data", "data_file", help="Also write the plotted data (display units) as CSV.")
def plot(args, ys, x, output, labels, title, list_only, units, data_file):
    """Plot stored channels of results file(s) against time or another channel.

    Arguments that are existing files are results files; the others are channel names.

    Example: mbsim plot slider_inverse.h5 drivers.crank.torque -o torque.png
    """
    from mbsim.output import list_channels, plot_channels, plot_results, read_result, save_figure
    from mbsim.output.hdf5 import result_file_problem

    files = [a for a in args if Path(a).is_file()]
    missing = [a for a in args if not Path(a).is_file() and Path(a).suffix in (".h5", ".hdf5")]
    if missing:
        _fail(UsageError(f"no such results file: {missing[0]}"))
    if not files:
        _fail(UsageError(f"no results file among {', '.join(args)}"))
    ys = tuple(ys) + tuple(a for a in args if a not in files)
    # `mbsim plot DIR/*.h5` after a sweep also names DIR/index.h5: skip it (and any other
    # file that is not a results file) by name; refuse when nothing is left.
    problems = {f: result_file_problem(f) for f in files}
    if len(files) > 1:
        for f, why in problems.items():
            if why:
                _warn([f"skipping {f}: {why}"])
        if labels and len(labels) == len(files):
            labels = tuple(lab for lab, f in zip(labels, files) if not problems[f])
        files = [f for f in files if not problems[f]] or files
    bad = [f for f in files if problems[f]]
    if bad:
        _fail(UsageError(f"{bad[0]}: {problems[bad[0]]}"))
    if not list_only:  # before reading anything: a bad -o or --data costs nothing
        check_output(output, "-o", figure=True, inputs=files)
        if data_file:
            check_output(data_file, "--data", inputs=files)
    try:
        if list_only:
            for f in files:
                click.echo(f"{f}:")
                for name, shape, unit, desc in list_channels(f):
                    click.echo(f"  {name.replace('/', '.'):<44} {shape!s:<10} {unit:<8} {desc}")
            return
        if not ys:
            raise click.UsageError("name at least one channel with -y (see --list)")
        import matplotlib

        from mbsim.output.plots import case_label, export_plot_data

        shown = [u.strip() for item in units for u in item.split(",") if u.strip()] or None
        results = [read_result(f) for f in files]
        # titles, labels and the deck's names are plain text: a body named 'r$\frac$d' or a
        # --title '$x^$' ended the plot in matplotlib's math-text parser
        with matplotlib.rc_context({"text.parse_math": False}):
            if len(results) == 1:
                fig = plot_channels(results[0], list(ys), x=x, title=title, units=shown)
            else:
                labs = list(labels) or [case_label(r, Path(f).stem)
                                        for f, r in zip(files, results)]
                cases = list(zip(labs, results))
                if not labels:  # `DIR/*.h5` come in string order (k=10, k=200, k=50)
                    from mbsim.view.page import natural_key

                    cases.sort(key=lambda case: natural_key(case[0]))
                fig = plot_results(cases, ys[0], x=x, title=title, units=shown)
            save_figure(fig, output)
        if data_file:
            export_plot_data(fig, data_file)
            click.echo(f"data -> {data_file}")
    except (KeyError, IndexError) as exc:
        _fail(UsageError(_key_message(exc)))
    except (MbsimError, ValueError, OSError) as exc:
        _fail(exc if isinstance(exc, MbsimError) else UsageError(str(exc)))
    click.echo(f"plot -> {output}")


def _key_message(exc: Exception) -> str:
    """A KeyError's own text (str() of a KeyError is its repr, quotes and all)."""
    return str(exc.args[0]) if exc.args else str(exc)


def _results_file(path: str) -> None:
    """Refuse a file that is not a results file, by name (exit 2)."""
    from mbsim.output.hdf5 import result_file_problem

    why = result_file_problem(path)
    if why:
        _fail(UsageError(f"{path}: {why}"))


@main.command("list")
@click.argument("what", type=click.Choice(["joints", "drivers", "forces", "integrators", "modes",
                                           "functions", "units"]), default="joints")
def list_(what):
    """List what the registries hold, one line each.

    Example: mbsim list joints
    """
    if what == "joints":
        from mbsim.constraints import JOINTS

        for name, cls in JOINTS.items():
            click.echo(f"{name:<22} {cls.n_eq} eq.  {cls.description}")
    elif what == "drivers":
        from mbsim.constraints import DRIVERS

        for name, cls in DRIVERS.items():
            click.echo(f"{name:<22} {cls.description} [{cls.effort_unit}]")
    elif what == "forces":
        from mbsim.forces import FORCES

        for name, cls in FORCES.items():
            click.echo(f"{name:<22} {cls.description}")
    elif what == "integrators":
        from mbsim.integrators import DEFAULT, INTEGRATORS

        for name, cls in INTEGRATORS.items():
            doc = getattr(cls, "description", "") or (cls.__doc__ or "").strip().splitlines()[0]
            mark = " (default)" if name == DEFAULT else ""
            click.echo(f"{name:<22} {doc}{mark}")
    elif what == "modes":
        from mbsim.api import ANALYSES

        for name, (_, _, desc) in ANALYSES.items():
            click.echo(f"{name:<22} {desc}")
    elif what == "functions":
        from mbsim.expr import FUNCTIONS

        click.echo(" ".join(sorted(FUNCTIONS)))
    elif what == "units":
        from mbsim.units import UNITS

        click.echo(" ".join(sorted(UNITS)))


@main.command()
@click.argument("a", type=click.Path(exists=True, dir_okay=False))
@click.argument("b", type=click.Path(exists=True, dir_okay=False))
@click.option("--rtol", type=float, default=1e-9, show_default=True)
@click.option("--atol", type=float, default=None,
              help="Absolute tolerance (default: rtol x each channel's range in B).")
@click.option("--channels", help="Comma-separated channels to compare (default: all).")
@click.option("--monitors", is_flag=True,
              help="Also compare monitors.* and error.* (step sizes, violations, estimates).")
@click.option("-n", "--worst", type=click.IntRange(min=0), default=10, show_default=True,
              help="Rows in the table.")
def compare(a, b, rtol, atol, channels, monitors, worst):
    """Compare results A against reference B: exit 0 if they agree, 1 if not.

    Example: mbsim compare new.h5 golden.h5 --rtol 1e-6 --atol 1e-9
    """
    import math

    from mbsim.output import compare_results, read_result

    for option, tol in (("--rtol", rtol), ("--atol", atol)):
        if tol is not None and not (tol >= 0 and math.isfinite(tol)):  # NaN: every value
            # would "differ", exit 1, a false report
            _fail(UsageError(f"{option}: expected a finite number >= 0, got {tol:g}"))
    _results_file(a)
    _results_file(b)
    try:
        ra, rb = read_result(a), read_result(b)
        chans = [c.strip().replace(".", "/") for c in channels.split(",")] if channels else None
        ok, diffs, problems = compare_results(ra, rb, rtol=rtol, atol=atol, channels=chans,
                                              monitors=monitors)
    except (MbsimError, KeyError, ValueError, OSError) as exc:
        _fail(exc if isinstance(exc, MbsimError) else UsageError(_key_message(exc)))
    for p in problems:
        click.echo(f"problem: {p}")
    bad = [d for d in diffs if d.failed]
    show = bad or diffs
    if show:
        click.echo(f"{'channel':<40} {'time':>10} {'A':>14} {'B':>14} {'|A-B|':>10} {'scaled':>8}")
        for d in show[:worst]:
            click.echo(f"{d.channel.replace('/', '.'):<40} {d.time:>10.5g} {d.a:>14.7g} "
                       f"{d.b:>14.7g} {d.abs_err:>10.3g} {d.scaled:>8.3g}")
    atol_text = f"atol={atol:g}" if atol is not None else "atol=rtol x range"
    timing = [p for p in problems if p.startswith("time axes differ")]
    if timing and not diffs:  # nothing comparable: say why, not "0 of 0 channels"
        click.echo(f"DIFFER: {timing[0]}; run both with the same t_start, t_end and step")
    elif not diffs and not problems:  # two files without outputs: agree, on nothing
        click.echo(f"agree: no channel to compare (no output time in {a} nor {b})")
    else:
        click.echo(f"{'agree' if ok else 'DIFFER'}: {len(bad)} of {len(diffs)} channels outside "
                   f"rtol={rtol:g}, {atol_text}")
    sys.exit(EXIT_OK if ok else EXIT_FAILED)


@main.command()
@click.argument("file", type=click.Path(exists=True, dir_okay=False))
@click.option("--csv", "csv_path", is_flag=False, flag_value="", default=None,
              help="CSV file to write; --csv alone (or no option) writes FILE.csv.")
@click.option("--channels", help="Comma-separated channels (default: all).")
@click.option("--vtk", "vtk_dir", default=None, metavar="DIR",
              help="ParaView time series in DIR: <stem>_shapes.pvd, <stem>_points.pvd.")
@click.option("--parquet", is_flag=False, flag_value="", default=None,
              help="Parquet file (pandas columns); --parquet alone writes FILE.parquet.")
def export(file, csv_path, channels, vtk_dir, parquet):
    """Export a results file to CSV for spreadsheets, VTK for ParaView, Parquet for pandas.

    Example: mbsim export gov.h5 --csv gov.csv --channels bodies.collar.r
    """
    from mbsim.output import export_csv, read_result

    _results_file(file)
    lines = []
    want_csv = csv_path is not None or (vtk_dir is None and parquet is None)
    target = Path(csv_path or Path(file).with_suffix(".csv"))
    if want_csv and not _is_folder(target):  # a folder takes <deck stem>.csv (export_csv)
        check_output(target, "--csv", inputs=(file,))
    if parquet is not None:
        check_output(parquet or Path(file).with_suffix(".parquet"), "--parquet", inputs=(file,))
    try:
        if vtk_dir is not None or parquet is not None:  # mbsim/cli_view.py
            from mbsim.cli_view import export_exchange

            lines = export_exchange(file, vtk_dir, parquet)
        if want_csv:
            res = read_result(file)
            chans = [c.strip() for c in channels.split(",")] if channels else None
            paths = export_csv(res, target, channels=chans)
            lines += [f"csv -> {p}" for p in paths]
    except (MbsimError, KeyError, IndexError, ValueError, OSError) as exc:
        _fail(exc if isinstance(exc, MbsimError) else UsageError(
            _key_message(exc) if isinstance(exc, KeyError) else str(exc)))
    for line in lines:
        click.echo(line)


if __name__ == "__main__":  # pragma: no cover
    # `python -m mbsim.cli`: run the canonical module's group (the command modules import
    # helpers from `mbsim.cli`, which must not be a second copy of this file as __main__).
    from mbsim.cli import main as _main

    _main()
