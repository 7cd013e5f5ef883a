"""Studies: the runs, figures and key numbers that a deck's ``studies:`` section defines.

A study (format: ``docs/studies.md``; validated by the deck loader into plain data,
``DeckSpec.studies``) is a list of *cases*, each one analysis of the deck with a scene,
``--set`` overrides, a mode and options; *figures*, each one or more channels drawn with one
curve per case; and *numbers*, statistics of channels tabulated per case (peak torque,
period, transition time, ...).  ``mbsim study DECK NAME`` (:mod:`mbsim.cli_study`) comes
here as::

    outcome = run_study("models/slider_crank.yaml", "inverse_rod_length", out_dir="out")
    outcome.cases      # one CaseOutcome per case: status, message, file, wall time
    outcome.figures    # the PNG files written
    outcome.table      # (header, rows) of the key numbers

The deck is read and composed once (:func:`open_deck`, a
:class:`~mbsim.deck.loader.ParsedDeck`); each case applies its scene and ``set`` to that
tree copy-on-write and validates the result (its key paths were checked when the deck was
loaded), so a study of n cases costs one parse, not n + 1.  Cases run in other processes
(``jobs`` > 1) parse the deck text once per process.

Each case writes ``<out_dir>/<study>/<case name>.h5`` (the result, with the study, case,
scene and overrides in its ``settings``); each figure ``<out_dir>/<study>/<figure>.png``.
A case that raises (a bad value, an analysis error) is ``failed`` with the message and the
others go on; an analysis that stops part-way is ``incomplete``, as for ``mbsim run``.

The statistics of ``numbers:`` (``STATS``: final, max, period, settle, growth, ...) are
those of :mod:`mbsim.output.stats`, shared with a sweep's ``--summary``.  Cases run on the
batch runner (:mod:`mbsim.batch`) when ``jobs`` > 1.

:func:`threshold` finds by bisection the value of one deck setting at which a case turns
from one behaviour to another (the governor's feedback gain at which it becomes unstable).
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mbsim.errors import DeckError, MbsimError
from mbsim.output.stats import (  # noqa: F401 - the statistics, here since studies named them
    RATIO_STATS,
    STATS,
    TIME_STATS,
    growth,
    period,
    settle,
    upcrossings,
)
from mbsim.result import STATUS_COMPLETE, Result

if TYPE_CHECKING:
    from mbsim.deck.loader import ParsedDeck

log = logging.getLogger(__name__)

STATUS_FAILED = "failed"  # the case raised: no file (or an older one) on disk


# --------------------------------------------------------------------------- data


@dataclass
class CaseOutcome:
    """What one case of a study gave."""

    name: str  # file stem
    label: str  # curve label
    mode: str
    status: str  # 'complete' | 'incomplete' | 'failed'
    message: str = ""
    path: Path | None = None  # the HDF5 file (None when the case failed)
    wall_time: float = 0.0  # s, load + analysis + write
    warnings: list[str] = field(default_factory=list)
    result: Result | None = None  # kept in memory for the figures and numbers


@dataclass
class StudyOutcome:
    name: str
    description: str
    out_dir: Path
    cases: list[CaseOutcome]
    figures: list[Path]
    table: tuple[list[str], list[list[str]]]  # header, rows (case label first)
    values: dict[str, dict[str, float]]  # case name -> {number column: value}
    wall_time: float = 0.0
    problems: list[str] = field(default_factory=list)  # figures/numbers that could not be made

    @property
    def ok(self) -> bool:
        return not self.problems and all(c.status == STATUS_COMPLETE for c in self.cases)


def open_deck(deck: str | Path | ParsedDeck) -> ParsedDeck:
    """``deck`` (a file name) read and composed once, as a
    :class:`~mbsim.deck.loader.ParsedDeck`; a ParsedDeck is returned as it is."""
    from mbsim.deck.loader import ParsedDeck, parse_deck, remember_deck

    if isinstance(deck, ParsedDeck):
        return deck
    return remember_deck(parse_deck(deck))  # study_columns finds it again by the text


def load_studies(deck: str | Path | ParsedDeck):
    """The deck's validated spec (``DeckSpec.studies`` holds the studies); ``deck`` a file
    name or a ParsedDeck."""
    return open_deck(deck).spec()


def list_studies(spec) -> list[tuple[str, str, list[str]]]:
    """(name, description, modes of its cases) of every study of a loaded deck."""
    return [
        (name, st["description"], sorted({c["mode"] for c in st["cases"]}))
        for name, st in spec.studies.items()
    ]


def study_names(spec, name: str) -> list[str]:
    """``[name]``, or every study for ``all``; an unknown name is a DeckError that lists
    the deck's studies."""
    if name == "all":
        return list(spec.studies)
    if name not in spec.studies:
        import difflib

        close = difflib.get_close_matches(name, list(spec.studies), n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        listed = ", ".join(spec.studies) or "the deck has none"
        raise DeckError(f"unknown study {name!r}{hint} (studies: {listed})", _where(spec))
    return [name]


def _where(spec):
    from mbsim.errors import Where

    return Where(spec.file, "studies")


# --------------------------------------------------------------------------- running


def overrides_of(case: dict) -> dict[str, str]:
    """A case's ``set`` as ``--set`` texts (JSON is YAML flow text)."""
    return {path: json.dumps(value) for path, value in case["set"].items()}


def case_model(deck: str | Path | ParsedDeck, case: dict,
               overrides: dict[str, str] | None = None):  # fmt: skip
    """(spec, model) of a study case: the case's scene, then its ``set`` (or `overrides`),
    applied to the parsed deck (:meth:`~mbsim.deck.loader.ParsedDeck.spec`, without
    validating the ``studies:`` section again), compiled."""
    from mbsim.model import compile_model

    overrides = overrides_of(case) if overrides is None else overrides
    spec = open_deck(deck).spec(case.get("scene"), overrides, studies=False)
    return spec, compile_model(spec)


def run_case(deck: str | Path | ParsedDeck, study: str, case: dict,
             path: str | Path) -> CaseOutcome:  # fmt: skip
    """Apply the case's scene and overrides to the deck (a file name or a ParsedDeck), run
    its analysis, write `path`.

    Never raises: a case whose loading or analysis raises is ``failed`` with the message
    (the exception logged at DEBUG level).  Module-level so that a process pool can run it.
    """
    from mbsim.api import run_model
    from mbsim.output import write_result

    t0 = time.perf_counter()
    out = CaseOutcome(case["name"], case["label"], case["mode"], STATUS_FAILED)
    overrides = overrides_of(case)
    try:
        spec, model = case_model(deck, case, overrides)
        out.warnings = list(spec.warnings)
        result = run_model(model, case["mode"], case["options"], deck=spec)
        result.settings.setdefault("overrides", overrides)
        if case["scene"]:
            result.settings.setdefault("scene", case["scene"])
        result.settings["study"] = {"study": study, "case": case["name"], "label": case["label"]}
        write_result(result, path)
    except Exception as exc:  # noqa: BLE001 - a case that raises is reported, the others run
        log.debug("study %s, case %s failed", study, case["name"], exc_info=True)
        out.message = str(exc) if isinstance(exc, MbsimError) else f"{type(exc).__name__}: {exc}"
        out.wall_time = time.perf_counter() - t0
        return out
    out.status, out.message, out.path = result.status, result.message, Path(path)
    out.result = result
    out.wall_time = time.perf_counter() - t0
    return out


def _run_in_pool(text: str, file: str, study: str, case: dict, path: str) -> CaseOutcome:
    from mbsim.deck.loader import parse_deck_cached

    try:
        deck = parse_deck_cached(text, file)  # once per worker process, not once per case
    except MbsimError as exc:
        return CaseOutcome(case["name"], case["label"], case["mode"], STATUS_FAILED, str(exc))
    out = run_case(deck, study, case, path)
    out.result = None  # the parent reads the file back (cheaper than pickling the Result)
    return out


@dataclass(frozen=True)
class _StudyTask:
    number: int  # index into the study's cases
    args: tuple  # _run_in_pool(*args)


def run_cases(
    deck: str | Path | ParsedDeck,
    study: str,
    cases: Sequence[dict],
    out_dir: Path,
    jobs: int = 1,
    on_case: Callable[[CaseOutcome], None] | None = None,
) -> list[CaseOutcome]:
    """Run `cases` (``jobs`` > 1: in that many processes, on :func:`mbsim.batch.run_batch`;
    each worker writes its case's file, read back here) into ``out_dir/<name>.h5``; `deck`
    a file name or a ParsedDeck (read once here).  Ctrl-C or SIGTERM while cases run in
    processes: the running ones are stopped, KeyboardInterrupt raised."""
    from mbsim.output import read_result

    out_dir.mkdir(parents=True, exist_ok=True)
    deck = open_deck(deck)
    paths = [str(out_dir / f"{c['name']}.h5") for c in cases]
    if jobs <= 1 or len(cases) == 1:
        outcomes = []
        for case, path in zip(cases, paths):
            outcomes.append(run_case(deck, study, case, path))
            if on_case:
                on_case(outcomes[-1])
        return outcomes
    from mbsim.batch import WorkerLost, run_batch

    outcomes: list[CaseOutcome | None] = [None] * len(cases)

    def finish(task: _StudyTask, out: CaseOutcome | WorkerLost) -> None:
        case = cases[task.number]
        if isinstance(out, WorkerLost):
            out = CaseOutcome(case["name"], case["label"], case["mode"], STATUS_FAILED,
                              out.message)
        if out.path is not None:
            out.result = read_result(out.path)
        outcomes[task.number] = out
        if on_case:
            on_case(out)

    tasks = [_StudyTask(i, (deck.text, deck.file, study, c, p))
             for i, (c, p) in enumerate(zip(cases, paths))]
    run_batch(tasks, _run_in_pool, finish, jobs=min(jobs, len(cases)))
    return [o for o in outcomes if o is not None]


def run_study(deck: str | Path | ParsedDeck, name: str, out_dir: str | Path = ".", jobs: int = 1,
              spec=None, on_case: Callable[[CaseOutcome], None] | None = None,
              dpi: float = 110) -> StudyOutcome:  # fmt: skip
    """Run every case of study `name` of `deck`, draw its figures, compute its numbers.

    Parameters
    ----------
    deck : the deck file, or the deck already read (:func:`open_deck`).
    name : the study (a key of the deck's ``studies:``).
    out_dir : files go to ``out_dir/<name>/``.
    jobs : cases run at once (processes); 1 runs them here, one after the other.
    spec : the deck already validated (``open_deck(deck).spec()``; saves validating it again).
    on_case : called with each CaseOutcome as it finishes (progress).
    dpi : resolution of the PNG figures.
    """
    from mbsim.output import save_figure

    t0 = time.perf_counter()
    deck = open_deck(deck)
    spec = spec if spec is not None else deck.spec()
    study_names(spec, name)
    st = spec.studies[name]
    folder = Path(out_dir) / name
    outcomes = run_cases(deck, name, st["cases"], folder, jobs, on_case)
    by_name = {o.name: o for o in outcomes}
    figures, problems = [], []
    for fig in st["figures"]:
        results = _results_for(st, fig["cases"], by_name)
        if not results:
            problems.append(f"{fig['where']}: figure {fig['name']}: no case gave results")
            continue
        try:
            figure = study_figure(fig, results)
        except (KeyError, IndexError, ValueError) as exc:
            problems.append(f"{fig['where']}: figure {fig['name']}: {str(exc).strip(chr(34))}")
            continue
        figures.append(save_figure(figure, folder / f"{fig['name']}.png", dpi=dpi))
    header, rows, values = number_table(st, outcomes, problems)
    return StudyOutcome(name, st["description"], folder, outcomes, figures, (header, rows),
                        values, time.perf_counter() - t0, problems)  # fmt: skip


def _results_for(st: dict, names: list[str], by_name: dict[str, CaseOutcome]):
    wanted = names or [c["name"] for c in st["cases"]]
    return [(by_name[n].label, by_name[n].result) for n in wanted
            if n in by_name and by_name[n].result is not None]  # fmt: skip


# --------------------------------------------------------------------------- derived columns


def study_columns(result: Result, selector: str):
    """The columns a figure or number selector names: a channel (``select_columns``), or one
    of two derived series that no analysis writes as a channel.

    - ``drivers.D.function``: driver D's function of time f(t) as the deck defines it (with
      the case's scene and overrides), at the output times: the input curve itself (the
      vehicle's rack displacement, which a dynamic run does not record).
    - ``A - B`` or ``A + B`` (spaces around the sign): the difference or sum of two
      one-column selectors (the compressor's motor torque, rotor driver minus twist driver).

    Raises KeyError, IndexError, ValueError as ``select_columns`` does.
    """
    from mbsim.output.export import Column, select_columns

    for sign in (" - ", " + "):
        if sign in selector:
            left, right = (study_columns(result, s.strip()) for s in selector.split(sign, 1))
            if len(left) != 1 or len(right) != 1:
                raise ValueError(f"{selector!r}: each side of {sign.strip()!r} must be one column")
            (a,), (b,) = left, right
            data = a.data - b.data if sign == " - " else a.data + b.data
            return [Column(selector, data, a.unit, selector, "")]
    parts = selector.split(".")
    if len(parts) == 3 and parts[0] == "drivers" and parts[2] == "function":
        from mbsim.deck.loader import parse_deck_cached
        from mbsim.functions import from_spec

        deck = parse_deck_cached(result.deck_text, result.deck_file or "<deck>")  # once
        spec = deck.spec(result.settings.get("scene"), result.settings.get("overrides") or {},
                         studies=False)  # fmt: skip
        if parts[1] not in spec.drivers:
            raise KeyError(f"no driver {parts[1]!r} (drivers: {', '.join(spec.drivers)})")
        from mbsim.constraints import DRIVERS

        driver = spec.drivers[parts[1]]
        f = from_spec(driver.function)
        data = np.asarray(f(np.asarray(result.t, float)), float) * np.ones(len(result.t))
        return [Column(selector, data, DRIVERS[driver.type].unit, selector, "")]
    return select_columns(result, selector)


# --------------------------------------------------------------------------- figures

LINESTYLES = ("-", "--", "-.", ":")


def study_figure(fig: dict, results: Sequence[tuple[str, Result]],
                 figsize: tuple[float, float] = (6.4, 4.2)):  # fmt: skip
    """One figure of a study: every channel of ``fig['y']`` from every case, one labelled
    curve per case (and per component or channel when there are several), the y values
    times ``fig['scale']``, x times ``fig['xscale']``.  ``fig['labels']`` (optional, one per
    curve of a case) replaces the channel and component names in the legend; with several
    cases each is preceded by the case label.

    Returns
    -------
    matplotlib.figure.Figure
        Axes labelled with the deck's ``xlabel``/``ylabel`` (default ``name [unit]``).

    Raises
    ------
    KeyError, IndexError
        A channel or component a result does not have (the message suggests close names).
    ValueError
        ``labels`` does not match the number of curves of a case; ``x`` is not one column.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from mbsim.output.export import header_name

    select_columns = study_columns
    figure = Figure(figsize=figsize, layout="constrained")
    FigureCanvasAgg(figure)
    ax = figure.add_subplot()
    colors = [f"C{i}" for i in range(10)]
    ylabel, xlabel = "", "time [s]"
    many = len(fig["y"]) > 1
    labels = fig.get("labels") or []
    for ci, (label, result) in enumerate(results):
        mark = "" if result.complete else " (incomplete)"
        if fig["x"] == "time":
            xdata = result.t
        else:
            xcols = select_columns(result, fig["x"])
            if len(xcols) != 1:
                raise ValueError(f"x {fig['x']!r} has {len(xcols)} components; name one")
            xdata, xlabel = xcols[0].data, header_name(xcols[0].name, xcols[0].unit)
        curves = []  # (selector, column, columns of its channel) of every curve of this case
        for sel in fig["y"]:
            cols = select_columns(result, sel)
            ylabel = ylabel or header_name(
                cols[0].channel if len(cols) > 1 else cols[0].name, cols[0].unit
            )
            curves += [(sel, col, len(cols)) for col in cols]
        if labels and len(labels) != len(curves):
            raise ValueError(f"labels: {len(labels)} given for {len(curves)} curves of case "
                             f"{label!r}; give one per channel or component")  # fmt: skip
        for k, (sel, col, ncols) in enumerate(curves):
            if labels:
                text = f"{label} {labels[k]}" if len(results) > 1 else labels[k]
            else:
                extra = (col.label or sel.rsplit(".", 1)[-1]) if (many or ncols > 1) else ""
                text = f"{label} {extra}".strip()
            ax.plot(np.asarray(xdata) * fig["xscale"], col.data * fig["scale"],
                    color=colors[ci % len(colors)], linestyle=LINESTYLES[k % 4],
                    label=text + mark)  # fmt: skip
    ax.set_xlabel(fig["xlabel"] or xlabel)
    ax.set_ylabel(fig["ylabel"] or ylabel)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize="small")
    if fig["title"]:
        ax.set_title(fig["title"])
    return figure


# --------------------------------------------------------------------------- numbers


def summary_value(result: Result, key: str) -> Any:
    """``summary.a.b`` -> result.summary['a']['b'], ``counters.steps`` ->
    result.counters['steps'] (KeyError naming the keys there)."""
    where, *parts = key.split(".")
    value: Any = result.summary if where == "summary" else result.counters
    for part in parts:
        if isinstance(value, dict) and part in value:
            value = value[part]
        elif isinstance(value, list) and part.isdigit() and int(part) < len(value):
            value = value[int(part)]
        else:
            have = ", ".join(value) if isinstance(value, dict) else type(value).__name__
            raise KeyError(f"no {key!r} in the result's {where} (there: {have})")
    return value


def number_values(result: Result, number: dict) -> list[tuple[str, Any]]:
    """[(column, value)] of one number for one result: one column per component of the
    selected channel (``name.x`` when it has several), or the summary or counter value."""
    if number["y"].startswith(("summary.", "counters.")):
        return [(number["name"], summary_value(result, number["y"]))]
    stat = STATS[number["stat"]]
    cols = study_columns(result, number["y"])
    out = []
    for col in cols:
        name = number["name"] if len(cols) == 1 else f"{number['name']}.{col.label}"
        out.append((name, stat(result.t, col.data * number["scale"], number)))
    return out


def _format(value: Any) -> str:
    if isinstance(value, (bool, np.bool_)):
        return str(bool(value))
    if isinstance(value, (int, float, np.floating, np.integer)):
        return f"{float(value):.6g}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_format(v) for v in value) + "]"
    return str(value)


def number_table(st: dict, outcomes: Sequence[CaseOutcome], problems: list[str] | None = None):
    """(header, rows, values): one row per case (label, status, wall time, then one column
    per number and component), values as text; `values` holds the raw values per case
    name.  Numbers that cannot be computed for a case are left blank and reported in
    `problems`."""
    problems = problems if problems is not None else []
    columns: list[str] = []
    values: dict[str, dict[str, Any]] = {o.name: {} for o in outcomes}
    for number in st["numbers"]:
        for o in outcomes:
            if o.result is None or (number["cases"] and o.name not in number["cases"]):
                continue
            try:
                pairs = number_values(o.result, number)
            except (KeyError, IndexError, ValueError) as exc:
                problems.append(f"{number['where']}: number {number['name']} for case "
                                f"{o.label}: {str(exc).strip(chr(34))}")  # fmt: skip
                continue
            for col, value in pairs:
                unit = "s" if number["stat"] in TIME_STATS else number["unit"]
                key = f"{col} [{unit}]" if unit else col
                if key not in columns:
                    columns.append(key)
                values[o.name][key] = value
    header = ["case", "mode", "status", "wall [s]"] + columns
    unsettled = {c for n in st["numbers"] if n["stat"] == "settle" for c in columns
                 if c == f"{n['name']} [s]" or c.startswith(f"{n['name']}.")}  # fmt: skip

    def text(values_of: dict, c: str) -> str:
        if c not in values_of:
            return ""
        v = values_of[c]
        if c in unsettled and isinstance(v, float) and np.isnan(v):
            return "does not settle"
        return _format(v)

    rows = [[o.label, o.mode, o.status, f"{o.wall_time:.3g}"]
            + [text(values[o.name], c) for c in columns]
            for o in outcomes]  # fmt: skip
    return header, rows, values


# --------------------------------------------------------------------------- thresholds


@dataclass
class Threshold:
    """Outcome of :func:`threshold`: the switch lies in [low, high]."""

    low: float  # the largest value tried that behaves like `lo`
    high: float  # the smallest value tried that behaves like `hi`
    runs: list[tuple[float, bool, float]]  # (value, criterion, wall s) per run, in order

    @property
    def value(self) -> float:
        return 0.5 * (self.low + self.high)


def threshold(deck: str | Path | ParsedDeck, case: dict, path: str, lo: float, hi: float,
              criterion: Callable[[Result], bool], rtol: float = 0.01,
              max_runs: int = 30) -> Threshold:  # fmt: skip
    """Bisection on one deck value (``path``, as for ``--set``) between `lo` and `hi`, at
    which ``criterion(result)`` of `case` (a study case: scene, set, mode, options) turns
    from False (at `lo`) to True (at `hi`), to a relative width `rtol`.  `deck`: a file
    name or a ParsedDeck (read once, not once per run).

    Raises
    ------
    MbsimError
        A run that fails; ValueError when the criterion does not differ at lo and hi.
    """
    from mbsim.api import run_model

    deck = open_deck(deck)
    runs: list[tuple[float, bool, float]] = []

    def judge(value: float) -> bool:
        t0 = time.perf_counter()
        overrides = overrides_of(case) | {path: json.dumps(float(value))}
        spec, model = case_model(deck, case, overrides)
        result = run_model(model, case["mode"], case.get("options", {}), deck=spec)
        verdict = bool(criterion(result))
        runs.append((float(value), verdict, time.perf_counter() - t0))
        log.info("threshold %s = %g: %s", path, value, verdict)
        return verdict

    if judge(lo) or not judge(hi):
        raise ValueError(
            f"{path}: the criterion must be False at {lo:g} and True at {hi:g} "
            f"(got {runs[0][1]} and {runs[-1][1] if len(runs) > 1 else '-'})"
        )
    while hi - lo > rtol * abs(hi) and len(runs) < max_runs:
        mid = 0.5 * (lo + hi)
        if judge(mid):
            hi = mid
        else:
            lo = mid
    return Threshold(lo, hi, runs)
