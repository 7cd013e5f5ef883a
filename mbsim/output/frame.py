"""Results in pandas: ``mbsim.read(path).frame(group)`` and ``mbsim export --parquet``.

A frame is indexed by time (``time [s]``) and has one column per channel component, named
as in the CSV export (mbsim.output.export): ``bodies/slider/r/x [m]`` (the unit in brackets,
none for a dimensionless channel), so a column means the same in CSV, Parquet and pandas.
pandas is an optional extra (``pip install 'mbsim[pandas]'``); without it the call raises one
``UsageError`` saying so.
"""

from __future__ import annotations

from pathlib import Path

from mbsim.errors import UsageError
from mbsim.output.export import header_name, select_all
from mbsim.result import Result


def _pandas():
    try:
        import pandas
    except ImportError:
        raise UsageError("results as pandas DataFrames need pandas: pip install "
                         "'mbsim[pandas]' (or pip install pandas)") from None
    return pandas


def result_frame(result: Result, group: str | None = None):
    """A DataFrame of the channels under ``group`` (``bodies/slider``, ``drivers``, one channel
    ``bodies/slider/r``, dots or slashes; None: every channel), indexed by time."""
    pd = _pandas()
    names = list(result.channels)
    if group:
        key = group.replace(".", "/").strip("/")
        names = [n for n in names if n == key or n.startswith(key + "/")]
        if not names:
            result.channel(key)  # KeyError naming close channels
    cols = select_all(result, names)
    index = pd.Index(result.t, name="time [s]")
    return pd.DataFrame({header_name(c.name, c.unit): c.data for c in cols}, index=index)


class ResultFile:
    """A result file opened for Python: ``.result`` (mbsim.result.Result), ``.channels``
    (names), ``.frame(group)`` (pandas DataFrame, see :func:`result_frame`)."""

    def __init__(self, path: str | Path):
        from mbsim.output.hdf5 import read_result, result_file_problem

        problem = result_file_problem(path)
        if problem:
            raise UsageError(f"{path}: {problem}")
        self.path = Path(path)
        self.result = read_result(path)

    @property
    def channels(self) -> list[str]:
        return list(self.result.channels)

    def frame(self, group: str | None = None):
        return result_frame(self.result, group)

    def __repr__(self) -> str:
        r = self.result
        return (f"<mbsim result {self.path.name}: {r.mode}, {r.status}, {len(r.t)} outputs, "
                f"{len(r.channels)} channels>")


def export_parquet(result: Result, path: str | Path) -> Path:
    """Every channel to one Parquet file (pyarrow), columns as :func:`result_frame`'s; the
    time index is kept.  Written to a temporary name, then renamed."""
    import os

    frame = result_frame(result)
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        frame.to_parquet(tmp)
        os.replace(tmp, path)
    except ImportError:
        tmp.unlink(missing_ok=True)
        raise UsageError("Parquet files need pyarrow: pip install 'mbsim[pandas]' (or pip "
                         "install pyarrow)") from None
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise UsageError(f"cannot write {path}: {exc.strerror or exc}") from None
    return path
