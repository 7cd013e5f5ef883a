"""Work-precision (mbsim.analyses.bench) and the `mbsim bench` command."""

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from mbsim.analyses.bench import interpolate_cost, work_precision, work_precision_figure
from tests.integrators import models as M

ROOT = Path(__file__).resolve().parents[2]


def test_work_precision_ladder():
    """Errors fall as the tolerance (or step) tightens; the table and the plot come out."""
    model = M.slider_crank()
    q, qd = M.slider_crank_state(model, 2 * np.pi)
    bench = work_precision(
        model,
        ["projection", "rk4"],
        tolerances=(1e-3, 1e-6),
        steps=(0.01, 0.005),
        t_end=0.2,
        options={"q0": q, "qd0": qd},
    )
    rows = {(r.integrator, r.setting): r for r in bench.rows}
    assert rows["projection", "rtol=1e-06"].error < rows["projection", "rtol=0.001"].error
    assert rows["rk4", "h=0.005"].error < rows["rk4", "h=0.01"].error / 8  # 4th order
    assert all(r.status == "complete" and r.wall > 0 for r in bench.rows)
    assert "projection" in bench.table() and "h=0.005" in bench.table()
    cost = bench.cost_to_reach(1e-3)
    assert set(cost) == {"projection", "rk4"}
    fig = work_precision_figure(bench)
    assert fig.axes[0].get_xscale() == "log" and len(fig.axes[0].lines) == 2


def test_interpolated_cost():
    pts = [(1.0, 1e-3), (2.0, 1e-5)]
    assert interpolate_cost(pts, 1e-4) == pytest.approx(np.sqrt(2.0))
    assert np.isnan(interpolate_cost(pts, 1e-9))


def test_bench_command(tmp_path):
    pytest.importorskip("yaml")
    from mbsim.cli_dynamic import bench_command

    deck = ROOT / "models" / "slider_crank.yaml"
    if not deck.exists():
        pytest.skip("models/slider_crank.yaml not present")
    out = tmp_path / "wp.png"
    res = CliRunner().invoke(
        bench_command,
        [
            str(deck),
            "--scene",
            "free",
            "--t-end",
            "0.1",
            "--integrators",
            "projection,genalpha",
            "--tolerances",
            "1e-3,1e-5",
            "-o",
            str(out),
        ],
    )
    assert res.exit_code == 0, res.output
    assert "max error" in res.output and "1e-06" in res.output
    assert out.exists() and out.stat().st_size > 1000
