"""Parameter sweeps: one deck, many cases, run in parallel, one HDF5 file per case and an index.

``mbsim sweep DECK --param k=1000,2000 --param C=7500,12500`` (the CLI layer is
:mod:`mbsim.cli_sweep`) comes here as::

    params = [parse_param("k=1000,2000"), parse_param("C=7500,12500")]
    sweep = plan_sweep("models/governor.yaml", "dynamic", params, out_dir="gov_sweep")
    with open_executor(jobs=4) as ex:                      # or open_executor(scheduler=...)
        outcome = run_sweep(sweep, ex, on_case=print)

Cases
    A ``--param`` is ``NAME=V1,V2,...``: NAME is a deck parameter (shorthand for
    ``parameters.NAME``) or a full key path (``forces.spring.c``, as for ``--set``); each V is
    YAML text, as a ``--set`` value (commas inside ``[...]``, ``{...}`` or quotes do not
    split). The cases are the Cartesian product of the lists (the first ``--param`` varies
    slowest), or with ``zip=True`` the lists taken element by element (equal lengths). A
    case is named from its values, ``k=1000_C=7500``; its file is ``<name>.h5`` in the
    output folder (characters other than letters, digits and ``. + - =`` become ``-``).

Running
    Every case runs :func:`run_case` on an executor, a :class:`concurrent.futures.Executor`:
    a local process pool or a Dask cluster's executor, one code path. A worker gets the deck
    *text* and returns the :class:`~mbsim.result.Result`, so workers need mbsim but neither
    the deck file nor the output folder; this process writes every file (atomically,
    :func:`~mbsim.output.write_result`) and the index. An exception in a case (a bad value,
    an analysis that raises) makes that case ``failed`` with the message; the others go on.
    An analysis that stops part-way gives an ``incomplete`` file, as ``mbsim run`` does.

Resuming
    A case whose file exists, has status ``complete`` and was made from the same deck text,
    mode, scene, ``--set`` overrides, case values and analysis options (stored in the file's
    ``settings``: ``overrides``, ``scene``, ``sweep``) is not run again (``skipped`` in the
    index). So re-running an interrupted or partly failed sweep runs only what is missing.

Interrupting
    A ``KeyboardInterrupt`` (Ctrl-C) while cases run cancels the cases not started, stops
    the running ones (their results are lost; nothing of theirs was written), keeps every
    finished file and writes the index with the unfinished cases as ``cancelled``, then
    re-raises. The index is also rewritten (atomically) as cases finish, at most once a
    second, so even a killed sweep leaves an index of what had finished by then.

Index
    ``index.csv`` and ``index.h5`` (compound dataset ``/cases``, one record per case; root
    attributes describe the sweep), columns: ``case``, one per parameter (its label as
    given), ``status`` (complete, incomplete, failed, cancelled), ``skipped``, ``message``,
    ``wall_s`` (load + analysis in the worker; for a skipped case the stored analysis wall
    time), ``file`` (relative to the index; empty when no file was written), then one per
    summary, ``CHANNEL:NAME``. Summaries are computed for complete cases only (empty/NaN
    otherwise).

Summaries
    ``SUMMARIES`` maps a name to ``f(t, x) -> float`` over the time axis ``t`` (nt,) and one
    scalar column ``x`` (nt,) (a channel or one component, ``bodies.collar.r.y``). A function
    whose result is a time carries ``unit = "s"``; otherwise the value has the channel's unit.
    Add entries to the dict to make new names available on the command line.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import csv
import itertools
import json
import math
import multiprocessing
import os
import re
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from mbsim.errors import DeckError, MbsimError, Where
from mbsim.result import STATUS_COMPLETE, STATUS_INCOMPLETE, Result

STATUS_FAILED = "failed"  # the case raised: no results file
STATUS_CANCELLED = "cancelled"  # interrupted before it finished: no results file
SETTLE_BAND = 0.02  # settle_time: half-width of the band around the final value, relative
INDEX_INTERVAL = 1.0  # s: the index is rewritten at most this often while cases finish
MAX_NAME = 150  # longer case names are replaced by case<number>
CONNECT_TIMEOUT = 20.0  # s to reach a Dask scheduler
_UNSAFE = re.compile(r"[^A-Za-z0-9.+=-]+")


class SweepError(MbsimError):
    """A usage error of a sweep (bad --param, --summary, --scheduler); exit code 2."""

    exit_code = 2


# --------------------------------------------------------------------------- summaries


def final(t: np.ndarray, x: np.ndarray) -> float:
    """The last value."""
    return float(x[-1])


def minimum(t: np.ndarray, x: np.ndarray) -> float:
    """The smallest value."""
    return float(np.min(x))


def maximum(t: np.ndarray, x: np.ndarray) -> float:
    """The largest value."""
    return float(np.max(x))


def mean(t: np.ndarray, x: np.ndarray) -> float:
    """The time average, trapezoidal rule: (1 / (t_end - t_0)) * integral of x dt
    (the plain average of the samples for a single sample)."""
    if len(t) < 2 or t[-1] == t[0]:
        return float(np.mean(x))
    integral = float(np.sum(0.5 * (x[1:] + x[:-1]) * np.diff(t)))
    return integral / float(t[-1] - t[0])


def peak(t: np.ndarray, x: np.ndarray) -> float:
    """The largest absolute value, max |x|."""
    return float(np.max(np.abs(x)))


def settle_time(t: np.ndarray, x: np.ndarray) -> float:
    """The transition time to a new steady state: when `x` last enters, and then stays in,
    the band |x - x_f| <= 0.02 |x_f| around its final value x_f = x[-1].

    The time is interpolated linearly between the last sample outside the band and the next
    one; it is ``t[0]`` when no sample is outside. When x_f = 0 the band is 2 % of max |x|
    instead. The run must be long enough to reach the steady state: x_f is the last sample,
    whatever it is. (The 2 % settling-time criterion of control engineering, taken relative
    to the final value.)
    """
    xf = float(x[-1])
    band = SETTLE_BAND * (abs(xf) if xf != 0 else float(np.max(np.abs(x))))
    outside = np.flatnonzero(np.abs(x - xf) > band)
    if outside.size == 0:
        return float(t[0])
    k = int(outside[-1])  # k < nt - 1: the last sample is always inside
    d0, d1 = abs(x[k] - xf) - band, abs(x[k + 1] - xf) - band  # > 0, <= 0
    return float(t[k] + (t[k + 1] - t[k]) * d0 / (d0 - d1)) if d0 != d1 else float(t[k + 1])


settle_time.unit = "s"  # type: ignore[attr-defined]

SUMMARIES: dict[str, Callable[[np.ndarray, np.ndarray], float]] = {
    "final": final,
    "min": minimum,
    "max": maximum,
    "mean": mean,
    "peak": peak,
    "settle_time": settle_time,
}


@dataclass(frozen=True)
class Summary:
    """``--summary CHANNEL:NAME``: the summary `name` of one scalar column `channel`."""

    channel: str  # dotted selector, e.g. bodies.collar.r.y
    name: str  # key of SUMMARIES

    @property
    def column(self) -> str:
        return f"{self.channel}:{self.name}"


def parse_summary(text: str) -> Summary:
    """``bodies.collar.r.y:final`` -> Summary; the name must be in SUMMARIES."""
    channel, sep, name = text.strip().rpartition(":")
    channel = channel.strip().replace("/", ".").strip(".")
    name = name.strip()
    if not sep or not channel:
        raise SweepError(f"--summary {text!r}: expected CHANNEL:NAME, e.g. "
                         f"bodies.collar.r.y:final (names: {', '.join(SUMMARIES)})")
    if name not in SUMMARIES:
        import difflib

        close = difflib.get_close_matches(name, list(SUMMARIES), n=1)
        hint = f"did you mean {close[0]!r}? " if close else ""
        raise SweepError(f"--summary {text!r}: unknown summary {name!r}; {hint}"
                         f"(names: {', '.join(SUMMARIES)})")
    return Summary(channel, name)


def summary_unit(summary: Summary, channel_unit: str) -> str:
    return getattr(SUMMARIES[summary.name], "unit", None) or channel_unit


def evaluate_summary(result: Result, summary: Summary) -> tuple[float, str]:
    """(value, unit) of `summary` on `result`.

    Raises
    ------
    KeyError, IndexError
        Unknown channel or component (the message suggests close names).
    ValueError
        The selector names a vector channel (several columns) or there are no samples.
    """
    from mbsim.output import select_columns

    cols = select_columns(result, summary.channel)
    if len(cols) != 1:
        labels = ", ".join(f"{summary.channel}.{c.label}".replace(".[", "[") for c in cols)
        raise ValueError(f"channel {summary.channel!r} has {len(cols)} components; "
                         f"name one: {labels}")
    col = cols[0]
    t = np.asarray(result.t, dtype=float)
    if t.size == 0:
        raise ValueError("no output samples")
    return SUMMARIES[summary.name](t, col.data), summary_unit(summary, col.unit)


# --------------------------------------------------------------------------- parameters, cases


@dataclass(frozen=True)
class Param:
    """One ``--param``: `label` as the user wrote it, the deck key `path`, the value texts."""

    label: str  # 'k' or 'forces.spring.c'
    path: str  # 'parameters.k' or 'forces.spring.c'
    values: tuple[str, ...]  # YAML texts, as for --set


def split_values(text: str) -> list[str]:
    """Split ``1,2,[3, 4],'a,b'`` at the commas outside brackets and quotes."""
    items, depth, quote, cur = [], 0, "", ""
    for ch in text:
        if quote:
            quote = "" if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch in "[{(":
            depth += 1
        elif ch in "]})":
            depth -= 1
        elif ch == "," and depth == 0:
            items.append(cur.strip())
            cur = ""
            continue
        cur += ch
    items.append(cur.strip())
    return items


def parse_param(text: str) -> Param:
    """``k=1000,2000,3000`` or ``forces.spring.c=10,20`` -> Param."""
    name, sep, values = text.partition("=")
    name = name.strip()
    if not sep or not name:
        raise SweepError(f"--param {text!r}: expected NAME=V1,V2,..., e.g. k=1000,2000,3000 "
                         "or forces.spring.c=10,20")
    vals = split_values(values)
    if any(v == "" for v in vals):
        raise SweepError(f"--param {text!r}: empty value in the list {values!r}")
    path = name if ("." in name or "[" in name) else f"parameters.{name}"
    return Param(name, path, tuple(vals))


@dataclass(frozen=True)
class Case:
    """One run of the sweep."""

    number: int  # 1-based, in sweep order
    name: str  # file stem, 'k=1000_C=7500'
    values: dict[str, str]  # param label -> value text
    overrides: dict[str, str]  # key path -> value text: this case's --param values only


def safe_name(text: str) -> str:
    """`text` with runs of characters other than ``A-Z a-z 0-9 . + - =`` replaced by ``-``."""
    return _UNSAFE.sub("-", text).strip("-") or "-"


def make_cases(params: Sequence[Param], zip_: bool = False) -> list[Case]:
    """The cases: Cartesian product of the value lists (first param slowest) or, with
    `zip_`, element by element (the lists must have equal lengths)."""
    if not params:
        raise SweepError("name at least one --param NAME=V1,V2,...")
    paths = [p.path for p in params]
    dup = sorted({p for p in paths if paths.count(p) > 1})
    if dup:
        raise SweepError(f"--param {dup[0]} is given twice")
    if zip_:
        lengths = {p.label: len(p.values) for p in params}
        if len(set(lengths.values())) > 1:
            listed = ", ".join(f"{k}: {n}" for k, n in lengths.items())
            raise SweepError(f"--zip needs lists of equal length, got {listed}")
        combos = list(zip(*(p.values for p in params)))
    else:
        combos = list(itertools.product(*(p.values for p in params)))
    labels = [p.label for p in params]
    cases, seen = [], {}
    for i, combo in enumerate(combos, start=1):
        values = dict(zip(labels, combo))
        name = "_".join(f"{safe_name(k)}={safe_name(v)}" for k, v in values.items())
        if len(name) > MAX_NAME:
            name = f"case{i:0{len(str(len(combos)))}d}"
        if name in seen:
            raise SweepError(f"cases {seen[name]} and {values} give the same file name "
                             f"{name}.h5; write the values differently")
        seen[name] = values
        cases.append(Case(i, name, values, {p.path: v for p, v in zip(params, combo)}))
    return cases


# --------------------------------------------------------------------------- the plan


@dataclass(frozen=True)
class Sweep:
    """Everything a sweep runs: the deck, the cases, the options, where the files go."""

    deck: str  # deck file as given (names it in messages and results)
    deck_text: str  # deck YAML text, sent to the workers
    mode: str  # analysis mode
    params: tuple[Param, ...]
    cases: tuple[Case, ...]
    out_dir: Path
    overrides: dict[str, str] = field(default_factory=dict)  # --set, applied to every case
    scene: str | None = None
    options: dict = field(default_factory=dict)  # analysis options (t_end, step, ...)
    summaries: tuple[Summary, ...] = ()

    def case_file(self, case: Case) -> Path:
        return self.out_dir / f"{case.name}.h5"

    def case_overrides(self, case: Case) -> dict[str, str]:
        """--set overrides, then the case's values."""
        return {**self.overrides, **case.overrides}


def _check_paths(text: str, file: str, scene: str | None, params: Sequence[Param]) -> None:
    """Every --param key path must exist in the deck (or be a key the format allows there)."""
    from mbsim.deck.schema import can_add
    from mbsim.deck.tree import Node, PathError, apply_scene, compose, set_path

    root = compose(text, file)
    if root is None or root.kind != "map":
        return  # load_deck has already said what is wrong
    if scene is not None:
        apply_scene(root, scene, file)
    for p in params:
        try:
            set_path(root, p.path, Node("scalar", 0, None, "0"), can_add)
        except PathError as exc:
            raise DeckError(f"cannot --param {p.label}: {exc.message}", Where(file, p.path)) \
                from None


def plan_sweep(deck: str | Path, mode: str, params: Sequence[Param], out_dir: str | Path,
               zip_: bool = False, overrides: Mapping[str, str] | None = None,
               scene: str | None = None, options: Mapping | None = None,
               summaries: Sequence[Summary] = ()) -> Sweep:  # fmt: skip
    """Check the sweep before anything runs and list its cases.

    The deck is loaded once with the ``--set`` overrides and the scene (a DeckError here is
    a usage error of the whole sweep), the mode must be available, every ``--param`` path
    must exist in the deck and a path may not be both ``--set`` and ``--param``. Values are
    not checked here: a bad value fails its own case only.

    Raises
    ------
    DeckError, SweepError
        Exit code 2: nothing has run.
    """
    from mbsim.api import analysis_function
    from mbsim.deck import load_deck
    from mbsim.model import compile_model  # noqa: F401 - forked workers inherit the import

    analysis_function(mode)  # DeckError for a mode that does not exist or is not available
    overrides = dict(overrides or {})
    both = [p.label for p in params if p.path in overrides]
    if both:
        raise SweepError(f"{both[0]} is both --set and --param; give it once")
    cases = make_cases(params, zip_)
    spec = load_deck(deck, overrides=overrides, scene=scene)
    _check_paths(spec.text, str(deck), scene, params)
    opts = {k: v for k, v in (options or {}).items() if v is not None}
    return Sweep(str(deck), spec.text, mode, tuple(params), tuple(cases), Path(out_dir),
                 overrides, scene, opts, tuple(summaries))


def default_out_dir(deck: str | Path, mode: str, scene: str | None = None) -> Path:
    """``<deck stem>_<mode>_sweep`` (``<stem>_<scene>_<mode>_sweep`` with a scene)."""
    stem = Path(deck).stem
    return Path(f"{stem}_{scene}_{mode}_sweep" if scene else f"{stem}_{mode}_sweep")


# --------------------------------------------------------------------------- one case


@dataclass
class CaseRun:
    """What a worker sends back: the result, or why there is none."""

    result: Result | None
    message: str  # the error of a failed case
    wall_time: float  # s in the worker: load, compile, analysis


def run_case(deck_text: str, deck_file: str, overrides: dict[str, str], scene: str | None,
             mode: str, options: dict) -> CaseRun:  # fmt: skip
    """Load, compile and run one case in a worker; any exception becomes a failed CaseRun.

    A module-level function of plain arguments, so a process pool and Dask can send it.
    """
    from mbsim.api import run_model
    from mbsim.deck import load_deck_text
    from mbsim.model import compile_model

    t0 = time.perf_counter()
    try:
        spec = load_deck_text(deck_text, deck_file, overrides=overrides, scene=scene)
        result = run_model(compile_model(spec), mode, options)
    except MbsimError as exc:
        return CaseRun(None, str(exc).replace("\n", " "), time.perf_counter() - t0)
    except Exception as exc:  # a bug or an unexpected value: the case fails, the sweep goes on
        msg = f"{type(exc).__name__}: {exc}".replace("\n", " ")
        return CaseRun(None, msg, time.perf_counter() - t0)
    return CaseRun(result, "", time.perf_counter() - t0)


@dataclass
class CaseRecord:
    """One row of the index."""

    case: Case
    status: str  # complete | incomplete | failed | cancelled
    message: str = ""
    wall_time: float = float("nan")  # s
    file: str = ""  # relative to the output folder; '' when no file was written
    skipped: bool = False  # an up-to-date file from an earlier run was kept
    summary: dict[str, float] = field(default_factory=dict)  # column -> value
    summary_errors: list[str] = field(default_factory=list)


def _case_settings(sweep: Sweep, case: Case) -> dict:
    return {"overrides": sweep.case_overrides(case), "scene": sweep.scene,
            "sweep": {"case": case.name, "values": case.values, "options": sweep.options}}


def _jsonable(value):
    from mbsim.output.hdf5 import from_json, to_json

    return from_json(to_json(value))


def up_to_date(sweep: Sweep, case: Case) -> bool:
    """True when the case's file exists, is complete and was made by this very case."""
    import h5py

    from mbsim.output.hdf5 import from_json

    path = sweep.case_file(case)
    if not path.is_file():
        return False
    want = _jsonable(_case_settings(sweep, case))
    try:
        with h5py.File(path, "r") as f:
            a = f.attrs
            if str(a.get("status", "")) != STATUS_COMPLETE or str(a.get("mode", "")) != sweep.mode:
                return False
            settings = from_json(str(a.get("settings", "")))
            deck = f["deck"].asstr()[()] if "deck" in f else ""
    except (OSError, KeyError, ValueError):
        return False  # unreadable or foreign: run it again
    have = {k: settings.get(k) for k in want}
    return have == want and deck == sweep.deck_text


def _summarise(record: CaseRecord, result: Result, summaries: Sequence[Summary]) -> None:
    for s in summaries:
        try:
            record.summary[s.column] = evaluate_summary(result, s)[0]
        except (KeyError, IndexError, ValueError) as exc:
            why = str(exc).strip("'\"")  # KeyError quotes its message
            record.summary_errors.append(f"--summary {s.column}: {why}")


def finish_case(sweep: Sweep, case: Case, run: CaseRun) -> CaseRecord:
    """Write a finished case's file (atomically) and make its index row."""
    from mbsim.output import write_result

    if run.result is None:
        return CaseRecord(case, STATUS_FAILED, run.message, run.wall_time)
    result = run.result
    result.settings.update(_case_settings(sweep, case))
    try:
        path = write_result(result, sweep.case_file(case))
    except (OSError, ValueError) as exc:  # disk full, a channel name HDF5 cannot hold
        return CaseRecord(case, STATUS_FAILED, f"cannot write {sweep.case_file(case)}: {exc}",
                          run.wall_time)
    status = result.status if result.status in (STATUS_COMPLETE, STATUS_INCOMPLETE) \
        else STATUS_INCOMPLETE
    rec = CaseRecord(case, status, result.message, run.wall_time, path.name)
    if status == STATUS_COMPLETE:
        _summarise(rec, result, sweep.summaries)
    return rec


def skipped_case(sweep: Sweep, case: Case) -> CaseRecord:
    """The index row of an up-to-date case, summaries from its file."""
    from mbsim.output import read_info, read_result

    path = sweep.case_file(case)
    rec = CaseRecord(case, STATUS_COMPLETE, "", float(read_info(path).get("wall_time_s", 0.0)),
                     path.name, skipped=True)
    if sweep.summaries:
        _summarise(rec, read_result(path), sweep.summaries)
    return rec


# --------------------------------------------------------------------------- executors


def _ignore_sigint() -> None:
    """Pool workers leave Ctrl-C to the parent, which cancels and stops them."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _mp_context():
    """fork on Linux while this process has a single thread (workers start at once and
    inherit the imports); otherwise forkserver (spawn where there is none), which re-imports
    the main module in each worker: a script calling run_sweep needs an
    ``if __name__ == "__main__":`` guard there, as for any process pool."""
    methods = multiprocessing.get_all_start_methods()
    if sys.platform.startswith("linux") and "fork" in methods and threading.active_count() == 1:
        return multiprocessing.get_context("fork")
    return multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")


@contextlib.contextmanager
def open_executor(jobs: int | None = None, scheduler: str | None = None,
                  ncases: int | None = None) -> Iterator[cf.Executor]:  # fmt: skip
    """A concurrent.futures Executor for the cases.

    Without `scheduler`: a process pool of `jobs` workers (default min(CPUs, `ncases`)).
    With `scheduler` (``tcp://host:8786``): the executor of a ``distributed.Client``
    connected to that Dask scheduler; `jobs` is ignored (the cluster's workers decide).
    On leaving, the pool is shut down; after an exception (Ctrl-C) without waiting, and
    running workers are stopped.
    """
    if scheduler:
        try:
            from distributed import Client
        except ImportError:
            raise SweepError("--scheduler needs Dask distributed: pip install 'mbsim[cluster]'") \
                from None
        try:
            client = Client(scheduler, set_as_default=False, timeout=CONNECT_TIMEOUT)
        except (OSError, TimeoutError, ValueError) as exc:
            raise SweepError(f"--scheduler {scheduler}: cannot connect: {exc}") from None
        ex = client.get_executor(pure=False)
        try:
            yield ex
        except BaseException:
            ex.shutdown(wait=False)  # cancels what has not finished
            raise
        finally:
            client.close()
        return
    n = jobs or min(os.cpu_count() or 1, max(ncases or 1, 1))
    if n < 1:
        raise SweepError(f"--jobs {jobs}: expected a positive number")
    ex = cf.ProcessPoolExecutor(max_workers=n, mp_context=_mp_context(),
                                initializer=_ignore_sigint)
    try:
        yield ex
    except BaseException:
        procs = list(getattr(ex, "_processes", {}).values())  # our own workers
        ex.shutdown(wait=False, cancel_futures=True)
        for p in procs:
            if p.is_alive():
                p.terminate()
        for p in procs:
            p.join(timeout=5)
        raise
    else:
        ex.shutdown(wait=True)


# --------------------------------------------------------------------------- the sweep


@dataclass
class SweepOutcome:
    records: list[CaseRecord]  # one per case, in sweep order
    index_csv: Path
    index_h5: Path
    interrupted: bool = False

    def count(self, status: str) -> int:
        return sum(r.status == status for r in self.records)

    @property
    def ok(self) -> bool:
        return all(r.status == STATUS_COMPLETE for r in self.records)

    @property
    def summary_errors(self) -> list[str]:
        return sorted({e for r in self.records for e in r.summary_errors})


def run_sweep(sweep: Sweep, on_case: Callable[[CaseRecord], None] | None = None,
              jobs: int | None = None, scheduler: str | None = None,
              executor: cf.Executor | None = None) -> SweepOutcome:  # fmt: skip
    """Run the cases that are not up to date, write their files and the index.

    Parameters
    ----------
    sweep : the plan (:func:`plan_sweep`).
    on_case : called as ``on_case(record)`` once per case, from this thread, as the case is
        found up to date or finishes.
    jobs, scheduler : the executor :func:`open_executor` opens when there is something to
        run (none is opened when every case is up to date).
    executor : use this one instead (left open).

    A KeyboardInterrupt is re-raised after the index is written (unfinished cases
    ``cancelled``); an executor opened here is stopped first (running workers ended).
    """
    sweep.out_dir.mkdir(parents=True, exist_ok=True)
    records: dict[int, CaseRecord] = {}
    todo = []
    for case in sweep.cases:
        if up_to_date(sweep, case):
            records[case.number] = skipped_case(sweep, case)
            if on_case:
                on_case(records[case.number])
        else:
            todo.append(case)
    last_index = -math.inf

    def index_now(force=False):
        nonlocal last_index
        if force or time.monotonic() - last_index >= INDEX_INTERVAL:
            write_index(sweep, _all_records(sweep, records))
            last_index = time.monotonic()

    try:
        if todo:
            with contextlib.ExitStack() as stack:
                ex = executor or stack.enter_context(
                    open_executor(jobs, scheduler, ncases=len(todo)))
                futures = {ex.submit(run_case, sweep.deck_text, sweep.deck,
                                     sweep.case_overrides(c), sweep.scene, sweep.mode,
                                     sweep.options): c for c in todo}
                try:
                    for fut in cf.as_completed(futures):
                        case = futures[fut]
                        try:
                            run = fut.result()
                        except Exception as exc:  # the worker died (killed, out of memory)
                            run = CaseRun(None, f"{type(exc).__name__}: {exc}", float("nan"))
                        records[case.number] = finish_case(sweep, case, run)
                        if on_case:
                            on_case(records[case.number])
                        index_now()
                except BaseException:
                    for fut in futures:
                        fut.cancel()
                    raise
    except BaseException:  # Ctrl-C, or an error of this process: the index of what finished
        index_now(force=True)
        raise
    index_now(force=True)
    return SweepOutcome(_all_records(sweep, records), *index_paths(sweep.out_dir))


def _all_records(sweep: Sweep, records: dict[int, CaseRecord]) -> list[CaseRecord]:
    return [records.get(c.number) or CaseRecord(c, STATUS_CANCELLED, "not finished")
            for c in sweep.cases]


# --------------------------------------------------------------------------- the index


def index_paths(out_dir: Path) -> tuple[Path, Path]:
    return out_dir / "index.csv", out_dir / "index.h5"


def _numeric(values: Sequence[str]) -> bool:
    try:
        [float(v) for v in values]
    except ValueError:
        return False
    return True


def index_columns(sweep: Sweep) -> list[str]:
    return (["case"] + [p.label for p in sweep.params]
            + ["status", "skipped", "message", "wall_s", "file"]
            + [s.column for s in sweep.summaries])


def index_rows(sweep: Sweep, records: Sequence[CaseRecord]) -> list[dict]:
    """The index as dicts (column -> value), parameter values as the texts given."""
    rows = []
    for r in records:
        msg = "; ".join([r.message] * bool(r.message) + r.summary_errors)
        row = {"case": r.case.name, **r.case.values, "status": r.status, "skipped": r.skipped,
               "message": msg, "wall_s": r.wall_time, "file": r.file}
        row.update({s.column: r.summary.get(s.column, float("nan")) for s in sweep.summaries})
        rows.append(row)
    return rows


def _atomic(path: Path, write: Callable[[Path], None]) -> None:
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _csv_text(value) -> str:
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return "" if math.isnan(value) else repr(value)
    return str(value)


def write_index(sweep: Sweep, records: Sequence[CaseRecord]) -> tuple[Path, Path]:
    """Write ``index.csv`` and ``index.h5`` in the output folder, each atomically
    (temporary file, then :func:`os.replace`)."""
    import h5py

    from mbsim import __version__
    from mbsim.output.hdf5 import to_json

    csv_path, h5_path = index_paths(sweep.out_dir)
    cols = index_columns(sweep)
    rows = index_rows(sweep, records)

    def write_csv(tmp: Path) -> None:
        with open(tmp, "w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(cols)
            for row in rows:
                w.writerow([_csv_text(row[c]) for c in cols])

    numbers = {p.label for p in sweep.params if _numeric(p.values)} | {"wall_s"} \
        | {s.column for s in sweep.summaries}
    str_t = h5py.string_dtype("utf-8")
    kinds = {c: np.float64 if c in numbers else str_t for c in cols}
    kinds["skipped"] = np.bool_
    dtype = np.dtype([(c, kinds[c]) for c in cols])

    def write_h5(tmp: Path) -> None:
        table = np.array([tuple(float(row[c]) if c in numbers else row[c]
                                for c in cols) for row in rows], dtype=dtype)
        with h5py.File(tmp, "w") as f:
            f.create_dataset("cases", data=table)
            a = f.attrs
            a["mbsim_version"] = __version__
            a["created"] = datetime.now(timezone.utc).isoformat(timespec="seconds")
            a["deck_file"] = sweep.deck
            a["mode"] = sweep.mode
            a["scene"] = sweep.scene or ""
            a["overrides"] = to_json(sweep.overrides)
            a["options"] = to_json(sweep.options)
            a["params"] = to_json({p.label: p.path for p in sweep.params})
            a["columns"] = json.dumps(cols)
            a["summaries"] = json.dumps([s.column for s in sweep.summaries])

    _atomic(csv_path, write_csv)
    _atomic(h5_path, write_h5)
    return csv_path, h5_path


def read_index(path: str | Path) -> list[dict]:
    """Rows of ``index.h5`` or ``index.csv`` as dicts (column -> value). From HDF5 the
    numbers are floats and ``skipped`` a bool; from CSV everything is text."""
    path = Path(path)
    if path.suffix == ".csv":
        with open(path, newline="", encoding="utf-8") as fh:
            return list(csv.DictReader(fh))
    import h5py

    with h5py.File(path, "r") as f:
        table = f["cases"][()]
        cols = json.loads(f.attrs["columns"])
    out = []
    for rec in table:
        row = {}
        for c in cols:
            v = rec[c]
            row[c] = v.decode() if isinstance(v, bytes) else (bool(v) if isinstance(v, np.bool_)
                                                                else float(v))
        out.append(row)
    return out


__all__ = [
    "SUMMARIES", "Case", "CaseRecord", "Param", "Summary", "Sweep", "SweepError",
    "SweepOutcome", "make_cases", "open_executor", "parse_param", "parse_summary",
    "plan_sweep", "read_index", "run_case", "run_sweep", "settle_time", "write_index",
]
