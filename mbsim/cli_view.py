"""``mbsim view``: the click layer over :mod:`mbsim.view.page` (registered in mbsim.cli's
LazyGroup.LAZY; imports mbsim.cli only inside the command, so importing this module first does
not loop).  Also the ``--vtk`` and ``--parquet`` halves of ``mbsim export``.
"""

from __future__ import annotations

from pathlib import Path

import click


@click.command("view")
@click.argument("files", nargs=-1, required=True, type=click.Path())
@click.option("-o", "--output", default=None,
              help="HTML file to write (default: the first FILE with .html; a folder: "
                   "FOLDER/view.html).")  # fmt: skip
@click.option("--title", default=None, help="Page title (default: the file names).")
def view_command(files, output, title):
    """Write one self-contained HTML page showing result FILES in 3D (opens offline in any
    browser): the mechanism with its shapes, joints and force elements; play, time slider,
    speed, camera; channel time histories with a cursor.  Several files, or a sweep's folder,
    become cases to choose from; a file of --mode linear shows each mode oscillating.

    Example: mbsim view gov.h5 -o gov.html   (then open gov.html#t=1.5 at t = 1.5 s)
    """
    from mbsim.cli import _fail, _warn, overwrite_problem
    from mbsim.errors import MbsimError, UsageError
    from mbsim.output.hdf5 import prepare_output
    from mbsim.view.page import write_page

    first = Path(files[0])
    out = Path(output) if output else (first / "view.html" if first.is_dir()
                                       else first.with_suffix(".html"))  # fmt: skip
    try:
        why = overwrite_problem(out, inputs=files)
        if why:
            raise UsageError(f"-o: {why}")
        prepare_output(out)  # before reading anything: a bad -o fails at once
        skipped: list[str] = []  # a folder's *.h5 that are not results files
        path = write_page(list(files), out, title, skipped)
    except (MbsimError, OSError, KeyError, ValueError) as exc:
        _fail(exc if isinstance(exc, MbsimError) else UsageError(f"{files[0]}: {exc}"))
    _warn(f"skipping {s}" for s in skipped)
    click.echo(f"view -> {path} ({path.stat().st_size / 1e6:.2f} MB)")


def export_exchange(file: str, vtk_dir: str | None, parquet: str | None) -> list[str]:
    """``mbsim export --vtk DIR`` / ``--parquet [FILE]``: the lines to print."""
    from mbsim.output import read_result

    result = read_result(file)
    lines = []
    if vtk_dir is not None:
        from mbsim.view.vtk import export_vtk

        pvd = export_vtk(result, vtk_dir, stem=Path(file).stem)
        lines.append(f"vtk -> {pvd} ({len(result.t)} outputs)")
    if parquet is not None:
        from mbsim.output.frame import export_parquet

        out = export_parquet(result, parquet or str(Path(file).with_suffix(".parquet")))
        lines.append(f"parquet -> {out}")
    return lines
