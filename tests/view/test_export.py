"""Exchange formats: ``mbsim export --vtk`` (read back with meshio), ``--parquet`` and
``mbsim.read(path).frame(group)`` (pandas)."""

import re
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import mbsim
from mbsim.cli import main
from mbsim.rotations import A

MODELS = Path(__file__).resolve().parents[2] / "models"


@pytest.fixture(scope="module")
def slider_h5(tmp_path_factory):
    """The slider-crank's kinematic run, 0.2 s (41 outputs)."""
    out = tmp_path_factory.mktemp("export") / "slider.h5"
    res = CliRunner().invoke(main, ["run", str(MODELS / "slider_crank.yaml"), "--mode",
                                    "kinematic", "--t-end", "0.2", "-o", str(out)])  # fmt: skip
    assert res.exit_code == 0, res.output
    return out


def test_vtk_series_reads_back_with_meshio(slider_h5, tmp_path):
    meshio = pytest.importorskip("meshio")
    from mbsim.output import read_result

    res = CliRunner().invoke(main, ["export", str(slider_h5), "--vtk", str(tmp_path / "vtk")])
    assert res.exit_code == 0, res.output
    result = read_result(slider_h5)
    t, names, k = result.t, result.names["bodies"], 17
    r = {b: result.channels[f"bodies/{b}/r"].data[k] for b in names}
    p = {b: result.channels[f"bodies/{b}/p"].data[k] for b in names}
    verts = result.arrays["shapes/slider/vertices"][0]
    pvd = (tmp_path / "vtk" / "slider_shapes.pvd").read_text()
    steps = [float(x) for x in re.findall(r'timestep="([^"]+)"', pvd)]
    assert steps == pytest.approx(t, rel=0, abs=0)  # repr of each float64: exact
    points_pvd = (tmp_path / "vtk" / "slider_points.pvd").read_text()
    files = re.findall(r'file="([^"]+)"', points_pvd)
    assert len(files) == len(t)
    pts = meshio.read(tmp_path / "vtk" / files[k])
    i = names.index("slider")
    np.testing.assert_array_equal(pts.points[i], r["slider"])  # float64 written, exact
    shapes = meshio.read(tmp_path / "vtk" / re.findall(r'file="([^"]+)"', pvd)[k])
    body = np.asarray(shapes.cell_data["body"][0]).reshape(-1)
    tri = shapes.cells_dict["triangle"][body == i]
    got = shapes.points[np.unique(tri)]
    want = r["slider"] + verts @ A(p["slider"]).T
    np.testing.assert_allclose(np.sort(got, axis=0), np.sort(want, axis=0), atol=1e-6)  # float32


def test_frame_of_a_body_is_indexed_by_time_with_units(slider_h5):
    pd = pytest.importorskip("pandas")
    f = mbsim.read(slider_h5)
    df = f.frame("bodies/slider")
    assert isinstance(df, pd.DataFrame)
    assert df.index.name == "time [s]"
    np.testing.assert_array_equal(df.index.to_numpy(), f.result.t)
    assert "bodies/slider/r/x [m]" in df.columns
    assert "bodies/slider/p/e0" in df.columns  # dimensionless: no brackets
    np.testing.assert_array_equal(df["bodies/slider/r/x [m]"].to_numpy(),
                                  f.result.channels["bodies/slider/r"].data[:, 0])
    assert list(f.frame("bodies.slider.r").columns) == [f"bodies/slider/r/{c} [m]" for c in "xyz"]
    with pytest.raises(KeyError, match="did you mean"):
        f.frame("bodies/slidr")


def test_frame_without_pandas_says_how_to_get_it(slider_h5, monkeypatch):
    from mbsim.errors import UsageError

    monkeypatch.setitem(sys.modules, "pandas", None)
    with pytest.raises(UsageError, match=r"pip install 'mbsim\[pandas\]'"):
        mbsim.read(slider_h5).frame()


def test_parquet_matches_the_frame(slider_h5, tmp_path):
    pd = pytest.importorskip("pandas")
    pytest.importorskip("pyarrow")
    out = tmp_path / "s.parquet"
    res = CliRunner().invoke(main, ["export", str(slider_h5), "--parquet", str(out)])
    assert res.exit_code == 0, res.output
    assert f"parquet -> {out}" in res.output
    pd.testing.assert_frame_equal(pd.read_parquet(out), mbsim.read(slider_h5).frame())


def test_export_vtk_into_a_missing_parent_is_one_error_line(slider_h5, tmp_path):
    res = CliRunner().invoke(main, ["export", str(slider_h5), "--vtk",
                                    str(tmp_path / "no" / "dir")])  # fmt: skip
    assert res.exit_code == 2
    assert res.output.strip().startswith("error:") and "does not exist" in res.output
    assert len(res.output.strip().splitlines()) == 1
