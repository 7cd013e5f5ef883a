"""``mbsim study`` and ``mbsim animate``: the click layer over :mod:`mbsim.study` and
:mod:`mbsim.animate` (registered by ``mbsim.cli._register_optional``).

Exit codes as for every command: 0 every case complete and every figure made; 1 a case
failed or stopped part-way (the others are still run, drawn and tabulated); 2 bad input.
"""

from __future__ import annotations

import sys
from pathlib import Path

import click

from mbsim.cli import EXIT_FAILED, _fail, _results_file, _warn, check_output
from mbsim.cli_options import jobs_option, quiet_option
from mbsim.errors import MbsimError, UsageError
from mbsim.progress import Progress, format_duration

VIEWS = ("iso", "xy", "xz", "yz")


MIN_DPI, MAX_DPI = 10, 1200  # study figures (about 6 x 4 in: 1200 dpi is 7200 x 4800 px)
MIN_FPS, MAX_FPS = 0.01, 1000  # frames per second: a GIF stores a frame's duration in
# hundredths of a second as a 16-bit number (at most 655 s: --fps 0.001 overflowed PIL)
MIN_PIXELS, MAX_PIXELS = 16, 2160  # a frame's side (dpi x size); drawn 2x larger (render.py)


def _table(header: list[str], rows: list[list[str]], indent: str = "  ") -> None:
    widths = [max(len(str(r[i])) for r in [header, *rows]) for i in range(len(header))]
    for row in [header, *rows]:
        click.echo(indent + "  ".join(str(c).ljust(w) for c, w in zip(row, widths)).rstrip())


@click.command("study")
@click.argument("deck", type=click.Path(dir_okay=False))
@click.argument("name", required=False)
@click.option(
    "-o",
    "--output",
    "out_dir",
    default=None,
    help="Output folder; each study writes into <folder>/<study>/. Default: <deck stem>_studies",
)
@jobs_option(default=1, help="Cases run at once (processes).")
@click.option("--list", "list_only", is_flag=True, help="List the deck's studies.")
@click.option("--dpi", type=float, default=110, show_default=True, help="Figure resolution.")
@quiet_option(help="Print only errors and the tables.")
def study_command(deck, name, out_dir, jobs, list_only, dpi, quiet):
    """Run study NAME of DECK (`all`: every study): every case to HDF5, every figure to PNG,
    and a table of the key numbers.

    Example: mbsim study models/slider_crank.yaml inverse_rod_length -o out
    """
    from mbsim.study import list_studies, open_deck, run_study, study_names

    if not MIN_DPI <= dpi <= MAX_DPI:  # NaN too; before any case runs
        _fail(UsageError(f"--dpi must be {MIN_DPI} to {MAX_DPI} (dots per inch of the "
                         f"figures), got {dpi:g}"))
    try:
        parsed = open_deck(deck)  # read and composed once for every case of every study
        spec = parsed.spec()
        if list_only or not name:
            studies = list_studies(spec)
            if not studies:
                click.echo(f"{deck}: no studies")
            for sname, desc, modes in studies:
                n = len(spec.studies[sname]["cases"])
                click.echo(f"{sname:<28} {n} case{'s' * (n != 1)} ({', '.join(modes)})  {desc}")
            if not name and not list_only:
                raise click.UsageError("name a study (or `all`); the deck's studies are above")
            return
        names = study_names(spec, name)
    except MbsimError as exc:
        _fail(exc, deck)
    _warn(spec.warnings)
    folder = Path(out_dir) if out_dir else Path(f"{Path(deck).stem}_studies")
    from mbsim.sweep import prepare_out_dir

    try:
        prepare_out_dir(folder)  # before any case: a folder that cannot be written is exit 2
    except MbsimError as exc:
        _fail(exc, deck)
    failed = False
    seen_warnings: set[str] = set(spec.warnings)

    def progress(case):
        new = [w for w in case.warnings if w not in seen_warnings]
        seen_warnings.update(new)
        _warn(new)
        if not quiet:
            where = case.path if case.path else case.message
            click.echo(
                f"  {case.label}: {case.mode} {case.status} in {case.wall_time:.3g} s -> {where}"
            )

    for sname in names:
        if not quiet:
            click.echo(f"study {sname}: {spec.studies[sname]['description']}")
        try:
            outcome = run_study(
                parsed, sname, folder, jobs=jobs, spec=spec, on_case=progress, dpi=dpi
            )
        except MbsimError as exc:
            _fail(exc, deck)
        for case in outcome.cases:
            if case.status != "complete":
                click.echo(
                    f"error: {deck}: study {sname}, case {case.label}: {case.status}: "
                    f"{case.message}",
                    err=True,
                )
        for problem in outcome.problems:
            click.echo(f"error: {problem}", err=True)
        if not quiet:
            for fig in outcome.figures:
                click.echo(f"  figure -> {fig}")
        _table(*outcome.table)
        click.echo(
            f"  study {sname}: {len(outcome.cases)} cases, wall {outcome.wall_time:.3g} s"
            f" -> {outcome.out_dir}"
        )
        failed = failed or not outcome.ok
    if failed:
        sys.exit(EXIT_FAILED)


class FrameProgress(Progress):
    """The animation's progress line: ``animate  frame 40/126  32%  95 frames/s  ETA 0:01``
    (a :class:`mbsim.progress.Progress` whose line counts frames, not simulated seconds)."""

    def line(self, t: float, t_end: float, now: float) -> str:
        elapsed = now - self.wall_first
        rate = (self.steps - 1) / elapsed if elapsed > 0 else float("nan")
        eta = (t_end - t) / rate if rate > 0 else float("nan")
        return (f"animate  frame {t:.0f}/{t_end:.0f}  {100 * t / t_end:3.0f}%  "
                f"{rate:.3g} frames/s  ETA {format_duration(eta)}")


def _frame_progress():
    """A :class:`FrameProgress` on stderr when it is a terminal, else None."""
    from mbsim.progress import terminal_progress

    bar = terminal_progress()
    return None if bar is None else FrameProgress(bar.stream, tty=bar.tty)


@click.command("animate")
@click.argument("file", type=click.Path(exists=True, dir_okay=False))
@click.option("-o", "--output", default=None,
              help="GIF or MP4 file (default: FILE with .gif); checked before drawing.")
@click.option("--fps", type=float, default=20, show_default=True, help="Frames per second.")
@click.option(
    "--view",
    type=click.Choice(VIEWS),
    default="iso",
    show_default=True,
    help="Projection: isometric or onto a coordinate plane.",
)
@click.option(
    "--every", type=int, default=1, show_default=True, help="Draw every N-th output time."
)
@click.option("--dpi", type=float, default=80, show_default=True, help="Frame resolution.")
@click.option(
    "--size", type=float, default=5.0, show_default=True, help="Frame size, inches (square)."
)
@click.option("--mode-shape", "mode_shape", type=int, default=None,
              help="File of --mode linear: draw mode K (as numbered in its table) oscillating.")
@click.option("--labels", "labels", is_flag=True, help="Write body names at their centroids.")
@click.option("--style", type=click.Choice(["3d", "sketch"]), default="3d", show_default=True,
              help="3d: the bodies' shapes, shaded; sketch: the 2D line drawing (GIF only).")
def animate_command(file, output, fps, view, every, dpi, size, mode_shape, labels, style):
    """Draw the mechanism of a results FILE moving: in 3D, the bodies' shapes with joints,
    springs and a ground grid (or, --style sketch, bodies as lines between their joint
    points), a time stamp; a progress line on a terminal.

    Example: mbsim animate slider.h5 -o slider.gif --view iso --every 2
    """
    from mbsim.animate import animate_file

    _results_file(file)  # a file that is not a results file: named, not h5py's words
    out = Path(output) if output else Path(file).with_suffix(".gif")
    if every < 1 or not MIN_FPS <= fps <= MAX_FPS:
        _fail(UsageError(f"--every must be >= 1 and --fps {MIN_FPS:g} to {MAX_FPS}, got "
                         f"--every {every} --fps {fps:g}"))
    if not (dpi > 0 and size > 0 and MIN_PIXELS <= dpi * size <= MAX_PIXELS):  # NaN too
        _fail(UsageError(f"--dpi and --size must be > 0, their product (a frame's pixels a "
                         f"side) {MIN_PIXELS} to {MAX_PIXELS} (default 80 x 5 = 400), got "
                         f"--dpi {dpi:g} --size {size:g}"))
    check_output(out, "-o", inputs=(file,))  # before rendering: a bad -o costs nothing
    try:
        bar = _frame_progress()
        try:
            path, nframes = animate_file(file, out, fps=fps, view=view, every=every, dpi=dpi,
                                         size=size, mode_shape=mode_shape, labels=labels,
                                         style=style, progress=bar)
        finally:
            if bar is not None:
                bar.close()
    except (MbsimError, KeyError, ValueError, OSError) as exc:
        _fail(exc if isinstance(exc, MbsimError)
              else UsageError(f"{file}: {str(exc).strip(chr(39) + chr(34))}"))
    click.echo(f"animation: {nframes} frames at {fps:g} fps -> {path}")
