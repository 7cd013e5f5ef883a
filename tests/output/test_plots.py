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


# -- issue 14: one quantity per axes, legends outside, styles, display units, export ---------


def test_one_axes_per_physical_quantity_with_display_units():
    """m and N m never share an axis; --units deg,mm shows lengths in mm (x 1000) while the
    stored data stay SI; the shared x axis is labelled once, at the bottom."""
    r = make_result()
    fig = plot_channels(r, ["drivers.crank.torque", "bodies.crank.r"], units=["deg", "mm"])
    top, bottom = fig.axes
    assert top.get_ylabel() == "drivers/crank/torque [N m]"
    assert bottom.get_ylabel() == "bodies/crank/r [mm]" and bottom.get_xlabel() == "time [s]"
    np.testing.assert_allclose(bottom.get_lines()[0].get_ydata(),
                               1000 * r.channels["bodies/crank/r"].data[:, 0])
    assert r.channels["bodies/crank/r"].data[0, 0] == 1.0  # the result is untouched


def test_coinciding_curves_get_different_line_styles_and_the_legend_is_outside():
    fig = plot_channels(make_result(), ["bodies.crank.r"])
    ax = fig.axes[0]
    styles = [ln.get_linestyle() for ln in ax.get_lines()]
    assert len(set(styles)) == 3  # z = 0 is drawn over nothing else, but x, y, z differ
    fig.canvas.draw()
    leg = ax.get_legend().get_window_extent()
    assert leg.x0 >= ax.get_window_extent().x1 - 1  # right of the data area


def test_parameter_labels_for_sweep_legends():
    from mbsim.output.plots import case_label, parameter_label

    assert parameter_label("omega", 2 * np.pi) == "ω = 2π"
    assert parameter_label("parameters.omega", -np.pi / 2) == "ω = −π/2"
    assert parameter_label("k", "2000") == "k = 2000"
    assert parameter_label("omega", "-4*pi") == "ω = −4π"  # a sweep value as written
    assert parameter_label("v0", "55 mph") == "v0 = 55 mph"
    assert parameter_label("forces.spring.c", 30.5) == "c = 30.5"
    r = make_result()
    r.settings = {"sweep": {"values": {"omega": "6.283185307179586", "k": "1000"}}}
    assert case_label(r, "omega=2-pi") == "ω = 2π, k = 1000"
    assert case_label(make_result(), "stem") == "stem"


def test_export_plot_data(tmp_path):
    import csv

    from mbsim.output.plots import export_plot_data

    r = make_result()
    fig = plot_channels(r, ["drivers.crank.torque", "bodies.crank.r.x"], units=["mm"])
    rows = list(csv.reader(open(export_plot_data(fig, tmp_path / "d.csv"))))
    # named as export_csv names columns (issue 26: one channel naming in every export)
    assert rows[0] == ["time [s]", "drivers/crank/torque [N m]", "bodies/crank/r/x [mm]"]
    assert float(rows[11][2]) == pytest.approx(1000 * np.cos(0.1))
    cases = [("a", make_result(1.0)), ("b", make_result(2.0))]
    rows = list(csv.reader(open(export_plot_data(plot_results(cases, "drivers.crank.torque"),
                                                 tmp_path / "e.csv"))))
    assert rows[0] == ["time [s]", "a [N m]", "b [N m]"]


def test_root_locus_threshold_by_interpolation():
    """A synthetic family lambda = (C - 9700)/1e4 +- 6i: max Re changes sign at C = 9700,
    found exactly by linear interpolation between the cases at 7500 and 12500."""
    from mbsim.output.locus import crossings, root_locus

    def case(C):
        r = Result(mode="linear", t=np.zeros(1))
        lam = np.array([0, -1.0, (C - 9700) / 1e4 + 6j, (C - 9700) / 1e4 - 6j])
        r.arrays = {"linear/eigenvalues": (lam, {}),
                    "linear/neutral": (np.array([1, 0, 0, 0], np.int8), {})}
        return r

    cases = [({"C": C}, case(C)) for C in (5000.0, 7500.0, 12500.0, 17500.0)]
    fig, found = root_locus(cases, "C")
    assert len(found) == 1 and found[0].value == pytest.approx(9700.0)
    assert found[0].direction == "destabilising" and (found[0].low, found[0].high) == (7500, 12500)
    assert crossings([1, 2, 3], [0.5, -0.5, -1.0])[0].direction == "stabilising"
    assert len(fig.axes) == 3  # locus, growth rate, colour bar
