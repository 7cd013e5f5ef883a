"""``mbsim run --plot``: the quick look at a run, one figure chosen by its mode.

- kinematic, inverse, dynamic: one panel per physical quantity (same unit), the channels that
  say most about the run where they exist: energy, driving torques and forces, force
  elements' forces, measures, output points (else the moving bodies' centroids); legends are
  channel names with units (``drivers.crank.torque [N m]``); curves that are all zero, or
  identical to another, are folded into one labelled line;
- equilibrium: the configuration found, drawn in 3D (mbsim.view.render), with its numbers;
- linear: a chart of the modes, one row per mode: natural frequency (bar) and damping ratio
  written beside it, neutral modes listed apart (no labels drawn over each other).

Matplotlib Figure objects, no pyplot state (as mbsim.output.plots).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mbsim.output.export import Column, select_columns
from mbsim.output.plots import LINESTYLES, _legend, _new_figure, _quantity, _title
from mbsim.result import Result

MAX_CURVES = 12  # per figure, after folding
ROUND_OFF = 1e-12  # a curve within this fraction of its unit's largest value of 0 is zero
PICK = (  # (channel prefix, suffixes) in the order they are shown
    ("monitors/energy", ("",)),
    ("drivers/", ("torque", "force")),
    ("forces/", ("/force",)),
    ("measures/", ("",)),
    ("points/", ("/position",)),
)


def quick_look(result: Result, title: str | None = None):
    """The figure ``--plot`` saves for ``result`` (None when there is nothing to draw)."""
    title = title or f"{result.mode}: {Path(result.deck_file).name}"
    if result.mode == "linear" and "linear/eigenvalues" in result.arrays:
        return mode_chart(result, title)
    if result.mode == "equilibrium":
        return configuration_figure(result, title)
    return channels_figure(result, title)


def pick_channels(result: Result) -> list[str]:
    """The channels a quick look shows (module docstring), in that order."""
    names = []
    for prefix, ends in PICK:
        names += [n for n in result.channels if n.startswith(prefix) and n.endswith(ends)
                  and n not in names]  # fmt: skip
    if not any(n.startswith(("points/", "measures/")) for n in names):
        names += [n for n in result.channels if n.startswith("bodies/") and n.endswith("/r")
                  and not n.startswith("bodies/ground/")][:4]  # fmt: skip
    return names


def curve_name(col: Column) -> str:
    """``bodies.crank.r.x [m]``: the channel (dots) and component, with the unit."""
    name = col.channel.replace("/", ".") + (f".{col.label}" if col.label and
                                            not col.label.startswith("[") else col.label)
    return f"{name} [{col.unit}]" if col.unit else name


def fold(cols: list[Column]) -> list[tuple[str, np.ndarray, str]]:
    """(label, data, unit) per curve to draw: columns that are zero (to ROUND_OFF of the
    largest value of their unit: 1e-17 m beside 0.2 m) become one line ``= 0: a, b, c``;
    columns equal to an earlier one (to the same bound) join its label."""
    out: list[list] = []
    zeros: dict[str, list[str]] = {}
    scale: dict[str, float] = {}
    for col in cols:
        finite = np.abs(np.asarray(col.data, float))
        finite = finite[np.isfinite(finite)]
        top = float(finite.max()) if finite.size else 0.0
        scale[col.unit] = max(scale.get(col.unit, 0.0), top)
    for col in cols:
        data = np.asarray(col.data, float)
        tol = ROUND_OFF * scale[col.unit]
        if data.size and np.all(np.abs(data) <= tol):
            zeros.setdefault(col.unit, []).append(curve_name(col).split(" [")[0])
            continue
        same = next((o for o in out if o[2] == col.unit and o[1].shape == data.shape
                     and np.all(np.abs(o[1] - data) <= tol)), None)  # fmt: skip
        if same is not None:
            same[0] += ", " + curve_name(col)
        else:
            out.append([curve_name(col), data, col.unit])
    for unit, names in zeros.items():
        more = [f"and {len(names) - 4} more"] if len(names) > 4 else []
        head = f"zero [{unit}]:" if unit else "zero:"
        out.append(["\n  ".join([head, *names[:4], *more]), np.zeros(0), unit])
    return [tuple(o) for o in out]


def channels_figure(result: Result, title: str):
    """One panel per quantity of the picked channels, curves folded (:func:`fold`)."""
    cols = [c for n in pick_channels(result) for c in select_columns(result, n)]
    curves = fold(cols)[:MAX_CURVES]
    if not curves:
        return None
    t = np.asarray(result.t, float)
    groups: dict[object, list[tuple]] = {}
    for curve in curves:
        groups.setdefault(_quantity(curve[2]), []).append(curve)
    fig, axes = _new_figure((7.0, 4.5), len(groups))
    for ax, group in zip(axes, groups.values()):
        for n, (label, data, _unit) in enumerate(group):
            y = data if data.size else np.zeros_like(t)
            ax.plot(t, y, label=label, color=f"C{n % 10}", ls=LINESTYLES[n % len(LINESTYLES)],
                    lw=1.6 if data.size else 1.0)  # fmt: skip
        unit = group[0][2]
        ax.set_ylabel(f"[{unit}]" if unit else "[-]")
        ax.grid(True, alpha=0.3)
        _legend(ax)
    axes[-1].set_xlabel("time [s]")
    axes[0].set_title(_title(title, result.complete))
    return fig


def configuration_figure(result: Result, title: str):
    """The equilibrium configuration drawn in 3D (one frame of mbsim.view.render) and the
    analysis' scalar findings beside it."""
    from mbsim.view.geometry import read_scene
    from mbsim.view.render import render_frames

    scene = read_scene(result)
    fig, (ax,) = _new_figure((9.0, 5.0))
    if scene.meshes:
        image = next(render_frames(scene, [len(scene.t) - 1], "iso",
                                   scene.layout.get("gravity"), 500, labels=True))  # fmt: skip
        ax.imshow(np.asarray(image))
    ax.set_axis_off()
    facts = [f"{k}: {v:.4g}" if isinstance(v, float) else f"{k}: {v}"
             for k, v in result.summary.items()
             if isinstance(v, (int, float, str)) and not isinstance(v, bool)][:8]  # fmt: skip
    if facts:
        ax.text(1.02, 1.0, "\n".join(facts), transform=ax.transAxes, va="top",
                fontsize="small", family="monospace")  # fmt: skip
    ax.set_title(_title(f"{title}: configuration", result.complete))
    return fig


def mode_chart(result: Result, title: str):
    """Natural frequency of each mode (one bar a row, conjugates once) with its damping
    ratio written at the bar's end; neutral modes named in a footnote."""
    lam = np.asarray(result.arrays["linear/eigenvalues"][0])
    neutral = np.asarray(result.arrays.get("linear/neutral", (np.zeros(len(lam)),))[0], bool)
    rows = [k for k in range(len(lam)) if not neutral[k] and lam[k].imag >= 0]
    fig, (ax,) = _new_figure((7.0, 1.2 + 0.35 * max(len(rows), 1)))
    freq = np.array([abs(lam[k]) / (2 * np.pi) for k in rows])
    ax.barh(np.arange(len(rows)), freq, color="C0", height=0.6)
    top = float(freq.max()) if len(rows) else 1.0
    for i, k in enumerate(rows):
        zeta = -lam[k].real / abs(lam[k]) if abs(lam[k]) else 0.0
        kind = "growing" if lam[k].real > 0 else ("real" if lam[k].imag == 0 else "")
        ax.text(freq[i] + 0.01 * top, i, f"{freq[i]:.4g} Hz, zeta {zeta:.3g} {kind}".strip(),
                va="center", fontsize="small")  # fmt: skip
    ax.set_yticks(np.arange(len(rows)), [f"mode {k + 1}" for k in rows])
    ax.invert_yaxis()
    ax.set_xlim(0, 1.45 * top if top > 0 else 1.0)
    ax.set_xlabel("natural frequency |lambda| / 2 pi [Hz]")
    n_neutral = int(neutral.sum())
    note = f"; {n_neutral} neutral mode(s) not shown" if n_neutral else ""
    ax.set_title(f"{title}: {result.summary.get('stability', '')}{note}", fontsize="medium")
    ax.grid(True, axis="x", alpha=0.3)
    return fig
