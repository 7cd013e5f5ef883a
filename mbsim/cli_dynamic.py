"""``mbsim bench``: work-precision of the integrators on a deck (a thin click layer over
:mod:`mbsim.analyses.bench`; registered by the CLI as ``bench_command``)."""

from __future__ import annotations

import math

import click

from mbsim.cli_options import deck_options
from mbsim.errors import DeckError, MbsimError


def _floats(text, what, below: float = math.inf):
    """The comma-separated numbers of option ``what``, each finite, > 0 and < ``below``
    (a tolerance below 1); at least one.  Otherwise a usage error naming the option, before
    the reference run (which takes longest)."""
    try:
        values = tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise click.BadParameter(f"expected comma-separated numbers, got {text!r}",
                                 param_hint=what) from None
    bad = [v for v in values if not (0 < v < below and math.isfinite(v))]
    if not values or bad:
        limit = f"> 0 and < {below:g}" if math.isfinite(below) else "finite and > 0"
        got = f"{bad[0]:g}" if bad else "no number"
        raise click.BadParameter(f"expected comma-separated numbers {limit}, got {got}",
                                 param_hint=what)
    return values


@click.command("bench")
@click.argument("deck", type=click.Path(dir_okay=False))
@click.option("--integrators", help="Comma-separated names (default: all; see `mbsim list "
              "integrators`).")
@click.option("--tolerances", default="1e-3,1e-5,1e-7,1e-9", show_default=True,
              help="rtol ladder of the adaptive methods (atol = rtol/100).")
@click.option("--steps", "steps_", default="1e-2,5e-3,2.5e-3,1.25e-3", show_default=True,
              help="Step ladder of the fixed-step methods, s.")
@click.option("--t-end", type=float, default=1.0, show_default=True, help="Simulated time, s.")
@click.option("--outputs", default="bodies/*/r", show_default=True,
              help="Channels whose error is measured (globs, comma-separated).")
@click.option("--repeats", type=click.IntRange(min=1), default=1, show_default=True,
              help="Runs per point (median wall).")
@deck_options()
@click.option("-o", "--output", help="Write the work-precision plot here (.png/.svg/.pdf).")
def bench_command(deck, integrators, tolerances, steps_, t_end, outputs, repeats, sets, scene,
                  output):
    """Work-precision of every integrator on DECK against a tight reference run.

    Example: mbsim bench models/governor.yaml --t-end 1 --integrators gcp-dop853,genalpha
    """
    from mbsim.analyses.bench import work_precision, work_precision_figure
    from mbsim.cli import _fail, _key_message, _load, check_output
    from mbsim.options import deck_context

    if output:  # before the benchmark: a bad -o costs nothing
        check_output(output, "-o", figure=True)
    names = [n.strip() for n in integrators.split(",")] if integrators else None
    ladders = _floats(tolerances, "--tolerances", below=1.0), _floats(steps_, "--steps")
    if not (0 < t_end and math.isfinite(t_end)):
        raise click.BadParameter(f"expected a finite time > 0, got {t_end:g}", param_hint="--t-end")
    try:
        spec, model = _load(deck, sets, scene)
        bench = work_precision(
            model, names, *ladders,
            t_end=t_end, outputs=[o.strip() for o in outputs.split(",")], repeats=repeats,
            progress=lambda r: click.echo(f"  {r.integrator:<18} {r.setting:<11} "
                                          f"error {r.error:.3e}  wall {r.wall:.4f} s/s",
                                          err=True),
            context=deck_context(spec, shapes=False))
    except (MbsimError, KeyError, RuntimeError) as exc:
        _fail(exc if isinstance(exc, MbsimError) else DeckError(_key_message(exc)), deck)
    click.echo(bench.table())
    click.echo("\nwall time per simulated second to reach an error of:")
    for target in (1e-3, 1e-6, 1e-9):
        cost = bench.cost_to_reach(target)
        reached = [(k, v) for k, v in cost.items() if v == v]  # NaN would upset the sort
        best = ", ".join(f"{k} {v:.3g}" for k, v in sorted(reached, key=lambda kv: kv[1]))
        click.echo(f"  {target:g}: {best or 'not reached'}")
    if output:
        from mbsim.output import save_figure

        save_figure(work_precision_figure(bench), output)
        click.echo(f"plot -> {output}")
