"""The library entry points the CLI (and scripts) call: load a deck, run an analysis.

``ANALYSES`` maps a mode name to ``(module, function, description)``; each function has the
signature ``analysis(model, options) -> Result``.  A script runs a deck as the CLI does::

    spec, model = load_model("models/governor.yaml")
    result = run_model(model, "dynamic", {"t_end": 2.0}, deck=spec)

The compiled model does not carry its deck: ``deck=`` gives the run the deck's
``analysis:`` settings, ``analysis.assembly.hold``, ``outputs: only:`` and the text and
shapes stored in the results file (:func:`mbsim.options.run_options`, once, here).
"""

from __future__ import annotations

import importlib
import logging
import re
import string
import time
from pathlib import Path

from mbsim.errors import AnalysisError, MbsimError, UsageError, quote
from mbsim.result import STATUS_INCOMPLETE, Result

log = logging.getLogger(__name__)  # "mbsim.api": shown with -v

ANALYSES: dict[str, tuple[str, str, str]] = {
    "kinematic": ("mbsim.analyses.kinematic", "kinematic",
                  "driven system (DOF = 0): position, velocity, acceleration over time"),
    "dynamic": ("mbsim.analyses.dynamic", "dynamic",
                "motion under applied forces from the deck's initial conditions"),
    "inverse": ("mbsim.analyses.inverse", "inverse",
                "driving forces/torques and joint reactions of a driven system"),
    "equilibrium": ("mbsim.analyses.equilibrium", "equilibrium",
                    "static equilibrium (minimum potential energy, settling, steady spin)"),
    "linear": ("mbsim.analyses.linear", "linear",
               "eigenvalues, frequencies and modes about an equilibrium, steady spin or state"),
}


def load_model(path, overrides=None, scene=None, studies=True):
    """Load and validate a deck, compile it; returns (spec, model).  ``studies=False``
    skips validating the deck's ``studies:`` (see :func:`mbsim.deck.load_deck`)."""
    from mbsim.deck import load_deck
    from mbsim.model import compile_model

    spec = load_deck(path, overrides=overrides, scene=scene, studies=studies)
    return spec, compile_model(spec)


def analysis_function(mode: str):
    if mode not in ANALYSES:
        raise UsageError(f"unknown mode {mode!r}; choose one of {', '.join(ANALYSES)}")
    mod, fn, _ = ANALYSES[mode]
    return getattr(importlib.import_module(mod), fn)


def analysis_defaults(mode: str) -> dict:
    """The ``DEFAULTS`` of a mode's analysis module (t_start, t_end, step, tolerances)."""
    if mode not in ANALYSES:
        return {}
    return dict(getattr(importlib.import_module(ANALYSES[mode][0]), "DEFAULTS", {}))


def run_model(model, mode: str, options=None, deck=None, keep_start_failure: bool = False
              ) -> Result:
    """Run one analysis.  The analyses return their partial data themselves, marked
    incomplete; an AnalysisError raised before the first output (the assembly fails, the
    deck's formulas are not finite at the start) is raised, or with ``keep_start_failure``
    becomes an incomplete Result with no output time and its message (what ``mbsim run``
    writes, so that a failed run never leaves an earlier file of that name looking current).

    options: a dict of settings (None: none) or a :class:`~mbsim.options.RunOptions`
    (resolved already where the run was requested, the CLI: taken as they are, with their
    deck context; ``deck`` is not read then); deck: the validated
    :class:`~mbsim.deck.spec.DeckSpec` the model was compiled from (None: a run without
    deck settings, deck text or shapes).  A dict is merged and checked here, once
    (:func:`mbsim.options.run_options`): the analysis's defaults, the deck's ``analysis:
    <mode>:`` and ``options``; their names (mbsim.deck.schema.ANALYSIS_SETTINGS: a typo such
    as ``t_ennd`` is a UsageError with a suggestion), tolerances in (0, 1), steps > 0, the
    number of output times (mbsim.deck.limits), so a sweep or study case with ``step: 0`` is
    a UsageError too.  The analysis gets the merged RunOptions; the Result gets the deck
    text and shapes of their :class:`~mbsim.options.DeckContext`."""
    from mbsim.options import RunOptions, run_options

    fn = analysis_function(mode)
    if not isinstance(options, RunOptions):  # (resolved already by the CLI)
        options = run_options(mode, deck, options)
    t0 = time.perf_counter()
    log.info("%s analysis of %s: %d bodies, %d constraint equations", mode,
             getattr(model, "title", "") or "the model", model.nb, model.m)
    try:
        try:
            result = fn(model, options)
        except (ValueError, FloatingPointError, ArithmeticError) as exc:
            _overflow(mode, exc)
    except KeyboardInterrupt:  # before the analysis' own output loop, which keeps its outputs
        result = interrupted_result(mode)
    except AnalysisError as exc:
        if not keep_start_failure:
            raise
        import numpy as np

        result = Result(mode, np.empty(0), status=STATUS_INCOMPLETE, message=str(exc))
    context = options.context
    _apply_only(result, context.only)
    result.deck_text = context.text
    result.arrays.update(context.shapes)  # shapes/...: what viewers draw (docs/hdf5.md)
    if not result.wall_time:
        result.wall_time = time.perf_counter() - t0
    log.info("%s: %s in %.3g s; %s", mode, result.status, result.wall_time,
             ", ".join(f"{k} {v}" for k, v in result.counters.items()) or "no counters")
    return result


def interrupted_result(mode: str) -> Result:
    """The result of a run stopped by Ctrl-C or SIGTERM before its first output (while
    it assembled or set up): no output time, marked incomplete, so that it is still written
    and says why (the analyses catch an interrupt in their output loops themselves)."""
    import numpy as np

    return Result(mode, np.empty(0), status=STATUS_INCOMPLETE,
                  message="interrupted (Ctrl-C or SIGTERM) before the first output")


def _overflow(mode: str, exc: Exception) -> None:
    """Safety net for overflow an analysis does not guard itself (mbsim.core guards the KKT
    solve): LAPACK's "array must not contain infs or NaNs", "SVD did not converge" become an
    AnalysisError (exit 1).  Anything else is a bug and keeps its traceback."""
    import numpy as np

    from mbsim.errors import AnalysisError

    text = " ".join(str(exc).split())
    if not (isinstance(exc, (np.linalg.LinAlgError, FloatingPointError, OverflowError))
            or "inf" in text or "NaN" in text):  # fmt: skip
        raise exc
    raise AnalysisError(f"{mode} analysis: the numbers overflowed ({text}); check the deck's "
                        "magnitudes (values such as 1e308)") from None


def _apply_only(result, patterns) -> None:
    """Drop the channels the deck's ``outputs: only:`` (slash ``patterns``, None: all) does
    not select (the recorder already skipped computing most of them; monitors and
    multipliers are added by the analyses)."""
    from mbsim.measures import selected

    if patterns is not None:
        for path in [p for p in result.channels if not selected(p, patterns)]:
            del result.channels[path]


# A format spec of an -o field: fill/align, sign, zero padding, width and precision of at most
# two digits, a number type: `{ell:.3f}`, `{k:05d}`, `{mode:>8}`; nothing that builds a name of
# gigabytes (`{mode:>2000000000}`) or nests fields.
TEMPLATE_SPEC = re.compile(r"(?:[^{}]?[<>^=])?[+ -]?0?\d{0,2}(?:\.\d{1,2})?[bdeEfFgGnosxX%]?")
TEMPLATE_CHARS = 1000  # the template and the name it gives, characters


def output_path(template: str | None, deck: str | Path, mode: str, parameters: dict,
                scene: str | None = None) -> Path:
    """Default ``<deck stem>_<mode>.h5``; a template may use the fields ``{deck}``,
    ``{mode}``, ``{scene}`` and any parameter name, e.g. ``gov_k{k}.h5``, each a plain name
    with at most a short format spec (:data:`TEMPLATE_SPEC`: ``{ell:.3f}``); attribute or
    index access (``{mode.__class__}``), conversions (``{mode!r}``) and wide or nested specs
    are UsageErrors (exit 2) before anything runs."""
    stem = Path(deck).stem
    if template is not None and not template.strip():
        raise UsageError("-o: an empty file name (an unset shell variable?); give a file name")
    if template is None:
        return Path(f"{stem}_{mode}.h5" if not scene else f"{stem}_{scene}_{mode}.h5")
    fields = {k: (int(v) if float(v).is_integer() else v) for k, v in parameters.items()}
    fields.update(mode=mode, scene=scene or "", deck=stem)
    available = f"available: {', '.join(sorted(fields))}"
    what = f"output name template {quote(template)}"
    if len(template) > TEMPLATE_CHARS:
        raise UsageError(f"{what}: longer than {TEMPLATE_CHARS} characters")
    try:
        parts = list(string.Formatter().parse(template))
    except ValueError as exc:  # a lone '{' or '}'
        raise UsageError(f"{what}: {exc} (write {{{{ and }}}} for braces)") from None
    for _text, name, spec, conversion in parts:
        if name is None:
            continue
        if name not in fields:
            plain = re.match(r"[A-Za-z_][A-Za-z_0-9]*", name)
            if plain and plain.group() != name and plain.group() in fields:
                raise UsageError(f"{what}: field {quote('{' + name + '}')}: only plain "
                                 f"names, no attribute or index access; {available}")
            raise UsageError(f"{what}: unknown field {quote(name or '{}')}; {available}")
        if conversion is not None:
            raise UsageError(f"{what}: field {{{name}!{conversion}}}: no conversions; "
                             f"write {{{name}}}")
        if spec and not TEMPLATE_SPEC.fullmatch(spec):
            raise UsageError(f"{what}: field {{{name}}}: format {quote(spec)} not allowed "
                             "(a width or precision of at most two digits, e.g. {ell:.3f})")
    try:
        name = template.format(**fields)
    except (ValueError, TypeError) as exc:  # '{mode:.3f}': a number format for a text
        raise UsageError(f"{what}: {exc}") from None
    if len(name) > TEMPLATE_CHARS:
        raise UsageError(f"{what}: gives a name longer than {TEMPLATE_CHARS} characters")
    return Path(name)


__all__ = ["ANALYSES", "STATUS_INCOMPLETE", "MbsimError", "load_model", "output_path", "run_model"]
