"""`mbsim plot`: several files are legend entries in numeric order of their names (a shell's
`DIR/*.h5` gives k10, k200, k50), and `plot --data` names columns as `mbsim export` does."""

from pathlib import Path

import pytest
from click.testing import CliRunner

from mbsim.cli import main

MODELS = Path(__file__).resolve().parents[2] / "models"


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def cases(tmp_path_factory):
    d = tmp_path_factory.mktemp("cases")
    for w in (10, 200, 50):
        res = run("run", MODELS / "slider_crank.yaml", "--mode", "kinematic", "--t-end", "0.05",
                  "--set", f"parameters.omega=-{w}", "-o", d / f"k{w}.h5")
        assert res.exit_code == 0, res.output
    return d


def test_legend_follows_the_numbers_in_the_file_names(cases, tmp_path, monkeypatch):
    import mbsim.output.plots as plots

    seen = []
    real = plots.plot_results
    monkeypatch.setattr(plots, "plot_results",
                        lambda c, *a, **k: seen.append(c) or real(c, *a, **k))
    files = sorted(cases.glob("*.h5"))  # string order: k10, k200, k50
    res = run("plot", *files, "bodies.slider.r.x", "-o", tmp_path / "p.png")
    assert res.exit_code == 0, res.output
    assert [label for label, _ in seen[0]] == ["k10", "k50", "k200"]
    fig = real(seen[0], "bodies.slider.r.x")
    assert [t.get_text() for t in fig.axes[0].get_legend().get_texts()] == ["k10", "k50", "k200"]


def test_plot_data_columns_are_named_as_in_export(cases, tmp_path):
    f = cases / "k10.h5"
    res = run("plot", f, "bodies.slider.r.x", "drivers.crank.torque", "-o", tmp_path / "p.png",
              "--data", tmp_path / "d.csv")
    if res.exit_code != 0:  # a kinematic run has no driver torque: plot positions only
        res = run("plot", f, "bodies.slider.r", "-o", tmp_path / "p.png", "--data",
                  tmp_path / "d.csv")
    assert res.exit_code == 0, res.output
    plotted = (tmp_path / "d.csv").read_text().splitlines()[0].split(",")[1:]
    run("export", f, "--csv", tmp_path / "e.csv")
    exported = (tmp_path / "e.csv").read_text().splitlines()[0].split(",")
    assert plotted and set(plotted) <= set(exported), (plotted, exported[:5])
