"""Plots of result channels as :class:`matplotlib.figure.Figure` objects.

No pyplot global state: figures are built with ``Figure`` and a ``FigureCanvasAgg``, so
they can be made from worker threads and never open windows. Channels are named with dots
or slashes, with an optional component (``bodies.crank.r[1]``, ``bodies.crank.r.y``); see
:mod:`mbsim.output.export` for the selector rules.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from mbsim.output.export import Column, header_name, select_columns
from mbsim.result import Result

FORMATS = {".png": "png", ".svg": "svg", ".pdf": "pdf"}
INCOMPLETE = "(incomplete)"


def _new_figure(figsize: tuple[float, float]) -> tuple[Figure, object]:
    fig = Figure(figsize=figsize, layout="constrained")
    FigureCanvasAgg(fig)
    return fig, fig.add_subplot()


def _x_axis(result: Result, x: str) -> tuple[object, str]:
    """The x data and axis label: ``time [s]`` or a single column ``name [unit]``."""
    if x == "time":
        return result.t, "time [s]"
    cols = select_columns(result, x)
    if len(cols) != 1:
        raise ValueError(
            f"x must name one column; {x!r} has {len(cols)} components "
            f"(pick one, e.g. {x}[0] or {cols[0].name.replace('/', '.')})"
        )
    return cols[0].data, header_name(cols[0].name, cols[0].unit)


def _axis_label(cols: Sequence[Column]) -> str:
    """``drivers/crank/torque [N m]``: per channel its name, or the component's name when
    only one component of it is shown; several channels are joined with ``, ``."""
    by_channel: dict[str, list[Column]] = {}
    for col in cols:
        by_channel.setdefault(col.channel, []).append(col)
    return ", ".join(
        header_name(group[0].name if len(group) == 1 else chan, group[0].unit)
        for chan, group in by_channel.items()
    )


def _title(title: str | None, complete: bool) -> str:
    title = title or ""
    return title if complete else f"{title} {INCOMPLETE}".strip()


def plot_channels(
    result: Result,
    y: list[str] | str,
    x: str = "time",
    labels: Sequence[str] | None = None,
    title: str | None = None,
    figsize: tuple[float, float] = (7.0, 4.5),
) -> Figure:
    """Plot channels of one result on one axes.

    Parameters
    ----------
    result : Result
        The result to plot.
    y : list of str or str
        Channel selectors; a vector channel gives one curve per component (legend labels
        from its ``components``), ``name[i]`` or ``name.label`` selects one component.
    x : str
        ``"time"`` (default) or a selector of a single column (phase plots).
    labels : sequence of str, optional
        Legend labels, one per curve, replacing the automatic ones.
    title : str, optional
        Figure title; an incomplete result gets the suffix ``(incomplete)``.
    figsize : (float, float)
        Figure size in inches.

    Returns
    -------
    Figure
        Axes labelled ``name [unit]``; the time axis is ``time [s]``.

    Raises
    ------
    KeyError
        Unknown channel (the message suggests close names) or component.
    ValueError
        `labels` does not match the number of curves, or `x` has several components.
    """
    selectors = [y] if isinstance(y, str) else list(y)
    cols = [col for sel in selectors for col in select_columns(result, sel)]
    xdata, xlabel = _x_axis(result, x)
    if labels is not None and len(labels) != len(cols):
        raise ValueError(f"{len(labels)} labels given for {len(cols)} curves")
    fig, ax = _new_figure(figsize)
    single = len({c.channel for c in cols}) == 1
    for i, col in enumerate(cols):
        if labels is not None:
            label = labels[i]
        else:
            label = (col.label or col.name) if single else col.name
        ax.plot(xdata, col.data, label=label)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(_axis_label(cols))
    ax.grid(True, alpha=0.3)
    if len(cols) > 1 or labels is not None:
        ax.legend()
    text = _title(title, result.complete)
    if text:
        ax.set_title(text)
    return fig


def plot_results(
    results: Sequence[tuple[str, Result]],
    y: str,
    x: str = "time",
    title: str | None = None,
    figsize: tuple[float, float] = (7.0, 4.5),
) -> Figure:
    """Plot one channel from several results (cases of a study), one labelled curve each.

    Parameters
    ----------
    results : sequence of (label, Result)
        The cases, e.g. ``[("k = 1000", r1), ("k = 2000", r2)]``.
    y : str
        Channel selector; for a vector channel each case gives one curve per component,
        labelled ``<case> <component>``.
    x : str
        ``"time"`` or a single-column selector.
    title : str, optional
        Figure title; incomplete cases are marked ``(incomplete)`` in the legend, and the
        title gets that suffix when any case is incomplete.
    figsize : (float, float)
        Figure size in inches.

    Returns
    -------
    Figure
    """
    if not results:
        raise ValueError("plot_results needs at least one (label, Result) pair")
    fig, ax = _new_figure(figsize)
    first: list[Column] = []
    xlabel = "time [s]"
    for case, result in results:
        cols = select_columns(result, y)
        xdata, xlabel = _x_axis(result, x)
        mark = "" if result.complete else f" {INCOMPLETE}"
        for col in cols:
            label = f"{case} {col.label}" if col.label else case
            ax.plot(xdata, col.data, label=label + mark)
        first = first or cols
    ax.set_xlabel(xlabel)
    ax.set_ylabel(_axis_label(first))
    ax.grid(True, alpha=0.3)
    ax.legend()
    text = _title(title, all(result.complete for _, result in results))
    if text:
        ax.set_title(text)
    return fig


def save_figure(fig: Figure, path: str | Path, dpi: float = 150) -> Path:
    """Save `fig` to `path`; the format comes from the suffix (.png, .svg or .pdf).

    Raises
    ------
    ValueError
        Any other suffix.
    """
    path = Path(path)
    fmt = FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise ValueError(
            f"cannot save a figure as {path.suffix or 'a file without suffix'!r} ({path.name}); "
            f"use one of {', '.join(FORMATS)}"
        )
    if fig.canvas is None or not isinstance(fig.canvas, FigureCanvasAgg):
        FigureCanvasAgg(fig)
    fig.savefig(path, format=fmt, dpi=dpi)
    return path
