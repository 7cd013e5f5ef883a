"""The version-1 writer of mbsim.output.hdf5 (before layout_version 2), kept to make files of
the old layout for the test that they are still read: a dataset per channel at its slash
path, settings/counters/summary/channels/arrays as root attributes."""

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
