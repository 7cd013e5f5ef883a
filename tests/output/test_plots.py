"""Plots: files in each format, axis labels, component selection, error messages."""

from __future__ import annotations

import numpy as np
import pytest

from mbsim.output.plots import plot_channels, plot_results, save_figure
from mbsim.result import Result


def make_result(k: float = 1.0, status: str = "complete") -> Result:
    t = np.linspace(0.0, 1.0, 101)
    r = Result(mode="dynamic", t=t, status=status)
    r.add(
        "bodies/crank/r",
        np.column_stack([np.cos(k * t), np.sin(k * t), 0 * t]),
        "m",
        "centroid",
        ("x", "y", "z"),
    )
    r.add("drivers/crank/torque", k * t, "N m", "torque")
    return r


@pytest.mark.parametrize("suffix", [".png", ".svg", ".pdf"])
def test_save_formats(tmp_path, suffix):
    fig = plot_channels(make_result(), ["drivers.crank.torque", "bodies/crank/r"])
    path = save_figure(fig, tmp_path / f"plot{suffix}")
    assert path.exists() and path.stat().st_size > 500


def test_save_unknown_format(tmp_path):
    fig = plot_channels(make_result(), ["drivers.crank.torque"])
    with pytest.raises(ValueError, match=r"\.png"):
        save_figure(fig, tmp_path / "plot.jpg")


def test_axis_labels_and_title():
    fig = plot_channels(make_result(), ["drivers.crank.torque"])
    ax = fig.axes[0]
    assert ax.get_xlabel() == "time [s]"
    assert ax.get_ylabel() == "drivers/crank/torque [N m]"
    assert ax.get_title() == ""
    fig = plot_channels(make_result(status="incomplete"), ["drivers.crank.torque"], title="Crank")
    assert fig.axes[0].get_title() == "Crank (incomplete)"


def test_vector_channel_plots_each_component():
    ax = plot_channels(make_result(), ["bodies.crank.r"]).axes[0]
    assert [ln.get_label() for ln in ax.get_lines()] == ["x", "y", "z"]
    assert ax.get_ylabel() == "bodies/crank/r [m]"


@pytest.mark.parametrize("selector", ["bodies.crank.r[1]", "bodies.crank.r.y", "bodies/crank/r/y"])
def test_component_selection(selector):
    r = make_result()
    ax = plot_channels(r, [selector]).axes[0]
    (line,) = ax.get_lines()
    np.testing.assert_array_equal(line.get_ydata(), r.channels["bodies/crank/r"].data[:, 1])
    assert ax.get_ylabel() == "bodies/crank/r/y [m]"


def test_phase_plot_x_channel():
    r = make_result()
    ax = plot_channels(r, ["bodies.crank.r.y"], x="bodies.crank.r.x").axes[0]
    assert ax.get_xlabel() == "bodies/crank/r/x [m]"
    with pytest.raises(ValueError, match="one column"):
        plot_channels(r, ["bodies.crank.r.y"], x="bodies.crank.r")


def test_unknown_channel_suggests_names():
    with pytest.raises(KeyError, match=r"did you mean drivers\.crank\.torque"):
        plot_channels(make_result(), ["drivers.crank.torqe"])


def test_bad_component():
    with pytest.raises(KeyError, match="components: x, y, z"):
        plot_channels(make_result(), ["bodies.crank.r.w"])
    with pytest.raises(IndexError, match="out of range"):
        plot_channels(make_result(), ["bodies.crank.r[3]"])


def test_labels_override():
    ax = plot_channels(make_result(), ["bodies.crank.r"], labels=["a", "b", "c"]).axes[0]
    assert [ln.get_label() for ln in ax.get_lines()] == ["a", "b", "c"]
    with pytest.raises(ValueError, match="labels"):
        plot_channels(make_result(), ["bodies.crank.r"], labels=["a"])


def test_plot_results_one_curve_per_case(tmp_path):
    cases = [(f"k = {k}", make_result(k)) for k in (1000, 2000, 3000)]
    cases.append(("k = 4000", make_result(4000, status="incomplete")))
    fig = plot_results(cases, "drivers.crank.torque", title="Stiffness study")
    ax = fig.axes[0]
    assert [ln.get_label() for ln in ax.get_lines()] == [
        "k = 1000",
        "k = 2000",
        "k = 3000",
        "k = 4000 (incomplete)",
    ]
    assert ax.get_ylabel() == "drivers/crank/torque [N m]"
    assert ax.get_title() == "Stiffness study (incomplete)"
    assert save_figure(fig, tmp_path / "study.png").stat().st_size > 0
