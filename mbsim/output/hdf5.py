"""HDF5 storage of a :class:`~mbsim.result.Result`: one file per analysis run.

Layout (see ``docs/hdf5.md`` for an ``h5ls -r`` listing)::

    /                 attrs: mbsim_version, mode, status, message, deck_file, wall_time_s,
                             created, settings (JSON), counters (JSON), summary (JSON),
                             channels (JSON list of channel names, in order)
    /deck             scalar variable-length UTF-8 string: the deck YAML text
    /time             (nt,) float64, attr unit = 's'
    /<channel path>   (nt,) or (nt, k) float64, attrs unit, description, components
    /names/<kind>     (n,) UTF-8 strings: result.names[kind]

Writes are atomic: the file is built as ``.<name>.tmp-<pid>`` next to the target and moved
onto it with :func:`os.replace` only once it is complete and closed.
"""

from __future__ import annotations

import json
import os
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from mbsim.result import STATUS_COMPLETE, Channel, Result

RESERVED = ("time", "deck", "names", "linear")  # top-level names that channels may not use
COMPRESS_MIN_SIZE = 1000  # datasets with more elements are chunked and gzip-compressed
GZIP_LEVEL = 4
CHUNK_ELEMENTS = 65536  # target elements per chunk (chunks span whole rows, cut along time)

_STR = h5py.string_dtype("utf-8")


# --------------------------------------------------------------------------- JSON helpers


def _json_default(obj: Any) -> Any:
    """Convert the numpy and other non-JSON values found in settings/summary/counters."""
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (complex, np.complexfloating)):
        return {"__complex__": [float(obj.real), float(obj.imag)]}
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, (set, frozenset)):
        return sorted(obj, key=str)
    if isinstance(obj, Path):
        return str(obj)
    return str(obj)  # last resort: keep something readable rather than lose the whole file


def _json_hook(obj: dict) -> Any:
    if set(obj) == {"__complex__"}:
        re, im = obj["__complex__"]
        return complex(re, im)
    return obj


def to_json(value: Any) -> str:
    """Serialise settings/counters/summary; numpy scalars and arrays become plain numbers
    and lists, complex numbers ``{"__complex__": [re, im]}`` (read back as ``complex``)."""
    return json.dumps(value, default=_json_default)


def from_json(text: str) -> Any:
    """Inverse of :func:`to_json` (tuples come back as lists)."""
    return json.loads(text, object_hook=_json_hook) if text else {}


# --------------------------------------------------------------------------- writing


def _check_names(channels: dict[str, Channel]) -> list[str]:
    """Normalised channel paths; raise ValueError for names HDF5 cannot hold side by side."""
    paths = []
    for name in channels:
        path = name.replace(".", "/").strip("/")
        if not path or "//" in path:
            raise ValueError(f"channel name {name!r} is not a valid slash path")
        if path.split("/")[0] in RESERVED:
            raise ValueError(f"channel name {name!r} uses a reserved name {RESERVED}")
        paths.append(path)
    seen = set(paths)
    if len(seen) != len(paths):
        raise ValueError("two channel names map to the same HDF5 path")
    for path in paths:
        parts = path.split("/")
        for i in range(1, len(parts)):
            if "/".join(parts[:i]) in seen:
                raise ValueError(
                    f"channel {'/'.join(parts[:i])!r} is also the group of channel {path!r}"
                )
    return paths


def _dataset_options(shape: tuple[int, ...]) -> dict[str, Any]:
    """Compression and chunking (along time) for datasets above COMPRESS_MIN_SIZE elements."""
    size = int(np.prod(shape)) if shape else 1
    if size <= COMPRESS_MIN_SIZE or shape[0] == 0:
        return {}
    row = int(np.prod(shape[1:])) if len(shape) > 1 else 1
    rows = max(1, min(shape[0], CHUNK_ELEMENTS // max(row, 1)))
    return {
        "chunks": (rows, *shape[1:]),
        "compression": "gzip",
        "compression_opts": GZIP_LEVEL,
        "shuffle": True,
    }


def _write_dataset(f: h5py.File, path: str, data: np.ndarray) -> h5py.Dataset:
    data = np.asarray(data, dtype=np.float64)
    return f.create_dataset(path, data=data, **_dataset_options(data.shape))


def _write_channel(f: h5py.File, path: str, channel: Channel) -> None:
    ds = _write_dataset(f, path, channel.data)
    ds.attrs["unit"] = channel.unit
    ds.attrs["description"] = channel.description
    ds.attrs["components"] = np.array(list(channel.components), dtype=_STR)


def _write_file(f: h5py.File, result: Result, paths: list[str]) -> None:
    from mbsim import __version__

    a = f.attrs
    a["mbsim_version"] = __version__
    a["mode"] = result.mode
    a["status"] = result.status
    a["message"] = result.message
    a["deck_file"] = str(result.deck_file)
    a["wall_time_s"] = float(result.wall_time)
    a["created"] = datetime.now(timezone.utc).isoformat(timespec="seconds")
    a["settings"] = to_json(result.settings)
    a["counters"] = to_json(result.counters)
    a["summary"] = to_json(result.summary)
    a["channels"] = json.dumps(paths)
    f.create_dataset("deck", data=result.deck_text or "", dtype=_STR)
    _write_dataset(f, "time", np.asarray(result.t, dtype=np.float64).reshape(-1))
    f["time"].attrs["unit"] = "s"
    for path, channel in zip(paths, result.channels.values()):
        _write_channel(f, path, channel)
    names = f.create_group("names")
    for kind, items in result.names.items():
        names.create_dataset(kind, data=np.array([str(s) for s in items], dtype=_STR))
    for key, value in result.attrs.items():  # e.g. 'stable' (bool) of a linear analysis
        a[key] = value
    for path, (data, attrs) in result.arrays.items():  # no time axis; complex kept complex
        data = np.asarray(data)
        ds = f.create_dataset(path, data=data.astype(_STR) if data.dtype.kind in "US" else data)
        for k, v in attrs.items():
            ds.attrs[k] = v
    if result.arrays:
        a["arrays"] = json.dumps(list(result.arrays))


def write_result(result: Result, path: str | Path) -> Path:
    """Write `result` to the HDF5 file `path`, atomically.

    The file is first written to ``.<name>.tmp-<pid>`` in the target's directory, closed,
    then moved onto `path` with :func:`os.replace`; an exception at any point removes the
    temporary file and leaves an existing `path` untouched. An incomplete result (status
    ``'incomplete'``, data up to the failure) is written the same way.

    Parameters
    ----------
    result : Result
        The result to store; channel names are slash paths (dots are accepted).
    path : str or Path
        Target file, conventionally ``*.h5``.

    Returns
    -------
    Path
        The written file.

    Raises
    ------
    ValueError
        A channel name clashes with a reserved name (``time``, ``deck``, ``names``) or is
        the group of another channel (``a/b`` and ``a/b/c``).
    """
    path = Path(path)
    paths = _check_names(result.channels)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        with h5py.File(tmp, "w") as f:
            _write_file(f, result, paths)
            f.flush()
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


# --------------------------------------------------------------------------- reading


def _attr_str(attrs: h5py.AttributeManager, key: str, default: str = "") -> str:
    value = attrs.get(key, default)
    return value.decode() if isinstance(value, bytes) else str(value)


def _channel_paths(f: h5py.File) -> list[str]:
    """Channel paths in written order (root attr ``channels``), else found by walking."""
    if "channels" in f.attrs:
        return json.loads(_attr_str(f.attrs, "channels"))
    found: list[str] = []

    def visit(name: str, obj: Any) -> None:
        top = name.split("/")[0]
        if isinstance(obj, h5py.Dataset) and top not in RESERVED and "unit" in obj.attrs:
            found.append(name)

    f.visititems(visit)
    return found


def _components(ds: h5py.Dataset) -> tuple[str, ...]:
    comps = ds.attrs.get("components", ())
    return tuple(c.decode() if isinstance(c, bytes) else str(c) for c in np.atleast_1d(comps))


def read_result(path: str | Path) -> Result:
    """Read a file written by :func:`write_result` back into a :class:`Result`.

    Parameters
    ----------
    path : str or Path
        The HDF5 file.

    Returns
    -------
    Result
        Channels with unit, description and components; settings, counters and summary
        parsed from JSON (tuples come back as lists).
    """
    with h5py.File(path, "r") as f:
        a = f.attrs
        channels = {}
        for name in _channel_paths(f):
            ds = f[name]
            channels[name] = Channel(
                np.asarray(ds[()], dtype=np.float64),
                _attr_str(ds.attrs, "unit"),
                _attr_str(ds.attrs, "description"),
                _components(ds),
            )
        arrays = {}
        for path in json.loads(_attr_str(a, "arrays", "[]")):
            ds = f[path]
            data = ds.asstr()[()] if ds.dtype.kind == "O" else ds[()]
            arrays[path] = (np.asarray(data), {k: ds.attrs[k] for k in ds.attrs})
        extra = {k: a[k] for k in ("stable", "stability") if k in a}
        names = {}
        if "names" in f:
            for kind, ds in f["names"].items():
                names[kind] = [str(s) for s in ds.asstr()[()]]
        return Result(
            mode=_attr_str(a, "mode"),
            t=np.asarray(f["time"][()], dtype=np.float64),
            channels=channels,
            status=_attr_str(a, "status", STATUS_COMPLETE),
            message=_attr_str(a, "message"),
            settings=from_json(_attr_str(a, "settings")),
            counters=from_json(_attr_str(a, "counters")),
            summary=from_json(_attr_str(a, "summary")),
            deck_file=_attr_str(a, "deck_file"),
            deck_text=f["deck"].asstr()[()] if "deck" in f else "",
            wall_time=float(a.get("wall_time_s", 0.0)),
            names=names,
            arrays=arrays,
            attrs=extra,
        )


def read_info(path: str | Path) -> dict[str, Any]:
    """The root attributes of a result file (version, status, created, ...), JSON parsed."""
    with h5py.File(path, "r") as f:
        info: dict[str, Any] = {}
        for key in f.attrs:
            value = f.attrs[key]
            info[key] = value.decode() if isinstance(value, bytes) else value
        for key in ("settings", "counters", "summary"):
            if key in info:
                info[key] = from_json(str(info[key]))
        if "channels" in info:
            info["channels"] = json.loads(str(info["channels"]))
        return info


def list_channels(path: str | Path) -> list[tuple[str, tuple, str, str]]:
    """The channels of a result file without loading their data.

    Returns
    -------
    list of (name, shape, unit, description)
        `name` is the slash path, `shape` the dataset shape (time first).
    """
    with h5py.File(path, "r") as f:
        return [
            (
                name,
                tuple(f[name].shape),
                _attr_str(f[name].attrs, "unit"),
                _attr_str(f[name].attrs, "description"),
            )
            for name in _channel_paths(f)
        ]
