"""HDF5 storage of a :class:`~mbsim.result.Result`: one file per analysis run.

Layout version 3 (root attribute ``layout_version``; ``docs/hdf5.md`` has the full table and
an ``h5ls -r`` listing).  Channels are data, not one dataset each: every channel is a block
of columns of one 2-D array, and one table (a compound dataset, a row per channel) says
which, so no attribute or header grows with the model and the file is a few objects written
in bulk whatever its size (a governor run: 15)::

    /                 attrs: layout_version (3), mbsim_version, mode, status, message,
                             deck_file, wall_time_s, created; Result.attrs (stable, ...)
    /deck, /settings, /counters, /summary   scalar UTF-8 strings (deck YAML; JSON)
    /time             (nt,) float64, attr unit = 's'
    /values           (nt, ncol) float64: every channel's columns side by side
    /channels         (nch,) table: name, unit, description, components (JSON list), shape
                      (JSON, after time) strings, column, width int64: channel k is
                      values[:, column[k]:column[k] + width[k]] reshaped to (nt, *shape[k])
    /names            (n,) table: kind, name (result.names); attr kinds: JSON list of kinds
    /arrays           (na,) strings: the Result.arrays stored at their own path (linear/...)
    /shapes/<leaf>    shapes/<body>/<leaf> of every body stacked by rows; /shapes/index
                      (table: leaf, item, start, stop) says whose rows are whose

Version 2 (the channel table and the names a dataset per field and per kind, shapes/<leaf>/
data, item, start: 35 objects for a governor run) is still read, and so is version 1 (a
dataset per channel at its slash path with attributes unit, description, components;
settings, counters, summary and the list of channels as root attributes): version 1 failed
for large models ("object header message is too large", the root attribute listing 7000
channels) and cost about 1 ms per channel to write.

Writes are atomic: the file is built in memory, written as ``.<name>.tmp-<pid>`` next to the
target and moved onto it with :func:`os.replace` only once it is complete and closed; a failed
write (disk full) leaves the target untouched.  Temporary files of runs killed mid-write
(kill -9) are removed by the next run or sweep into that folder (:func:`prepare_output`).
"""

from __future__ import annotations

import json
import logging
import math
import os
import re
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from mbsim.errors import MbsimError, UsageError
from mbsim.result import STATUS_COMPLETE, STATUS_INCOMPLETE, Channel, Result

log = logging.getLogger(__name__)


class OutputError(MbsimError):
    """A results file that could not be written (disk full, ...): exit 1, file untouched."""

    exit_code = 1

RESERVED = ("time", "deck", "names", "linear", "shapes")  # names that channels may not start with
LAYOUT_VERSION = 3  # root attribute layout_version; files without it are version 1
JSON_DATASETS = ("settings", "counters", "summary")  # scalar JSON strings (attributes in v1)
EXTRA_ATTRS = ("stable", "stability", "error_estimate", "error_estimate_reason")  # Result.attrs
STACKED = ("shapes",)  # arrays <group>/<item>/<leaf> stored one dataset per leaf for all items
COMPRESS_MIN_SIZE = 100_000  # arrays (shapes/...) with more elements are chunked, compressed
GZIP_LEVEL = 4
CHUNK_ELEMENTS = 65536  # target elements per chunk (chunks span whole rows)
"""/time and /values are stored contiguous and uncompressed: gzip (level 4, shuffle) made
them only 1.2-1.4x smaller (simulated float64 series) and cost 8 of a governor run's 17 ms of
writing, 36 of the vehicle's 48 (benchmarks/user_run.py).  The meshes of ``shapes/``
compress 2.6x (faces, constant colours), but a chunked, filtered dataset costs about 0.5 ms
to create whatever its size: the governor's three (8 000 to 14 000 elements, 190 kB) cost
1.8 ms compressed against 0.3 ms stored as they are, so only meshes above
COMPRESS_MIN_SIZE (800 kB of float64: chains of hundreds of links) are compressed."""

_STR = h5py.string_dtype("utf-8")
_VSTR_FILE, _VSTR_MEMORY = h5py.h5t.py_create(_STR, logical=True), h5py.h5t.py_create(_STR)


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
    """Compression and chunking for arrays above COMPRESS_MIN_SIZE elements: chunks of
    whole rows (``shape[1:]``), about CHUNK_ELEMENTS each."""
    size = int(np.prod(shape)) if shape else 1
    if size <= COMPRESS_MIN_SIZE or shape[0] == 0:
        return {}
    row = int(np.prod(shape[1:])) if len(shape) > 1 else 1
    chunks = (max(1, min(shape[0], CHUNK_ELEMENTS // max(row, 1))), *shape[1:])
    return {
        "chunks": chunks,
        "compression": "gzip",
        "compression_opts": GZIP_LEVEL,
        "shuffle": True,
    }


def _put(group: h5py.File | h5py.Group, name: str, data) -> h5py.h5d.DatasetID:
    """A contiguous, uncompressed dataset ``name`` (no slash) of ``group`` holding the numbers
    ``data``, through h5py's low-level API: about half the cost of ``create_dataset`` (its
    option handling), which counts at the ~30 objects of a small run's file.  Returns the
    low-level id (:func:`_set_attrs` takes it): wrapping it in ``h5py.Dataset`` costs more
    than writing a small dataset (its property lists, each a registered object)."""
    data = np.ascontiguousarray(data)
    space = h5py.h5s.create_simple(data.shape) if data.ndim else _scalar_space()
    ds = h5py.h5d.create(group.id, name.encode(), _number_type(data.dtype), space)
    if data.size:
        ds.write(h5py.h5s.ALL, h5py.h5s.ALL, data)
    return ds


def _strings(group: h5py.File | h5py.Group, name: str, items) -> h5py.h5d.DatasetID:
    """``name`` (no slash) in ``group``: the strings ``items`` (a list: (n,); one str: a
    scalar) as fixed-length, null-padded UTF-8 (the longest's length in bytes), or as
    variable-length where padding would more than double the bytes (:func:`_string_column`).
    Read as any HDF5 string (``.asstr()``); fixed-length ones are written in about a fifth of
    the time of variable-length strings, which h5py converts one by one."""
    scalar = isinstance(items, str)
    data, tid, mtid = _string_column([items] if scalar else items)
    data = data.reshape(()) if scalar else data
    space = _scalar_space() if scalar else h5py.h5s.create_simple(data.shape)
    ds = h5py.h5d.create(group.id, name.encode(), tid, space)
    if data.size:
        ds.write(h5py.h5s.ALL, h5py.h5s.ALL, data, mtype=mtid)
    return ds


def _set_attrs(obj, items: dict[str, Any]) -> None:
    """``obj.attrs.update(items)`` with the types h5py gives them (str: a variable-length UTF-8
    scalar, float and int: float64 and int64 scalars; anything else through h5py), written
    with HDF5's own calls: a fifth of the cost of ``attrs[key] = value`` (0.03 against 0.14
    ms each; a run's file has about twelve).  ``obj``: a file, group or dataset, or the
    low-level id of one (what :func:`_put` returns)."""
    oid = obj if isinstance(obj, h5py.h5d.DatasetID) else obj.id
    for key, value in items.items():
        if isinstance(value, str):
            data, ftype, mtype = np.array(value, dtype=_STR), _VSTR_FILE, _VSTR_MEMORY
        elif isinstance(value, (float, int, np.floating, np.integer)) and not isinstance(
                value, (bool, np.bool_)):  # fmt: skip
            data = np.asarray(value)
            ftype = mtype = _number_type(data.dtype)
        else:
            (obj if hasattr(obj, "attrs") else h5py.Dataset(oid)).attrs[key] = value
            continue
        attr = h5py.h5a.create(oid, key.encode(), ftype, _scalar_space())
        attr.write(data, mtype=mtype)


def _vlen_strings(group: h5py.File | h5py.Group, name: str, items) -> h5py.h5d.DatasetID:
    """``name`` (no slash) in ``group``: the strings ``items`` (n,) as variable-length UTF-8
    (the type ``create_dataset(data=np.array(items, dtype=h5py.string_dtype()))`` gives,
    read back as str objects), through HDF5's own calls."""
    data = np.array(list(items), dtype=_STR)
    ds = h5py.h5d.create(group.id, name.encode(), _VSTR_FILE,
                         h5py.h5s.create_simple(data.shape))
    if data.size:
        ds.write(h5py.h5s.ALL, h5py.h5s.ALL, data, mtype=_VSTR_MEMORY)
    return ds


# HDF5 types and the scalar dataspace made once per process (h5py registers every id it
# makes, about 10 us each, and a small run's file needs about a hundred): read only, as
# HDF5 copies a type into each object it creates.
_NUMBER_TYPES: dict[np.dtype, h5py.h5t.TypeID] = {}
_STRING_TYPES: dict[int, h5py.h5t.TypeStringID] = {}
_SCALAR: list = []


def _number_type(dtype: np.dtype) -> h5py.h5t.TypeID:
    """``h5py.h5t.py_create(dtype)``, made once per dtype."""
    tid = _NUMBER_TYPES.get(dtype)
    if tid is None:
        tid = _NUMBER_TYPES[dtype] = h5py.h5t.py_create(dtype)
    return tid


def _scalar_space() -> h5py.h5s.SpaceID:
    if not _SCALAR:
        _SCALAR.append(h5py.h5s.create(h5py.h5s.SCALAR))
    return _SCALAR[0]


VLEN_ENTRY = 32  # bytes a variable-length string costs besides its text: its (length, heap
# id) in the row and its global-heap object's header, 16 each


def _string_column(items) -> tuple[np.ndarray, h5py.h5t.TypeID, h5py.h5t.TypeID]:
    """(data, file type, memory type) of the strings ``items``: fixed-length (
    :func:`_fixed_strings`), unless padding every entry to the longest would take more than
    twice the bytes of variable-length strings (the text plus VLEN_ENTRY each): one long
    entry among many short ones, as the components of constraints/lam (every row's name) in
    a channel table of a large model, would make the column O(n^2) in bytes."""
    texts = [str(s) for s in items]
    lengths = [len(s) for s in texts]  # characters: bytes for ASCII, decided before padding
    if len(texts) * max(lengths, default=0) > 2 * (sum(lengths) + VLEN_ENTRY * len(texts)):
        return np.array(texts, dtype=_STR), _VSTR_FILE, _VSTR_MEMORY
    data, tid = _fixed_strings(texts)
    return data, tid, tid


def _fixed_strings(items) -> tuple[np.ndarray, h5py.h5t.TypeStringID]:
    """(bytes array (n,), its HDF5 type): ``items`` as UTF-8, fixed-length at the longest's
    length in bytes (at least 1)."""
    try:  # ASCII (names, units, JSON): numpy's own conversion
        data = np.array([str(s) for s in items], dtype="S")
    except UnicodeEncodeError:
        raw = [str(s).encode() for s in items]
        data = np.array(raw, dtype=f"S{max([len(b) for b in raw] + [1])}")
    return data, _string_type(data.dtype.itemsize)


def _string_type(size: int) -> h5py.h5t.TypeStringID:
    """HDF5's fixed-length, null-padded UTF-8 string of ``size`` bytes (made once per size)."""
    tid = _STRING_TYPES.get(size)
    if tid is None:
        tid = h5py.h5t.TypeStringID.copy(h5py.h5t.C_S1)
        tid.set_size(size)
        tid.set_cset(h5py.h5t.CSET_UTF8)
        tid.set_strpad(h5py.h5t.STR_NULLPAD)
        if len(_STRING_TYPES) < 1000:
            _STRING_TYPES[size] = tid
    return tid


def _table(group: h5py.File | h5py.Group, name: str,
           columns: dict[str, Any]) -> h5py.h5d.DatasetID:
    """``name`` (no slash) in ``group``: one compound dataset (n,) with a field per entry of
    ``columns`` (equal lengths), strings (lists of str) as fixed-length, null-padded UTF-8
    (variable-length where padding would more than double the bytes: :func:`_string_column`),
    numbers (arrays) in their own type: a table of n rows is one HDF5 object, not one per
    column.  Read back with :func:`_read_table` (or h5py: ``f[name][()]['field']``)."""
    fields, tids, data = [], [], []
    for key, items in columns.items():
        if isinstance(items, np.ndarray):
            arr = np.ascontiguousarray(items)
            tid = mtid = _number_type(arr.dtype)
        else:
            arr, tid, mtid = _string_column(items)
        fields.append((key, arr.dtype))
        tids.append((tid, mtid))
        data.append(arr)
    rows = np.empty(len(data[0]) if data else 0, dtype=np.dtype(fields))
    for (key, _), arr in zip(fields, data):
        rows[key] = arr
    ctid = h5py.h5t.create(h5py.h5t.COMPOUND, rows.dtype.itemsize)  # in the file
    mtid = h5py.h5t.create(h5py.h5t.COMPOUND, rows.dtype.itemsize)  # in memory
    for (key, _), (tid, memory) in zip(fields, tids):
        ctid.insert(key.encode(), rows.dtype.fields[key][1], tid)
        mtid.insert(key.encode(), rows.dtype.fields[key][1], memory)
    ds = h5py.h5d.create(group.id, name.encode(), ctid, h5py.h5s.create_simple(rows.shape))
    if rows.size:
        ds.write(h5py.h5s.ALL, h5py.h5s.ALL, rows, mtype=mtid)
    return ds


def _channel_table(result: Result, paths: list[str]) -> tuple[np.ndarray, dict[str, Any]]:
    """Every channel side by side in one (nt, ncol) array, and the channel table (name, unit,
    description, components, column, width, shape) that says which columns are whose."""
    nt = len(np.asarray(result.t).reshape(-1))
    chans = list(result.channels.values())
    datas = [np.asarray(ch.data, dtype=np.float64) for ch in chans]
    for path, data in zip(paths, datas):
        if data.ndim == 0 or data.shape[0] != nt:
            raise ValueError(f"channel {path!r} has shape {data.shape}; the time axis has "
                             f"{nt} outputs")
    shapes = [data.shape[1:] for data in datas]
    widths = [math.prod(shape) for shape in shapes]
    column = np.zeros(len(widths) + 1, dtype=np.int64)
    np.cumsum(widths, dtype=np.int64, out=column[1:])
    values = (np.concatenate([d.reshape(nt, w) for d, w in zip(datas, widths)], axis=1)
              if datas else np.empty((nt, 0)))
    components = [tuple(c.components) for c in chans]
    # the few distinct component lists and shapes, dumped once
    text = {v: json.dumps(list(v)) for v in {*components, *shapes}}
    table = {
        "name": paths,
        "unit": [c.unit for c in chans],
        "description": [c.description for c in chans],
        "components": [text[v] for v in components],
        "column": column[:-1],
        "width": np.asarray(widths, dtype=np.int64),
        "shape": [text[v] for v in shapes],
    }
    return values, table


def _stack_key(path: str) -> tuple[str, str, str] | None:
    """(group, item, leaf) of an array stored stacked with its siblings (``shapes/<body>/
    vertices``: one dataset per leaf for all bodies), else None."""
    parts = path.split("/")
    if len(parts) == 3 and parts[0] in STACKED:
        return parts[0], parts[1], parts[2]
    return None


def _write_arrays(f: h5py.File, arrays: dict[str, tuple[np.ndarray, dict]]) -> None:
    """Result.arrays (no time axis; complex kept complex): ``shapes/<body>/<leaf>`` stacked
    per leaf (``/shapes/<leaf>`` the rows of every body; the table ``/shapes/index``: leaf,
    item (the body), start, stop: its rows), the others each at its own path, listed in
    ``/arrays``."""
    stacks: dict[tuple[str, str], list[tuple[str, np.ndarray, dict]]] = {}
    single = []
    groups: dict[str, h5py.Group] = {}

    def group_of(name: str) -> h5py.File | h5py.Group:
        if not name:
            return f
        if name not in groups:
            groups[name] = f.require_group(name)
        return groups[name]

    for path, (data, attrs) in arrays.items():
        data = np.asarray(data)
        key = _stack_key(path)
        if key is None or data.ndim == 0 or data.dtype.kind in "USO":
            single.append(path)
            parent, _, leaf = path.rpartition("/")
            if data.dtype.kind in "US" and data.ndim == 1:  # shapes/layout: its JSON text
                ds = _vlen_strings(group_of(parent), leaf, data.tolist())
            else:
                ds = f.create_dataset(path, data=data.astype(_STR) if data.dtype.kind in "US"
                                      else data)
            _set_attrs(ds, attrs)
        else:
            stacks.setdefault((key[0], key[2]), []).append((key[1], data, attrs))
    index: dict[str, dict[str, list]] = {}  # group -> the columns of its index table
    for (group, leaf), members in stacks.items():
        first = members[0][1]
        if any(d.shape[1:] != first.shape[1:] or d.dtype != first.dtype or a != members[0][2]
               for _, d, a in members):
            raise ValueError(f"arrays {group}/*/{leaf} differ in shape, type or attributes")
        g = group_of(group)
        data = np.concatenate([d for _, d, _ in members])
        options = _dataset_options(data.shape)
        ds = g.create_dataset(leaf, data=data, **options) if options else _put(g, leaf, data)
        _set_attrs(ds, members[0][2])
        stop = np.cumsum([len(d) for _, d, _ in members])
        cols = index.setdefault(group, {"leaf": [], "item": [], "start": [], "stop": []})
        cols["leaf"] += [leaf] * len(members)
        cols["item"] += [m[0] for m in members]
        cols["start"] += [0, *stop[:-1].tolist()]
        cols["stop"] += stop.tolist()
    for group, cols in index.items():
        _table(group_of(group), "index", {"leaf": cols["leaf"], "item": cols["item"],
                                   "start": np.asarray(cols["start"], dtype=np.int64),
                                   "stop": np.asarray(cols["stop"], dtype=np.int64)})
    _strings(f, "arrays", single)


def _write_file(f: h5py.File, result: Result, values: np.ndarray, table: dict) -> None:
    """The objects of ``result``'s file in ``f``; values, table: :func:`_channel_table`."""
    from mbsim import __version__

    _set_attrs(f, {
        "layout_version": LAYOUT_VERSION, "mbsim_version": __version__, "mode": result.mode,
        "status": result.status, "message": result.message, "deck_file": str(result.deck_file),
        "wall_time_s": float(result.wall_time),
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        **result.attrs})  # e.g. 'stable' (bool) of a linear analysis
    _strings(f, "deck", result.deck_text or "")
    for key in JSON_DATASETS:
        _strings(f, key, to_json(getattr(result, key)))
    _set_attrs(_put(f, "time", np.asarray(result.t, dtype=np.float64).reshape(-1)), {"unit": "s"})
    _put(f, "values", values)  # contiguous, uncompressed (see CHUNK_ELEMENTS)
    _table(f, "channels", table)
    kinds = list(result.names)
    names = _table(f, "names", {"kind": [k for k in kinds for _ in result.names[k]],
                                "name": [n for k in kinds for n in result.names[k]]})
    _set_attrs(names, {"kinds": json.dumps(kinds)})  # every kind, also those without items
    _write_arrays(f, result.arrays)


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
        the group of another channel (``a/b`` and ``a/b/c``); a channel's first axis is not
        the time axis; arrays ``shapes/*/<leaf>`` that cannot be stacked (differing shapes
        after the first axis, types or attributes).
    """
    path = Path(path)
    values, table = _channel_table(result, _check_names(result.channels))
    check_finite(result, values)
    tmp = _tmp_name(path)
    try:
        # The file is built in memory (HDF5's core driver, no backing store) and written with
        # plain file I/O: HDF5 writing to a full disk itself raises from its object finalisers
        # and then crashes the interpreter (issue 13: segmentation fault, exit 139), while a
        # failed os.write is one OSError.  Memory: one copy of the compressed file.
        with h5py.File(tmp, "w", driver="core", backing_store=False) as f:
            _write_file(f, result, values, table)
            f.flush()
            image = f.id.get_file_image()
        with open(tmp, "wb") as out:
            out.write(image)
            out.flush()
            os.fsync(out.fileno())
        del image
        os.replace(tmp, path)
    except (OSError, RuntimeError) as exc:  # disk full, quota, permissions
        tmp.unlink(missing_ok=True)
        raise OutputError(f"cannot write the results to {path}: {_reason(exc)} (an earlier "
                          f"{path.name} is left as it was)") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def _tmp_name(path: Path) -> Path:
    return path.with_name(f".{path.name}.tmp-{os.getpid()}")


def _reason(exc: BaseException) -> str:
    """errno's words when there is one ('No space left on device'), else h5py's first clause."""
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    text = " ".join(str(exc).split())
    for known in ("No space left on device", "File too large", "Disk quota exceeded",
                  "Permission denied", "Read-only file system"):  # fmt: skip
        if known.lower() in text.lower():
            return known
    return text[:160]


TMP_RE = re.compile(r"\.(?P<name>.+)\.tmp-(?P<pid>\d+)")
SPOOL_RE = re.compile(r"\.spool-(?P<pid>\d+)-.+")
"""A sweep's result spool folder (mbsim.sweep), named after the sweeping process."""


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):  # someone else's live process (or cannot tell): keep
        return True
    return True


def remove_stale_temporaries(folder: str | Path) -> list[Path]:
    """Remove ``.<name>.tmp-<pid>`` files and sweep spool folders ``.spool-<pid>-*`` that a
    killed run (kill -9, power loss) left in ``folder``: those whose process no longer
    exists.  Returns the paths removed."""
    import shutil

    removed = []
    try:
        entries = list(Path(folder).iterdir())
    except OSError:
        return removed
    for p in entries:
        m = SPOOL_RE.fullmatch(p.name)
        if m and p.is_dir() and not p.is_symlink() and not _pid_alive(int(m["pid"])):
            shutil.rmtree(p, ignore_errors=True)
            if not p.exists():
                removed.append(p)
            continue
        m = TMP_RE.fullmatch(p.name)
        if m and not _pid_alive(int(m["pid"])):
            try:
                p.unlink()
                removed.append(p)
            except OSError:
                pass  # not ours to remove (permissions): harmless, it stays hidden
    if removed:
        log.info("removed %d stale temporary file(s) of dead runs in %s: %s", len(removed),
                 folder, ", ".join(p.name for p in removed[:5]))
    return removed


def probe_write(path: Path) -> None:
    """Create and remove the file ``path``: OSError where its folder takes no new file."""
    with open(path, "wb"):
        pass
    path.unlink()


def prepare_output(path: str | Path) -> Path:
    """Check before an analysis that ``path`` can be written: not a folder, its folder exists
    and takes a new file (tried by creating and removing the temporary file); removes stale
    temporaries of dead runs there.  Raises UsageError (exit 2) naming the problem."""
    path = Path(path)
    folder = path.parent
    if path.is_dir():
        raise UsageError(f"output {path} is a folder; give a file name, e.g. "
                         f"{path / 'results.h5'}")
    if not folder.exists():
        raise UsageError(f"output {path}: the folder {folder} does not exist")
    if not folder.is_dir():
        raise UsageError(f"output {path}: {folder} is a file, not a folder")
    try:
        probe_write(_tmp_name(path))
    except OSError as exc:
        raise UsageError(f"output {path}: cannot create a file in {folder}: "
                         f"{exc.strerror or exc}") from None
    remove_stale_temporaries(folder)
    return path


def check_finite(result: Result, values: np.ndarray | None = None) -> None:
    """A result marked complete holds no NaN or inf (issue 13): if a channel does, mark it
    incomplete, naming the channel and the first time, so the CLI exits 1.  ``values``: the
    channels side by side (:func:`_channel_table`), when the writer has them: all finite,
    the channels are not visited one by one."""
    if not result.complete:
        return
    t = np.asarray(result.t, dtype=float)
    bad_t = np.flatnonzero(~np.isfinite(t))
    if bad_t.size:
        result.status = STATUS_INCOMPLETE
        result.message = f"time holds NaN or inf (output {int(bad_t[0])})"
        return
    if values is not None and np.isfinite(values).all():
        return
    for name, ch in result.channels.items():
        data = np.asarray(ch.data, dtype=float)
        if data.size and not np.isfinite(data).all():
            rows = np.flatnonzero(~np.isfinite(data.reshape(data.shape[0], -1)).all(axis=1)) \
                if data.ndim else np.array([0])
            k = int(rows[0]) if rows.size else 0
            when = f" from t = {t[k]:.6g} s" if data.ndim and k < t.size else ""
            result.status = STATUS_INCOMPLETE
            result.message = (f"channel {name.replace('/', '.')} holds NaN or inf{when} "
                              "(an overflow: check the deck's magnitudes); results kept, marked "
                              "incomplete")
            log.warning("%s", result.message)
            return


# --------------------------------------------------------------------------- reading


def _attr_str(attrs: h5py.AttributeManager, key: str, default: str = "") -> str:
    value = attrs.get(key, default)
    return value.decode() if isinstance(value, bytes) else str(value)


def layout_version(f: h5py.File) -> int:
    """The file's layout: 3 (channels as columns of /values, tables as compound datasets),
    2 (the same with a dataset per table column), 1 (a dataset per channel)."""
    return int(f.attrs.get("layout_version", 1))


def _str_list(ds: h5py.Dataset) -> list[str]:
    return [str(s) for s in ds.asstr()[()]]


def _read_table(ds: h5py.Dataset) -> dict[str, Any]:
    """The columns of a table written by :func:`_table`: strings as lists of str, numbers as
    arrays."""
    rows = ds[()]
    return {key: ([b.decode() if isinstance(b, bytes) else b for b in rows[key]]
                  if rows.dtype[key].kind in "SO" else np.asarray(rows[key]))
            for key in rows.dtype.names}  # fmt: skip


def json_document(f: h5py.File, key: str) -> Any:
    """settings/counters/summary: a scalar JSON dataset (v2) or root attribute (v1)."""
    if key in f and isinstance(f[key], h5py.Dataset):
        return from_json(f[key].asstr()[()])
    return from_json(_attr_str(f.attrs, key))


@dataclass
class ChannelTable:
    """The channel table of a file: per channel its name, unit, description, components,
    first column in /values, width and shape after time (a v1 file: shape only)."""

    name: list[str]
    unit: list[str]
    description: list[str]
    components: list[tuple[str, ...]]
    column: np.ndarray  # (nch,) int64; -1 in a v1 file (each channel its own dataset)
    shape: list[tuple[int, ...]]  # trailing shape: () for (nt,), (3,) for (nt, 3)


def channel_table(f: h5py.File) -> ChannelTable:
    """The channels of an open result file, without their data, in written order."""
    if layout_version(f) >= 3:
        t = _read_table(f["channels"])
        return ChannelTable(
            t["name"], t["unit"], t["description"],
            [tuple(json.loads(c)) for c in t["components"]],
            np.asarray(t["column"], dtype=np.int64), [tuple(json.loads(s)) for s in t["shape"]])
    if layout_version(f) >= 2:
        g = f["channels"]
        return ChannelTable(
            _str_list(g["name"]), _str_list(g["unit"]), _str_list(g["description"]),
            [tuple(json.loads(c)) for c in g["components"].asstr()[()]],
            np.asarray(g["column"][()], dtype=np.int64),
            [tuple(json.loads(s)) for s in g["shape"].asstr()[()]])  # fmt: skip
    names = _channel_paths_v1(f)
    dss = [f[n] for n in names]
    return ChannelTable(
        names, [_attr_str(d.attrs, "unit") for d in dss],
        [_attr_str(d.attrs, "description") for d in dss], [_components(d) for d in dss],
        np.full(len(names), -1, dtype=np.int64), [tuple(d.shape[1:]) for d in dss])


def _channel_paths_v1(f: h5py.File) -> list[str]:
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


def _read_channels(f: h5py.File, nt: int) -> dict[str, Channel]:
    table = channel_table(f)
    values = np.asarray(f["values"][()], dtype=np.float64) if "values" in f else None
    channels = {}
    for k, name in enumerate(table.name):
        shape = table.shape[k]
        if values is None:  # v1: a dataset per channel
            data = np.asarray(f[name][()], dtype=np.float64)
        else:  # a view of its columns (no copy)
            start = int(table.column[k])
            width = math.prod(shape)
            data = values[:, start:start + width].reshape(nt, *shape)
        channels[name] = Channel(data, table.unit[k], table.description[k], table.components[k])
    return channels


def _read_arrays(f: h5py.File) -> dict[str, tuple[np.ndarray, dict]]:
    """Result.arrays: those at their own path (listed in /arrays, v1: the root attribute
    ``arrays``), then the stacked ``shapes/<leaf>`` split back per body."""
    def read(ds: h5py.Dataset) -> np.ndarray:
        return np.asarray(ds.asstr()[()] if ds.dtype.kind == "O" else ds[()])

    arrays = {}
    if "arrays" in f and isinstance(f["arrays"], h5py.Dataset):
        paths = _str_list(f["arrays"])
    else:
        paths = json.loads(_attr_str(f.attrs, "arrays", "[]"))
    for path in paths:
        ds = f[path]
        arrays[path] = (read(ds), {k: ds.attrs[k] for k in ds.attrs})
    for group in STACKED:
        if layout_version(f) < 2 or group not in f:
            continue
        if layout_version(f) >= 3:
            if "index" not in f[group]:
                continue
            t = _read_table(f[group]["index"])
            leaves = {leaf: (read(f[group][leaf]), dict(f[group][leaf].attrs))
                      for leaf in dict.fromkeys(t["leaf"])}  # fmt: skip
            for leaf, item, start, stop in zip(t["leaf"], t["item"], t["start"], t["stop"]):
                data, attrs = leaves[leaf]
                arrays[f"{group}/{item}/{leaf}"] = (data[start:stop], dict(attrs))
            continue
        for leaf, g in f[group].items():
            if not (isinstance(g, h5py.Group) and {"data", "item", "start"} <= set(g)):
                continue
            data, start = read(g["data"]), g["start"][()]
            attrs = {k: g["data"].attrs[k] for k in g["data"].attrs}
            for k, item in enumerate(_str_list(g["item"])):
                arrays[f"{group}/{item}/{leaf}"] = (data[start[k]:start[k + 1]], dict(attrs))
    return arrays


def read_result(path: str | Path) -> Result:
    """Read a file written by :func:`write_result` back into a :class:`Result` (either
    layout: version 2, or version 1 of files written before it).

    Parameters
    ----------
    path : str or Path
        The HDF5 file.

    Returns
    -------
    Result
        Channels with unit, description and components (a channel's data is a view of the
        file's /values columns); settings, counters and summary parsed from JSON (tuples
        come back as lists).
    """
    with h5py.File(path, "r") as f:
        a = f.attrs
        t = np.asarray(f["time"][()], dtype=np.float64)
        channels = _read_channels(f, len(t))
        extra = {k: a[k] for k in EXTRA_ATTRS if k in a}
        names: dict[str, list[str]] = {}
        if "names" in f and isinstance(f["names"], h5py.Dataset):  # v3: a table (kind, name)
            names = {kind: [] for kind in json.loads(_attr_str(f["names"].attrs, "kinds", "[]"))}
            table = _read_table(f["names"])
            for kind, name in zip(table["kind"], table["name"]):
                names.setdefault(kind, []).append(name)
        elif "names" in f:
            for kind, ds in f["names"].items():
                names[kind] = _str_list(ds)
        return Result(
            mode=_attr_str(a, "mode"),
            t=t,
            channels=channels,
            status=_attr_str(a, "status", STATUS_COMPLETE),
            message=_attr_str(a, "message"),
            settings=json_document(f, "settings"),
            counters=json_document(f, "counters"),
            summary=json_document(f, "summary"),
            deck_file=_attr_str(a, "deck_file"),
            deck_text=f["deck"].asstr()[()] if "deck" in f else "",
            wall_time=float(a.get("wall_time_s", 0.0)),
            names=names,
            arrays=_read_arrays(f),
            attrs=extra,
        )


def result_file_problem(path: str | Path) -> str | None:
    """Why ``path`` is not a results file of :func:`write_result` (None when it is one):
    'not an HDF5 file', 'a sweep index, not a results file', ... (plot, export and compare
    refuse or skip such files by name instead of failing inside h5py)."""
    path = Path(path)
    if not path.is_file():
        return "no such file"
    try:
        with h5py.File(path, "r") as f:
            if isinstance(f.get("time"), h5py.Dataset) and "mode" in f.attrs:
                try:
                    version = layout_version(f)
                except (TypeError, ValueError):
                    return f"layout_version {f.attrs['layout_version']!r} is not a number"
                if version > LAYOUT_VERSION:  # read as ours, it could be read wrong
                    return (f"written in layout {version} by a newer mbsim "
                            f"({_attr_str(f.attrs, 'mbsim_version', '?')}); this one reads "
                            f"layouts 1 to {LAYOUT_VERSION}: update mbsim")
                return None
            if path.name == "index.h5" or "cases" in f or "sweep" in f.attrs:
                return "a sweep index, not a results file"
            return "an HDF5 file without mbsim results (no /time dataset or mode attribute)"
    except (OSError, RuntimeError, ValueError):
        return "not an HDF5 file"


def read_info(path: str | Path) -> dict[str, Any]:
    """The root attributes of a result file (version, status, created, ...), with
    ``settings``, ``counters``, ``summary`` parsed from JSON, ``channels`` (the channel
    names) and ``layout_version`` (1 for files without it)."""
    with h5py.File(path, "r") as f:
        info: dict[str, Any] = {}
        for key in f.attrs:
            value = f.attrs[key]
            info[key] = value.decode() if isinstance(value, bytes) else value
        info["layout_version"] = layout_version(f)
        for key in JSON_DATASETS:
            info[key] = json_document(f, key)
        info["channels"] = channel_table(f).name
        return info


def list_channels(path: str | Path) -> list[tuple[str, tuple, str, str]]:
    """The channels of a result file without loading their data.

    Returns
    -------
    list of (name, shape, unit, description)
        `name` is the slash path, `shape` the channel's shape (time first).
    """
    with h5py.File(path, "r") as f:
        nt = f["time"].shape[0]
        table = channel_table(f)
        return [(name, (nt, *table.shape[k]), table.unit[k], table.description[k])
                for k, name in enumerate(table.name)]
