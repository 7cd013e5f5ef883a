"""HDF5 storage of a :class:`~mbsim.result.Result`: one file per analysis run.

Layout (see ``docs/hdf5.md`` for an ``h5ls -r`` listing)::

    /                 attrs: mbsim_version, mode, status, message, deck_file, wall_time_s,
                             created, settings (JSON), counters (JSON), summary (JSON),
                             channels (JSON list of channel names, in order)
    /deck             scalar variable-length UTF-8 string: the deck YAML text
    /time             (nt,) float64, attr unit = 's'
    /<channel path>   (nt,) or (nt, k) float64, attrs unit, description, components
    /names/<kind>     (n,) UTF-8 strings: result.names[kind]
    /linear/...       arrays without a time axis (Result.arrays, listed in the root attribute
                      ``arrays``; complex kept complex), e.g. linear/eigenvalues; extra root
                      attributes from Result.attrs (``stable``, ``stability``)

Writes are atomic: the file is built in memory, written as ``.<name>.tmp-<pid>`` next to the
target and moved onto it with :func:`os.replace` only once it is complete and closed; a failed
write (disk full) leaves the target untouched.  Temporary files of runs killed mid-write
(kill -9) are removed by the next run or sweep into that folder (:func:`prepare_output`).
"""

from __future__ import annotations

import json
import logging
import os
import re
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

RESERVED = ("time", "deck", "names", "linear", "shapes")  # top-level names that channels may not use
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
    check_finite(result)
    tmp = _tmp_name(path)
    try:
        # The file is built in memory (HDF5's core driver, no backing store) and written with
        # plain file I/O: HDF5 writing to a full disk itself raises from its object finalisers
        # and then crashes the interpreter (issue 13: segmentation fault, exit 139), while a
        # failed os.write is one OSError.  Memory: one copy of the compressed file.
        with h5py.File(tmp, "w", driver="core", backing_store=False) as f:
            _write_file(f, result, paths)
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


def check_finite(result: Result) -> None:
    """A result marked complete holds no NaN or inf (issue 13): if a channel does, mark it
    incomplete, naming the channel and the first time, so the CLI exits 1."""
    if not result.complete:
        return
    t = np.asarray(result.t, dtype=float)
    bad_t = np.flatnonzero(~np.isfinite(t))
    if bad_t.size:
        result.status = STATUS_INCOMPLETE
        result.message = f"time holds NaN or inf (output {int(bad_t[0])})"
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


def result_file_problem(path: str | Path) -> str | None:
    """Why ``path`` is not a results file of :func:`write_result` (None when it is one):
    'not an HDF5 file', 'a sweep index, not a results file', ... (plot, export and compare
    refuse or skip such files by name instead of failing inside h5py)."""
    path = Path(path)
    if not path.is_file():
        return "no such file"
    try:
        with h5py.File(path, "r") as f:
            if "time" in f and "mode" in f.attrs:
                return None
            if path.name == "index.h5" or "cases" in f or "sweep" in f.attrs:
                return "a sweep index, not a results file"
            return "an HDF5 file without mbsim results (no /time or mode attribute)"
    except (OSError, RuntimeError, ValueError):
        return "not an HDF5 file"


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
