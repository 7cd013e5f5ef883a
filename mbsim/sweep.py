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
    Every case runs :func:`run_case` on the batch runner (:mod:`mbsim.batch`: executor,
    spool, Ctrl-C), a local process pool or a Dask cluster's executor, one code path. A
    worker gets the deck
    *text* and returns the :class:`~mbsim.result.Result`, so workers need mbsim but neither
    the deck file nor the output folder. A worker parses the text once
    (:func:`mbsim.deck.loader.parse_deck_cached`; forked workers inherit the deck parsed
    here) and each case applies its values to that tree copy-on-write, then validates and
    compiles it. This process writes every file (atomically,
    :func:`~mbsim.output.write_result`) and the index. An exception in a case (a bad value,
    an analysis that raises) makes that case ``failed`` with the message; the others go on.
    An analysis that stops part-way gives an ``incomplete`` file, as ``mbsim run`` does.

Resuming
    A case whose file exists, has status ``complete`` and was made from the same deck text,
    mode, scene, ``--set`` overrides, case values and analysis options (stored in the file's
    ``settings``: ``overrides``, ``scene``, ``sweep``) is not run again (``skipped`` in the
    index). So re-running an interrupted or partly failed sweep runs only what is missing.

Interrupting
    Ctrl-C (SIGINT) or SIGTERM while cases run (caught by the batch runner and raised as a
    ``KeyboardInterrupt`` from its wait loop) cancels the cases not started, stops the
    running ones (their results are lost; nothing of theirs was written), keeps every
    finished file and writes the index with the unfinished cases as ``cancelled``, then
    re-raises. The index is also rewritten (atomically) as cases finish, at most once a
    second, so even a killed sweep (SIGKILL) leaves an index of what had finished by then;
    the files decide what a re-run runs, not the index.

Index
    ``index.csv`` and ``index.h5`` (compound dataset ``/cases``, one record per case; root
    attributes describe the sweep), columns: ``case``, one per parameter (its label as
    given), ``status`` (complete, incomplete, failed, cancelled), ``skipped``, ``message``,
    ``wall_s`` (load + analysis in the worker; for a skipped case the stored analysis wall
    time), ``file`` (relative to the index; empty when no file was written), then one per
    summary, ``CHANNEL:NAME``. Summaries are computed for complete cases only (empty/NaN
    otherwise).

Summaries
    ``--summary CHANNEL:NAME[:from=T][:band=B]``: NAME is a statistic of a deck study's
    ``numbers:`` (``SUMMARIES`` is :data:`mbsim.output.stats.STATS`: final, min, max, mean,
    absmax, range, t_max, period, settle, growth, ...), computed by the same function over
    the time axis and one scalar column (a channel or one component, ``bodies.collar.r.y``),
    with ``from`` (window start, s) and ``band`` (settle) as the study keys of those names.
    So ``bodies.spindle.omega.y:settle:from=0.1`` is the transition time of the governor's
    study ``spring_rate``, to the last bit.
"""

from __future__ import annotations

import concurrent.futures as cf
import csv
import itertools
import json
import math
import os
import re
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from mbsim.batch import WorkerLost, open_executor, run_batch
from mbsim.deck.limits import CASES
from mbsim.errors import AnalysisError, DeckError, MbsimError, Where
from mbsim.output.stats import RATIO_STATS, STATS, TIME_STATS
from mbsim.result import STATUS_COMPLETE, STATUS_INCOMPLETE, Result

STATUS_FAILED = "failed"  # the case raised: no results file
STATUS_CANCELLED = "cancelled"  # interrupted before it finished: no results file
INDEX_INTERVAL = 1.0  # s: the index is rewritten at most this often while cases finish
MAX_NAME = 150  # longer case names are replaced by case<number>
_UNSAFE = re.compile(r"[^A-Za-z0-9.+=-]+")


class SweepError(MbsimError):
    """A usage error of a sweep (bad --param, --summary, --scheduler); exit code 2."""

    exit_code = 2


# --------------------------------------------------------------------------- summaries

# The statistics of studies (``numbers:`` of a deck's study, docs/studies.md): one definition
# of "transition time", "final", ... for studies and sweeps.  Each is f(t, y, options).
SUMMARIES: dict[str, Callable[[np.ndarray, np.ndarray, dict], float]] = STATS
SUMMARY_OPTIONS = ("from", "band")  # CHANNEL:NAME:from=T:band=B (the study number keys)


@dataclass(frozen=True)
class Summary:
    """``--summary CHANNEL:NAME[:from=T][:band=B]``: the statistic `name` (a key of
    :data:`SUMMARIES`, i.e. :data:`mbsim.output.stats.STATS`) of one scalar column `channel`,
    over the samples at t >= `from` (all when None); `band` is the relative band of
    ``settle`` (default 0.02)."""

    channel: str  # dotted selector, e.g. bodies.collar.r.y
    name: str  # key of SUMMARIES
    options: tuple[tuple[str, str], ...] = ()  # (key, number text as given), e.g. ('from', '0.1')

    @property
    def column(self) -> str:
        """The index column: ``bodies.spindle.omega.y:settle:from=0.1``."""
        return ":".join([self.channel, self.name] + [f"{k}={v}" for k, v in self.options])

    @property
    def number(self) -> dict[str, float]:
        """The options as a study number's keys, for ``STATS[name](t, y, number)``."""
        return {k: float(v) for k, v in self.options}


def parse_summary(text: str) -> Summary:
    """``bodies.collar.r.y:final`` or ``bodies.spindle.omega.y:settle:from=0.1`` -> Summary;
    the name must be in SUMMARIES, the options ``from`` (s) and ``band`` (settle only)."""
    channel, _, rest = text.strip().partition(":")
    channel = channel.strip().replace("/", ".").strip(".")
    name, *opts = [x.strip() for x in rest.split(":")] if rest else [""]
    names = ", ".join(SUMMARIES)
    if not channel or not name:
        raise SweepError(f"--summary {text!r}: expected CHANNEL:NAME, e.g. "
                         f"bodies.collar.r.y:final (names: {names})")
    if name not in SUMMARIES:
        import difflib

        close = difflib.get_close_matches(name, list(SUMMARIES), n=1)
        hint = f"did you mean {close[0]!r}? " if close else ""
        raise SweepError(f"--summary {text!r}: unknown summary {name!r}; {hint}(names: {names})")
    options: dict[str, str] = {}
    for opt in opts:
        key, sep, value = (x.strip() for x in opt.partition("="))
        if not sep or key not in SUMMARY_OPTIONS:
            raise SweepError(f"--summary {text!r}: {opt!r} is not one of from=T (start of the "
                             "window, s) or band=B (relative band of settle)")
        if key in options:
            raise SweepError(f"--summary {text!r}: {key} given twice")
        try:
            number = float(value)
        except ValueError:
            raise SweepError(f"--summary {text!r}: {key}={value!r} is not a number") from None
        if not math.isfinite(number) or (key == "band" and number <= 0):
            raise SweepError(f"--summary {text!r}: {key}={value} must be a finite number"
                             + (" > 0" if key == "band" else ""))
        if key == "band" and name != "settle":
            raise SweepError(f"--summary {text!r}: band applies to settle only")
        options[key] = value
    return Summary(channel, name, tuple(options.items()))


def summary_unit(summary: Summary, channel_unit: str) -> str:
    """``s`` for the time statistics, nothing for growth, else the channel's unit."""
    if summary.name in TIME_STATS:
        return "s"
    return "" if summary.name in RATIO_STATS else channel_unit


def evaluate_summary(result: Result, summary: Summary) -> tuple[float, str]:
    """(value, unit) of `summary` on `result`: ``STATS[name](t, y, {from, band})``, the very
    function (and so the very number) of a study's ``numbers:`` entry with the same keys.

    Raises
    ------
    KeyError, IndexError
        Unknown channel or component (the message suggests close names).
    ValueError
        The selector names a vector channel (several columns) or there are no samples (in
        the window).
    """
    from mbsim.output import select_columns

    cols = select_columns(result, summary.channel)
    if len(cols) != 1:
        labels = ", ".join(f"{summary.channel}.{c.label}".replace(".[", "[") for c in cols)
        raise ValueError(f"channel {summary.channel!r} has {len(cols)} components; "
                         f"name one: {labels}")
    col = cols[0]
    t = np.asarray(result.t, dtype=float)
    number = summary.number
    if t.size == 0:
        raise ValueError("no output samples")
    if number.get("from") is not None and not t[-1] >= number["from"] - 1e-12:
        raise ValueError(f"no output at t >= from={number['from']:g} s "
                         f"(the run ends at {t[-1]:g} s)")
    value = SUMMARIES[summary.name](t, np.asarray(col.data, dtype=float), number)
    return float(value), summary_unit(summary, col.unit)


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
    """`text` with runs of characters other than ``A-Z a-z 0-9 . + - =`` replaced by ``-``,
    such runs at either end dropped (a sign stays: ``-2*pi`` gives ``-2-pi``)."""
    name = _UNSAFE.sub("-", text)
    if _UNSAFE.match(text):
        name = name[1:]
    if text and _UNSAFE.match(text[-1]):
        name = name[:-1]
    return name or "-"


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
        count = math.prod(len(p.values) for p in params)
        if count > CASES.value:  # before the product: 300^4 cases took every byte of memory
            raise SweepError(CASES.exceeded(count))
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


def _check_paths(deck, scene: str | None, params: Sequence[Param]) -> None:
    """Every --param key path must exist in the deck (a ParsedDeck) with the scene applied
    (or be a key the format allows there)."""
    from mbsim.deck.schema import can_add, setting_name_problems
    from mbsim.deck.tree import Node, PathError, set_path

    root, file = deck.variant(scene), deck.file  # a copy-on-write view: deck stays as parsed
    for p in params:
        try:
            set_path(root, p.path, Node("scalar", 0, None, "0"), can_add)
        except PathError as exc:
            raise DeckError(f"cannot --param {p.label}: {exc.message}", Where(file, p.path)) \
                from None
        segs = p.path.split(".")
        if len(segs) == 3 and segs[0] == "analysis":  # analysis.<mode>.<setting>
            for _, message in setting_name_problems(segs[1], [segs[2]]):
                raise DeckError(f"cannot --param {p.label}: {message}", Where(file, p.path))


def plan_sweep(deck: str | Path, mode: str, params: Sequence[Param], out_dir: str | Path,
               zip_: bool = False, overrides: Mapping[str, str] | None = None,
               scene: str | None = None, options: Mapping | None = None,
               summaries: Sequence[Summary] = ()) -> Sweep:  # fmt: skip
    """Check the sweep before anything runs and list its cases.

    The deck is read once (and remembered for the workers, which fork from here or parse
    it once each) and validated with the ``--set`` overrides and the scene (a DeckError here
    is a usage error of the whole sweep), the mode must be available, every ``--param`` path
    must exist in the deck and a path may not be both ``--set`` and ``--param``. Values are
    not checked here: a bad value fails its own case only.

    Raises
    ------
    DeckError, SweepError
        Exit code 2: nothing has run.
    """
    from mbsim.api import analysis_function
    from mbsim.deck.loader import parse_deck, remember_deck
    from mbsim.model import compile_model  # noqa: F401 - forked workers inherit the import

    analysis_function(mode)  # DeckError for a mode that does not exist or is not available
    overrides = dict(overrides or {})
    both = [p.label for p in params if p.path in overrides]
    if both:
        raise SweepError(f"{both[0]} is both --set and --param; give it once")
    cases = make_cases(params, zip_)
    fixed = {"case", "status", "skipped", "message", "wall_s", "file"}
    clash = [p.label for p in params if p.label in fixed]
    if clash:
        raise SweepError(f"--param {clash[0]}: the index has a column of that name; "
                         f"write the key path, parameters.{clash[0]}")
    summaries = tuple(dict.fromkeys(summaries))  # one column per distinct --summary
    from mbsim.deck.schema import setting_name_problems

    given = [k for k, v in (options or {}).items() if v is not None]
    for key, _ in setting_name_problems(mode, given):
        raise SweepError(f"--{key.replace('_', '-')} does not apply to --mode {mode}")
    parsed = parse_deck(deck, scene)
    spec = parsed.spec(scene, overrides)
    _check_paths(parsed, scene, params)
    remember_deck(parsed)  # run_case finds it (here, and in workers forked from here)
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
    from mbsim.deck.loader import parse_deck_cached
    from mbsim.model import compile_model

    t0 = time.perf_counter()
    try:  # the deck is parsed once per process; the case's edits are copy-on-write
        deck = parse_deck_cached(deck_text, deck_file)
        spec = deck.spec(scene, overrides, studies=False)  # studies: checked by plan_sweep
        result = run_model(compile_model(spec), mode, options, deck=spec)
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

    from mbsim.output.hdf5 import json_document

    path = sweep.case_file(case)
    if not path.is_file():
        return False
    want = _jsonable(_case_settings(sweep, case))
    try:
        with h5py.File(path, "r") as f:
            a = f.attrs
            if str(a.get("status", "")) != STATUS_COMPLETE or str(a.get("mode", "")) != sweep.mode:
                return False
            settings = json_document(f, "settings")
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


@dataclass(frozen=True)
class _SweepTask:
    number: int
    args: tuple  # run_case(*args)
    case: Case


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

    Ctrl-C (SIGINT) or SIGTERM while the cases run: the cases that have finished are
    written, then a KeyboardInterrupt is raised (from this function's wait loop, never from
    inside an executor's locks) after the index is written (unfinished cases
    ``cancelled``); an executor opened here is stopped first (running workers ended).
    """
    prepare_out_dir(sweep.out_dir)
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
    index_failed: list[str] = []  # why the index could not be written (disk full, read-only)

    def index_now(force=False):
        nonlocal last_index
        if force or time.monotonic() - last_index >= INDEX_INTERVAL:
            try:
                write_index(sweep, _all_records(sweep, records))
                index_failed.clear()
            except OSError as exc:  # the cases go on: their files are what matters
                index_failed[:] = [f"cannot write the index {index_paths(sweep.out_dir)[0]}: "
                                   f"{exc.strerror or exc}"]
            last_index = time.monotonic()

    def finish(task: _SweepTask, run: CaseRun | WorkerLost) -> None:
        if isinstance(run, WorkerLost):
            run = CaseRun(None, run.message, float("nan"))
        records[task.case.number] = finish_case(sweep, task.case, run)
        if on_case:
            on_case(records[task.case.number])
        index_now()

    try:
        tasks = [_SweepTask(c.number, (sweep.deck_text, sweep.deck, sweep.case_overrides(c),
                                       sweep.scene, sweep.mode, sweep.options), c)
                 for c in todo]  # fmt: skip
        jobs = min(jobs, len(tasks)) if jobs and tasks else jobs  # no idle processes
        run_batch(tasks, run_case, finish, jobs, scheduler, executor, spool_dir=sweep.out_dir)
    except BaseException:  # Ctrl-C, or an error of this process: the index of what finished
        index_now(force=True)
        raise
    index_now(force=True)
    if index_failed:
        done = [r for r in records.values() if r.file and not r.skipped]
        raise SweepWriteError(f"{index_failed[0]}; {len(done)} case file(s) written and "
                              f"{sum(r.skipped for r in records.values())} kept in "
                              f"{sweep.out_dir} (re-run the same command when there is room: "
                              "it runs only the missing cases)")
    return SweepOutcome(_all_records(sweep, records), *index_paths(sweep.out_dir))


class SweepWriteError(AnalysisError):
    """The sweep ran but its index could not be written (disk full, read-only): exit 1,
    the case files written are kept."""


def prepare_out_dir(out_dir: Path) -> Path:
    """Make the sweep's folder and check that it takes a new file, before any case runs:
    a folder that cannot be made or written is a SweepError (exit 2) naming it."""
    from mbsim.output.hdf5 import probe_write

    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        probe_write(out_dir / f".write-probe-{os.getpid()}")
    except OSError as exc:
        raise SweepError(f"output folder {out_dir}: cannot write there: "
                         f"{exc.strerror or exc}") from None
    return out_dir


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
    "plan_sweep", "read_index", "run_case", "run_sweep", "write_index",
]
