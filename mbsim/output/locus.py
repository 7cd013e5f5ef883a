"""Root locus of a linear analysis swept over a parameter (``mbsim sweep ... --mode linear``).

The eigenvalues of every case (``linear/eigenvalues``, neutral modes left out) are drawn in
the complex plane, coloured by the swept parameter; a second panel shows the largest growth
rate max Re(lambda) against the parameter, and the stability threshold is where it changes
sign, found by linear interpolation between the two cases around the crossing.  With several
``--param``, the last one is the locus parameter and each combination of the others is its
own curve (and threshold).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mbsim.output.plots import LINESTYLES, _new_figure, parameter_label


@dataclass
class Crossing:
    """Where max Re(lambda) changes sign between two cases of one curve."""

    group: str  # the other parameters' values ('' for a single --param)
    value: float  # interpolated parameter value
    low: float  # the bracketing cases' values
    high: float
    direction: str  # 'destabilising' (growth starts above) or 'stabilising'


def growth_rate(result) -> float:
    """max Re(lambda) over the non-neutral eigenvalues of a linear result (1/s)."""
    lam = np.asarray(result.arrays["linear/eigenvalues"][0])
    neutral = np.asarray(result.arrays["linear/neutral"][0], bool)
    lam = lam[~neutral]
    return float(lam.real.max()) if lam.size else float("nan")


def crossings(values, rates, group="") -> list[Crossing]:
    """Sign changes of ``rates`` along sorted ``values``, linearly interpolated."""
    order = np.argsort(values)
    v, g = np.asarray(values, float)[order], np.asarray(rates, float)[order]
    out = []
    for k in range(len(v) - 1):
        if np.isfinite(g[k]) and np.isfinite(g[k + 1]) and (g[k] < 0) != (g[k + 1] < 0):
            x = v[k] - g[k] * (v[k + 1] - v[k]) / (g[k + 1] - g[k])
            out.append(Crossing(group, float(x), float(v[k]), float(v[k + 1]),
                                "destabilising" if g[k + 1] > g[k] else "stabilising"))
    return out


def root_locus(cases, param: str, title: str | None = None):
    """(Figure, crossings) for ``cases`` = [(values dict label -> number, Result)], the locus
    along ``param`` (a key of the values dicts)."""
    from matplotlib import colormaps
    from matplotlib.colors import Normalize

    groups: dict[str, list] = {}
    for values, res in cases:
        other = ", ".join(parameter_label(k, v) for k, v in values.items() if k != param)
        groups.setdefault(other, []).append((float(values[param]), res))
    allv = [float(v[param]) for v, _ in cases]
    norm = Normalize(min(allv), max(allv) if max(allv) > min(allv) else min(allv) + 1)
    cmap = colormaps["viridis"]
    fig, _ = _new_figure((11.0, 4.8))
    fig.clear()
    ax, ax2 = fig.subplots(1, 2, width_ratios=[1.3, 1])
    markers = "os^Dv<>p"
    found = []
    for n, (group, items) in enumerate(groups.items()):
        items.sort(key=lambda it: it[0])
        for value, res in items:
            lam = np.asarray(res.arrays["linear/eigenvalues"][0])
            keep = ~np.asarray(res.arrays["linear/neutral"][0], bool) & (lam.imag >= 0)
            ax.scatter(lam.real[keep], lam.imag[keep], color=cmap(norm(value)),
                       marker=markers[n % len(markers)], s=28, edgecolor="k", lw=0.3)
        vals = [v for v, _ in items]
        rates = [growth_rate(r) for _, r in items]
        lab = group or "max Re(lambda)"
        ax2.plot(vals, rates, marker=markers[n % len(markers)], ls=LINESTYLES[n % 4],
                 color=f"C{n % 10}", label=lab)
        for c in crossings(vals, rates, group):
            found.append(c)
            ax2.axvline(c.value, color=f"C{n % 10}", lw=0.8, ls=":")
            ax2.annotate(f"{param} = {c.value:.5g}", (c.value, 0), textcoords="offset points",
                         xytext=(4, 6), fontsize="x-small", color=f"C{n % 10}")
        if group:
            ax.scatter([], [], marker=markers[n % len(markers)], color="0.6", edgecolor="k",
                       lw=0.3, label=group)
    ax.axvline(0.0, color="k", lw=0.8)
    ax.set_xlabel("Re(lambda) [1/s]")
    ax.set_ylabel("Im(lambda) [rad/s]")
    ax.grid(True, alpha=0.3)
    sm = __import__("matplotlib.cm", fromlist=["ScalarMappable"]).ScalarMappable(norm, cmap)
    fig.colorbar(sm, ax=ax, label=parameter_label(param, "").split(" =")[0])
    if len(groups) > 1:
        ax.legend(loc="upper left", bbox_to_anchor=(0.0, -0.14), fontsize="x-small",
                  ncols=min(4, len(groups)), frameon=False)
        ax2.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="x-small",
                   frameon=False)
    ax2.axhline(0.0, color="k", lw=0.8)
    ax2.set_xlabel(parameter_label(param, "").split(" =")[0])
    ax2.set_ylabel("largest growth rate max Re(lambda) [1/s]")
    ax2.grid(True, alpha=0.3)
    if title:
        fig.suptitle(title, fontsize="medium")
    return fig, found


def eigenvalue_plot(result, title: str | None = None):
    """The eigenvalues of one linear result in the complex plane (upper half plane and the
    real axis): filled markers, neutral ones hollow; each labelled ``f Hz, zeta``."""
    fig, (ax,) = _new_figure((7.0, 4.5))
    lam = np.asarray(result.arrays["linear/eigenvalues"][0])
    neutral = np.asarray(result.arrays["linear/neutral"][0], bool)
    keep = lam.imag >= 0
    for k in np.flatnonzero(keep):
        hollow = neutral[k]
        ax.plot(lam[k].real, lam[k].imag, "o", mfc="white" if hollow else "C0", mec="C0")
        if not hollow:
            zeta = -lam[k].real / abs(lam[k])
            ax.annotate(f"{abs(lam[k]) / (2 * np.pi):.3g} Hz, zeta {zeta:.2g}",
                        (lam[k].real, lam[k].imag), textcoords="offset points",
                        xytext=(5, 4), fontsize="x-small")
    ax.axvline(0.0, color="k", lw=0.8)
    ax.set_xlabel("Re(lambda) [1/s]")
    ax.set_ylabel("Im(lambda) [rad/s]")
    ax.grid(True, alpha=0.3)
    ax.set_title(title or f"eigenvalues: {result.summary.get('stability', '')}",
                 fontsize="medium")
    return fig


def sweep_root_locus(out_dir, records, params) -> tuple[Path | None, list[Crossing]]:
    """Draw ``root_locus.png`` in a sweep folder from its complete cases; the locus
    parameter is the last of ``params`` (labels as in the index).  Returns (path, crossings);
    (None, []) when fewer than two cases have numeric values."""
    from mbsim.output import read_result
    from mbsim.output.plots import save_figure

    out_dir = Path(out_dir)
    cases = []
    for rec in records:
        if rec.status != "complete" or not rec.file:
            continue
        try:
            values = {k: float(v) for k, v in rec.case.values.items()}
        except ValueError:
            return None, []
        cases.append((values, read_result(out_dir / rec.file)))
    if len(cases) < 2 or not params:
        return None, []
    fig, found = root_locus(cases, params[-1], title=f"root locus over {params[-1]}")
    path = save_figure(fig, out_dir / "root_locus.png")
    return path, found
