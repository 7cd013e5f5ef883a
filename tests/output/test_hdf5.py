"""HDF5 round trip, atomic writes, incomplete results, and CSV export."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

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
    """Layout version 3 (docs/hdf5.md): the channels are columns of /values, named by the
    table /channels (one compound dataset); the names one table (kind, name); settings,
    counters and summary are JSON datasets."""
    r = make_result()
    r.names = {"bodies": ["crank"], "joints": ["REV1", "REV2"], "drivers": []}
    path = write_result(r, tmp_path / "out.h5")
    with h5py.File(path) as f:
        assert f.attrs["layout_version"] == 3
        assert f.attrs["mbsim_version"] == mbsim.__version__
        assert f.attrs["status"] == "complete"
        assert json.loads(f["counters"].asstr()[()]) == {"steps": 200, "newton_iterations": 612}
        assert "T" in f.attrs["created"]
        assert f["time"].attrs["unit"] == "s"
        ch = f["channels"][()]
        assert ch.dtype.names == ("name", "unit", "description", "components", "column",
                                  "width", "shape")
        assert f["channels"].id.get_type().get_member_type(0).get_cset() == h5py.h5t.CSET_UTF8
        names = [n.decode() for n in ch["name"]]
        assert names == ["bodies/crank/r", "drivers/crank/torque", "joints/REV1/force"]
        assert list(ch["column"]) == [0, 3, 4]
        assert list(ch["width"]) == [3, 1, 3]
        assert [s.decode() for s in ch["shape"]] == ["[3]", "[]", "[3]"]
        assert json.loads(ch["components"][0]) == ["x", "y", "z"]
        assert [u.decode() for u in ch["unit"]] == ["m", "N m", "N"]
        values = f["values"]
        assert values.dtype == np.float64 and values.shape == (2001, 7)
        assert values.compression is None and values.chunks is None  # contiguous (docs)
        assert "µ" in f["deck"].asstr()[()]
        nm = f["names"][()]
        assert [(k.decode(), n.decode()) for k, n in zip(nm["kind"], nm["name"])] == [
            ("bodies", "crank"), ("joints", "REV1"), ("joints", "REV2")]
        assert json.loads(f["names"].attrs["kinds"]) == ["bodies", "joints", "drivers"]
        assert set(f.attrs) == {"layout_version", "mbsim_version", "mode", "status", "message",
                                "deck_file", "wall_time_s", "created"}
    assert read_result(path).names == r.names  # a kind without items comes back empty


def test_shapes_are_one_dataset_per_leaf_and_an_index(tmp_path):
    """/shapes/<leaf> holds the rows of every body, /shapes/index (leaf, item, start, stop)
    says whose; read back per body with the leaf's attributes."""
    r = make_result(nt=5)
    for body, n in (("crank", 4), ("rod", 2)):
        r.arrays[f"shapes/{body}/vertices"] = (np.full((n, 3), float(n)), {"unit": "m"})
        r.arrays[f"shapes/{body}/faces"] = (np.zeros((n - 1, 3), dtype=np.int32), {})
    r.arrays["shapes/layout"] = (np.array(["{}"]), {"format": "JSON"})
    path = write_result(r, tmp_path / "s.h5")
    with h5py.File(path) as f:
        assert f["shapes/vertices"].shape == (6, 3) and f["shapes/faces"].shape == (4, 3)
        index = f["shapes/index"][()]
        rows = [(a.decode(), b.decode(), int(c), int(d)) for a, b, c, d in
                zip(index["leaf"], index["item"], index["start"], index["stop"])]
        assert rows == [("vertices", "crank", 0, 4), ("vertices", "rod", 4, 6),
                        ("faces", "crank", 0, 3), ("faces", "rod", 3, 4)]
        assert f["shapes/vertices"].compression is None  # small: stored as it is
        info = h5py.check_string_dtype(f["shapes/layout"].dtype)  # the JSON: a str dataset
        assert info.encoding == "utf-8" and info.length is None  # variable-length, as h5py's
        assert f["shapes/layout"].attrs["format"] == "JSON"
    back = read_result(path)
    assert set(back.arrays) == set(r.arrays)
    assert str(back.arrays["shapes/layout"][0][0]) == "{}"
    np.testing.assert_array_equal(back.arrays["shapes/rod/vertices"][0], np.full((2, 3), 2.0))
    assert back.arrays["shapes/rod/vertices"][1] == {"unit": "m"}
    assert back.arrays["shapes/rod/faces"][0].dtype == np.int32


def test_large_meshes_are_compressed(tmp_path):
    """Meshes above hdf5.COMPRESS_MIN_SIZE elements are chunked and gzip-compressed, and
    read back unchanged."""
    r = make_result(nt=3)
    n = hdf5.COMPRESS_MIN_SIZE // 3 + 1
    verts = np.repeat(np.arange(n, dtype=float)[:, None] % 7, 3, axis=1)
    r.arrays["shapes/hull/vertices"] = (verts, {"unit": "m"})
    path = write_result(r, tmp_path / "big_mesh.h5")
    with h5py.File(path) as f:
        assert f["shapes/vertices"].compression == "gzip"
    np.testing.assert_array_equal(read_result(path).arrays["shapes/hull/vertices"][0], verts)


def test_a_governor_run_writes_fifteen_objects(tmp_path):
    """A default governor run's file: 15 HDF5 objects (35 in layout version 2: a dataset
    per column of the channel table, per kind of names, three per leaf of the shapes)."""
    from mbsim.cli import main

    out = tmp_path / "governor.h5"
    deck = Path(__file__).resolve().parents[2] / "models" / "governor.yaml"
    assert CliRunner().invoke(main, ["run", str(deck), "--mode", "dynamic", "--t-end", "0.1",
                                     "-o", str(out), "-q"]).exit_code == 0
    with h5py.File(out) as f:
        found: list[str] = []
        f.visit(found.append)
    assert len(found) == 15, found


def test_h5py_recipe_of_the_docs(tmp_path):
    """The five lines of docs/hdf5.md that read one channel with h5py alone."""
    r = make_result(nt=20)
    path = write_result(r, tmp_path / "slider_crank.h5")
    with h5py.File(path, "r") as f:
        ch = f["channels"][()]  # the channel table: one row per channel
        k = list(ch["name"]).index(b"bodies/crank/r")
        start, width = ch["column"][k], ch["width"][k]
        x = f["values"][:, start:start + width]  # (nt, 3), unit ch["unit"][k].decode()
        unit = ch["unit"][k].decode()
    np.testing.assert_array_equal(x, r.channels["bodies/crank/r"].data)
    assert unit == "m"


def test_a_model_of_thousands_of_channels_writes(tmp_path):
    """No attribute or header grows with the model: 30 000 channels (a 4096-link chain has
    about 29 000) write and read back; version 1 failed at ~7000 ("object header message
    is too large")."""
    r = Result(mode="dynamic", t=np.linspace(0, 1, 3))
    for i in range(10_000):
        r.add(f"bodies/link{i}/r", np.full((3, 3), float(i)), "m", "centroid", ("x", "y", "z"))
        r.add(f"bodies/link{i}/p", np.full((3, 4), -float(i)), "", "Euler parameters")
        r.add(f"measures/m{i}", np.full(3, 0.5 * i), "rad")
        r.arrays[f"shapes/link{i}/vertices"] = (np.full((4, 3), float(i)), {"unit": "m"})
        r.arrays[f"shapes/link{i}/faces"] = (np.arange(6, dtype=np.int32).reshape(2, 3), {})
    r.arrays["linear/eigenvalues"] = (np.array([1j, -1j]), {"unit": "1/s"})
    r.summary["redundant"] = [f"S{i}" for i in range(10_000)]  # a summary can grow too
    back = read_result(write_result(r, tmp_path / "big.h5"))
    assert list(back.channels) == list(r.channels)
    assert back.channels["bodies/link9999/p"].data[2, 3] == -9999.0
    assert back.channels["measures/m7"].data.shape == (3,)
    assert back.summary["redundant"][-1] == "S9999"
    assert set(back.arrays) == set(r.arrays)
    np.testing.assert_array_equal(back.arrays["shapes/link77/vertices"][0], np.full((4, 3), 77.0))
    assert back.arrays["shapes/link77/vertices"][1] == {"unit": "m"}
    assert back.arrays["shapes/link3/faces"][0].dtype == np.int32
    assert back.arrays["linear/eigenvalues"][0].dtype == np.complex128
    with h5py.File(tmp_path / "big.h5") as f:
        assert len(f) < 20  # a few datasets and groups at the root, not one per channel


def test_one_long_string_among_thousands_does_not_pad_the_table(tmp_path):
    """A 4096-link chain's constraints/lam names its 28 000 rows in one components entry
    (about 300 kB); padded to it, the channel table's 29 000 rows would take 9 GB.  Such a
    column is written variable-length: the file stays in proportion to its text, and reads
    back the same, with h5py alone too."""
    n, rows = 4000, [f"SPH{i}.{c}" for i in range(3000) for c in "xyz"]
    r = Result(mode="dynamic", t=np.linspace(0, 1, 2))
    for i in range(n):
        r.add(f"bodies/link{i}/r", np.zeros((2, 3)), "m", "centroid", ("x", "y", "z"))
    r.add("constraints/lam", np.zeros((2, len(rows))), "", "multipliers", rows)
    path = write_result(r, tmp_path / "long.h5")
    text = sum(len(json.dumps(list(c.components))) for c in r.channels.values())
    assert path.stat().st_size < 4 * (text + 100 * (n + 1))  # padded: n x 150 kB = 600 MB
    back = read_result(path)
    assert back.channels["constraints/lam"].components == tuple(rows)
    assert back.channels["bodies/link3999/r"].components == ("x", "y", "z")
    with h5py.File(path, "r") as f:
        ch = f["channels"][()]
        assert json.loads(ch["components"][-1]) == rows and ch["name"][0] == b"bodies/link0/r"


def test_files_of_layout_version_1_are_read(tmp_path):
    """A file of the old layout (written here by old_layout.write_v1, the version-1 writer
    as it was) reads back into the same Result through read_result, list_channels and
    read_info."""
    from tests.output.old_layout import write_v1

    r = make_result(nt=9)
    r.arrays["linear/eigenvalues"] = (np.array([1 + 2j, 1 - 2j]), {"unit": "1/s"})
    r.arrays["shapes/crank/vertices"] = (np.ones((4, 3)), {"unit": "m", "frame": "body"})
    r.attrs["stable"] = True
    path = write_v1(r, tmp_path / "v1.h5")
    back = read_result(path)
    assert_same(back, r)
    assert back.summary["eig"] == [1 + 2j, 1 - 2j]
    assert back.settings["x"] == [1, 2]
    assert set(back.arrays) == set(r.arrays) and bool(back.attrs["stable"])
    assert list_channels(path) == list_channels(write_result(r, tmp_path / "v2.h5"))
    info = hdf5.read_info(path)
    assert info["layout_version"] == 1 and info["counters"]["steps"] == 200
    assert info["channels"] == list(r.channels)


def test_files_of_layout_version_2_are_read(tmp_path):
    """A file of layout version 2 (old_layout.write_v2: the channel table and the names a
    dataset per column and per kind, shapes/<leaf>/data, item, start) reads back into the
    same Result."""
    from tests.output.old_layout import write_v2

    r = make_result(nt=9)
    r.names = {"bodies": ["crank", "rod"], "drivers": []}
    r.arrays["shapes/crank/vertices"] = (np.ones((4, 3)), {"unit": "m", "frame": "body"})
    r.arrays["shapes/rod/vertices"] = (np.zeros((2, 3)), {"unit": "m", "frame": "body"})
    path = write_v2(r, tmp_path / "v2.h5")
    back = read_result(path)
    assert_same(back, r)
    assert back.names == r.names
    assert set(back.arrays) == set(r.arrays)
    np.testing.assert_array_equal(back.arrays["shapes/rod/vertices"][0], np.zeros((2, 3)))
    assert list_channels(path) == list_channels(write_result(r, tmp_path / "v3.h5"))
    assert hdf5.read_info(path)["layout_version"] == 2


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

    def boom(f, arrays):
        f.create_dataset("half", data=np.zeros(3))
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(hdf5, "_write_arrays", boom)
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
