"""The writers of older layouts of mbsim.output.hdf5, kept to make files of those layouts for
the tests that they are still read.  Version 1 (before layout_version 2): a dataset per
channel at its slash path, settings/counters/summary/channels/arrays as root attributes.
Version 2 (before 3): the channel table and the names as a group of datasets each
(``/channels/name``, ``/names/<kind>``), ``/shapes/<leaf>/data, item, start``."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np

from mbsim.output.hdf5 import to_json
from mbsim.result import Result

_STR = h5py.string_dtype("utf-8")


def write_v1(result: Result, path: str | Path) -> Path:
    paths = [name.replace(".", "/").strip("/") for name in result.channels]
    with h5py.File(path, "w") as f:
        a = f.attrs
        a["mbsim_version"] = "0.1.0"
        a["mode"] = result.mode
        a["status"] = result.status
        a["message"] = result.message
        a["deck_file"] = str(result.deck_file)
        a["wall_time_s"] = float(result.wall_time)
        a["created"] = "2026-11-01T00:00:00+00:00"
        a["settings"] = to_json(result.settings)
        a["counters"] = to_json(result.counters)
        a["summary"] = to_json(result.summary)
        a["channels"] = json.dumps(paths)
        f.create_dataset("deck", data=result.deck_text or "", dtype=_STR)
        f.create_dataset("time", data=np.asarray(result.t, dtype=np.float64))
        f["time"].attrs["unit"] = "s"
        for p, ch in zip(paths, result.channels.values()):
            ds = f.create_dataset(p, data=np.asarray(ch.data, dtype=np.float64))
            ds.attrs["unit"] = ch.unit
            ds.attrs["description"] = ch.description
            ds.attrs["components"] = np.array(list(ch.components), dtype=_STR)
        names = f.create_group("names")
        for kind, items in result.names.items():
            names.create_dataset(kind, data=np.array([str(s) for s in items], dtype=_STR))
        for key, value in result.attrs.items():
            a[key] = value
        for p, (data, attrs) in result.arrays.items():
            data = np.asarray(data)
            ds = f.create_dataset(p, data=data.astype(_STR) if data.dtype.kind in "US" else data)
            for k, v in attrs.items():
                ds.attrs[k] = v
        if result.arrays:
            a["arrays"] = json.dumps(list(result.arrays))
    return Path(path)


def write_v2(result: Result, path: str | Path) -> Path:
    """Version 2 as mbsim wrote it (up to 4711b72), with h5py's high-level calls."""
    from mbsim.output.hdf5 import JSON_DATASETS, _channel_table, _check_names

    paths = _check_names(result.channels)
    with h5py.File(path, "w") as f:
        a = f.attrs
        a["layout_version"] = 2
        for key in ("mode", "status", "message"):
            a[key] = getattr(result, key)
        a["mbsim_version"] = "0.2.0"
        a["deck_file"] = str(result.deck_file)
        a["wall_time_s"] = float(result.wall_time)
        a["created"] = "2026-11-27T00:00:00+00:00"
        for key, value in result.attrs.items():
            a[key] = value
        f.create_dataset("deck", data=result.deck_text or "", dtype=_STR)
        for key in JSON_DATASETS:
            f.create_dataset(key, data=to_json(getattr(result, key)), dtype=_STR)
        f.create_dataset("time", data=np.asarray(result.t, dtype=np.float64)).attrs["unit"] = "s"
        values, table = _channel_table(result, paths)
        f.create_dataset("values", data=values)
        for key, items in table.items():
            f.create_dataset(f"channels/{key}", data=items if isinstance(items, np.ndarray)
                             else np.array(items, dtype=object), dtype=None
                             if isinstance(items, np.ndarray) else _STR)
        for kind, items in result.names.items():
            f.create_dataset(f"names/{kind}", data=np.array(items, dtype=object), dtype=_STR)
        single, stacks = [], {}
        for p, (data, attrs) in result.arrays.items():
            parts = p.split("/")
            if len(parts) == 3 and parts[0] == "shapes":
                stacks.setdefault(parts[2], []).append((parts[1], np.asarray(data), attrs))
                continue
            single.append(p)
            ds = f.create_dataset(p, data=data)
            for k, v in attrs.items():
                ds.attrs[k] = v
        for leaf, members in stacks.items():
            ds = f.create_dataset(f"shapes/{leaf}/data",
                                  data=np.concatenate([d for _, d, _ in members]))
            for k, v in members[0][2].items():
                ds.attrs[k] = v
            f.create_dataset(f"shapes/{leaf}/item", data=np.array([m[0] for m in members],
                                                                  dtype=object), dtype=_STR)
            f.create_dataset(f"shapes/{leaf}/start", data=np.concatenate(
                [[0], np.cumsum([len(d) for _, d, _ in members])]).astype(np.int64))
        f.create_dataset("arrays", data=np.array(single, dtype=object), dtype=_STR)
    return Path(path)
