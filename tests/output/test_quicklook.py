"""`mbsim run --plot` quick looks (mbsim.output.quicklook), checked on the figures' artists
and labels, not on pixels (issue 26)."""

from pathlib import Path

import numpy as np
import pytest

from mbsim.api import load_model, run_model
from mbsim.output.export import Column
from mbsim.output.quicklook import fold, quick_look
from mbsim.result import Result

MODELS = Path(__file__).resolve().parents[2] / "models"


def run(deck, mode, **options):
    spec, model = load_model(MODELS / deck)
    return run_model(model, mode, options, deck=spec)


def legend_texts(fig):
    return [t.get_text() for ax in fig.axes if ax.get_legend()
            for t in ax.get_legend().get_texts()]  # fmt: skip


def test_inverse_quick_look_names_channels_with_units_and_folds_zeros():
    res = run("slider_crank.yaml", "inverse", t_end=0.2, step=0.01)
    fig = quick_look(res)
    texts = legend_texts(fig)
    assert "drivers.crank.torque [N m]" in texts  # the driving torque, with its unit
    assert not any("/" in t for t in texts)  # no raw HDF5 paths
    zero = [t for t in texts if t.startswith("zero [m]:")]
    assert len(zero) == 1 and "points.slider.position.y" in zero[0]
    assert [ax.get_ylabel() for ax in fig.axes] == ["[N m]", "[m]"]  # a panel per unit
    assert fig.axes[-1].get_xlabel() == "time [s]"


def test_dynamic_quick_look_shows_energy_and_force_elements():
    res = run("governor.yaml", "dynamic", t_end=0.2, step=0.01, error_estimate=False)
    texts = legend_texts(quick_look(res))
    assert "monitors.energy [J]" in texts and "forces.spring.force [N]" in texts


def test_fold_joins_identical_curves_and_zero_to_round_off():
    t = np.linspace(0, 1, 5)
    cols = [Column("a/x", np.sin(t), "m", "a", "x"),
            Column("b/x", np.sin(t) + 1e-18, "m", "b", "x"),
            Column("c", 1e-17 * np.ones(5), "m", "c", ""),
            Column("d", np.zeros(5), "N", "d", "")]
    labels = [c[0] for c in fold(cols)]
    assert labels == ["a.x [m], b.x [m]", "zero [m]:\n  c", "zero [N]:\n  d"]


def test_equilibrium_quick_look_draws_the_configuration():
    res = run("governor.yaml", "equilibrium")
    fig = quick_look(res)
    (ax,) = fig.axes
    assert len(ax.images) == 1 and ax.images[0].get_array().shape[:2] == (500, 500)
    assert "configuration" in ax.get_title()
    assert not ax.lines  # no one-sample time plot


def test_linear_quick_look_is_a_mode_chart_without_overprint():
    res = run("governor.yaml", "linear")
    fig = quick_look(res)
    (ax,) = fig.axes
    ticks = [t.get_text() for t in ax.get_yticklabels()]
    assert ticks == ["mode 3"]  # the oscillating pair once; the 2 neutral modes in the title
    assert "2 neutral mode(s) not shown" in ax.get_title()
    notes = [t.get_text() for t in ax.texts]
    assert len(notes) == 1 and notes[0].startswith("1.04") and "Hz, zeta 0.07" in notes[0]
    assert ax.get_xlabel().endswith("[Hz]")


@pytest.mark.filterwarnings("ignore:No artists with labels")  # a bench without rows
def test_bench_figure_axes_have_units():
    from mbsim.analyses.bench import Bench, work_precision_figure

    bench = Bench(deck="d", t_end=1.0, outputs=["bodies/*/r"], reference={}, rows=[])
    ax = work_precision_figure(bench).axes[0]
    assert ax.get_xlabel() == "wall time per simulated second [s/s]"
    assert ax.get_ylabel() == "max error of bodies.*.r [m]"


def test_empty_result_has_no_quick_look():
    assert quick_look(Result(mode="kinematic", t=np.zeros(0))) is None
