"""HDF5 round trip, atomic writes, incomplete results, and CSV export."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

import mbsim
from mbsim.output import export, hdf5
from mbsim.output.hdf5 import list_channels, read_result, write_result
from mbsim.result import STATUS_INCOMPLETE, Result


def make_result(nt: int = 2001, status: str = "complete") -> Result:
    """A crank with a vector position channel and a scalar torque channel."""
    t = np.linspace(0.0, 2.0, nt)
    r = Result(
        mode="kinematic",
        t=t,
        status=status,
        message="" if status == "complete" else "t = 2 s: Newton did not converge: REV2",
        settings={"t_end": 2.0, "tol": np.float64(1e-10), "steps": np.int64(200), "x": (1, 2)},
        counters={"steps": 200, "newton_iterations": 612},
        summary={"dof": np.int64(1), "eig": np.array([1 + 2j, 1 - 2j]), "nan": float("nan")},
        deck_file="models/slider_crank.yaml",
        deck_text="bodies:\n  crank: {mass: 1.0}  # µ, π\n",
        wall_time=0.25,
        names={"bodies": ["ground", "crank", "rod"], "joints": ["REV1", "REV2"], "forces": []},
    )
    r.add(
        "bodies/crank/r",
        np.column_stack([np.cos(t), np.sin(t), 0 * t]),
        "m",
        "centroid position",
        ("x", "y", "z"),
    )
    r.add("drivers/crank/torque", 3.0 * np.sin(2 * t), "N m", "driving torque")
    r.add("joints/REV1/force", np.ones((nt, 3)), "N", "reaction")  # no component labels
    return r


def assert_same(a: Result, b: Result) -> None:
    assert a.mode == b.mode and a.status == b.status and a.message == b.message
    np.testing.assert_array_equal(a.t, b.t)
    assert list(a.channels) == list(b.channels)
    for name, ch in a.channels.items():
        other = b.channels[name]
        np.testing.assert_array_equal(ch.data, other.data)
        assert (ch.unit, ch.description, ch.components) == (
            other.unit,
            other.description,
            other.components,
        )
    assert a.names == b.names
    assert a.deck_file == b.deck_file and a.deck_text == b.deck_text
    assert a.wall_time == b.wall_time
    assert a.counters == b.counters


def test_round_trip(tmp_path):
    r = make_result()
    path = write_result(r, tmp_path / "out.h5")
    back = read_result(path)
    assert_same(back, r)
    assert back.settings == {"t_end": 2.0, "tol": 1e-10, "steps": 200, "x": [1, 2]}
    assert back.summary["dof"] == 1
    assert back.summary["eig"] == [1 + 2j, 1 - 2j]
    assert np.isnan(back.summary["nan"])
    assert back.channels["bodies/crank/r"].components == ("x", "y", "z")
    assert back.channels["joints/REV1/force"].components == ()


def test_layout(tmp_path):
    path = write_result(make_result(), tmp_path / "out.h5")
    with h5py.File(path) as f:
        assert f.attrs["mbsim_version"] == mbsim.__version__
        assert f.attrs["status"] == "complete"
        assert json.loads(f.attrs["counters"]) == {"steps": 200, "newton_iterations": 612}
        assert "T" in f.attrs["created"]
        assert f["time"].attrs["unit"] == "s"
        ds = f["bodies/crank/r"]
        assert ds.dtype == np.float64 and ds.shape == (2001, 3)
        assert ds.attrs["unit"] == "m" and list(ds.attrs["components"]) == ["x", "y", "z"]
        assert ds.compression == "gzip" and ds.shuffle and ds.chunks[1] == 3
        assert f["drivers/crank/torque"].compression == "gzip"
        assert "µ" in f["deck"].asstr()[()]
        assert list(f["names/joints"].asstr()[()]) == ["REV1", "REV2"]
    small = write_result(make_result(nt=11), tmp_path / "small.h5")
    with h5py.File(small) as f:
        assert f["bodies/crank/r"].compression is None


def test_list_channels(tmp_path):
    path = write_result(make_result(nt=5), tmp_path / "out.h5")
    assert list_channels(path) == [
        ("bodies/crank/r", (5, 3), "m", "centroid position"),
        ("drivers/crank/torque", (5,), "N m", "driving torque"),
        ("joints/REV1/force", (5, 3), "N", "reaction"),
    ]


def test_incomplete_result(tmp_path):
    r = make_result(nt=7, status=STATUS_INCOMPLETE)
    back = read_result(write_result(r, tmp_path / "fail.h5"))
    assert back.status == STATUS_INCOMPLETE and not back.complete
    assert "REV2" in back.message
    assert back.t.shape == (7,)


def test_empty_result(tmp_path):
    r = Result(mode="assembly", t=np.zeros(0))
    back = read_result(write_result(r, tmp_path / "empty.h5"))
    assert back.t.shape == (0,) and back.channels == {} and back.settings == {}


def test_atomic_write_keeps_old_file(tmp_path, monkeypatch):
    target = tmp_path / "out.h5"
    old = make_result(nt=5)
    write_result(old, target)

    calls = []

    def boom(f, path, channel):
        calls.append(path)
        if len(calls) == 2:
            raise RuntimeError("disk on fire")
        f.create_dataset(path, data=channel.data)

    monkeypatch.setattr(hdf5, "_write_channel", boom)
    new = make_result(nt=9)
    with pytest.raises(hdf5.OutputError, match="disk on fire.*left as it was"):
        write_result(new, target)  # h5py's RuntimeError becomes one clean error (exit 1)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.h5"]
    assert_same(read_result(target), old)


def test_reserved_channel_names(tmp_path):
    r = make_result(nt=3)
    r.add("time", np.zeros(3))
    with pytest.raises(ValueError, match="reserved"):
        write_result(r, tmp_path / "x.h5")
    r = make_result(nt=3)
    r.add("bodies/crank", np.zeros(3))
    with pytest.raises(ValueError, match="group"):
        write_result(r, tmp_path / "x.h5")
    assert list(tmp_path.iterdir()) == []


def test_export_csv_round_trip(tmp_path):
    r = make_result(nt=50)
    (path,) = export.export_csv(r, tmp_path / "out.csv")
    header = path.read_text().splitlines()[0].split(",")
    assert header[:4] == [
        "time [s]",
        "bodies/crank/r/x [m]",
        "bodies/crank/r/y [m]",
        "bodies/crank/r/z [m]",
    ]
    assert header[4] == "drivers/crank/torque [N m]"
    assert header[5] == "joints/REV1/force[0] [N]"
    table = np.loadtxt(path, delimiter=",", skiprows=1)
    expected = np.column_stack(
        [
            r.t,
            r.channels["bodies/crank/r"].data,
            r.channels["drivers/crank/torque"].data,
            r.channels["joints/REV1/force"].data,
        ]
    )
    np.testing.assert_array_equal(table, expected)  # shortest repr round-trips exactly


def test_export_csv_selection_and_directory(tmp_path):
    r = make_result(nt=4)
    (path,) = export.export_csv(r, tmp_path, channels=["bodies.crank.r.y", "drivers.crank.torque"])
    assert path == tmp_path / "slider_crank.csv"
    table = np.loadtxt(path, delimiter=",", skiprows=1)
    np.testing.assert_array_equal(table[:, 1], r.channels["bodies/crank/r"].data[:, 1])
    assert table.shape == (4, 3)
    with pytest.raises(KeyError, match="drivers.crank.torque"):
        export.export_csv(r, tmp_path / "x.csv", channels=["drivers.crank.torqe"])
