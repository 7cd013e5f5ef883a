"""The library entry points the CLI (and scripts) call: load a deck, run an analysis.

``ANALYSES`` maps a mode name to ``(module, function, description)``; each function has the
signature ``analysis(model, options: dict) -> Result``.
"""

from __future__ import annotations

import importlib
import time
from pathlib import Path

from mbsim.errors import MbsimError, UsageError
from mbsim.result import STATUS_INCOMPLETE, Result

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


def load_model(path, overrides=None, scene=None):
    """Load and validate a deck, compile it; returns (spec, model)."""
    from mbsim.deck import load_deck
    from mbsim.model import compile_model

    spec = load_deck(path, overrides=overrides, scene=scene)
    return spec, compile_model(spec)


def analysis_function(mode: str):
    if mode not in ANALYSES:
        raise UsageError(f"unknown mode {mode!r}; choose one of {', '.join(ANALYSES)}")
    mod, fn, _ = ANALYSES[mode]
    return getattr(importlib.import_module(mod), fn)


def run_model(model, mode: str, options: dict | None = None) -> Result:
    """Run one analysis. An MbsimError during the run becomes an incomplete Result only if the
    analysis itself did not already return one (analyses keep partial data themselves)."""
    fn = analysis_function(mode)
    t0 = time.perf_counter()
    result = fn(model, dict(options or {}))
    if not result.wall_time:
        result.wall_time = time.perf_counter() - t0
    return result


def output_path(template: str | None, deck: str | Path, mode: str, parameters: dict,
                scene: str | None = None) -> Path:
    """Default ``<deck stem>_<mode>.h5``; a template may use {mode}, {scene}, {deck} and any
    parameter name, e.g. ``gov_k{k}.h5``."""
    stem = Path(deck).stem
    if not template:
        return Path(f"{stem}_{mode}.h5" if not scene else f"{stem}_{scene}_{mode}.h5")
    fields = {k: (int(v) if float(v).is_integer() else v) for k, v in parameters.items()}
    fields.update(mode=mode, scene=scene or "", deck=stem)
    try:
        return Path(template.format(**fields))
    except (KeyError, IndexError, ValueError) as exc:
        raise UsageError(f"output name template {template!r}: unknown field {exc}; "
                        f"available: {', '.join(sorted(fields))}") from exc


__all__ = ["ANALYSES", "STATUS_INCOMPLETE", "MbsimError", "load_model", "output_path", "run_model"]
