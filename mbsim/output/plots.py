"""Plots of result channels as :class:`matplotlib.figure.Figure` objects.

No pyplot global state: figures are built with ``Figure`` and a ``FigureCanvasAgg``, so
they can be made from worker threads and never open windows. Channels are named with dots
or slashes, with an optional component (``bodies.crank.r[1]``, ``bodies.crank.r.y``); see
:mod:`mbsim.output.export` for the selector rules.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from mbsim.output.export import Column, header_name, select_columns
from mbsim.result import Result

FORMATS = {".png": "png", ".svg": "svg", ".pdf": "pdf"}
INCOMPLETE = "(incomplete)"


LINESTYLES = ("-", "--", "-.", ":")  # cycled with the colours: coinciding curves stay visible
GREEK = {"alpha": "α", "beta": "β", "gamma": "γ", "delta": "δ", "zeta": "ζ", "theta": "θ",
         "lambda": "λ", "mu": "μ", "omega": "ω", "phi": "φ", "psi": "ψ", "tau": "τ"}


def _new_figure(figsize: tuple[float, float], n: int = 1) -> tuple[Figure, list]:
    fig = Figure(figsize=(figsize[0], figsize[1] * (1 + 0.55 * (n - 1))), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(n, 1, sharex=True, squeeze=False)[:, 0]
    return fig, list(axes)


def display_unit(unit: str, units: Sequence[str] | None) -> tuple[str, float]:
    """(shown unit, factor): the first of ``units`` (e.g. ``deg``, ``mm``, ``rpm``) of the same
    dimension as the SI ``unit`` and its factor (value shown = SI value * factor); the SI
    unit itself when none matches.  The stored data are never changed."""
    if not units or not unit:
        return unit, 1.0
    from mbsim.units import parse_unit

    try:
        si = parse_unit(unit)
    except Exception:  # a unit the parser does not know: shown as stored
        return unit, 1.0
    for u in units:
        try:
            d = parse_unit(u)
        except Exception as exc:
            raise ValueError(f"unknown display unit {u!r}: {exc}") from None
        if d.dims == si.dims:
            return u, si.scale / d.scale
    return unit, 1.0


def _quantity(unit: str) -> object:
    """A key shared by columns of one physical quantity (their dimensions)."""
    from mbsim.units import parse_unit

    try:
        return parse_unit(unit).dims if unit else ""
    except Exception:
        return unit


def _x_axis(result: Result, x: str, units=None) -> tuple[object, str, str]:
    """The x data, axis label and unit: ``time [s]`` or a single column ``name [unit]``."""
    if x == "time":
        return result.t, "time [s]", "s"
    cols = select_columns(result, x)
    if len(cols) != 1:
        raise ValueError(
            f"x must name one column; {x!r} has {len(cols)} components "
            f"(pick one, e.g. {x}[0] or {cols[0].name.replace('/', '.')})"
        )
    shown, f = display_unit(cols[0].unit, units)
    return cols[0].data * f, header_name(cols[0].name, shown), shown


def _axis_label(cols: Sequence[Column], unit: str | None = None) -> str:
    """``drivers/crank/torque [N m]``: per channel its name, or the component's name when
    only one component of it is shown; several channels are joined with ``, ``."""
    by_channel: dict[str, list[Column]] = {}
    for col in cols:
        by_channel.setdefault(col.channel, []).append(col)
    if len(by_channel) > 1:  # the legend names the curves; the axis the quantity
        last = {c.split("/")[-1] for c in by_channel}
        shown = cols[0].unit if unit is None else unit
        return f"{last.pop() if len(last) == 1 else 'value'} [{shown}]"
    return ", ".join(
        header_name(group[0].name if len(group) == 1 else chan,
                    group[0].unit if unit is None else unit)
        for chan, group in by_channel.items()
    )


def _title(title: str | None, complete: bool) -> str:
    title = title or ""
    return title if complete else f"{title} {INCOMPLETE}".strip()


def _legend(ax) -> None:
    """Legend outside the data, right of the axes."""
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small", frameon=False)


def _groups(cols: Sequence[Column]) -> list[list[int]]:
    """Indices of the columns, grouped by physical quantity, in order of first appearance."""
    groups: dict[object, list[int]] = {}
    for i, col in enumerate(cols):
        groups.setdefault(_quantity(col.unit), []).append(i)
    return list(groups.values())


def plot_channels(
    result: Result,
    y: list[str] | str,
    x: str = "time",
    labels: Sequence[str] | None = None,
    title: str | None = None,
    figsize: tuple[float, float] = (7.0, 4.5),
    units: Sequence[str] | None = None,
) -> Figure:
    """Plot channels of one result: one axes per physical quantity (stacked, shared x).

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
        Size in inches of a one-axes figure (each further axes adds 55 % of the height).
    units : sequence of str, optional
        Display units (``deg``, ``mm``, ``rpm``, ``kN``): a curve whose SI unit has the
        dimension of one of them is shown in it (:func:`display_unit`).

    Returns
    -------
    Figure
        Axes labelled ``name [unit]``; the time axis is ``time [s]``; legends outside the
        data; curves of one axes in different colours and line styles.  The plotted data
        (display units) are in ``fig.mbsim_data`` for :func:`export_plot_data`.

    Raises
    ------
    KeyError
        Unknown channel (the message suggests close names) or component.
    ValueError
        `labels` does not match the number of curves, or `x` has several components.
    """
    selectors = [y] if isinstance(y, str) else list(y)
    cols = [col for sel in selectors for col in select_columns(result, sel)]
    xdata, xlabel, xunit = _x_axis(result, x, units)
    if labels is not None and len(labels) != len(cols):
        raise ValueError(f"{len(labels)} labels given for {len(cols)} curves")
    groups = _groups(cols)
    fig, axes = _new_figure(figsize, len(groups))
    fig.mbsim_data = []
    for ax, idx in zip(axes, groups):
        shown, f = display_unit(cols[idx[0]].unit, units)
        group = [cols[i] for i in idx]
        single = len({c.channel for c in group}) == 1
        for n, i in enumerate(idx):
            col = cols[i]
            if labels is not None:
                label = labels[i]
            else:
                label = (col.label or col.name) if single else col.name
            ax.plot(xdata, col.data * f, label=label, color=f"C{n % 10}",
                    ls=LINESTYLES[n % len(LINESTYLES)], lw=1.6)
            fig.mbsim_data.append({"label": label if labels is not None else col.name,
                                   "x": xdata, "y": col.data * f, "xunit": xunit,
                                   "unit": shown, "xlabel": xlabel})
        ax.set_ylabel(_axis_label(group, shown))
        ax.grid(True, alpha=0.3)
        if len(group) > 1 or labels is not None:
            _legend(ax)
    axes[-1].set_xlabel(xlabel)
    text = _title(title, result.complete)
    if text:
        axes[0].set_title(text)
    return fig


def parameter_label(name: str, value) -> str:
    """``ω = 2π`` for omega = 6.283185..., ``k = 2000`` for k = 2000.0: a legend entry from a
    parameter's name (Greek names as letters, the key path's last part) and value (whole
    multiples and simple fractions of pi written with π)."""
    short = str(name).split(".")[-1]
    short = GREEK.get(short, short)
    try:
        v = float(value)
    except (TypeError, ValueError):
        try:  # a formula of numbers, as a sweep value may be ('-2*pi'): the safe evaluator
            from mbsim.expr import evaluate

            v = float(evaluate(str(value)))
        except Exception:  # names, units: shown as written
            return f"{short} = {value}"
    for den in (1, 2, 3, 4, 6):
        num = v * den / np.pi
        if abs(v) > 1e-12 and abs(num - round(num)) < 1e-6 * max(1.0, abs(num)) and \
                abs(round(num)) <= 24 and not float(v).is_integer():
            k = int(round(num))
            top = {1: "π", -1: "−π"}.get(k, f"{k}π".replace("-", "−"))
            return f"{short} = {top}" + (f"/{den}" if den > 1 else "")
    text = f"{v:g}".replace("-", "−")
    return f"{short} = {text}"


def case_label(result: Result, fallback: str) -> str:
    """A legend entry for one case of a sweep: its parameter values (``ω = 2π, k = 2000``)
    from the file's ``settings.sweep.values``, else ``fallback`` (the file stem)."""
    values = (result.settings.get("sweep") or {}).get("values") if result.settings else None
    if isinstance(values, dict) and values:
        return ", ".join(parameter_label(k, v) for k, v in values.items())
    return fallback


def plot_results(
    results: Sequence[tuple[str, Result]],
    y: str,
    x: str = "time",
    title: str | None = None,
    figsize: tuple[float, float] = (7.0, 4.5),
    units: Sequence[str] | None = None,
) -> Figure:
    """Plot one channel from several results (cases of a study), one labelled curve each.

    Parameters
    ----------
    results : sequence of (label, Result)
        The cases, e.g. ``[("k = 1000", r1), ("k = 2000", r2)]`` (see :func:`case_label`).
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
    units : sequence of str, optional
        Display units, as for :func:`plot_channels`.

    Returns
    -------
    Figure
        Legend outside the data; cases in different colours and line styles; the plotted
        data in ``fig.mbsim_data``.
    """
    if not results:
        raise ValueError("plot_results needs at least one (label, Result) pair")
    fig, (ax,) = _new_figure(figsize)
    fig.mbsim_data = []
    first: list[Column] = []
    xlabel = "time [s]"
    shown = None
    n = 0
    for case, result in results:
        cols = select_columns(result, y)
        xdata, xlabel, xunit = _x_axis(result, x, units)
        mark = "" if result.complete else f" {INCOMPLETE}"
        for col in cols:
            shown, f = display_unit(col.unit, units)
            label = f"{case} {col.label}" if col.label and len(cols) > 1 else case
            ax.plot(xdata, col.data * f, label=label + mark, color=f"C{n % 10}",
                    ls=LINESTYLES[n % len(LINESTYLES)], lw=1.6)
            fig.mbsim_data.append({"label": label, "x": xdata, "y": col.data * f,
                                   "xunit": xunit, "unit": shown, "xlabel": xlabel})
            n += 1
        first = first or cols
    ax.set_xlabel(xlabel)
    ax.set_ylabel(_axis_label(first, shown))
    ax.grid(True, alpha=0.3)
    _legend(ax)
    text = _title(title, all(result.complete for _, result in results))
    if text:
        ax.set_title(text)
    return fig


def export_plot_data(fig: Figure, path: str | Path) -> Path:
    """Write the curves of a figure made here as CSV, in the units shown.  One column per
    curve next to a shared x column when all curves share their x values; otherwise long
    form (``curve, x, y``)."""
    import csv

    from mbsim.output.export import header_name

    data = getattr(fig, "mbsim_data", None)
    if not data:
        raise ValueError("the figure holds no plotted data (not made by mbsim.output.plots)")
    path = Path(path)
    same = all(len(d["x"]) == len(data[0]["x"]) and np.array_equal(d["x"], data[0]["x"])
               for d in data)
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        if same:
            w.writerow([data[0]["xlabel"]] + [header_name(d["label"], d["unit"])
                                              for d in data])  # as export_csv names them
            for k in range(len(data[0]["x"])):
                w.writerow([repr(float(data[0]["x"][k]))] + [repr(float(d["y"][k]))
                                                              for d in data])
        else:
            w.writerow(["curve", "x", "y", "x unit", "y unit"])
            for d in data:
                for xv, yv in zip(d["x"], d["y"]):
                    w.writerow([d["label"], repr(float(xv)), repr(float(yv)), d["xunit"],
                                d["unit"]])
    return path


def figure_suffix_problem(path: str | Path) -> str:
    """Why a figure cannot be saved as ``path`` judging by its suffix, '' when it can."""
    path = Path(path)
    if path.suffix.lower() in FORMATS:
        return ""
    return (f"cannot save a figure as {path.suffix or 'a file without suffix'!r} ({path.name}); "
            f"use one of {', '.join(FORMATS)}")


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
        raise ValueError(figure_suffix_problem(path))
    if fig.canvas is None or not isinstance(fig.canvas, FigureCanvasAgg):
        FigureCanvasAgg(fig)
    fig.savefig(path, format=fmt, dpi=dpi)
    return path
