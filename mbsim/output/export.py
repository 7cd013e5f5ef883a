"""Channel selection shared by plots and exports, and CSV export.

A *selector* names a channel or one component of it, with dots or slashes:

- ``drivers.crank.torque``: the whole channel (a vector channel gives one column per
  component);
- ``bodies.crank.r[1]``: component 1 (second column) of ``bodies/crank/r``;
- ``bodies.crank.r.y``: the component labelled ``y`` in the channel's ``components``.
"""

from __future__ import annotations

import csv
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mbsim.result import Result

_INDEX = re.compile(r"^(?P<base>.+?)\[(?P<index>-?\d+)\]$")


@dataclass
class Column:
    """One plottable/exportable series: a scalar channel or one component of a vector one."""

    name: str  # slash path, with '/<component>' or '[i]' appended for a component
    data: np.ndarray  # (nt,)
    unit: str
    channel: str  # the channel's slash path
    label: str  # the component label ('' for a scalar channel)


def _component_labels(components: tuple[str, ...], ncol: int) -> list[str]:
    if len(components) == ncol:
        return list(components)
    return [f"[{i}]" for i in range(ncol)]


def _columns_of(name: str, result: Result) -> list[Column]:
    ch = result.channels[name]
    data = np.asarray(ch.data, dtype=float)
    if data.ndim <= 1:
        return [Column(name, data.reshape(-1), ch.unit, name, "")]
    flat = data.reshape(data.shape[0], -1)
    labels = _component_labels(ch.components, flat.shape[1])
    return [
        Column(
            name + (f"/{lab}" if not lab.startswith("[") else lab), flat[:, i], ch.unit, name, lab
        )
        for i, lab in enumerate(labels)
    ]


def select_columns(result: Result, selector: str) -> list[Column]:
    """The column(s) named by `selector` (see the module docstring).

    Raises
    ------
    KeyError
        Unknown channel (the message suggests close names) or unknown component label.
    IndexError
        Component index out of range.
    """
    key = selector.replace(".", "/").strip("/")
    if key in result.channels:
        return _columns_of(key, result)
    m = _INDEX.match(key)
    if m:
        base = m.group("base")
        result.channel(base)  # raises KeyError with close-name suggestions
        cols = _columns_of(base, result)
        i = int(m.group("index"))
        if not -len(cols) <= i < len(cols):
            raise IndexError(
                f"channel {base!r} has {len(cols)} component(s); index {i} is out of range"
            )
        return [cols[i]]
    base, _, comp = key.rpartition("/")
    if base in result.channels:
        cols = _columns_of(base, result)
        for col in cols:
            if col.label == comp:
                return [col]
        have = ", ".join(c.label for c in cols if c.label) or "none"
        raise KeyError(f"channel {base!r} has no component {comp!r} (components: {have})")
    group = [n for n in result.channels if n.startswith(key + "/")]
    if group:  # 'drivers', 'bodies.slider': a group of channels, not one
        listed = ", ".join(n.replace("/", ".") for n in group[:6]) + (", ..." * (len(group) > 6))
        raise KeyError(f"{selector!r} is a group of {len(group)} channel(s), not a channel; "
                       f"name one of: {listed}")
    result.channel(selector)  # raises KeyError with close-name suggestions
    raise KeyError(selector)  # pragma: no cover - channel() found it after all


def select_all(result: Result, selectors: list[str] | str | None) -> list[Column]:
    """Columns for several selectors (``None``: every channel, in order)."""
    if selectors is None:
        selectors = list(result.channels)
    elif isinstance(selectors, str):
        selectors = [selectors]
    return [col for sel in selectors for col in select_columns(result, sel)]


def header_name(name: str, unit: str) -> str:
    """``name [unit]``, or just ``name`` for a dimensionless quantity."""
    return f"{name} [{unit}]" if unit else name


def export_csv(
    result: Result, path_or_dir: str | Path, channels: list[str] | None = None
) -> list[Path]:
    """Write the time axis and channels to one comma-separated file.

    Format: one header row, ``time [s],bodies/crank/r/x [m],...,drivers/crank/torque [N m]``
    (a vector channel is one column per component, labelled by ``components`` or ``[i]``),
    then one row per output time. Numbers are written with the shortest representation
    that reads back to the same float64 (``nan``/``inf`` for non-finite values). The file
    reads back with ``numpy.loadtxt(path, delimiter=",", skiprows=1)``.

    Parameters
    ----------
    result : Result
        The result to export; status and message are not part of the CSV.
    path_or_dir : str or Path
        A ``.csv`` file, or an existing directory (the file is then named after the deck,
        ``<deck stem>.csv``, or ``result.csv``).
    channels : list of str, optional
        Selectors (``bodies.crank.r``, ``bodies.crank.r.x``, ``bodies.crank.r[0]``);
        default every channel.

    Returns
    -------
    list of Path
        The written file(s).
    """
    path = Path(path_or_dir)
    if path.is_dir():
        stem = Path(result.deck_file).stem if result.deck_file else "result"
        path = path / f"{stem}.csv"
    cols = select_all(result, channels)
    t = np.asarray(result.t, dtype=float).reshape(-1)
    for col in cols:
        if col.data.shape[0] != t.shape[0]:
            raise ValueError(
                f"channel {col.channel!r} has {col.data.shape[0]} samples, time has {t.shape[0]}"
            )
    table = np.column_stack([t] + [c.data for c in cols])
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        with open(tmp, "w", newline="", encoding="utf-8") as fh:
            writer = csv.writer(fh, lineterminator="\n")
            writer.writerow(["time [s]"] + [header_name(c.name, c.unit) for c in cols])
            fh.writelines(",".join(map(repr, row)) + "\n" for row in table.tolist())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return [path]
