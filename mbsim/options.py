"""Analysis options, merged and validated once, where a run is requested.

:func:`resolve_options` takes an analysis's defaults, the deck's settings for it
(``analysis: <mode>:``) and the caller's overrides (command line, API, sweep or study case)
and returns :class:`RunOptions`: the merged settings, read-only, with which keys the caller
gave.  Every problem is one error naming where the value came from: a command-line option
(``--rtol: rtol must be > 0 and < 1 ...``, UsageError, exit 2) or the deck key
(``models/x.yaml: analysis.dynamic.rtol: ...``, DeckError, exit 2).  What it checks:

- names: every key is a setting of the mode (:func:`mbsim.deck.schema.setting_name_problems`,
  a typo gets a suggestion);
- values: tolerances in (0, 1), positive steps, t_end > t_start, the number of output
  times (:func:`mbsim.deck.limits.setting_problems`);
- dynamic: rtol, atol, accuracy, estimate_ratio, estimate_method, step, h, h_max
  (:func:`dynamic_problems`); atol follows rtol when not given (:data:`ATOL_PER_RTOL`).

What a run takes from its deck besides the compiled model travels with the options, read
once where the run is requested (:func:`run_options`): :class:`DeckContext` holds the deck's
``analysis:`` settings of every mode (an analysis that runs another, such as linear about
the deck's equilibrium, merges them with :meth:`RunOptions.within`), the assembly's
``hold``, the output patterns ``outputs: only:``, the deck text and the shapes stored in the
results file.  The compiled :class:`~mbsim.model.Model` holds physics and names only.

Only light modules are imported here (no numpy), so the deck loader and ``mbsim check`` can
use it.  The callers: :func:`mbsim.api.run_model` (``deck=``), the CLI's ``run``, sweep and
study cases (:func:`run_options`), the loader's ``analysis:`` section, and the analyses
called directly (:func:`analysis_options`: no deck settings then).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

from mbsim.errors import DeckError, UsageError, Where

ATOL_PER_RTOL = 1e-2  # atol when not given: rtol / 100 (as mbsim bench's ladder)
ESTIMATE_METHODS = ("coarse", "tighter")  # mbsim.analyses.estimate
HOLD_COORDS = ("x", "y", "z", "e0", "e1", "e2", "e3")  # analysis.assembly.hold: BODY.COORD


@dataclass(frozen=True)
class DeckContext:
    """What a run takes from its deck besides the compiled model (:func:`deck_context`).

    analysis: mode -> the deck's settings (``analysis: <mode>:``), for an analysis that runs
    another (:meth:`RunOptions.within`); hold: ``analysis.assembly.hold``, coordinates kept
    at their estimates by the assembly ('BODY.COORD', checked by the loader); only: the
    output channel patterns of ``outputs: only:`` (slash form; None: every channel); text:
    the deck's YAML text and shapes: what viewers draw (``shapes/...`` arrays,
    docs/hdf5.md), both stored in the results file.  ``DeckContext()``: a run without a deck."""

    analysis: Mapping = field(default_factory=dict)
    hold: tuple[str, ...] = ()
    only: tuple[str, ...] | None = None
    text: str = ""
    shapes: Mapping = field(default_factory=dict)


NO_DECK = DeckContext()


def deck_context(spec, shapes: bool = True) -> DeckContext:
    """The :class:`DeckContext` of a validated deck (:class:`~mbsim.deck.spec.DeckSpec`);
    ``shapes``: also build the shapes stored in the results file (imports numpy)."""
    only = getattr(spec, "output_only", None)
    arrays = {}
    if shapes:
        from mbsim.view.geometry import scene_arrays

        arrays = scene_arrays(spec)
    return DeckContext(
        analysis=MappingProxyType({m: MappingProxyType(dict(s)) for m, s in spec.analysis.items()}),
        hold=tuple(str(h) for h in spec.analysis.get("assembly", {}).get("hold") or ()),
        only=None if only is None else tuple(p.replace(".", "/").strip("/") for p in only),
        text=spec.text or "", shapes=MappingProxyType(arrays))


class RunOptions(Mapping):
    """The settings of one run: ``values`` (read-only), ``given`` (the keys the caller gave:
    command line, API, case), ``deck`` (the keys the deck's ``analysis:`` gave), ``mode``,
    and ``context``, what the run takes from its deck besides the model
    (:class:`DeckContext`)."""

    def __init__(self, mode: str, values: dict, given, deck, context: DeckContext = NO_DECK):
        self.mode = mode
        self.values = MappingProxyType(dict(values))
        self.given = frozenset(given)
        self.deck = frozenset(deck)
        self.context = context

    def __getitem__(self, key):
        return self.values[key]

    def __iter__(self) -> Iterator:
        return iter(self.values)

    def __len__(self) -> int:
        return len(self.values)

    def replace(self, **values) -> RunOptions:
        """The same settings with ``values`` set by code (a progress callback): not checked
        again, and not counted as given."""
        return RunOptions(self.mode, {**self.values, **values}, self.given, self.deck,
                          self.context)

    def within(self, mode: str, overrides: Mapping | None = None,
               defaults: Mapping | None = None) -> RunOptions:
        """The options of a ``mode`` analysis this run runs (equilibrium's settling run,
        linear about the deck's equilibrium): the deck's ``analysis: <mode>:`` under
        ``overrides`` (code's, checked), the same :class:`DeckContext`."""
        return context_options(mode, self.context, overrides, defaults)

    def __repr__(self) -> str:
        return f"RunOptions({self.mode!r}, {dict(self.values)!r})"


def resolve_options(mode: str, deck_settings: Mapping | None = None,
                    overrides: Mapping | None = None, *, defaults: Mapping | None = None,
                    option_names: Mapping[str, str] | None = None,
                    label: str = "--{option}", file: str | None = None,
                    where_of: Callable[[str], Where] | None = None,
                    internal: bool = True, context: DeckContext = NO_DECK) -> RunOptions:
    """Merge ``defaults`` < ``deck_settings`` < ``overrides`` (None values in overrides are
    not given) and validate the result once (module doc); returns :class:`RunOptions`.

    mode: the analysis (``mbsim.api.ANALYSES``); defaults: its ``DEFAULTS`` (None: looked up
    with :func:`mbsim.api.analysis_defaults`, which imports the analysis); option_names:
    {setting: command-line option} for the messages (an unknown setting given under one:
    "does not apply to --mode"); label: how other settings the caller gave are named
    (``{option}``: the key with dashes, ``{key}``); file, where_of:
    where a deck value is (default ``Where(file, 'analysis.<mode>.<key>')``); internal:
    accept the settings code passes (progress, q0, qd0, h0); context: what the run takes
    from its deck besides the model (:func:`run_options` fills it)."""
    from mbsim.deck.limits import setting_problems
    from mbsim.deck.schema import setting_name_problems

    if defaults is None:
        from mbsim.api import analysis_defaults

        defaults = analysis_defaults(mode)
    deck = dict(deck_settings or {})
    given = {k: v for k, v in (overrides or {}).items() if v is not None}
    names = dict(option_names or {})

    def fail(key, message):
        if key in given:
            option = names.get(key) or label.format(option=key.replace("_", "-"), key=key)
            raise UsageError(f"{option}: {message}")
        where = where_of(key) if where_of else Where(file or "<options>", f"analysis.{mode}.{key}")
        raise DeckError(message, where)

    for key, message in setting_name_problems(mode, list(given), internal=internal):
        raise UsageError(f"{names[key]} does not apply to --mode {mode}" if key in names
                         else message)
    for key, message in setting_problems({**deck, **given}, defaults):
        fail(key, message)
    values = {**defaults, **deck, **given}
    if mode == "dynamic":
        for key, message in dynamic_problems(values):
            fail(key, message)
        if values.get("atol") is None and values.get("rtol") is not None:
            # atol follows rtol: 1e-8 at the default rtol 1e-6
            values["atol"] = ATOL_PER_RTOL * float(values["rtol"])
    return RunOptions(mode, values, given, deck, context)


def context_options(mode: str, context: DeckContext = NO_DECK,
                    overrides: Mapping | None = None,
                    defaults: Mapping | None = None) -> RunOptions:
    """The options of a ``mode`` analysis run by code with a deck's ``context`` (an analysis
    running another, ``mbsim bench``'s runs): the deck's ``analysis: <mode>:`` under
    ``overrides`` (checked) over ``defaults`` (None: the analysis's)."""
    return resolve_options(mode, context.analysis.get(mode, {}), overrides, defaults=defaults,
                           label="analysis setting {key}", context=context)


def run_options(mode: str, spec=None, overrides: Mapping | None = None, *,
                option_names: Mapping[str, str] | None = None,
                label: str = "analysis setting {key}", internal: bool = True,
                shapes: bool = True) -> RunOptions:
    """The options of a run of ``mode`` requested on the deck ``spec`` (a validated
    :class:`~mbsim.deck.spec.DeckSpec`, with its scene and ``--set`` values applied; None: no
    deck): :func:`resolve_options` over the analysis's defaults, the deck's ``analysis:
    <mode>:`` and ``overrides`` (command line, API, case), with the run's
    :class:`DeckContext` (:func:`deck_context`).  The one call the CLI, the API, sweeps and
    studies make; option_names, label, internal: as :func:`resolve_options`; shapes: build
    the shapes for the results file (False: a run whose result is not written)."""
    if spec is None:
        return resolve_options(mode, {}, overrides, option_names=option_names, label=label,
                               internal=internal)
    return resolve_options(mode, spec.analysis.get(mode, {}), overrides,
                           option_names=option_names, label=label, file=spec.file,
                           internal=internal, context=deck_context(spec, shapes))


def dynamic_problems(opt: Mapping) -> list[tuple[str, str]]:
    """[(key, message)] for a dynamic run's rtol, atol, accuracy (finite, in (0, 1)),
    estimate_ratio (> 1), estimate_method (one of ESTIMATE_METHODS), step, h, h_max (finite,
    > 0): a run that would hang or fail with a traceback otherwise."""
    out = []

    def number(v):
        try:
            return float(v)
        except (TypeError, ValueError):
            return None

    for key in ("rtol", "atol", "accuracy"):
        v = opt.get(key)
        if v is None:
            continue
        x = number(v)
        if x is None or isinstance(v, bool) or not (math.isfinite(x) and 0 < x < 1):
            want = ("a position error in m (and rad) in (0, 1), e.g. 1e-6" if key == "accuracy"
                    else "a number in (0, 1), e.g. 1e-6 (0 would ask for exact arithmetic)")
            out.append((key, f"expected {want}, got {v!r}"))
    r = number(opt.get("estimate_ratio", 5.0))
    if r is None or not (math.isfinite(r) and r > 1):
        out.append(("estimate_ratio", f"expected a number > 1, e.g. 5, got "
                                      f"{opt.get('estimate_ratio')!r}"))
    if opt.get("estimate_method", "coarse") not in ESTIMATE_METHODS:
        out.append(("estimate_method", f"expected {' or '.join(ESTIMATE_METHODS)}, got "
                                       f"{opt.get('estimate_method')!r}"))
    for key in ("step", "h", "h_max"):
        v = opt.get(key)
        if v is not None and not (isinstance(v, (int, float)) and not isinstance(v, bool)
                                  and math.isfinite(v) and v > 0):
            out.append((key, f"expected a positive time in s, got {v!r}"))
    return out


def analysis_options(mode: str, model, options, defaults: Mapping) -> RunOptions:
    """The options of an analysis called with ``options``: as they are when resolved where
    the run was requested (:func:`run_options`: :func:`mbsim.api.run_model`, the CLI), else
    a dict (or None) merged here over the analysis's ``defaults`` and checked, without deck
    settings (direct calls: scripts, tests; the model does not carry its deck)."""
    if isinstance(options, RunOptions):
        return options
    return resolve_options(mode, {}, options, defaults=defaults,
                           file=getattr(model, "file", None), label="analysis setting {key}")
